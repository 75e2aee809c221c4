"""Inverse-dynamics estimator: generated base form == symbolic model, known answers, noise handling."""

import pickle

import casadi as ca
import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excavator_payload.cli import main
from excavator_payload.data.io import read_estimates, write_dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators import Status, create_estimator, load_estimator
from excavator_payload.estimators.classical.inverse_dynamics import (
    InverseDynamicsEstimator,
    base_parameters,
    base_regressor,
    information_terms,
    residual_nis,
    sensor_variances,
    split_torque,
    torque_jacobian,
)
from excavator_payload.evaluation.crb import cramer_rao_bound
from excavator_payload.model.dynamics import ArmModel, symbolic
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk
from excavator_payload.simulation.sensors import NoisePreset, get_noise_preset

finite = st.floats(-2.0, 2.0, allow_nan=False)


def _final_estimates(dataset, estimates):
    last = estimates.groupby("experiment", sort=False)["payload_estimate"].last().to_numpy()
    return last - dataset.payloads


# -- generated base form == symbolic model ------------------------------------------------

@pytest.mark.parametrize("machine", ["cat345c", "cat345c-3pct"])
def test_base_form_equals_symbolic_model(machine):
    """τ0 = Yθ0 and φ = Y[:, :5]θ1 with the generated regressor and the solved parameters."""
    arm = ArmModel(machine)
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-2, 2, (200, 2)) for _ in range(3))
    tau0, phi = split_torque(q, qd, qdd, *base_parameters(arm.machine))
    np.testing.assert_allclose(tau0, arm.torque_empty(q, qd, qdd), rtol=1e-12, atol=1e-7)
    np.testing.assert_allclose(phi, arm.payload_regressor(q, qd, qdd), rtol=1e-12, atol=1e-10)


def test_base_regressor_is_free_of_machine_parameters():
    assert not ca.depends_on(symbolic().base_regressor, ca.vertcat(symbolic().p, symbolic().payload))


@pytest.mark.parametrize("machine", ["cat345c", "cat345c-3pct"])
def test_base_parameters_equal_the_hand_calculation(machine):
    """Appendix A.1 worked out by hand for uniform bars and a point-mass bucket."""
    m = load_machine(machine)
    l1, l2, m1, m2, mb, g = (m.boom_length, m.dipper_length, m.boom_mass, m.dipper_mass,
                             m.bucket_mass, m.gravity)
    hand_empty = [m1 * l1**2 / 3 + (m2 + mb) * l1**2, m2 * l2**2 / 3 + mb * l2**2,
                  (m2 / 2 + mb) * l1 * l2, g * (m1 / 2 + m2 + mb) * l1, g * (m2 / 2 + mb) * l2,
                  m.boom_friction, m.dipper_friction]
    hand_payload = [l1**2, l2**2, l1 * l2, g * l1, g * l2]
    theta_empty, theta_payload = base_parameters(m)
    np.testing.assert_allclose(theta_empty, hand_empty, rtol=1e-13)  # 1.3e-14 on an AMD EPYC's BLAS
    np.testing.assert_array_equal(theta_payload, hand_payload)
    Y = base_regressor(np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([1.0, 0.0]))
    np.testing.assert_allclose(Y, [[1, 1, 2, 1, 1, 0, 0], [0, 1, 1, 0, 1, 0, 0]], atol=1e-15)


