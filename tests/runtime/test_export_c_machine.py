"""C export of the machine sensor set's estimators (``inverse-dynamics`` and ``calibrated``
fitted on pressure + IMU data): compiles cleanly under strict C99 and equals Python's ``estimate``
(double: 1e-6 relative, float: 0.1 kg), status codes and ``ep_sigma`` included, on simulated
machine experiments with faults injected."""

import copy
import re
import subprocess

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.runtime.c_harness import STRICT_FLAGS, c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

from .test_export_c import _assert_c_equals_python

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")


@pytest.fixture(scope="module")
def machine_swings():
    """Three swings of the hydraulic machine (field noise, 100 Hz)."""
    return simulate_machine_dataset(3, seed=3)


@pytest.fixture(scope="module")
def machine_faulty(machine_swings):
    """The swings with bad samples: a NaN pressure, a pressure above 1000 bar, a repeated
    time, time going back, a house inclination whose ground tilt has no arcsine (the
    calibrated kernel's state goes NaN and restarts), one-frame glitches (the kernels'
    outlier test), a 0.2 s gap (bridged) and a 2 s gap (a restart)."""
    frame = machine_swings.frame.copy()
    ids = list(machine_swings.experiment_ids)
    rows = {e: frame.index[frame["experiment"] == e] for e in ids}
    r0, r1, r2 = (rows[e] for e in ids)
    frame.loc[r0[30], "boom_head_pressure"] = np.nan
    frame.loc[r0[300], "dipper_rod_pressure"] = 2e8
    frame.loc[r0[500], "time"] = frame.loc[r0[499], "time"]
    frame.loc[r1[400], "time"] = frame.loc[r1[399], "time"] - 0.5
    frame.loc[r1[700:705], ["house_pitch", "house_roll"]] = 0.99  # five frames: not one glitch
    # one-frame glitches for the outlier test: a pressure, an angle, a rate, one next to a gap
    frame.loc[r0[100], "boom_head_pressure"] += 5e6
    frame.loc[r1[200], "dipper_angle"] += 0.05
    frame.loc[r2[100], "slew_rate"] -= 0.5
    frame.loc[r2[222], "bucket_rod_pressure"] += 8e6
    drop = list(r2[200:220]) + list(r2[600:800])
    frame = frame.drop(index=drop).reset_index(drop=True)
    return Dataset(frame, machine_swings.meta)


def _machine_models(data):
    yield "inverse-dynamics", create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(data)
    for low_speed in ("skip", "downweight", "model"):  # reporting from the first information
        yield f"calibrated-{low_speed}", create_estimator(
            "calibrated", machine="cat345c-hydraulic-3pct", low_speed=low_speed, wait_for_boom="no").fit(data)
    yield "calibrated-momentum", create_estimator(
        "calibrated", machine="cat345c-hydraulic-3pct", balance="momentum").fit(data)


@pytest.fixture(scope="module")
def machine_models(machine_swings):
    models = dict(_machine_models(machine_swings))
    for est in models.values():
        # the rest of the status logic, with the sensor health monitor off (EP_HEALTH 0 then);
        # tests/runtime/test_export_c_health.py compares the monitor itself
        est.health = False
    return models


NAMES = ["inverse-dynamics", "calibrated-skip", "calibrated-downweight", "calibrated-model",
         "calibrated-momentum"]


@pytest.mark.parametrize("name", NAMES)
def test_c_equals_python_on_the_machine_set(name, machine_models, machine_faulty, tmp_path):
    est = machine_models[name]
    header, source = export_c(est, tmp_path / "export")
    h = header.read_text()
    assert f"#define EP_N_SIGNALS {len(MACHINE_SENSORS.signals)}" in h
    names = re.search(r"EP_SIGNAL_NAMES\[EP_N_SIGNALS\] = \{(.*)\};", source.read_text()).group(1)
    assert [n.strip().strip('"') for n in names.split(",")] == list(MACHINE_SENSORS.signals)
    py = None
    for single in (False, True):
        py = _assert_c_equals_python(est, source, machine_faulty, tmp_path / "build", single)
    seen = set(py["status"])
    assert {"invalid_input", "out_of_range", "gap", "warming_up", "ok"} <= seen
    if name.startswith("calibrated"):
        assert "state_reset" in seen  # the NaN ground tilt: a non-finite state restarts
    waits = getattr(est.kernel.regression, "wait_for_boom", False)  # the calibrated kernel's option
    if not waits:
        # the pressure kernels' one-frame outlier test (a rejection before any information, or
        # before the boom was weighed, is reported as warming_up)
        assert (py["status"] == "rejected_outlier").sum() >= 2
    if waits:  # the default momentum form waits for the boom
        first_ok = int(np.flatnonzero(py["status"].to_numpy() == "ok")[0])
        assert first_ok > 50 and np.isnan(py["payload_estimate"].to_numpy()[:first_ok]).all()
    assert np.isfinite(py["sigma"]).any()


