"""The joint check holds a new fault of one joint whose sums hold windows of both signs of its
regressor φ_j while the joint weighed on one side alone agrees with the others
(machine_calibration/joint_check.py, ``JointCheck._side_agrees``; docs/findings/false-alarms.md,
"The braked end of a curl"): a `slopes` bucket weighed 914 kg in its curl and about 1 800 kg on the
far side of the pose where the load sits over its pin, braking to a stop before the weighing was
ready, and was named (919 kg load) from the weighing's readiness to the experiment's end. The check
is driven through the stand-in kernel of test_joint_check.py."""

import copy

from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import JOINT_CHI2
from tests.estimators.classical.test_joint_check import INFO, RATED, StandIn

BUCKET = "bucket_head_pressure:balance,bucket_rod_pressure:balance"


def _windows(check, kernel, masses, count, info, negative=(False, False, False)):
    """``count`` windows in which joint j weighs ``masses[j]`` kg on ``info[j]`` (none where None),
    its regressor negative where ``negative[j]``."""
    for _ in range(count):
        d_info = [i if m is not None else 0.0 for m, i in zip(masses, info)]
        d_num = [i * m if m is not None else 0.0 for m, i in zip(masses, d_info)]
        check.update(kernel, d_num, d_info, list(negative))


def _curl_then_boom(bucket_near: float, bucket_far: float, far_windows: int = 25):
    """The traced cycle's shape: before the weighing is ready the dipper (1 000 kg) and the bucket
    curl, the bucket weighing ``bucket_near`` on its regressor's negative side and then
    ``bucket_far`` on the positive side (``far_windows`` windows); then the boom is weighed
    (1 000 kg) and the weighing is ready once its windows are in."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel = copy.copy(kernel)
    kernel.ready = False
    _windows(check, kernel, (None, 1000.0, bucket_near), 100, (0.0, INFO / 10, INFO / 40), (False, False, True))
    _windows(check, kernel, (None, None, bucket_far), far_windows, (0.0, 0.0, INFO / 40))
    _windows(check, kernel, (1000.0, None, None), 60, (INFO / 10, 0.0, 0.0))
    kernel.ready = True  # the boom's windows are in
    _windows(check, kernel, (1000.0, None, None), 10, (INFO / 10, 0.0, 0.0))
    return check


def test_a_bucket_that_agrees_before_the_crossing_is_not_named(monkeypatch):
    """The bucket agrees with boom and dipper on the near side, and is 800 kg high on the far side:
    χ² past the limit, not named; without the rule (``_side_agrees`` off) it is named."""
    check = _curl_then_boom(1000.0, 1800.0)
    assert check.chi2 > JOINT_CHI2 and check.checked
    assert check.fault == ""
    monkeypatch.setattr(JointCheck, "_side_agrees", lambda self, joints, m, w: False)
    assert _curl_then_boom(1000.0, 1800.0).fault == BUCKET


def test_a_bucket_off_on_both_sides_is_named():
    """A pressure's bias shows on both sides (b / φ_j: of opposite signs): neither side agrees, named."""
    check = _curl_then_boom(1300.0, 700.0)  # the bucket moves the weighing 28 kg: past the slight limit
    assert check.fault == BUCKET


def test_a_bucket_off_on_its_only_side_is_named():
    """No crossing (every window on one side): the rule does not apply, named as before."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel = copy.copy(kernel)
    kernel.ready = False
    _windows(check, kernel, (None, 1000.0, 1250.0), 100, (0.0, INFO / 10, INFO / 40), (False, False, True))
    _windows(check, kernel, (1000.0, None, None), 60, (INFO / 10, 0.0, 0.0))
    kernel.ready = True  # the boom's windows are in
    _windows(check, kernel, (1000.0, None, None), 10, (INFO / 10, 0.0, 0.0))
    assert check.fault == BUCKET
