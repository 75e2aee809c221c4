"""C export: compiles cleanly under strict C99, equals Python's estimate (double: 1e-6 relative,
float: 0.1 kg), status codes and ``ep_sigma`` included, on simulated experiments with faults
injected and on hostile streams (glitches, non-finite and huge values, time going back, gaps,
a run of glitches long enough to re-initialise)."""

import re

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, create_estimator, gate_threshold
from excavator_payload.runtime.c_harness import build, c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.sensors import get_noise_preset

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")

CODES = {s.value: i for i, s in enumerate(Status)}
NET = dict(train_experiments=3, validation_experiments=1, epochs=3, progress=False)


@pytest.fixture(scope="module")
def swings():
    """Four NMPC swings (thesis noise)."""
    return simulate_dataset(4, seed=8, workers=1, noise="thesis", progress=False)


@pytest.fixture(scope="module")
def faulty(swings):
    """The swings with every kind of bad sample: NaN, an angle out of range, a repeated time,
    a short gap (0.2 s) and a long one (2 s)."""
    frame = swings.frame.copy()
    ids = list(swings.experiment_ids)
    rows = {e: frame.index[frame["experiment"] == e] for e in ids}
    frame.loc[rows[ids[0]][30], "boom_torque"] = np.nan
    frame.loc[rows[ids[0]][50], "dipper_angle"] = 1.0          # dipper range is -150°…-15°
    frame.loc[rows[ids[1]][40], "time"] = frame.loc[rows[ids[1]][39], "time"]
    drop = list(rows[ids[2]][60:63]) + list(rows[ids[3]][20:60])
    frame = frame.drop(index=drop).reset_index(drop=True)
    return Dataset(frame, swings.meta)


@pytest.fixture(scope="module")
def hostile(swings):
    """The swings as an ECU may see them: isolated torque glitches of 10, 100 and 1000 noise
    sigmas (the gate's rejected_outlier), NaN, ±inf, 1e308 (invalid or implausible), 1e30 (finite
    even in float, implausible), time going back, a 0.2 s and a 2 s gap, and a run of eight
    glitches (five rejections, then the lock-out guard re-initialises)."""
    frame = swings.frame.copy()
    std = get_noise_preset("thesis").std
    ids = list(swings.experiment_ids)
    rows = {e: frame.index[frame["experiment"] == e] for e in ids}
    r0, r1, r2, r3 = (rows[e] for e in ids)
    for k, factor in zip((40, 50, 60), (10, 100, 1000)):
        frame.loc[r0[k], "boom_torque"] += factor * std["boom_torque"]
    frame.loc[r0[70], "dipper_torque"] -= 100 * std["dipper_torque"]
    frame.loc[r0[30], "boom_angle"] = np.nan
    frame.loc[r0[31], "dipper_rate"] = np.inf
    frame.loc[r0[32], "boom_accel"] = -np.inf
    frame.loc[r0[33], "dipper_torque"] = 1e308
    frame.loc[r0[34], "boom_torque"] = -1e30
    frame.loc[r1[45], "time"] = frame.loc[r1[44], "time"] - 0.5      # time goes back
    frame.loc[r1[46], "time"] = np.nan
    frame.loc[r2[30:38], "dipper_torque"] += 1000 * std["dipper_torque"]  # lock-out path
    frame.loc[r2[60], "boom_torque"] += 30 * std["boom_torque"]
    drop = list(r3[20:24]) + list(r3[50:90])                          # 0.2 s and 2 s gaps
    frame = frame.drop(index=drop).reset_index(drop=True)
    return Dataset(frame, swings.meta)


def _as_float32(dataset):
    """What a single-precision ECU receives: time and signals rounded to float."""
    frame = dataset.frame.copy()
    columns = ["time", *dataset.sensor_set.signals]
    with np.errstate(over="ignore"):
        frame[columns] = frame[columns].to_numpy(dtype=np.float32).astype(float)
    return Dataset(frame, dataset.meta)


