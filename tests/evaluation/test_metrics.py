"""Metrics on hand-computed cases, the Cramér–Rao efficiency and estimate alignment."""

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excavator_payload.errors import DatasetError
from excavator_payload.evaluation.crb import cramer_rao_bound
from excavator_payload.evaluation.metrics import (
    align_estimates,
    bound_window,
    convergence_time,
    default_discard,
    display_label,
    evaluate_estimates,
    experiment_metrics,
    summarize,
)

T = np.arange(101) * 0.05


def test_constant_error_of_10_kg():
    m = experiment_metrics(T, np.full(101, 1010.0), 1000.0, discard=81)
    assert m["max_error"] == pytest.approx(10.0)
    assert m["rms_error"] == pytest.approx(10.0)
    assert m["mean_error"] == pytest.approx(10.0)
    for p in ("p90", "p95", "p99"):
        assert m[p] == pytest.approx(10.0)
    assert m["n_judged"] == 20 and m["n_estimated"] == 20 and m["estimated_share"] == 1.0
    assert m["convergence_time"] == 0.0  # 10 kg < 1 % of 5000 kg from the first sample


def test_max_and_rms_use_absolute_and_squared_errors():
    est = np.r_[np.zeros(81), np.tile([1003.0, 996.0], 10)]  # errors +3, -4
    m = experiment_metrics(T, est, 1000.0, discard=81)
    assert m["max_error"] == pytest.approx(4.0)
    assert m["rms_error"] == pytest.approx(math.sqrt((9 + 16) / 2))
    assert m["mean_error"] == pytest.approx(-0.5)


def test_discarded_samples_are_not_judged():
    est = np.full(101, 2000.0)
    est[:81] = 1e6
    m = experiment_metrics(T, est, 2000.0, discard=81)
    assert m["max_error"] == 0.0 and m["n_judged"] == 20
    m0 = experiment_metrics(T, est, 2000.0, discard=0)
    assert m0["max_error"] == pytest.approx(1e6 - 2000.0)


def test_percentiles_match_matlab_prctile():
    # |errors| 1…100 in some order: MATLAB prctile(1:100, [90 95 99]) = 90.5, 95.5, 99.5
    rng = np.random.default_rng(0)
    errors = rng.permutation(np.arange(1.0, 101.0)) * rng.choice([-1, 1], 100)
    m = experiment_metrics(np.arange(100) * 0.05, 500.0 + errors, 500.0, discard=0)
    assert (m["p90"], m["p95"], m["p99"]) == pytest.approx((90.5, 95.5, 99.5))
    # few samples: MATLAB clamps to the extremes (5 values sit at 10 %, 30 %, …, 90 %)
    m5 = experiment_metrics(np.arange(5) * 0.05, np.array([1.0, 2, 3, 4, 5]), 0.0, discard=0)
    assert (m5["p90"], m5["p95"], m5["p99"]) == pytest.approx((5.0, 5.0, 5.0))


def test_convergence_time():
    err = np.where(T < 2.0, 1000.0, 10.0)
    assert convergence_time(T, err, 50.0) == pytest.approx(2.0)
    err_late = err.copy()
    err_late[60] = 60.0  # leaves the band once more at t = 3 s
    assert convergence_time(T, err_late, 50.0) == pytest.approx(3.05)
    err_end = err.copy()
    err_end[-1] = 51.0  # outside at the end: never converged
    assert math.isnan(convergence_time(T, err_end, 50.0))
    err_nan = err.copy()
    err_nan[70] = np.nan  # no estimate counts as not converged
    assert convergence_time(T, err_nan, 50.0) == pytest.approx(3.55)
    # through experiment_metrics: tolerance is 1 % of the rated payload
    m = experiment_metrics(T, 3000.0 + np.where(T < 1.0, 80.0, 40.0), 3000.0, rated_payload=5000.0)
    assert m["convergence_time"] == pytest.approx(1.0)
    m = experiment_metrics(T, 3000.0 + np.where(T < 1.0, 80.0, 40.0), 3000.0, rated_payload=2000.0)
    assert math.isnan(m["convergence_time"])


def test_nan_estimates_are_not_judged_but_reported():
    est = np.full(101, 1005.0)
    est[81:86] = np.nan
    m = experiment_metrics(T, est, 1000.0, discard=81)
    assert m["n_estimated"] == 15 and m["estimated_share"] == pytest.approx(0.75)
    assert m["max_error"] == pytest.approx(5.0)
    none = experiment_metrics(T, np.full(101, np.nan), 1000.0)
    assert math.isnan(none["max_error"]) and none["estimated_share"] == 0.0


def test_summary_over_experiments():
    rows = []
    for k, e in enumerate([10.0, 30.0, 80.0]):
        rows.append({"experiment": k, "payload": 1000.0,
                     **experiment_metrics(T, np.full(101, 1000.0 + e), 1000.0, rated_payload=5000.0)})
    s = summarize(pd.DataFrame(rows), rated_payload=5000.0)
    assert s["mean_max"] == pytest.approx(40.0)
    assert s["std_max"] == pytest.approx(np.std([10, 30, 80], ddof=1))  # MATLAB std
    assert s["mean_rms"] == pytest.approx(40.0)
    assert s["mean_max_pct"] == pytest.approx(0.8)
    assert s["meets_requirement_share"] == pytest.approx(2 / 3)  # 80 kg > 50 kg
    assert s["converged_share"] == pytest.approx(2 / 3)
    assert s["n_experiments"] == 3


