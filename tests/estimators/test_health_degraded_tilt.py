"""Degraded weighing on a named house tilt (``calibrated``, momentum form): while the health
monitor names house pitch or roll (any kind), the tilt is its mean from before the fault
(``health.TILT_SUBSTITUTE_BACK``), for at most ``health.TILT_SUBSTITUTE_LIMIT`` and while the
house has not slewed so far that the frozen tilt could be off by more than
``health.TILT_OFFSET_LIMIT``; the weighing goes on (``degraded``) instead of stopping and
restarting from nothing after the fault (a drifting tilt on seed 6800 of bench_faults.py:
``ok`` 51 kg off after the restart, docs/sensor-health.md)."""

import math

import numpy as np
import pytest

from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status

from .test_health import _with  # a signal of one experiment rewritten on rows a:b
from .test_health_degraded import _moving, assert_stream_equals_batch, models, swing  # noqa: F401  (fixtures)

SIGNALS = ("house_pitch", "house_roll", "slew_rate")
TILTS = ("house_pitch", "house_roll")


def _monitor(pitch, roll, slew, n):
    m = health.HealthMonitor(SIGNALS, 0.01, {s: 1e-6 for s in SIGNALS})
    for k in range(n):
        m.step(0.01 * k, [pitch(k), roll(k), slew])
    return m


def test_reference_is_the_tilt_before_the_fault():
    """Pitch and roll averaged over n_sub samples ending n_tilt_back back; a drift since then is
    not in it; the substitute replaces only the named tilt; not allowed, none."""
    m = _monitor(lambda k: 0.01 + (0.0005 * (k - 150) if k > 150 else 0.0), lambda k: -0.02, 0.0, 200)
    m.active = {(0, "offset"): 0}
    m._tilt_reference()
    assert m.tilt_ref == pytest.approx((0.01, -0.02), abs=1e-12)  # from samples 79..99: before the drift
    got = m.substitute(np.array([0.5, -0.03, 0.0]), tilts=TILTS)
    assert got[0] == pytest.approx(0.01, abs=1e-12) and got[1] == -0.03  # the roll as measured
    assert m.substitute(np.array([0.5, -0.03, 0.0]), tilts=()) is None
    m.tilt_age = m.n_tilt_limit + 1  # bounded in time
    assert m.substitute(np.array([0.5, -0.03, 0.0]), tilts=TILTS) is None


def test_no_substitute_once_the_house_has_slewed_far_on_a_slope():
    """On a 5° slope the frozen tilt may be off by |tilt| × slew angle: past the tilt's offset
    limit (0.015 rad) the substitute ends; on level ground the same slew keeps it."""
    slope = math.radians(5.0)
    m = _monitor(lambda k: slope, lambda k: 0.0, 0.5, 200)  # slewing at 0.5 rad/s
    m.active = {(0, "stuck"): 0}
    m._tilt_reference()
    # 0.5 rad/s from the reference window's centre (0.9 s back... 1.1 s): 0.55 rad × 0.087 > 0.015
    assert m.tilt_turn * 0.01 == pytest.approx(0.5 * (m.n_tilt_back + m.n_sub - m.n_sub // 2) * 0.01)
    assert m.substitute(np.array([0.0, 0.0, 0.5]), tilts=TILTS) is None
    level = _monitor(lambda k: 0.001, lambda k: 0.0, 0.5, 200)
    level.active = {(0, "stuck"): 0}
    level._tilt_reference()
    assert level.substitute(np.array([0.0, 0.0, 0.5]), tilts=TILTS)[0] == pytest.approx(0.001)


def test_no_reference_after_a_hole_in_time():
    m = _monitor(lambda k: 0.01, lambda k: 0.0, 0.0, 200)
    m.active = {(1, "stuck"): 0}
    m._tilt_reference()
    assert m.substitute(np.array([0.01, 0.0, 0.0]), tilts=TILTS) is not None
    m.step(5.0, [0.01, 0.0, 0.0])  # a hole in time: the reference is gone with its samples
    m.active = {(1, "stuck"): 0}
    assert m.substitute(np.array([0.01, 0.0, 0.0]), tilts=TILTS) is None


def test_drifting_tilt_weighs_degraded_and_does_not_restart(models, swing):  # noqa: F811
    """A house pitch drifting at 3 °/s for 2.5 s: named, weighed ``degraded`` within 2σ of the
    clean run, and the weighing is not restarted after it (before: ``sensor_fault``, then a
    ``gap``, then ``warming_up`` from nothing)."""
    est = models["calibrated"]
    assert est.degraded_tilts() == TILTS
    clean = est.estimate(swing)
    a = _moving(swing, "boom_rate", clean)
    b = a + 250
    t = swing.frame["time"].to_numpy()
    out = est.estimate(_with(swing, "house_pitch", a, b, lambda v, a, b: v[a:b] + math.radians(3.0) * (t[a:b] - t[a])))
    status, fault = out["status"].to_numpy(), out["fault"].to_numpy()
    named = np.flatnonzero(np.array(["house_pitch:" in f for f in fault]))
    assert len(named) and named[0] - a <= 100
    degraded = status == Status.DEGRADED.value
    assert degraded.sum() >= 100 and not (status[named] == Status.SENSOR_FAULT.value).any()
    after = slice(named[0], None)
    assert not np.isin(status[after], [Status.GAP.value, Status.WARMING_UP.value]).any()
    diff = out["payload_estimate"].to_numpy()[degraded] - clean["payload_estimate"].to_numpy()[degraded]
    assert np.all(np.abs(diff) <= 2 * out["sigma"].to_numpy()[degraded])


def test_streaming_equals_batch_on_a_named_tilt(models, swing):  # noqa: F811
    est = models["calibrated"]
    a = _moving(swing, "boom_rate", est.estimate(swing))
    bad = _with(swing, "house_roll", a, a + 250, lambda v, a, b: v[a:b] + math.radians(6.0))
    batch = est.estimate(bad)
    assert (batch["status"] == Status.DEGRADED.value).sum() >= 20
    assert_stream_equals_batch(est, bad, batch)


def test_inverse_dynamics_still_stops_on_a_named_tilt(models, swing):  # noqa: F811
    est = models["inverse-dynamics"]
    assert est.degraded_tilts() == ()
    a = _moving(swing, "boom_rate")
    out = est.estimate(_with(swing, "house_roll", a, a + 250, lambda v, a, b: v[a:b] + math.radians(6.0)))
    named = np.array(["house_roll:" in f for f in out["fault"]])
    assert named.any() and (out["status"].to_numpy()[named] == Status.SENSOR_FAULT.value).all()