def _assert_c_equals_python(est, c_file, dataset, folder, single, round_inputs=False, extra_flags=()):
    """C statuses, estimates and ep_sigma equal Python's ``estimate`` sample by sample."""
    reference = _as_float32(dataset) if round_inputs else dataset
    py = est.estimate(reference)
    want, want_sigma = py["payload_estimate"].to_numpy(), py["sigma"].to_numpy()
    want_status = np.array([CODES[s] for s in py["status"]])
    got, status, sigma = build(c_file, folder, single=single, extra_flags=extra_flags).run(dataset)
    np.testing.assert_array_equal(status, want_status)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(np.isnan(sigma), np.isnan(want_sigma))
    ok, ok_sigma = ~np.isnan(want), ~np.isnan(want_sigma)
    if single:
        assert np.abs(got[ok] - want[ok]).max(initial=0.0) <= 0.1
        np.testing.assert_allclose(sigma[ok_sigma], want_sigma[ok_sigma], rtol=1e-4)
    else:
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(sigma[ok_sigma], want_sigma[ok_sigma], rtol=1e-6)
    return py


def _models(swings):
    yield "inverse-dynamics", create_estimator("inverse-dynamics").fit(swings)
    yield "calibrated", create_estimator("calibrated", machine="cat345c-3pct").fit(swings)
    yield "ekf", create_estimator("ekf").fit(swings)
    yield "ekf-thesis", create_estimator("ekf", tuning="thesis").fit(swings)
    yield "net1", create_estimator("net1", **NET).fit(swings)
    yield "net2", create_estimator("net2", **NET).fit(swings)


@pytest.fixture(scope="module")
def models(swings):
    return dict(_models(swings))


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated", "ekf", "ekf-thesis", "net1", "net2"])
def test_c_equals_python(name, models, faulty, tmp_path):
    est = models[name]
    paths = export_c(est, tmp_path / "export")
    py = est.estimate(faulty)
    want = py["payload_estimate"].to_numpy()
    want_status = np.array([CODES[s] for s in py["status"]])
    assert len(set(want_status)) >= 4  # the faults exercise several statuses
    assert not np.isnan(want).all()
    for single in (False, True):
        _assert_c_equals_python(est, paths[1], faulty, tmp_path / "build", single)


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated", "ekf", "ekf-thesis", "net1", "net2"])
def test_c_equals_python_on_hostile_streams(name, models, hostile, tmp_path):
    est = models[name]
    paths = export_c(est, tmp_path / "export")
    py = None
    for single in (False, True):
        # in float the ECU sees float inputs (1e308 is inf there): Python gets the same stream
        py = _assert_c_equals_python(est, paths[1], hostile, tmp_path / "build", single,
                                     round_inputs=single)
    seen = set(py["status"])
    assert {"invalid_input", "out_of_range", "gap"} <= seen
    # every model is gated: by its own noise model or by the borrowed one (the thesis-tuned
    # EKF and the networks), so glitches are rejected and a run of them re-initialises
    assert {"rejected_outlier", "reinitialised"} <= seen
    assert np.isfinite(py["sigma"]).any()
    # samples used right after rejected ones: the EKF bridges, the networks interpolate the
    # rejected slots (the equality above checks that C does the same)
    status = list(py["status"])
    assert any(a == "rejected_outlier" and b == "ok" for a, b in zip(status, status[1:]))


