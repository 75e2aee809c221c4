"""An ``ok`` estimate that jumps more than ``Estimator.jump_limit`` (health.JUMP_SHARE of the rated
payload) from the one before says ``load_changing`` while the health monitor runs: a drifting
bucket head pressure whose joint entered the weighing moved it 16 kg a sample, ``ok`` 52 kg off for
two samples before the moving rule saw it (seed 15500 of benchmarks/bench_faults.py)."""

import copy

import pytest

from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status, StepResult

from .test_health_degraded import models, swing  # noqa: F401  (fixtures)


def _stepped(est, swing, estimates, monkeypatch, n=None):  # noqa: F811
    """The statuses of ``est`` on the swing's first rows, its model's estimates replaced."""
    values = iter(estimates)
    monkeypatch.setattr(type(est), "_step", lambda self, time, v: StepResult(next(values), Status.OK))
    est.reset()
    rows = swing.frame.to_dict("records")[: len(estimates)]
    return [est.step(row).status for row in rows]


@pytest.mark.parametrize("jump, want", [(6.0, Status.LOAD_CHANGING), (4.0, Status.OK)])
def test_a_jump_past_the_limit_is_not_ok(models, swing, monkeypatch, jump, want):  # noqa: F811
    est = copy.deepcopy(models["calibrated"])
    est.gating = False
    limit = est.jump_limit()
    assert limit == pytest.approx(health.JUMP_SHARE * est.rated_payload) and limit == pytest.approx(5.0)
    estimates = [1000.0 + 0.01 * k for k in range(300)]
    estimates[200:] = [e + jump for e in estimates[200:]]
    status = _stepped(est, swing, estimates, monkeypatch)
    assert status[150:200] == [Status.OK] * 50
    assert status[200] is want
    assert status[201:] == [Status.OK] * 99  # the next sample moved 0.01 kg


def test_no_rule_without_the_monitor_or_for_other_estimators(models, swing, monkeypatch):  # noqa: F811
    est = copy.deepcopy(models["calibrated"])
    est.gating = False
    est.health = False
    estimates = [1000.0] * 200 + [1100.0] * 100
    assert _stepped(est, swing, estimates, monkeypatch)[200] is Status.OK
    assert models["inverse-dynamics"].jump_limit() is None
    differentiated = copy.deepcopy(models["calibrated"])
    differentiated.options["balance"] = "differentiated"
    assert differentiated.jump_limit() is None
