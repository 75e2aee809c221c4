"""Degraded weighing on a lost link angle (``calibrated``, momentum form): while the health
monitor names a boom, dipper or bucket angle stuck or dropped out (its rate at most named
``disagree`` with it), the angle is the last healthy one plus the rate integrated since, for at
most ``health.ANGLE_SUBSTITUTE_LIMIT``; then the estimator stops (``sensor_fault``)."""

import math

import numpy as np
import pytest

from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status

from .test_health import _with  # a signal of one experiment rewritten on rows a:b
from .test_health_degraded import _moving, assert_stream_equals_batch, models, swing  # noqa: F401  (fixtures)


def test_reference_plus_integrated_rate():
    """The reference is the mean of angle − integrated rate over n_sub samples ending n_stuck
    back; the substitute adds the integral since; a rate named with anything but ``disagree``,
    or the bound passed, gives none."""
    signals = ("boom_angle", "boom_rate")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    angle = lambda k: 0.2 + 0.3 * 0.01 * k  # noqa: E731  (rate 0.3 rad/s, angle 0.2 rad at k = 0)
    for k in range(100):
        m.step(0.01 * k, [angle(k), 0.3])
    m.active = {(0, "stuck"): 0, (0, "disagree"): 0, (1, "disagree"): 0}
    m._angle_references()
    assert m.angle_ref[0] == pytest.approx(0.2, abs=1e-12)  # y = angle − ∫rate: 0.2 throughout
    got = m.substitute(np.array([0.25, 0.3]), (), (), ("boom_angle",))
    assert got[0] == pytest.approx(angle(99), abs=1e-12) and got[1] == 0.3  # the rate as measured
    assert m.substitute(np.array([0.25, 0.3]), (), (), ()) is None  # not allowed: none
    m.active[(1, "stuck")] = 0
    assert m.substitute(np.array([0.25, 0.3]), (), (), ("boom_angle",)) is None
    del m.active[(1, "stuck")]
    m.angle_age[0] = m.n_angle_limit + 1
    assert m.substitute(np.array([0.25, 0.3]), (), (), ("boom_angle",)) is None


def test_stuck_angle_weighs_degraded_then_stops(models, swing):  # noqa: F811
    est = models["calibrated"]
    assert est.degraded_angles() == ("boom_angle", "dipper_angle", "bucket_angle")
    clean = est.estimate(swing)
    a = _moving(swing, "boom_rate", clean)
    out = est.estimate(_with(swing, "boom_angle", a, len(swing.frame), lambda v, a, b: v[a - 1]))
    status, fault = out["status"].to_numpy(), out["fault"].to_numpy()
    named = np.array(["boom_angle:" in f for f in fault])
    assert named.any() and not (status[named] == Status.OK.value).any()
    degraded = np.flatnonzero(status == Status.DEGRADED.value)
    assert len(degraded) >= 50 and named[degraded].all()
    diff = out["payload_estimate"].to_numpy()[degraded] - clean["payload_estimate"].to_numpy()[degraded]
    sigma = out["sigma"].to_numpy()[degraded]
    assert np.max(np.abs(diff)) <= 60.0 and np.all(np.abs(diff) <= 2 * sigma)
    # bounded: nothing degraded later than the limit after the angle was named, then sensor_fault
    first = int(np.flatnonzero(named)[0])
    limit = int(round(health.ANGLE_SUBSTITUTE_LIMIT / 0.01))
    assert degraded.max() <= first + limit
    if len(status) > first + limit + 10:
        assert (status[first + limit + 1:] == Status.SENSOR_FAULT.value).all()


def test_streaming_equals_batch_on_a_lost_angle(models, swing):  # noqa: F811
    est = models["calibrated"]
    a = _moving(swing, "boom_rate", est.estimate(swing))
    bad = _with(swing, "boom_angle", a, a + 300, lambda v, a, b: v[a - 1])
    batch = est.estimate(bad)
    assert (batch["status"] == Status.DEGRADED.value).sum() >= 20
    assert_stream_equals_batch(est, bad, batch)


def test_no_reference_after_a_hole_in_time():
    """A hole in time restarts the integral: a reference taken is lost, no substitute until the
    angle is no longer named."""
    signals = ("boom_angle", "boom_rate")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    for k in range(100):
        m.step(0.01 * k, [0.2 + 0.003 * k, 0.3])
    m.active = {(0, "stuck"): 0}
    m._angle_references()
    assert math.isfinite(m.angle_ref[0])
    m.step(5.0, [0.5, 0.3])  # 4 s later
    m.active[(0, "stuck")] = 0
    assert math.isnan(m.angle_ref[0])
    assert m.substitute(np.array([0.5, 0.3]), (), (), ("boom_angle",)) is None
