"""The platform interface on both worlds: the thesis' 2-link arm and the hydraulic machine.

Each platform owns its sensor set, machine loader, noise presets, the one motion table that
``simulate`` runs, plausibility rules and default discard; ``platform_for`` tells which platform
a dataset, sensor set, machine or name belongs to.
"""

from __future__ import annotations

import importlib

import pytest

from excavator_payload.data.schema import MACHINE_SENSORS, THESIS_SENSORS
from excavator_payload.errors import DatasetError, ExcavatorPayloadError, MachineError
from excavator_payload.model.machine import load_machine
from excavator_payload.platforms import HYDRAULIC, PLATFORMS, THESIS, Platform, platform_for
from excavator_payload.simulation import generate

#: (platform, its sensor set, a machine preset of it, the other world's preset, Hz, default
#: discard, default noise, default motion)
WORLDS = [
    (THESIS, THESIS_SENSORS, "cat345c", "cat345c-hydraulic", 20.0, 81, "thesis", "nmpc"),
    (HYDRAULIC, MACHINE_SENSORS, "cat345c-hydraulic", "cat345c", 100.0, 100, "field", "swing"),
]


@pytest.fixture(scope="module")
def datasets():
    """One small simulated dataset per platform."""
    return {THESIS.name: generate.simulate_dataset(2, seed=3, motion="minimum-jerk", workers=1, progress=False),
            HYDRAULIC.name: generate.simulate_dataset(1, seed=5, machine="cat345c-hydraulic", motion="work-cycle",
                                                      workers=1, progress=False)}


def test_both_platforms_are_registered_by_name():
    assert PLATFORMS == {"thesis": THESIS, "hydraulic": HYDRAULIC}
    assert all(isinstance(p, Platform) for p in PLATFORMS.values())


@pytest.mark.parametrize("platform, sensors, preset, other, rate, discard, noise, motion", WORLDS)
def test_platform_for_resolves_every_handle(platform, sensors, preset, other, rate, discard, noise, motion,
                                            datasets):
    machine = load_machine(preset)
    assert platform_for(machine) is platform
    assert platform_for(sensors) is platform
    assert platform_for(sensors.name) is platform  # "thesis" / "machine"
    assert platform_for(platform.name) is platform  # "thesis" / "hydraulic"
    assert platform_for(platform) is platform
    assert platform_for(datasets[platform.name]) is platform
    assert platform.carries(datasets[platform.name]) and platform.carries(sensors)
    assert not platform.carries(datasets[platform_for(load_machine(other)).name])
    # a sensor set's name, as saved model folders hold it
    assert platform.carries(sensors.name) and not platform.carries(platform_for(load_machine(other)).sensors.name)
    assert not platform.carries(None) and not platform.carries("crane")


def test_runs_reads_the_estimators_declared_sensor_sets():
    from excavator_payload.estimators.registry import estimator_class

    calibrated = estimator_class("calibrated")
    assert THESIS.runs(calibrated) and HYDRAULIC.runs(calibrated) and HYDRAULIC.runs(calibrated("cat345c-hydraulic"))
    ekf = estimator_class("ekf")  # issue 28: the Kalman filters left the machine set
    assert THESIS.runs(ekf) and not HYDRAULIC.runs(ekf)

    class ThesisOnly:
        SENSOR_SETS = ("thesis",)

    assert THESIS.runs(ThesisOnly) and not HYDRAULIC.runs(ThesisOnly)
    assert not THESIS.runs(object())  # declares nothing: runs nowhere


def test_platform_for_refuses_what_belongs_to_no_platform():
    with pytest.raises(ExcavatorPayloadError, match="unknown platform 'crane'"):
        platform_for("crane")
    with pytest.raises(ExcavatorPayloadError, match="belongs to no platform"):
        platform_for(3.0)


@pytest.mark.parametrize("platform, sensors, preset, other, rate, discard, noise, motion", WORLDS)
def test_sensor_set_rate_and_default_discard(platform, sensors, preset, other, rate, discard, noise, motion):
    assert platform.sensors is sensors
    assert platform.sample_rate == rate
    assert platform.default_discard() == discard
    # evaluate's default is the platform's (81 samples as thesis Table 7.1; the machine's first second)
    from excavator_payload.evaluation.metrics import default_discard

    assert default_discard(sensors) == discard