def _c_array_values(source, name):
    body = re.search(rf"{name}\[\d+\] = \{{(.*?)\}};", source, re.S).group(1)
    return np.array([float(re.sub(r"EP_C\((.*)\)", r"\1", x.strip())) for x in body.split(",")])


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated", "ekf", "ekf-thesis", "net1", "net2"])
def test_borrowed_gate_constants(name, models, tmp_path):
    """The sentinel's base parameters and variances are the Python sentinel's; a model with
    a noise model of its own (on its data's machine) carries no sentinel."""
    est = models[name]
    source = export_c(est, tmp_path)[1].read_text()
    if est._sentinel is None:
        assert name in ("inverse-dynamics", "ekf")
        assert "ep_gate_step" not in source
        return
    sentinel = est._sentinel
    for array, want in (("EP_GATE_THETA_EMPTY", sentinel.theta_empty),
                        ("EP_GATE_THETA_PAYLOAD", sentinel.theta_payload),
                        ("EP_GATE_VARIANCES", sentinel.variances)):
        np.testing.assert_array_equal(_c_array_values(source, array), np.asarray(want, float))
    threshold = float(re.search(r"#define EP_GATE_THRESHOLD EP_C\((.*)\)", source).group(1))
    assert threshold == gate_threshold(2)


def test_borrowed_gate_off(models, hostile, tmp_path):
    """-DEP_GATING=0 turns the borrowed gate off too (the sentinel still follows)."""
    est = models["net1"]
    paths = export_c(est, tmp_path / "export")
    est.gating = False
    try:
        py = _assert_c_equals_python(est, paths[1], hostile, tmp_path / "off", False,
                                     extra_flags=("-DEP_GATING=0",))
    finally:
        est.gating = True
    assert "rejected_outlier" not in set(py["status"])


def test_gate_off_and_constants(models, hostile, tmp_path):
    """-DEP_GATING=0 is ``Estimator.gating = False``; the gate's quantile is scipy's."""
    est = models["inverse-dynamics"]
    paths = export_c(est, tmp_path / "export")
    source = paths[1].read_text()
    threshold = float(re.search(r"#define EP_GATE_THRESHOLD EP_C\((.*)\)", source).group(1))
    assert threshold == gate_threshold(2)
    est.gating = False
    try:
        py = _assert_c_equals_python(est, paths[1], hostile, tmp_path / "off", False,
                                     extra_flags=("-DEP_GATING=0",))
    finally:
        est.gating = True
    assert "rejected_outlier" not in set(py["status"])


def test_interface_and_purity(models, tmp_path):
    est = models["net1"]
    header, source = export_c(est, tmp_path, precision="float32")
    h, c = header.read_text(), source.read_text()
    assert "#define EP_SINGLE 1" in h and "typedef float ep_real;" in h
    assert f"#define EP_N_SIGNALS {len(est.sensor_set.signals)}" in h
    names = re.search(r"EP_SIGNAL_NAMES\[EP_N_SIGNALS\] = \{(.*)\};", c).group(1)
    assert [n.strip().strip('"') for n in names.split(",")] == list(est.sensor_set.signals)
    for i, s in enumerate(Status):
        if s is not Status.DEGRADED:  # the last code, only where a health monitor weighs degraded
            assert f"#define EP_STATUS_{s.name} {i}" in h
    assert "EP_STATUS_DEGRADED" not in h and f"#define EP_N_STATUSES {len(Status) - 1}" in h
    for text in (h, c):
        includes = re.findall(r"#include\s*[<\"](.*)[>\"]", text)
        assert set(includes) <= {"math.h", "ep_net1.h"}
        assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", text)
    # the generated CasADi code leaves no public symbol behind
    c_id = export_c(models["ekf"], tmp_path / "ekf")[1].read_text()
    public = re.findall(r"^(?!static)(?:int|void|double|float|ep_real|const) [\w *]*\w+\(", c_id, re.M)
    assert sorted(p.split("(")[0].split()[-1] for p in public) == ["ep_reset", "ep_sigma", "ep_step"]


def test_export_errors_and_cli(models, swings, tmp_path):
    ukf = create_estimator("ukf").fit(swings)
    with pytest.raises(EstimatorError, match="has no C export"):
        export_c(ukf, tmp_path)
    model = tmp_path / "model"
    models["inverse-dynamics"].save(model)
    out = tmp_path / "c"
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(out)]) == 0
    assert (out / "ep_inverse_dynamics.c").is_file() and (out / "ep_inverse_dynamics.h").is_file()
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(out),
                 "--precision", "half"]) == 2
    assert main(["export", "--model", str(model), "--format", "pdf", "--out", str(out)]) == 2
    assert main(["export", "--model", str(model), "--format", "onnx", "--out", str(out)]) == 2


