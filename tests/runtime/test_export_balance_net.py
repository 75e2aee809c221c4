"""``balance-net``'s C and ONNX exports equal Python's streaming, sample by sample (estimate,
status and sigma), on both sensor sets: the thesis set (measured accelerations, the base class's
statistical gate) and the machine set (momentum windows, the one-frame glitch test), with bad
samples, a glitched frame and bridged gaps in the stream."""

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.runtime.c_harness import build, c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.runtime.export_onnx import export_onnx
from excavator_payload.simulation.machine_sim import simulate_machine_dataset
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk

CODES = {s.value: i for i, s in enumerate(Status)}
needs_cc = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")


def _thesis():
    est = create_estimator("balance-net", order=2).fit(simulate_minimum_jerk(12, seed=5, noise="thesis"))
    data = simulate_minimum_jerk(3, seed=9, noise="thesis")
    frame = data.frame.copy()
    rows = frame.index[frame["experiment"] == frame["experiment"].iloc[0]]
    frame.loc[rows[30], "boom_torque"] = np.nan                 # invalid_input, then a gap
    frame.loc[rows[60], "dipper_torque"] *= 3.0                 # the statistical gate rejects it
    frame = frame.drop(index=list(rows[70:74])).reset_index(drop=True)  # a bridged gap
    return est, Dataset(frame, data.meta)


def _machine():
    train = simulate_machine_dataset(3, seed=41, session=1)
    cycles = simulate_machine_dataset(4, seed=45, session=1, motion="work-cycle").until_dump()
    frame = cycles.frame.copy()
    frame["experiment"] += int(train.frame["experiment"].max()) + 1
    wide = Dataset(pd.concat([train.frame, frame], ignore_index=True), train.meta)
    est = create_estimator("balance-net", order=2, half_window=10, ramp=4, every=1).fit(wide)
    est.health = False  # the ONNX export has no sensor health monitor (the C one: test_export_c_health.py)
    data = simulate_machine_dataset(1, seed=44, session=1)
    frame = data.frame.copy()
    frame.loc[300, "boom_head_pressure"] += 5e6                 # a one-frame glitch
    frame.loc[350, "dipper_rod_pressure"] = 2e9                 # out_of_range
    frame = frame.drop(index=list(range(500, 520))).reset_index(drop=True)  # a bridged 0.2 s gap
    return est, Dataset(frame, data.meta)


@pytest.fixture(scope="module")
def cases():
    return {"thesis": _thesis(), "machine": _machine()}


def _python(est, data):
    py = est.estimate(data)
    return (py["payload_estimate"].to_numpy(), np.array([CODES[s] for s in py["status"]]),
            py["sigma"].to_numpy())


def _assert_equal(got, want):
    (est, status, sigma), (w_est, w_status, w_sigma) = got, want
    np.testing.assert_array_equal(status, w_status)
    for a, b in ((est, w_est), (sigma, w_sigma)):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        ok = ~np.isnan(b)
        np.testing.assert_allclose(a[ok], b[ok], rtol=1e-9, atol=0)


def _onnx_run(path, data, signals):
    from excavator_payload.runtime.export_onnx_balance import OnnxBalanceNet

    runner = OnnxBalanceNet(path)
    values = data.signals(signals)
    times = data.frame["time"].to_numpy(float)
    exp = data.frame["experiment"].to_numpy()
    out = []
    for i in range(len(times)):
        if i == 0 or exp[i] != exp[i - 1]:
            runner.reset()
        out.append(runner.step_values(times[i], values[i]))
    return (np.array([o[0] for o in out]), np.array([CODES[o[1]] for o in out]),
            np.array([o[2] for o in out]))


@needs_cc
@pytest.mark.parametrize("sensor_set", ["thesis", "machine"])
def test_c_equals_python(sensor_set, cases, tmp_path):
    est, data = cases[sensor_set]
    want = _python(est, data)
    seen = {Status(list(Status)[c]).value for c in set(want[1])}
    assert {"ok", "gap"} <= seen and np.isfinite(want[0]).sum() > 100
    assert ("rejected_outlier" in seen) == (sensor_set == "thesis")
    paths = export_c(est, tmp_path / "export")
    _assert_equal(build(paths[1], tmp_path / "build").run(data), want)


@needs_cc
@pytest.mark.parametrize("sensor_set", ["thesis", "machine"])
def test_c_without_gating_equals_python_without(sensor_set, cases, tmp_path):
    """-DEP_GATING=0 is Estimator.gating = False; the glitch and the gate change the numbers."""
    est, data = cases[sensor_set]
    gated = _python(est, data)
    paths = export_c(est, tmp_path / "export")
    est.gating = False
    try:
        want = _python(est, data)
    finally:
        est.gating = True
    assert np.nanmax(np.abs(want[0] - gated[0])) > 1e-6  # the glitch / outlier mattered
    _assert_equal(build(paths[1], tmp_path / "build", extra_flags=("-DEP_GATING=0",)).run(data), want)


@pytest.mark.parametrize("sensor_set", ["thesis", "machine"])
def test_onnx_equals_python(sensor_set, cases, tmp_path):
    pytest.importorskip("onnxruntime")
    est, data = cases[sensor_set]
    path = export_onnx(est, tmp_path)[0]
    _assert_equal(_onnx_run(path, data, est.sensor_set.signals), _python(est, data))


@pytest.mark.parametrize("fmt", ["c", "onnx"])
def test_export_command(fmt, cases, tmp_path):
    est, data = cases["thesis"]
    model = tmp_path / "model"
    est.save(model)
    out = tmp_path / fmt
    assert main(["export", "--model", str(model), "--format", fmt, "--out", str(out)]) == 0
    written = sorted(p.name for p in out.iterdir())
    assert written == (["ep_balance_net.c", "ep_balance_net.h"] if fmt == "c" else ["balance-net.onnx"])
    if fmt == "onnx":  # the loaded model's export runs as the trained one
        pytest.importorskip("onnxruntime")
        _assert_equal(_onnx_run(out / "balance-net.onnx", data, est.sensor_set.signals),
                      _python(load_estimator(model), data))


@pytest.mark.parametrize("sensor_set", ["thesis", "machine"])
def test_novelty_floor_exported(sensor_set, cases, tmp_path):
    """σ's floor growing with the motion's novelty and misfit (floor² = max(a + b·d̄ + c·χ̄², 0))
    is the same in C and ONNX as in Python; with b, c > 0 σ differs from the constant floor's, so
    both are exercised."""
    import copy

    est, data = cases[sensor_set]
    est = copy.deepcopy(est)
    assert len(est.novelty_mean) and est.novelty_precision.shape == (len(est.novelty_mean),) * 2
    constant = _python(est, data)
    est.floor_a, est.floor_b, est.floor_c = -0.5, 2.0, 0.0  # kg², kg² per unit: both signs of the sum
    novelty = _python(est, data)
    est.floor_c = 3.0
    want = _python(est, data)
    ok = np.isfinite(want[2])
    assert np.max(np.abs(want[2][ok] - constant[2][ok])) > 1e-3
    assert np.max(np.abs(want[2][ok] - novelty[2][ok])) > 1e-3  # the misfit adds its part
    np.testing.assert_array_equal(want[0], constant[0])  # the weighing itself is unchanged
    if c_compiler() is not None:
        _assert_equal(build(export_c(est, tmp_path / "c")[1], tmp_path / "build").run(data), want)
    pytest.importorskip("onnxruntime")
    _assert_equal(_onnx_run(export_onnx(est, tmp_path / "onnx")[0], data, est.sensor_set.signals), want)
