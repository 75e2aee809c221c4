"""A pause of the joint check that ends with the memories agreeing again restarts the weighing
(``settings.PAUSE_RESTARTS``): the check starts its sums from nothing, and the kernel's whole sums
still hold the windows the pause saw — a boom rod pressure 12 bar low for 0.7 s left a `lever`
weighing ``ok`` 61 kg off once the fresh sums agreed, a boom rate's bias in the warm-up 56 kg
(docs/sensor-health.md, session 21). A pause that lasts (``JOINT_PAUSE_WINDOWS``) is judged on
the sums instead and restarts nothing."""

from excavator_payload.estimators.classical.machine_calibration import joint_check as joint_check_module
from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import JOINT_PAUSE_WINDOWS
from tests.estimators.classical.test_joint_check import RATED, StandIn, _windows


def _memories(kernel, short_kg):
    """The new-load test's memories: the whole weighing at 1000 kg, the short one at ``short_kg``."""
    kernel.info, kernel.num = 1.0, 1000.0
    kernel.info_short, kernel.num_short = 0.5, 0.5 * short_kg


def _pause_then_agree(check, kernel, windows):
    _memories(kernel, 1200.0)  # 200 kg apart: past JOINT_CHANGE_SHARE (100 kg) and its σ
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), windows)
    _memories(kernel, 1000.0)
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), 1)


def test_a_pause_that_ends_restarts_the_weighing():
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _memories(kernel, 1200.0)
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), 5)
    assert check.pausing and not check.restart
    _memories(kernel, 1000.0)
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), 1)
    assert not check.pausing and check.restart and check.pause_restarts == 1
    assert check.info == [0.0, 0.0, 0.0]  # the check's sums start from nothing, as before


def test_without_the_rule_nothing_restarts(monkeypatch):
    monkeypatch.setattr(joint_check_module, "PAUSE_RESTARTS", False)
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _pause_then_agree(check, kernel, 5)
    assert not check.pausing and not check.restart and check.pause_restarts == 0


def test_a_lasting_pause_is_judged_not_restarted():
    """Past JOINT_PAUSE_WINDOWS the pause ends on the sums (disarmed): no restart then, nor when
    the memories agree afterwards (no pause was running)."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _pause_then_agree(check, kernel, JOINT_PAUSE_WINDOWS + 2)
    assert not check.restart and check.pause_restarts == 0


def test_no_restart_while_the_weighing_runs_on_substitutes():
    """The estimator weighs the monitor's substitutes (``degraded``: the kernel's ``substituting``):
    a pause that ends then restarts nothing, or the weighing would start again on the substitutes
    alone (a stuck boom rate's slope: 8 → 62 kg ``ok`` after the fault, bench_faults seed 94200)."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel.substituting = True
    _pause_then_agree(check, kernel, 5)
    assert not check.pausing and not check.restart and check.pause_restarts == 0