def test_physics_is_generated_with_the_fitted_parameters(machine_models, tmp_path):
    """The kernel is CasADi's code with the parameters, offsets and IMU dynamics as constants:
    it takes only the sample and the derived accelerations, and another calibration (other
    offsets) gives other code."""
    est = machine_models["calibrated-skip"]
    source = export_c(est, tmp_path / "a")[1].read_text()
    kernel = re.search(r"static int ep_pressure_regression\(.*?\n}", source, re.S).group(0)
    assert re.findall(r"arg\[(\d+)\]", kernel) and set(re.findall(r"arg\[(\d+)\]", kernel)) == {"0", "1"}
    assert np.any(est.calibration.offset_vector() != 0)
    other = copy.deepcopy(est)
    other.calibration.z[len(cm.CALIBRATED_PARAMETERS)] += 1e5  # the boom head pressure's offset
    other.use_calibration()
    other_kernel = re.search(r"static int ep_pressure_regression\(.*?\n}",
                             export_c(other, tmp_path / "b")[1].read_text(), re.S).group(0)
    assert other_kernel != kernel


def test_machine_set_export_errors_and_cli(machine_models, machine_swings, tmp_path):
    # an estimator of the machine set without a C export (the quasi-static map, from lifts)
    lifts = simulate_machine_dataset(4, seed=1, noise="none", motion="lifts")
    other = create_estimator("quasi-static", machine="cat345c-hydraulic").fit(lifts)
    with pytest.raises(EstimatorError, match="machine sensor set has no C export"):
        export_c(other, tmp_path)
    model = tmp_path / "model"
    machine_models["calibrated-skip"].save(model)
    out = tmp_path / "c"
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(out),
                 "--precision", "float32"]) == 0
    assert "#define EP_SINGLE 1" in (out / "ep_calibrated.h").read_text()


