"""After a dump, a joint weighed both before it and after it that weighs less after it restarts the
weighing (machine_calibration/joint_check.py, ``JointCheck._dumped_load``): a load too small for
the new-load test (300 kg dumped on `slopes`) otherwise left dipper and bucket standing with the old
load's sums while the boom, moving alone after the dump, weighed the empty bucket, and the check
named the sound boom (docs/findings/false-alarms.md, "The stale joint after a small dump"). The
check is driven through the stand-in kernel of test_joint_check.py."""

from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import JOINT_CHANGE_SHARE
from tests.estimators.classical.test_joint_check import RATED, StandIn, _windows

BOOM = "boom_head_pressure:balance,boom_rod_pressure:balance"


def _work_cycle(check, kernel, after, windows=300):
    """All three joints weigh 300 kg, the bucket dumps, then the boom moves alone weighing
    ``after`` kg, one window at a time; the kernel restarts when the check asks (a new load).
    Returns the window after the dump in which the weighing restarted (None: never)."""
    _windows(check, kernel, (300.0, 300.0, 300.0), 60)
    kernel.dumping = True
    _windows(check, kernel, (None, 200.0, 150.0), 30)
    kernel.dumping = False
    for k in range(windows):
        _windows(check, kernel, (after, None, None), 1)
        if check.restart:
            check.restart = False
            kernel.new_loads += 1
            return k
    return None


def test_a_load_left_in_a_dump_restarts_the_weighing():
    """The boom weighs the emptied bucket (0 kg) after the dump: the weighing restarts within a few
    windows, and nothing is named (before the rule the boom was named, its sums half of each
    load)."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    k = _work_cycle(check, kernel, 0.0)
    assert k is not None and k < 20 and check.dumped_loads == 1
    _windows(check, kernel, (0.0, None, None), 300)
    assert check.fault == "" and check.info[1] == check.info[2] == 0.0


def test_a_dump_that_leaves_the_load_does_not_restart():
    """The bucket opened fast but the boom weighs the same after it (a dump of nothing, or a load
    change under the limit): no restart, nothing named."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    assert _work_cycle(check, kernel, 300.0 - 0.8 * JOINT_CHANGE_SHARE * RATED) is None
    assert check.fault == "" and check.dumped_loads == 0


def test_a_joint_weighing_more_after_a_dump_is_still_named():
    """A dump takes a load away: a boom weighing 400 kg more after it (its sensor, not the load) is
    no dumped load; it is named as before."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    assert _work_cycle(check, kernel, 700.0) is None
    assert check.fault == BOOM and check.dumped_loads == 0
