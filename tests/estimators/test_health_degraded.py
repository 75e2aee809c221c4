"""Degraded weighing (estimators.health.HealthMonitor.substitute, Estimator.step_values): while
the monitor names only a link's rate (stuck, dropout, noise), the estimator weighs on with the
rate replaced by its angle's slope, says ``degraded`` (never ``ok``) with the signal still named
and sigma widened; streaming equals batch, a saved model does the same; where no substitute
exists (the house tilt, the slew rate, a disagreeing link) it stops as before (a cylinder
pressure: tests/estimators/test_health_degraded_pressure.py)."""

import copy
import math

import numpy as np
import pytest

from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

from .test_health import _with  # a signal of one experiment rewritten on rows a:b

DEG = np.pi / 180


@pytest.fixture(scope="module")
def swing():
    return simulate_machine_dataset(1, seed=31, session=2, motion="operator")


@pytest.fixture(scope="module")
def models():
    fitting = simulate_machine_dataset(3, seed=3)
    return {"inverse-dynamics": create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(fitting),
            "calibrated": create_estimator("calibrated", machine="cat345c-hydraulic-3pct",
                                           balance="momentum").fit(fitting)}


def _moving(swing, rate, clean=None):
    """A sample where ``rate``'s joint moves (and, given ``clean``, the estimate is ok)."""
    r = np.abs(swing.frame[rate].to_numpy())
    moving = r > 0.3 * r.max()
    if clean is not None:
        moving &= clean["status"].to_numpy() == Status.OK.value
    moving[len(moving) - 200:] = False
    moving = np.flatnonzero(moving)
    return int(moving[len(moving) // 3])


RATE_FAULTS = [
    ("boom_rate", "stuck", lambda v, a, b: v[a - 1]),
    ("dipper_rate", "dropout", lambda v, a, b: 0.0),
    ("bucket_rate", "noise", lambda v, a, b: v[a:b] + 1.5 * DEG * np.random.default_rng(1).standard_normal(b - a)),
]


def test_substitute_is_the_angles_slope():
    """The weights are a least-squares slope: exact on a ramp, the other signals untouched;
    nothing before the windows hold enough samples or while anything else is named."""
    signals = ("boom_angle", "boom_rate", "boom_head_pressure")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    assert m.n_sub == 21 and math.isclose(float(m.sub_weights.sum()), 0.0, abs_tol=1e-9)
    for k in range(30):
        m.step(0.01 * k, [0.3 * 0.01 * k, 0.0, 1e6])
        m.active = {(1, "stuck"): 0}
        got = m.substitute(np.array([0.3 * 0.01 * k, 0.0, 1e6]))
        assert (got is None) == (k + 1 < m.n_sub)
    assert got[1] == pytest.approx(0.3, rel=1e-9) and got[0] == 0.3 * 0.01 * 29 and got[2] == 1e6
    for other in [(2, "stuck"), (1, "disagree"), (0, "stuck")]:
        m.active = {(1, "stuck"): 0, other: 0}
        assert m.substitute(np.zeros(3)) is None


@pytest.mark.parametrize("signal,kind,how", RATE_FAULTS)
def test_rate_fault_weighs_degraded_never_ok(models, swing, signal, kind, how):
    est = models["calibrated"]
    clean = est.estimate(swing)
    a = _moving(swing, signal, clean)
    b = a + 150
    bad = _with(swing, signal, a, b, how)
    out = est.estimate(bad)
    named = out["fault"].str.contains(f"{signal}:", regex=False).to_numpy()
    status = out["status"].to_numpy()
    assert named.any()
    assert not (status[named] == Status.OK.value).any()  # never ok on a named signal
    degraded = status == Status.DEGRADED.value
    assert degraded.sum() >= 20
    assert named[degraded].all()  # degraded always names the signal (DM1 stays active)
    # the substitute does not drive the estimate off the clean run's: while degraded the
    # difference stays within 50 kg of what it was when weighing went degraded (the bad samples
    # before the fault was named, ok then, may have moved it: a dropped-out dipper rate 236 kg
    # in 0.3 s for inverse dynamics, which the degraded samples then bring back)
    diff = out["payload_estimate"].to_numpy()[degraded] - clean["payload_estimate"].to_numpy()[degraded]
    sigma = out["sigma"].to_numpy()[degraded]
    assert np.all(np.isfinite(diff)) and np.all(sigma > 0)
    assert np.max(np.abs(diff)) <= abs(diff[0]) + 50.0
    assert abs(diff[-1]) <= abs(diff[0]) + 25.0


@pytest.mark.parametrize("signal,joint,how", [  # (a pressure now drops its joint, a tilt its value
    ("slew_rate", "dipper_rate", lambda v, a, b: 0.0 * v[a:b]),  # from before: test_health_degraded_{pressure,tilt}.py)
    ("dipper_angle", "dipper_rate", lambda v, a, b: v[a:b] + np.radians(5)),  # disagree: the rate too
])
def test_no_substitute_stops_as_before(models, swing, signal, joint, how):
    est = models["calibrated"]
    a = _moving(swing, joint, est.estimate(swing))
    out = est.estimate(_with(swing, signal, a, a + 100, how))
    assert (out["status"] == Status.SENSOR_FAULT.value).any()
    assert not (out["status"] == Status.DEGRADED.value).any()


def test_only_the_estimators_measured_weigh_degraded(models, swing):
    """Inverse dynamics (not measured within its sigma on the substitute: 4–14 % within 2 sigma)
    and calibrated with another balance form stop on a rate fault as before."""
    assert models["inverse-dynamics"].degraded_rates() == ()
    assert create_estimator("calibrated", balance="differentiated").degraded_rates() == ()
    signal, _, how = RATE_FAULTS[0]
    a = _moving(swing, signal)
    out = models["inverse-dynamics"].estimate(_with(swing, signal, a, a + 150, how))
    assert (out["status"] == Status.SENSOR_FAULT.value).any()
    assert not (out["status"] == Status.DEGRADED.value).any()


def test_clean_data_never_degraded(models, swing):
    for est in models.values():
        assert not (est.estimate(swing)["status"] == Status.DEGRADED.value).any()


def test_streaming_equals_batch_and_save_load(models, swing, tmp_path):
    est = models["calibrated"]
    signal, _, how = RATE_FAULTS[0]
    a = _moving(swing, signal, est.estimate(swing))
    bad = _with(swing, signal, a, a + 150, how)
    batch = est.estimate(bad)
    assert (batch["status"] == Status.DEGRADED.value).any()
    assert_stream_equals_batch(est, bad, batch)
    est.save(tmp_path / "model")
    again = load_estimator(tmp_path / "model").estimate(bad)
    assert list(again["status"]) == list(batch["status"])
    np.testing.assert_allclose(again["payload_estimate"].to_numpy(), batch["payload_estimate"].to_numpy(),
                               rtol=1e-12, atol=1e-9)


def test_degraded_status_keeps_every_old_code():
    """Appended last: every status code on the bus and in C keeps its number."""
    statuses = list(Status)
    assert statuses[-1] is Status.DEGRADED and statuses.index(Status.SENSOR_FAULT) == 12


def assert_stream_equals_batch(est, bad, batch) -> None:
    """``est`` stepped over ``bad`` from a reset gives ``batch`` (its ``estimate``): statuses,
    faults, estimates and sigmas alike."""
    est.reset()
    stream = [est.step(row) for row in bad.frame.to_dict("records")]
    assert [r.status.value for r in stream] == list(batch["status"])
    assert [r.fault for r in stream] == list(batch["fault"])
    np.testing.assert_array_equal(np.array([r.estimate for r in stream]), batch["payload_estimate"].to_numpy())
    np.testing.assert_array_equal(np.array([r.sigma for r in stream]), batch["sigma"].to_numpy())


def test_the_samples_before_a_name_are_forgotten(models, swing, monkeypatch):  # noqa: F811
    """A stuck boom head pressure is named after the stuck window; the samples before the name
    carry the fault too: at the first degraded sample the estimator has the kernel forget the
    boom's windows over what its rings hold (``HealthMonitor.newly_named_joints``,
    ``CalibratedKernel.forget``), once."""
    est = models["calibrated"]
    a = _moving(swing, "boom_rate", est.estimate(swing))
    calls = []
    monkeypatch.setattr(type(est), "_forget_joints", lambda self, joints: calls.append(tuple(joints)))
    out = est.estimate(_with(swing, "boom_head_pressure", a, a + 250, lambda v, a, b: v[a - 1]))
    assert (out["status"] == Status.DEGRADED.value).sum() > 50
    assert calls and calls[0] == (True, False, False)


def test_a_forgotten_joint_weighs_no_window_over_the_rings(models, swing):  # noqa: F811
    """CalibratedKernel.forget: after it, no window weighs until every sample the rings held has
    left them (the estimate holds), then the weighing goes on."""
    est = copy.deepcopy(models["calibrated"])
    clean = est.estimate(swing)
    a = _moving(swing, "boom_rate", clean)
    rows = swing.frame.to_dict("records")
    est.reset()
    for row in rows[:a]:
        est.step(row)
    regression = est.kernel.regression
    regression.forget((True, True, True))
    after = [est.step(row).estimate for row in rows[a:a + 200]]
    held = regression._balance_len  # a window's samples: all of them fresh before it weighs
    assert np.allclose(after[:held], after[0], rtol=0.0, atol=1e-9)
    assert after[-1] != after[0]  # weighed again after


def test_newly_named_joints():
    """A pressure just named: its joint; a rate (or anything not a dropped pressure): every joint;
    a signal named at the sample before: none."""
    signals = ("boom_angle", "boom_rate", "dipper_head_pressure", "dipper_rate", "dipper_angle")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    m.previous, m.active = set(), {(2, "stuck"): 0}
    assert m.newly_named_joints(("dipper_head_pressure",)) == (False, True, False)
    assert m.newly_named_joints(()) == (True, True, True)  # not a pressure it drops
    m.active[(1, "stuck")] = 0
    assert m.newly_named_joints(("dipper_head_pressure",)) == (True, True, True)
    m.previous = {1, 2}
    assert m.newly_named_joints(("dipper_head_pressure",)) == (False, False, False)


def test_cleared_joints():
    """A substituted signal no longer named: every joint (its windows mix the substitute with the
    measured signal); a dropped pressure no longer named: none (its samples were dropped); still
    named, or not named before: none."""
    signals = ("boom_angle", "boom_rate", "dipper_head_pressure", "dipper_rate", "dipper_angle")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    m.previous, m.active = {1}, {}
    assert m.cleared_joints(("dipper_head_pressure",)) == (True, True, True)
    m.previous = {2}
    assert m.cleared_joints(("dipper_head_pressure",)) == (False, False, False)
    assert m.cleared_joints(()) == (True, True, True)  # not a pressure it drops
    m.previous, m.active = {1}, {(1, "noise"): 3}
    assert m.cleared_joints(("dipper_head_pressure",)) == (False, False, False)
    m.previous, m.active = set(), {(3, "stuck"): 0}
    assert m.cleared_joints(("dipper_head_pressure",)) == (False, False, False)


def test_the_windows_over_a_substitutes_end_are_forgotten(models, swing, monkeypatch):  # noqa: F811
    """A noisy bucket rate weighed on its angle's slope: at the first sample after its name has
    cleared the estimator has the kernel forget every joint's windows over its rings (they mix
    the slope with the measured rate: a dipper rate 46 kg ``ok`` after its noise, seed 15500)."""
    est = models["calibrated"]
    a = _moving(swing, "bucket_rate", est.estimate(swing))
    calls = []
    monkeypatch.setattr(type(est), "_forget_joints", lambda self, joints: calls.append(tuple(joints)))
    bad = _with(swing, "bucket_rate", a, a + 100, RATE_FAULTS[2][2])
    out = est.estimate(bad)
    named = out["fault"].astype(str).str.contains("bucket_rate:").to_numpy()
    assert named.any()
    end = int(np.flatnonzero(named)[-1]) + 1  # the first sample no longer named
    assert out["status"].iloc[end - 1] == Status.DEGRADED.value
    assert len(calls) >= 2 and calls[-1] == (True, True, True)
    # the last forget comes at the end: replayed up to that sample, it is the one that calls it
    calls.clear()
    est.reset()
    rows = bad.frame.to_dict("records")
    for row in rows[:end]:
        est.step(row)
    before = len(calls)
    est.step(rows[end])
    assert len(calls) == before + 1 and calls[-1] == (True, True, True)


def test_degraded_sigma_covers_the_move_since_it_began(models, swing):  # noqa: F811
    """While degraded, sigma is the own sigma doubled plus the estimate's move since the first
    degraded sample of the episode (a stuck bucket rate's slope moved a young weighing 50 kg
    within a sigma of 16 kg, seed 15500); a sample weighed as measured ends the episode."""
    est = copy.deepcopy(models["calibrated"])
    a = _moving(swing, "dipper_rate", est.estimate(swing))
    bad = _with(swing, "dipper_rate", a, a + 250, RATE_FAULTS[1][2])
    est.reset()
    first, moves, episodes, was = None, [], 0, False
    for row in bad.frame.to_dict("records"):
        r = est.step(row)
        degraded = r.status is Status.DEGRADED
        if degraded:
            if not was:
                first, episodes = r.estimate, episodes + 1
            own = est._estimate_sigma()
            move = abs(r.estimate - first)
            assert math.isclose(r.sigma, health.DEGRADED_SIGMA_FACTOR * own + move, rel_tol=1e-12, abs_tol=1e-12)
            moves.append(move)
        if r.status in (Status.OK, Status.DEGRADED):
            was = degraded
    assert len(moves) > 50 and episodes >= 1
    assert max(moves) > 0.5  # the rule is exercised
