"""The joint check's rules for the time before a fault is named and after it clears
(machine_calibration/joint_check.py; docs/sensor-health.md, "Before the name, and after"): no
``ok`` estimate while the whole weighing moves by more than JOINT_MOVING_SHARE of the rated
payload over JOINT_MOVING_WINDOWS windows (``suspect``: ``load_changing``), and a named joint
that clears restarts the weighing (its sums hold the fault's windows). The check is driven through the stand-in kernel of test_joint_check.py."""

import copy

import pytest

from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import (
    JOINT_CHI2, JOINT_MOVING_SHARE, JOINT_MOVING_WINDOWS, JOINT_SAMPLES)
from excavator_payload.estimators.status import Status
from tests.estimators.classical.test_joint_check import RATED, StandIn, _windows


def test_joints_that_part_below_the_naming_limit_are_not_suspect_alone():
    """The dipper 110 kg below boom and bucket (χ² between 10 and JOINT_CHI2): nothing named, and
    not suspect while the weighing holds still (clean lever motions on a slope part the joints
    that far with the estimate 4 kg off: a χ² rule below the naming one was dropped)."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel.info, kernel.num = 1.0, 1000.0
    _windows(check, kernel, (1000.0, 890.0, 1000.0), 10 * JOINT_SAMPLES)
    assert check.fault == "" and check.checked and 10.0 < check.chi2 < JOINT_CHI2
    assert not check.suspect


def test_a_weighing_that_moves_is_suspect():
    """N / I moving by 1.2 × the limit over JOINT_MOVING_WINDOWS windows is suspect, 0.8 × is not;
    a weighing without information (NaN) never is."""
    limit = JOINT_MOVING_SHARE * RATED
    for factor, moving in ((1.2, True), (0.8, False)):
        kernel, check = StandIn(), JointCheck(RATED, 2.5)
        kernel.info = 1.0
        for k in range(3 * JOINT_MOVING_WINDOWS):
            kernel.num = 1000.0 + factor * limit * k / JOINT_MOVING_WINDOWS
            _windows(check, kernel, (1000.0, 1000.0, 1000.0), 1)
        assert check.moving is moving and check.suspect is moving and check.chi2 < 1.0
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), 3 * JOINT_MOVING_WINDOWS)
    assert kernel.info == 0.0 and not check.moving


def test_a_named_joint_that_clears_asks_for_a_restart():
    """The dipper named; the check's sums start again (a new load) and the joints agree: the fault
    clears, and the check asks the kernel to start the weighing again; a clean run never does."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 700.0, 1000.0), 3 * JOINT_SAMPLES)
    assert check.fault != "" and not check.restart
    kernel.new_loads += 1
    asked = False
    for _ in range(10 * JOINT_SAMPLES):
        _windows(check, kernel, (1000.0, 1000.0, 1000.0), 1)
        asked |= check.restart
        check.restart = False  # the kernel's part (CalibratedKernel._check_joints)
    assert asked and check.fault == ""

    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 1000.0, 1000.0), 10 * JOINT_SAMPLES)
    assert not check.restart


@pytest.fixture(scope="module")
def momentum(machine_calibration):
    est = create_estimator("calibrated", "cat345c-hydraulic-3pct", balance="momentum")
    est.fit(machine_calibration["cal"])
    return est


def test_the_kernel_restarts_when_the_check_asks(momentum, machine_calibration):
    """CalibratedKernel._check_joints: the check's restart starts the weighing again as a new load's
    (sums empty, the wait for the boom, ``new_loads`` counted for the IMU dynamics)."""
    est = copy.deepcopy(momentum)
    kernel = est.kernel.regression
    kernel.joint_check = True
    f = machine_calibration["zero"].frame
    values = f[list(est.sensor_set.signals)].to_numpy(float)
    for i, v in enumerate(values[:400]):
        kernel.update(i / 100.0, v)
    assert kernel.info > 0.0 and kernel.boom_windows > 0
    loads = kernel.new_loads
    kernel._joints.restart = True
    kernel._joints.update = lambda *args: None  # the check's own judgement aside
    kernel._check_joints([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert kernel.info == 0.0 and kernel.num == 0.0 and kernel.boom_windows == 0
    assert kernel.new_loads == loads + 1 and not kernel._joints.restart and not kernel.changing


def test_the_zeros_share_restarts_with_the_weighing(momentum, machine_calibration):
    """After a zero the check's restart empties the zero's share of σ (OffsetShare) in the same
    window, as the C export does: it once did so a window late in Python and never in C (σ up to
    15 kg apart after a restart)."""
    est = copy.deepcopy(momentum)
    est.zero(machine_calibration["zero"])
    kernel = est.kernel.regression
    share = kernel._offset_share
    assert share is not None
    kernel.joint_check = True
    values = machine_calibration["cal"].frame[list(est.sensor_set.signals)].to_numpy(float)
    for i, v in enumerate(values[:400]):
        kernel.update(i / 100.0, v)
    assert abs(share.c).max() > 0.0
    kernel._joints.restart = True
    kernel._joints.update = lambda *args: None
    kernel._check_joints([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert share._loads == kernel.new_loads and share.std == 0.0
    assert not (share.Gr.any() or share.Gphi.any() or share.c.any() or share.c_short.any())


def test_a_suspect_weighing_says_load_changing(momentum, machine_calibration, monkeypatch):
    """PressureKernel.step: with the check on, a suspect check turns ``ok`` into ``load_changing``;
    with it off (``health`` off) nothing changes."""
    from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck as JC

    est = copy.deepcopy(momentum)
    est.options["joint_check"] = "on"
    est.use_calibration()
    data = machine_calibration["cal"]
    statuses = est.estimate(data)["status"].astype(str)
    assert (statuses == "ok").sum() > 100
    monkeypatch.setattr(JC, "suspect", property(lambda self: True))
    suspect = est.estimate(data)["status"].astype(str)
    assert (suspect == "ok").sum() == 0
    ok = (statuses == "ok").to_numpy()
    assert (suspect[ok] == Status.LOAD_CHANGING.value).all()
    assert (suspect[~ok] == statuses[~ok]).all()  # only ok turns
    est.health = False
    assert (est.estimate(data)["status"].astype(str) == "ok").sum() > 100