@pytest.mark.parametrize("name", ["calibrated-skip", "calibrated-momentum"])
def test_float_build_does_no_double_maths(name, machine_models, tmp_path):
    """In single precision nothing is promoted to double (constants of the generated code
    included): an ECU with a single-precision FPU never runs double arithmetic."""
    header, source = export_c(machine_models[name], tmp_path, precision="float32")
    result = subprocess.run([c_compiler(), *STRICT_FLAGS, "-Wdouble-promotion", "-O0", "-c", str(source),
                             "-o", str(tmp_path / "model.o")], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_outlier_test_off(machine_models, machine_faulty, tmp_path):
    """-DEP_GATING=0 is ``Estimator.gating = False`` for the kernels' outlier test too."""
    est = machine_models["inverse-dynamics"]
    source = export_c(est, tmp_path / "export")[1]
    est.gating = False
    try:
        py = _assert_c_equals_python(est, source, machine_faulty, tmp_path / "off", False,
                                     extra_flags=("-DEP_GATING=0",))
    finally:
        est.gating = True
    assert "rejected_outlier" not in set(py["status"])


@pytest.mark.parametrize("name", ["calibrated-skip", "calibrated-momentum"])
def test_c_equals_python_outside_the_calibrated_range(name, machine_models, machine_faulty, tmp_path):
    """--outside-calibration skip where it bites: the bucket's covered range narrowed to the
    middle of these swings' bucket angles, so its windows go in and out of it."""
    est = copy.deepcopy(machine_models[name])
    est.options["outside_calibration"] = "skip"
    bucket = machine_faulty.frame["bucket_angle"].to_numpy(float)
    middle = float(np.nanmedian(bucket[np.abs(bucket) < 10]))
    est.calibration.angle_coverage[2] = (middle - 0.15, middle + 0.15)
    est.use_calibration()
    wide = copy.deepcopy(machine_models[name])
    wide.options["outside_calibration"] = "use"
    wide.use_calibration()
    narrow_py = est.estimate(machine_faulty)["payload_estimate"].to_numpy(float)
    wide_py = wide.estimate(machine_faulty)["payload_estimate"].to_numpy(float)
    both = np.isfinite(narrow_py) & np.isfinite(wide_py)
    assert np.abs(narrow_py[both] - wide_py[both]).max() > 1.0  # the guard changed the weighing
    source = export_c(est, tmp_path / "export")[1]
    assert "EP_COVERAGE_LOW" in source.read_text()
    for single in (False, True):
        _assert_c_equals_python(est, source, machine_faulty, tmp_path / "build", single)


@pytest.mark.parametrize("name", ["calibrated-skip", "calibrated-momentum"])
def test_c_equals_python_with_the_arm_outside_the_calibrated_range(name, machine_models, machine_faulty, tmp_path):
    """--outside-calibration arm: the dipper's covered range narrowed to the middle of these
    swings' dipper angles, so the whole arm goes in and out of it; C stops weighing on the same
    samples as Python."""
    est = copy.deepcopy(machine_models[name])
    est.options["outside_calibration"] = "arm"
    dipper = machine_faulty.frame["dipper_angle"].to_numpy(float)
    middle = float(np.nanmedian(dipper[np.isfinite(dipper) & (np.abs(dipper) < 10)]))
    est.calibration.angle_coverage[1] = (middle - 0.2, middle + 0.2)
    est.use_calibration()
    skip = copy.deepcopy(est)
    skip.options["outside_calibration"] = "skip"
    skip.use_calibration()
    arm_py = est.estimate(machine_faulty)["payload_estimate"].to_numpy(float)
    skip_py = skip.estimate(machine_faulty)["payload_estimate"].to_numpy(float)
    assert not np.array_equal(arm_py, skip_py, equal_nan=True)  # the whole-arm guard changed the weighing
    source = export_c(est, tmp_path / "export")[1]
    assert "ep_arm_outside" in source.read_text()
    for single in (False, True):
        _assert_c_equals_python(est, source, machine_faulty, tmp_path / "build", single)


def test_c_equals_python_where_a_new_load_is_detected(machine_models, tmp_path):
    """--new-load detect (the momentum form's default) where it bites: two swings of 500 kg and
    4500 kg streamed as one experiment, as a sensor on a running machine sees one load after
    another. The weighing restarts on the new load (without the test it averages both), and the
    C export restarts on the same sample."""
    first = simulate_machine_dataset(1, seed=11, payload=500.0).frame
    second = simulate_machine_dataset(1, seed=12, payload=4500.0).frame
    second = second.assign(experiment=first["experiment"].iloc[0],
                           time=second["time"] + first["time"].iloc[-1] + 0.01)
    frame = __import__("pandas").concat([first, second], ignore_index=True).assign(payload=500.0)
    stream = Dataset(frame, {"sensor_set": "machine", "machine": "cat345c-hydraulic"})
    est = machine_models["calibrated-momentum"]
    assert est.kernel.regression.new_load
    off = copy.deepcopy(est)
    off.options["new_load"] = "off"
    off.use_calibration()
    detect_py = est.estimate(stream)["payload_estimate"].to_numpy(float)
    off_py = off.estimate(stream)["payload_estimate"].to_numpy(float)
    assert abs(detect_py[-1] - 4500.0) < 0.5 * abs(off_py[-1] - 4500.0)
    assert abs(detect_py[-1] - 4500.0) < 300.0
    n = len(first)  # the first load is weighed alike until the second arrives
    np.testing.assert_array_equal(detect_py[:n - 60], off_py[:n - 60])
    source = export_c(est, tmp_path / "export")[1]
    assert "#define EP_NEW_LOAD 1" in source.read_text() or "#define EP_NEW_LOAD 1" in (tmp_path / "export").joinpath(source.stem + ".h").read_text()
    for single in (False, True):
        _assert_c_equals_python(est, source, stream, tmp_path / "build", single)


def test_c_equals_python_where_a_load_change_settles(machine_models, tmp_path, monkeypatch):
    """A truck loaded pass after pass (the load enters the bucket while it curls, leaves on the
    dump): the new-load test restarts on each change, sometimes while the bucket still fills, and
    a ``load_changing`` episode of ``SETTLE_WINDOWS`` or more that ends without a new load sets
    the whole memory to the short one (``CalibratedKernel._settle``; what it buys on held-out
    shifts is measured in docs/loadout.md). The C export settles on the same samples. (The dumps'
    restarts, ``settings.DUMP_RESTARTS``, leave this truck no settle: off here.)"""
    _no_dump_restarts(monkeypatch)
    truck = simulate_machine_dataset(1, seed=7, session=2, motion="shift", truck_target=12000.0)
    est = machine_models["calibrated-momentum"]
    est.reset()
    f = truck.frame
    kernel, seen = None, 0
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        est.step_values(t, row)
        kernel = est.kernel.regression
        if kernel.settles > seen:  # this window settled: the whole memory is the short one
            seen = kernel.settles
            assert (kernel.num, kernel.info) == (kernel.num_short, kernel.info_short)
            assert not kernel.changing and kernel.changing_windows == 0
    assert seen >= 1
    source = export_c(est, tmp_path / "export")[1]
    for single in (False, True):
        _assert_c_equals_python(est, source, truck, tmp_path / "build", single)


def _no_dump_restarts(monkeypatch):
    """``settings.DUMP_RESTARTS`` off for the kernel and the C export alike."""
    from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module
    from excavator_payload.estimators.classical.machine_calibration import settings

    monkeypatch.setattr(kernel_module, "DUMP_RESTARTS", False)
    monkeypatch.setattr(settings, "DUMP_RESTARTS", False)


def test_c_equals_python_where_a_dump_restarts(machine_models, tmp_path):
    """A truck loaded pass after pass: each dump (the bucket opens fast and turns over with a load
    in it, ``settings.DUMP_TURN``) says ``load_changing`` until it ends, and its end restarts the
    weighing (``CalibratedKernel.dump_pending``, ``dump_restarts``; docs/findings/false-alarms.md,
    session 19); an empty bucket opened fast to set the next cut restarts nothing. The C export
    restarts on the same samples and says the same statuses (this small test model weighs no pass
    ``ok`` before its dump: the weighing says ``warming_up`` or ``sensor_fault`` then, never ``ok``)."""
    truck = simulate_machine_dataset(1, seed=7, session=2, motion="shift", truck_target=12000.0)
    est = machine_models["calibrated-momentum"]
    est.reset()
    f = truck.frame
    pending = []
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        result = est.step_values(t, row)
        pending.append((est.kernel.regression.dump_pending, str(result.status)))
    kernel = est.kernel.regression
    passes = len(truck.experiment_meta[int(f["experiment"].iloc[0])]["passes"])
    assert 1 <= kernel.dump_restarts <= passes
    assert any(p for p, _ in pending) and not any(p and s.endswith(".OK") for p, s in pending)
    source = export_c(est, tmp_path / "export")[1]
    assert "EP_DUMP_PENDING" in source.read_text()
    for single in (False, True):
        _assert_c_equals_python(est, source, truck, tmp_path / "build", single)


def test_a_quick_bucket_move_that_keeps_its_load_restarts_nothing(machine_models):
    """An operator's quick bucket moves open the bucket faster than the dump rate (the joint
    check's ``dumping``) but by a few degrees, keeping the load: no dump (``settings.DUMP_TURN``),
    never ``load_changing`` for it, no restart (a first version restarted at each and put the
    `operator` family at 10 % not ``ok``; docs/findings/false-alarms.md, session 19)."""
    motions = simulate_machine_dataset(2, seed=32, session=2, motion="operator")
    est = machine_models["calibrated-momentum"]
    signals = list(MACHINE_SENSORS.signals)
    dumping = pending = restarts = 0
    for _, sub in motions.frame.groupby("experiment"):
        est.reset()
        for t, row in zip(sub["time"].to_numpy(float), sub[signals].to_numpy(float)):
            est.step_values(t, row)
            kernel = est.kernel.regression
            dumping += kernel.dumping
            pending += kernel.dump_pending
        restarts += kernel.dump_restarts
    assert dumping > 0 and pending == 0 and restarts == 0