@settings(max_examples=25, deadline=None)
@given(st.lists(finite, min_size=6, max_size=6), st.floats(0.0, 5000.0))
def test_torque_jacobian_equals_casadi(x, payload):
    machine = load_machine("cat345c")
    arm = ArmModel(machine)
    q, qd, qdd = np.array(x[0:2]), np.array(x[2:4]), np.array(x[4:6])
    th0, th1 = base_parameters(machine)
    theta = th0.copy()
    theta[:5] += payload * th1
    jac = torque_jacobian(q, qd, qdd, theta)
    qs, qds, qdds = ca.SX.sym("q", 2), ca.SX.sym("qd", 2), ca.SX.sym("qdd", 2)
    tau = arm.casadi_function("inverse_dynamics")(qs, qds, qdds, payload)
    jf = ca.Function("j", [qs, qds, qdds], [ca.jacobian(tau, ca.vertcat(qs, qds, qdds))])
    expected = np.array(jf(q, qd, qdd))[:, [0, 2, 4, 1, 3, 5]]  # -> SIGNALS order
    np.testing.assert_allclose(jac, expected, rtol=1e-10, atol=1e-6 * np.abs(expected).max())


def test_scalar_kernel_equals_array_formula(mj_dataset):
    """The kernel used by step() gives the same residual terms as the array code."""
    machine = load_machine("cat345c")
    th0, th1 = base_parameters(machine)
    row = mj_dataset.signals()[37]
    var = sensor_variances("thesis")
    d_num, d_info = information_terms(row.tolist(), tuple(th0), tuple(th1), tuple(var), 0.0,
                                      weighting="torque", eiv_correction=False)
    q, qd, qdd, tau = row[[0, 3]], row[[1, 4]], row[[2, 5]], row[6:8]
    tau0, phi = split_torque(q, qd, qdd, th0, th1)
    assert d_num == pytest.approx(float(phi @ ((tau - tau0) / var[6:])), rel=1e-12)
    assert d_info == pytest.approx(float(phi @ (phi / var[6:])), rel=1e-12)


@pytest.mark.parametrize("weighting,eiv", [("full", True), ("diagonal", True), ("torque", False)])
def test_compiled_step_kernel_equals_casadi(mj_dataset, weighting, eiv):
    """The estimator's compiled kernel (buffer interface) == the generated function in CasADi's
    interpreter, for the information terms and the gate, on every fifth sample."""
    est = create_estimator("inverse-dynamics", "cat345c", weighting=weighting,
                           eiv_correction=eiv).fit(mj_dataset)
    args = (est.theta_empty.tolist(), est.theta_payload.tolist(), est.variances.tolist())
    for row in mj_dataset.signals()[::5][:200]:
        got = est.kernel.terms(row, 1234.5)
        want = information_terms(row.tolist(), *args, 1234.5, weighting, eiv)
        assert got == pytest.approx(want, rel=1e-12, abs=1e-18)
        assert est.kernel.nis(row, 1234.5, 4.0) == pytest.approx(
            residual_nis(row.tolist(), *args, 1234.5, 4.0), rel=1e-12)


def test_pickled_estimator_rebuilds_its_kernel(mj_dataset):
    est = create_estimator("inverse-dynamics", "cat345c").fit(mj_dataset)
    copy = pickle.loads(pickle.dumps(est))
    assert copy.kernel._compiled is not est.kernel._compiled
    subset = mj_dataset.subset(mj_dataset.experiment_ids[:3])
    pd.testing.assert_frame_equal(copy.estimate(subset), est.estimate(subset))


# -- known answers -------------------------------------------------------------------------

def test_noise_free_data_gives_the_exact_payload(mj_dataset_clean):
    est = create_estimator("inverse-dynamics", "cat345c").fit(mj_dataset_clean)
    out = est.estimate(mj_dataset_clean)
    err = out["payload_estimate"].to_numpy() - mj_dataset_clean.frame["payload"].to_numpy()
    assert np.abs(err).max() < 1e-3  # kg, from the very first sample
    assert (out["status"] == Status.OK.value).all()