@pytest.mark.parametrize("platform, sensors, preset, other, rate, discard, noise, motion", WORLDS)
def test_noise_presets_are_the_simulators(platform, sensors, preset, other, rate, discard, noise, motion):
    from excavator_payload.simulation import machine_sensors, sensors as thesis_sensors

    presets = thesis_sensors.PRESETS if platform is THESIS else machine_sensors.PRESETS
    assert platform.noise_presets is presets  # one table, named in two places
    assert platform.noise().name == noise
    assert platform.noise("none").name == "none"
    assert platform.noise(presets[noise]) is presets[noise]  # an object passes through
    with pytest.raises(ExcavatorPayloadError, match="unknown noise preset 'loud'"):
        platform.noise("loud")


def test_the_field_preset_differs_between_the_worlds():
    # "field" is a name of both platforms, with each world's own sensors behind it
    assert THESIS.noise("field").std["boom_torque"] == 15_000.0
    assert HYDRAULIC.noise("field").pressure_noise == 3.0e4


@pytest.mark.parametrize("platform, sensors, preset, other, rate, discard, noise, motion", WORLDS)
def test_machine_loader_takes_its_own_machines_only(platform, sensors, preset, other, rate, discard, noise,
                                                    motion):
    machine = platform.load_machine(preset)
    assert platform.owns(machine) and machine.name == preset
    assert platform.load_machine(machine) is machine  # loaded once: an object passes through
    with pytest.raises(MachineError, match=f"is not {platform.label}"):
        platform.load_machine(other)
    assert not platform.owns(load_machine(other))


@pytest.mark.parametrize("platform, sensors, preset, other, rate, discard, noise, motion", WORLDS)
def test_one_motion_table_drives_simulate(platform, sensors, preset, other, rate, discard, noise, motion):
    machine = load_machine(preset)
    assert generate.motions_for(machine) is platform.motions
    assert list(platform.motions)[0] == motion
    for name, entry in platform.motions.items():
        module, _, function = entry.experiment.partition(":")
        assert callable(getattr(importlib.import_module(module), function)), name
        assert entry.chunk_size(200) >= 1
    spec = generate.make_spec(2, 1, machine, None, False, None)
    assert (spec.motion, spec.noise.name) == (motion, noise)
    with pytest.raises(ExcavatorPayloadError, match=f"unknown motion 'dance' for {platform.label}: choose one of "
                                                    + ", ".join(platform.motions)):
        generate.make_spec(2, 1, machine, None, False, "dance")


def test_each_platform_refuses_the_others_settings():
    with pytest.raises(ExcavatorPayloadError, match="apply to a hydraulic machine only"):
        generate.make_spec(2, 1, load_machine("cat345c"), None, False, None, session=1)
    with pytest.raises(ExcavatorPayloadError, match="frozen noise is a thesis-setting study"):
        generate.make_spec(2, 1, load_machine("cat345c-hydraulic"), None, False, None, frozen_noise_seed=3)
    motion, _, options = HYDRAULIC.simulation_settings(load_machine("cat345c-hydraulic"), "shift", None,
                                                       session=4, truck_target=20_000.0)
    assert motion == "shift" and options == {"session": 4, "truck_target": 20_000.0}


@pytest.mark.parametrize("platform", [THESIS, HYDRAULIC])
def test_a_simulated_run_carries_its_platforms_metadata(platform, datasets):
    data = datasets[platform.name]
    assert data.meta["sensor_set"] == platform.sensors.name
    assert data.meta["sample_rate"] == platform.sample_rate
    extra = {"session", "true_sensor_offsets"}
    assert extra <= set(data.meta) if platform is HYDRAULIC else not extra & set(data.meta)


def test_plausibility_rules_are_the_platforms(datasets):
    data = datasets[HYDRAULIC.name]
    HYDRAULIC.check_plausible(data.frame, data.machine(), "ok.parquet")  # a correct wiring passes
    swapped = data.frame.copy()
    swapped[["boom_head_pressure", "boom_rod_pressure"]] = data.frame[["boom_rod_pressure",
                                                                      "boom_head_pressure"]].to_numpy()
    with pytest.raises(DatasetError, match="'boom_head_pressure' and 'boom_rod_pressure' swapped"):
        HYDRAULIC.check_plausible(swapped, data.machine(), "bad.parquet")
    thesis = datasets[THESIS.name]
    THESIS.check_plausible(thesis.frame, thesis.machine(), "thesis.parquet")  # no chambers to swap
    assert THESIS.sensors.cylinder_chambers == () and HYDRAULIC.sensors.cylinder_chambers == (
        "boom", "dipper", "bucket")
