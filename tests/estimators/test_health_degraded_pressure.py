"""Degraded weighing without a cylinder's joint (``calibrated``, momentum form): while the health
monitor names a boom, dipper or bucket cylinder pressure (stuck, dropout, noise), the estimator
weighs on the other joints' balance windows (a cylinder's force enters only its own joint's
balance), says ``degraded`` with the pressure still named and sigma widened; the named
pressure's values never reach the estimate; streaming equals batch; the other estimators stop."""

import copy

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status

from .test_health import _with  # a signal of one experiment rewritten on rows a:b
from .test_health_degraded import _moving, assert_stream_equals_batch, models, swing  # noqa: F401  (fixtures)

BAR = 1e5
SIGNALS = list(MACHINE_SENSORS.signals)

PRESSURE_FAULTS = [
    ("boom_head_pressure", "boom_rate", "stuck", lambda v, a, b: v[a - 1]),
    ("dipper_rod_pressure", "dipper_rate", "dropout", lambda v, a, b: 0.0),
    ("bucket_head_pressure", "bucket_rate", "noise",
     lambda v, a, b: v[a:b] + 10 * BAR * np.random.default_rng(2).standard_normal(b - a)),
]


@pytest.mark.parametrize("signal,rate,kind,how", PRESSURE_FAULTS)
def test_pressure_fault_weighs_degraded_never_ok(models, swing, signal, rate, kind, how):  # noqa: F811
    est = models["calibrated"]
    assert signal in est.degraded_pressures()
    clean = est.estimate(swing)
    a = _moving(swing, rate, clean)
    out = est.estimate(_with(swing, signal, a, a + 150, how))
    status, fault = out["status"].to_numpy(), out["fault"].to_numpy()
    named = np.array([f"{signal}:" in f for f in fault])
    assert named.any()
    assert not (status[named] == Status.OK.value).any()  # never ok on a named signal
    degraded = status == Status.DEGRADED.value
    assert degraded.sum() >= 20
    assert set(fault[degraded]) == {f"{signal}:{kind}"}  # the pressure still named (DM1 active), alone
    diff = out["payload_estimate"].to_numpy()[degraded] - clean["payload_estimate"].to_numpy()[degraded]
    sigma = out["sigma"].to_numpy()[degraded]
    assert np.all(np.isfinite(diff)) and np.all(sigma > 0)
    # weighed without the joint: near the clean run (a pressure of 0 or 10 bar of noise weighed
    # would be hundreds to thousands of kg off), within the widened sigma
    assert np.max(np.abs(diff)) <= 60.0
    assert np.all(np.abs(diff) <= 2 * sigma)


def _forced(monkeypatch, signal, t0, t1):
    """The monitor names ``signal`` stuck on every sample in [t0, t1) (besides what it finds)."""
    step, col = health.HealthMonitor.step, SIGNALS.index(signal)

    def forced_step(self, time, values):
        found = step(self, time, values)
        if not t0 <= time < t1:
            return found
        self.active[(col, "stuck")] = 0
        return ",".join(f"{self.signals[i]}:{k}" for i, k in sorted(self.active))

    monkeypatch.setattr(health.HealthMonitor, "step", forced_step)


def test_dropped_joints_pressure_never_reaches_the_estimate(models, swing, monkeypatch):  # noqa: F811
    """With the boom head pressure named on the same samples, its values there (as measured, or
    60 bar higher and ramping another 100 bar: a fault the monitor does not see) give the same
    estimates bit for bit, before, during and after; and while it is named the boom joint's
    information does not grow (where it grows when not named)."""
    est = copy.deepcopy(models["calibrated"])
    clean = est.estimate(swing)
    a = _moving(swing, "boom_rate", clean)
    b = a + 200
    t = swing.frame["time"].to_numpy()
    _forced(monkeypatch, "boom_head_pressure", t[a], t[b])
    same = _with(swing, "boom_head_pressure", a, b, lambda v, a, b: v[a:b])
    off = _with(swing, "boom_head_pressure", a, b, lambda v, a, b: v[a:b] + 60 * BAR + np.linspace(0, 100 * BAR, b - a))
    ref, bad = est.estimate(same), est.estimate(off)
    assert (ref["status"].to_numpy()[a:b] == Status.DEGRADED.value).sum() > 100
    assert list(ref["status"]) == list(bad["status"]) and list(ref["fault"]) == list(bad["fault"])
    np.testing.assert_array_equal(ref["payload_estimate"].to_numpy(), bad["payload_estimate"].to_numpy())
    np.testing.assert_array_equal(ref["sigma"].to_numpy(), bad["sigma"].to_numpy())
    # the kernel's per-joint information, streamed: flat for the boom while its windows hold a
    # named sample (from the differentiator's delay on), growing where it was weighed unnamed
    def boom_info(data):
        est.reset()
        info = []
        for row in data.frame.to_dict("records"):
            est.step(row)
            info.append(list(est.kernel.regression.info_joint))
        return np.array(info)

    named = boom_info(same)[a + 20:b]
    assert np.ptp(named[:, 0]) == 0.0
    monkeypatch.undo()
    unnamed = boom_info(same)[a + 20:b]
    assert np.ptp(unnamed[:, 0]) > 0.0  # the control: the boom is weighed on these samples


def test_streaming_equals_batch_on_a_degraded_pressure_run(models, swing):  # noqa: F811
    est = models["calibrated"]
    signal, rate, _, how = PRESSURE_FAULTS[0]
    a = _moving(swing, rate, est.estimate(swing))
    bad = _with(swing, signal, a, a + 150, how)
    batch = est.estimate(bad)
    assert (batch["status"] == Status.DEGRADED.value).sum() >= 20
    assert_stream_equals_batch(est, bad, batch)


def test_other_estimators_stop_on_a_pressure(models, swing):  # noqa: F811
    """Inverse dynamics and calibrated's other balance forms were not measured without a joint:
    a named pressure stops them (sensor_fault) as before."""
    from excavator_payload.estimators.base import create_estimator

    assert models["inverse-dynamics"].degraded_pressures() == ()
    assert create_estimator("calibrated", balance="differentiated").degraded_pressures() == ()
    signal, rate, _, how = PRESSURE_FAULTS[0]
    a = _moving(swing, rate)
    out = models["inverse-dynamics"].estimate(_with(swing, signal, a, a + 150, how))
    assert (out["status"] == Status.SENSOR_FAULT.value).any()
    assert not (out["status"] == Status.DEGRADED.value).any()


def test_named_joints_and_droppable():
    """The monitor's side: a named pressure of an allowed joint is set to 0 and its joint
    reported; a pressure not allowed gives no substitute."""
    signals = ("boom_angle", "boom_rate", "boom_head_pressure", "dipper_rod_pressure")
    m = health.HealthMonitor(signals, 0.01, {s: 1e-6 for s in signals})
    for k in range(30):
        m.step(0.01 * k, [0.01 * k, 1.0, 1e7, 5e6])
    m.active = {(3, "noise"): 0}
    got = m.substitute(np.array([0.3, 1.0, 1e7, 5e6]), (), ("dipper_rod_pressure",))
    assert got[3] == 0.0 and got[2] == 1e7 and m.named_joints(("dipper_rod_pressure",)) == (False, True, False)
    assert m.substitute(np.zeros(4), (), ("boom_head_pressure",)) is None
    assert m.named_joints(("boom_head_pressure",)) == (False, False, False)
    m.active = {(3, "offset"): 0}  # not a substitute kind
    assert m.substitute(np.zeros(4), (), ("dipper_rod_pressure",)) is None
