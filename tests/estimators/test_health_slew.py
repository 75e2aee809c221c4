"""The slew rate's partner on a slope (estimators/health_slew.py): the house tilt's direction
turns by −ψ in the model, the window's slope reads a slew-rate scale error, and the monitor names
it ``gain`` (slew rate and both tilts, FMI 13 on the bus) on a slope, never on clean work nor on
level ground."""

import math

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators import health_slew as S
from excavator_payload.estimators.health import GAIN_MIN_STD, for_sensor_set
from excavator_payload.model.hydraulic import hydraulic_symbolic
from excavator_payload.runtime import dbc
from excavator_payload.runtime.dm1 import DM1Transmitter, decode_dm1
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

SIGNALS = list(MACHINE_SENSORS.signals)
SLEW = SIGNALS.index("slew_rate")


def test_the_model_turns_the_tilts_direction_against_the_slew():
    """The premise, from the model's own rotations (HydraulicArmModel.house_inclination): on a
    tilted ground the house's (sin pitch, sin roll) keeps its size and its direction turns by −ψ."""
    f = hydraulic_symbolic().functions["house_inclination"]
    for tilt in ([0.06, -0.05], [-0.1, 0.02], [0.0, 0.12]):
        psi = np.linspace(-2.5, 2.5, 11)
        pr = np.array([np.array(f([0.3, -1.0, -0.5, p], tilt)).ravel() for p in psi])
        sp, sr = np.sin(pr[:, 0]), np.sin(pr[:, 1])
        np.testing.assert_allclose(np.hypot(sp, sr), np.hypot(sp[0], sr[0]), rtol=1e-12)
        np.testing.assert_allclose(np.unwrap(np.arctan2(sr, sp)) - math.atan2(sr[0], sp[0]), -(psi - psi[0]),
                                   atol=1e-12)


@pytest.fixture(scope="module")
def slope():
    """Work cycles on a ground tilted about 9° (seed 32 of the ``slopes`` motion), session 2."""
    ds = simulate_machine_dataset(1, seed=32, session=2, motion="slopes")
    assert np.hypot(np.sin(ds.frame["house_pitch"]), np.sin(ds.frame["house_roll"])).min() > 2 * S.SLEW_TILT_MIN
    return ds


def _slopes(values, period=0.01, n=201, every=5):
    terms = np.array([S.house_terms(p, r) for p, r in values[:, [SIGNALS.index("house_pitch"),
                                                                 SIGNALS.index("house_roll")]]])
    return np.array([S.slew_gain_slope(terms[end - n:end], values[end - n:end, SLEW], period, GAIN_MIN_STD)
                     for end in range(n, len(values) + 1, every)])


def test_the_windows_slope_reads_the_scale_error(slope):
    values = slope.frame[SIGNALS].to_numpy(float)
    clean = _slopes(values)
    judged = np.isfinite(clean)
    assert judged.sum() > 50  # the house slews on the slope
    assert np.abs(clean[judged]).max() < S.SLEW_GAIN_LIMIT
    for gain in (0.8, 1.25):
        bad = values.copy()
        bad[:, SLEW] *= gain
        got = _slopes(bad)[judged]
        assert np.median(got) == pytest.approx(1 - gain, abs=0.04)  # −e for a rate × (1 + e)
    level = values.copy()  # the same motion on (nearly) level ground: the direction is noise
    level[:, [SIGNALS.index("house_pitch"), SIGNALS.index("house_roll")]] *= 0.2
    assert np.isnan(_slopes(level)).all()


def _run(values, times):
    m = for_sensor_set(MACHINE_SENSORS)
    return [m.step(t, v) for t, v in zip(times, values)]


def test_the_monitor_names_a_slew_rate_scale_error_on_a_slope(slope):
    values = slope.frame[SIGNALS].to_numpy(float)
    times = slope.frame["time"].to_numpy(float)
    assert not any(":gain" in f for f in _run(values, times))
    bad = values.copy()
    bad[500:, SLEW] *= 0.75
    faults = _run(bad, times)
    named = [k for k, f in enumerate(faults) if "slew_rate:gain" in f]
    assert named and named[0] >= 500 and times[named[0]] - times[500] < 2.0
    assert {"slew_rate:gain", "house_pitch:gain", "house_roll:gain"} <= set(faults[named[0]].split(","))
    # once named it stays named while no window is judged (the house at rest): no gap in the name
    # shorter than a judged window
    assert len(named) > 0.5 * (len(times) - named[0])
    # a stuck house pitch is not a scale error: the check waits
    stuck = values.copy()
    stuck[800:1100, SIGNALS.index("house_pitch")] = stuck[799, SIGNALS.index("house_pitch")]
    assert not any("slew_rate:gain" in f for f in _run(stuck, times))


def test_a_named_slew_rate_gain_goes_on_the_bus_as_fmi_13():
    tx = DM1Transmitter(MACHINE_SENSORS)
    spn = {s.signal: s.spn for m in dbc.sensor_layout(MACHINE_SENSORS) for s in m.signals}
    sent = tx.update(1.0, "house_pitch:gain,house_roll:gain,slew_rate:gain")
    assert sent
    assert (spn["slew_rate"], 13, 1) in decode_dm1(b"".join(_payload(sent)))[1]


def _payload(frames):
    """The DM1's bytes from its frames (one frame, or BAM: TP.CM then TP.DT)."""
    from excavator_payload.runtime.dm1 import reassemble

    if len(frames) == 1:
        return [bytes(frames[0].data)]
    return reassemble(frames)