@given(st.lists(st.floats(-1e4, 1e4, allow_nan=False), min_size=1, max_size=60))
@settings(max_examples=60, deadline=None)
def test_metric_orderings(errors):
    e = np.array(errors)
    m = experiment_metrics(np.arange(len(e)) * 0.05, 100.0 + e, 100.0, discard=0)
    tol = 1e-9 * (1 + m["max_error"])
    assert m["p90"] <= m["p95"] + tol <= m["p99"] + 2 * tol <= m["max_error"] + 3 * tol
    assert m["rms_error"] <= m["max_error"] + tol
    assert m["rms_error"] >= abs(m["mean_error"]) - tol


def test_efficiency_is_one_for_bound_scaled_gaussian_noise(mj_dataset):
    payload = mj_dataset.frame["payload"].to_numpy()
    rng = np.random.default_rng(5)
    for window in (None, 6):
        bound = cramer_rao_bound(mj_dataset, window=window)
        est = payload + np.nan_to_num(bound) * rng.standard_normal(len(payload))
        ev = evaluate_estimates(mj_dataset, est, window=window, bound=bound, discard=10)
        # 20 experiments × 91 judged samples: the RMS of N(0,1) ratios is within ±10 %
        assert 0.9 < ev.summary["efficiency"] < 1.1, (window, ev.summary["efficiency"])
        # an estimator twice as noisy is half as efficient
        ev2 = evaluate_estimates(mj_dataset, payload + 2 * np.nan_to_num(bound) * rng.standard_normal(len(payload)),
                                 window=window, bound=bound, discard=10)
        assert 1.8 < ev2.summary["efficiency"] < 2.2


def test_evaluate_computes_the_bound_itself(mj_dataset):
    payload = mj_dataset.frame["payload"].to_numpy()
    ev = evaluate_estimates(mj_dataset, payload + 10.0, label="plus10")
    assert ev.summary["mean_max"] == pytest.approx(10.0)
    assert ev.summary["std_max"] == pytest.approx(0.0, abs=1e-9)
    assert ev.bound is not None and np.all(ev.bound[1:] > 0)
    # whole-history bound at the end of a 5 s swing is about a kilogram at thesis noise
    assert 0.1 < ev.summary["mean_final_bound"] < 20
    assert ev.summary["efficiency"] > 1.0
    d = ev.to_dict()
    assert d["summary"]["mean_max"] == pytest.approx(10.0) and len(d["per_experiment"]) == 20


def test_bound_windows():
    assert bound_window("net1") == 6
    assert bound_window("net1", {"delays": "0:3"}) == 4
    assert bound_window("net1", {"delays": "0,1,2,7"}) == 8
    assert bound_window("net1", {"delays": [0, 1, 2]}) == 3
    assert bound_window("ffnn", {"delays": "0"}) == 1
    assert bound_window("dtdnn") == 6
    for name in ("net2", "lrn", "ekf", "ukf", "inverse-dynamics", "calibrated", "somebody-elses", None):
        assert bound_window(name) is None


def test_display_labels():
    assert display_label("ekf", {"tuning": "thesis"}, "cat345c") == "EKF_ideal"
    assert display_label("ekf", {"tuning": "thesis"}, "cat345c-1pct") == "EKF_1%"
    assert display_label("ekf", {"tuning": "thesis"}, "cat345c-3pct") == "EKF_3%"
    assert display_label("net1") == "Net1" and display_label("net2") == "Net2"
    assert display_label("ukf", {}, "cat345c") == "ukf"


def test_align_estimates_matches_on_experiment_and_time(mj_dataset_clean):
    ds = mj_dataset_clean
    f = ds.frame
    est = pd.DataFrame({"experiment": f["experiment"], "time": f["time"] + 1e-9,
                        "payload_estimate": np.arange(len(f), dtype=float)})
    est = est.sample(frac=1.0, random_state=1).iloc[5:]  # shuffled, five rows missing
    aligned = align_estimates(ds, est)
    assert np.isnan(aligned).sum() == 5
    ok = ~np.isnan(aligned)
    assert np.array_equal(aligned[ok], np.arange(len(f), dtype=float)[ok])
    other = est.assign(experiment=est["experiment"] + 1000)
    with pytest.raises(DatasetError, match="no .experiment, time. matches"):
        align_estimates(ds, other)
    with pytest.raises(DatasetError, match="missing column"):
        align_estimates(ds, est.drop(columns="payload_estimate"))
    with pytest.raises(DatasetError, match="more than one"):
        align_estimates(ds, pd.concat([est, est.iloc[:1]]))
    with pytest.raises(DatasetError, match="estimates for"):
        evaluate_estimates(ds, np.zeros(3))


def test_default_discard_is_81_samples_on_the_thesis_set_and_1_s_on_the_machine_set(mj_dataset):
    """81 samples are 4.05 s of the thesis's 20 Hz data but 0.81 s of the machine set's 100 Hz."""
    from excavator_payload.data.schema import MACHINE_SENSORS, THESIS_SENSORS
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    assert default_discard(THESIS_SENSORS) == 81 and default_discard(MACHINE_SENSORS) == 100
    payload = mj_dataset.frame["payload"].to_numpy()
    ev = evaluate_estimates(mj_dataset, payload + 1.0, with_bound=False)
    assert (ev.per_experiment["n_judged"] == 101 - 81).all()  # as before: thesis Table 7.1
    swing = simulate_machine_dataset(1, seed=5, session=2, motion="swing")
    ev = evaluate_estimates(swing, swing.frame["payload"].to_numpy() + 1.0, with_bound=False)
    assert ev.per_experiment["n_judged"].tolist() == [len(swing.frame) - 100]