def test_wrong_model_gives_the_predicted_bias(mj_dataset_clean):
    """With the 3 % wrong machine the estimate is the weighted LS fit of the wrong model."""
    wrong = load_machine("cat345c-3pct")
    est = create_estimator("inverse-dynamics", wrong, weighting="torque",
                           eiv_correction=False).fit(mj_dataset_clean)
    # The bare least squares: on noise-free data a 3 % wrong model's residuals are far beyond
    # the noise model, and the statistical gate would (rightly) reject some samples.
    est.gating = False
    bias = _final_estimates(mj_dataset_clean, est.estimate(mj_dataset_clean))
    # Prediction from the symbolic model: m = Σ φ'(τ - τ0') / Σ φ'φ' (equal torque variances).
    arm = ArmModel(wrong)
    predicted = []
    for _, rows in mj_dataset_clean.experiments():
        q, qd, qdd = (rows[[f"boom_{s}", f"dipper_{s}"]].to_numpy() for s in ("angle", "rate", "accel"))
        tau = rows[["boom_torque", "dipper_torque"]].to_numpy()
        phi = arm.payload_regressor(q, qd, qdd)
        predicted.append((phi * (tau - arm.torque_empty(q, qd, qdd))).sum() / (phi * phi).sum()
                         - rows["payload"].iloc[0])
    np.testing.assert_allclose(bias, predicted, atol=1e-6)
    assert np.abs(bias).mean() > 30.0  # a 3 % model error costs tens of kg


def test_efficiency_against_cramer_rao_bound(mj_dataset):
    est = create_estimator("inverse-dynamics", "cat345c").fit(mj_dataset)
    out = est.estimate(mj_dataset)
    err = out["payload_estimate"].to_numpy() - mj_dataset.frame["payload"].to_numpy()
    bound = cramer_rao_bound(mj_dataset)
    judged = mj_dataset.frame.groupby("experiment").cumcount().to_numpy() >= 81
    ratio = np.sqrt(np.mean((err[judged] / bound[judged]) ** 2))
    assert 0.5 < ratio <= 1.5


def test_errors_in_variables_correction_removes_bias():
    """Large acceleration noise dilutes plain least squares; the correction removes it."""
    base = get_noise_preset("thesis")
    noisy = NoisePreset("noisy-accel", {**base.std, "boom_accel": 0.1, "dipper_accel": 0.1})
    ds = simulate_minimum_jerk(100, seed=4, noise=noisy)  # ≈ 3 kg standard error of the mean
    ds.meta = {**ds.meta, "noise": noisy}
    bias = {}
    for eiv in (False, True):
        est = create_estimator("inverse-dynamics", "cat345c", eiv_correction=eiv).fit(ds)
        bias[eiv] = _final_estimates(ds, est.estimate(ds)).mean()
    assert bias[False] < -12.0  # regression dilution: about -20 kg
    assert abs(bias[True]) < 8.0
    assert bias[True] - bias[False] > 12.0


def test_forgetting_follows_a_payload_change(mj_dataset_clean):
    ds = mj_dataset_clean
    (_, first), (_, second) = list(ds.experiments())[:2]
    second = second.copy()
    second["time"] += first["time"].iloc[-1] + 0.05  # one continuous stream
    stream = pd.concat([first, second])
    finals = {}
    for lam in (1.0, 0.9):
        est = create_estimator("inverse-dynamics", "cat345c", forgetting=lam).fit(ds)
        est.gating = False  # the bare least squares (the gate would restart it, see below)
        results = [est.step(row) for row in stream.to_dict("records")]
        finals[lam] = results[-1].estimate
        assert all(r.status is Status.OK for r in results)
    m1, m2 = first["payload"].iloc[0], second["payload"].iloc[0]
    assert abs(finals[0.9] - m2) < 0.5  # old data weigh 0.9**101 ≈ 2e-5
    assert abs(finals[1.0] - m2) > 0.2 * abs(m2 - m1)  # without forgetting the old payload lingers


