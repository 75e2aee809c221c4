"""Two rules of the weighing before a fault is named, found on bench_faults.py's worst cells
(docs/sensor-health.md, "Worst cells traced"): the moving rule follows the weighing reported (with
``--imu-nuisance on`` the IMU filter's payload, which moves up to 4× faster than N / I), and a
weighing that moved while its joints were compared waits (``warming_up``) after the check's pause
until they are compared again on fresh sums (a boom rate's bias: 74 kg ``ok`` before)."""

import math
from types import SimpleNamespace

from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import (
    JOINT_MOVING_SHARE, JOINT_MOVING_WINDOWS)
from excavator_payload.estimators.classical.pressure_regression import PressureKernel
from excavator_payload.estimators.status import Status
from tests.estimators.classical.test_joint_check import RATED, StandIn, _windows


def test_the_moving_rule_follows_the_imu_filters_payload():
    """N / I still, the filter's payload (as the last window left it) moving by 1.2 × the limit
    over JOINT_MOVING_WINDOWS windows: suspect; without the filter N / I is followed as before."""
    limit = JOINT_MOVING_SHARE * RATED
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel.info, kernel.num = 1.0, 1000.0
    kernel._imu_nuisance = object()
    for k in range(3 * JOINT_MOVING_WINDOWS):
        kernel.payload_before = 1000.0 - 1.2 * limit * k / JOINT_MOVING_WINDOWS
        _windows(check, kernel, (1000.0, 1000.0, 1000.0), 1)
    assert check.moving and check.suspect
    plain, check = StandIn(), JointCheck(RATED, 2.5)
    plain.info, plain.num, plain.payload_before = 1.0, 1000.0, math.nan
    for k in range(3 * JOINT_MOVING_WINDOWS):
        _windows(check, plain, (1000.0, 1000.0, 1000.0), 1)
    assert not check.moving


def _rules(**flags):
    regression = SimpleNamespace(joint_checked=True, joint_suspect=False, joint_moved_settled=False, joint_pausing=False,
                                 joint_fault="")
    kernel = SimpleNamespace(regression=regression, _lone_moved=False)
    vars(regression).update(flags)
    return kernel, regression


def test_a_move_while_compared_waits_for_a_comparison_after_the_pause():
    """The weighing moves while two joints are compared (suspect: load_changing); the check pauses
    and starts its sums again (not checked): ``warming_up``, not ``ok``, until two joints are
    compared on the new sums; a named joint is said, not waited on."""
    kernel, regression = _rules(joint_suspect=True, joint_moved_settled=True)
    rules = PressureKernel._joint_rules
    assert rules(kernel, Status.OK) is Status.LOAD_CHANGING and kernel._lone_moved
    regression.joint_suspect = regression.joint_moved_settled = False
    regression.joint_pausing = True  # held still, the pause on
    assert rules(kernel, Status.OK) is Status.LOAD_CHANGING and kernel._lone_moved
    regression.joint_pausing, regression.joint_checked = False, False  # fresh sums: one joint
    assert rules(kernel, Status.OK) is Status.WARMING_UP
    regression.joint_fault = "dipper_head_pressure:balance,dipper_rod_pressure:balance"
    assert rules(kernel, Status.OK) is Status.OK  # step() then says sensor_fault with the name
    regression.joint_fault, regression.joint_checked = "", True  # compared again
    assert rules(kernel, Status.OK) is Status.OK and not kernel._lone_moved