@pytest.mark.parametrize("name", ["ekf", "ekf-thesis"])
def test_single_precision_ekf_step_is_the_same_filter(name, models, swings):
    """The float build's EKF (sequential scalar Joseph updates, scalar NIS sum) equals the
    joint update of ``_kalman.ekf_step_symbolic``/``gate_symbolic`` in double arithmetic,
    along a filtered experiment."""
    from excavator_payload.estimators.classical import _kalman as kf
    from excavator_payload.runtime.export_c import _ekf_single_functions

    est = models[name]
    t = est.tuning
    thesis = est.options["tuning"] == "thesis"
    step = kf.ekf_step_symbolic(est.machine, thesis, t.torque_channel)
    gate = kf.gate_symbolic(est.machine, thesis, t.torque_channel)
    step_single, gate_single = _ekf_single_functions(est, t.torque_channel)
    sig = list(swings.sensor_set.signals)
    names = ["boom_angle", "dipper_angle", "boom_rate", "dipper_rate", "boom_torque", "dipper_torque"]
    y_index = [sig.index(n) for n in names[:6 if t.torque_channel else 4]]
    u_index = [sig.index(n) for n in names[4:]]
    a_index = [sig.index(n) for n in ("boom_accel", "dipper_accel")]
    values = swings.subset(swings.experiment_ids[:1]).signals()
    x, P = np.array(t.x0, float), t.P0.copy()
    if t.init_from_sample:
        x[:4] = values[0][y_index[:4]]
    for v in values[:40]:
        y, u, a = v[y_index], v[u_index], v[a_index]
        covs = (t.R, t.torque_cov, t.accel_cov)
        nis, nis_single = float(gate(x, P, y, a, *covs)), float(gate_single(x, P, y, a, *covs))
        assert nis_single == pytest.approx(nis, rel=1e-6, abs=1e-9)
        want = np.array(step(x, P, y, u, a, t.Q, *covs)).ravel()
        got = np.array(step_single(x, P, y, u, a, t.Q, *covs)).ravel()
        for start in (0, 30):  # [x (5), vec P (25)] of the posterior and of the prediction
            np.testing.assert_allclose(got[start:start + 5], want[start:start + 5], rtol=1e-6, atol=1e-9)
            P_got = got[start + 5:start + 30].reshape(5, 5)
            P_want = want[start + 5:start + 30].reshape(5, 5)
            scale = np.sqrt(np.outer(np.diag(P_want), np.diag(P_want)))  # covariances by their stds
            assert np.all(np.abs(P_got - P_want) <= 1e-6 * scale)
        x, P = want[30:35], want[35:60].reshape(5, 5, order="F")


def test_a_network_that_does_not_run_on_every_sample_names_its_options(tmp_path):
    """The refusal named '--smoothing 0' (the exportable value) beside the --decimation at fault."""
    from types import SimpleNamespace

    from excavator_payload.data.schema import THESIS_SENSORS

    est = SimpleNamespace(name="net1", fitted=True, decimation=5, smoothing=0.0, sensor_set=THESIS_SENSORS)
    with pytest.raises(EstimatorError, match=r"^net1: a network trained with --decimation 5 has no C export") as caught:
        export_c(est, tmp_path)
    assert "--smoothing 0 " not in str(caught.value).split("; train it")[0]


def test_the_help_lists_what_exports_to_c(capsys):
    """The tables come from the traits (tests/estimators/test_traits.py checks them against the
    registered builders); the help prints them."""
    from excavator_payload.runtime.exportable import C_EXPORTABLE, C_EXPORTABLE_MACHINE

    assert main(["export", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert f"c ({', '.join(C_EXPORTABLE)}; on the machine sensor set: {', '.join(C_EXPORTABLE_MACHINE)})" in text