def test_gate_notices_a_payload_change_and_restarts(mj_dataset_clean):
    """A new payload without a pause: a few samples are rejected, then the estimator restarts
    (status reinitialised) instead of locking itself out, and finds the new payload."""
    ds = mj_dataset_clean
    (_, first), (_, second) = list(ds.experiments())[:2]
    second = second.copy()
    second["time"] += first["time"].iloc[-1] + 0.05
    stream = pd.concat([first, second]).to_dict("records")
    est = create_estimator("inverse-dynamics", "cat345c").fit(ds)
    results = [est.step(row) for row in stream]
    statuses = [r.status for r in results[101:]]
    assert statuses[:5] == [Status.REJECTED] * 5 and statuses[5] is Status.REINITIALISED
    assert all(r.estimate == results[100].estimate for r in results[101:106])  # estimate kept
    assert abs(results[-1].estimate - second["payload"].iloc[0]) < 0.5
    assert results[-1].status is Status.OK and 0 < results[-1].sigma < 1.0


def test_warming_up_until_the_uncertainty_is_small():
    ds = simulate_minimum_jerk(2, seed=4, noise="field")
    est = create_estimator("inverse-dynamics", "cat345c", warmup_std=30.0).fit(ds)
    out = est.estimate(ds)
    status = out["status"].to_numpy()
    assert status[0] == Status.WARMING_UP.value
    assert status[100] == Status.OK.value
    first_ok = int(np.argmax(status[:101] == Status.OK.value))
    assert (status[first_ok:101] == Status.OK.value).all()  # information only grows


# -- protocol ------------------------------------------------------------------------------

def test_streaming_equals_batch_and_bad_samples(mj_dataset):
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:3])
    est = create_estimator("inverse-dynamics", "cat345c").fit(ds)
    batch = est.estimate(ds)
    streamed = []
    for _, rows in ds.experiments():
        est.reset()
        streamed += [est.step(r).estimate for r in rows[["time", *SIGNALS]].to_dict("records")]
    np.testing.assert_array_equal(batch["payload_estimate"].to_numpy(), np.array(streamed))
    before = est.step({"time": 10.0, **{s: 0.0 for s in SIGNALS}, "boom_torque": float("nan")})
    assert before.status is Status.INVALID


def test_save_load_round_trip(mj_dataset, tmp_path):
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:3])
    est = create_estimator("inverse-dynamics", "cat345c-1pct", forgetting=0.99,
                           weighting="diagonal").fit(ds)
    est.save(tmp_path / "model")
    loaded = load_estimator(tmp_path / "model")
    assert isinstance(loaded, InverseDynamicsEstimator)
    assert loaded.options == est.options and loaded.machine == est.machine
    pd.testing.assert_frame_equal(loaded.estimate(ds), est.estimate(ds))


def test_bad_options_are_clear_errors():
    with pytest.raises(EstimatorError, match="forgetting"):
        create_estimator("inverse-dynamics", "cat345c", forgetting=1.5)
    with pytest.raises(EstimatorError, match="weighting"):
        create_estimator("inverse-dynamics", "cat345c", weighting="magic")


def test_cli_train_and_estimate(mj_dataset, tmp_path):
    data = tmp_path / "data.parquet"
    write_dataset(mj_dataset.subset(mj_dataset.experiment_ids[:2]), data)
    assert main(["train", "inverse-dynamics", "--data", str(data), "--out", str(tmp_path / "m"),
                 "--forgetting", "0.995", "--eiv-correction", "false"]) == 0
    assert main(["estimate", "--model", str(tmp_path / "m"), "--data", str(data),
                 "--out", str(tmp_path / "e.parquet")]) == 0
    est = read_estimates(tmp_path / "e.parquet")
    loaded = load_estimator(tmp_path / "m")
    assert loaded.options["forgetting"] == 0.995 and loaded.options["eiv_correction"] is False
    assert np.abs(est["payload_estimate"].to_numpy()[-1] - mj_dataset.payloads[1]) < 20
    assert main(["train", "inverse-dynamics", "--data", str(data), "--out", str(tmp_path / "x"),
                 "--forgetting", "abc"]) == 2
