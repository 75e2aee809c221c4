"""Two rules of the joint check at a new load, found on fresh simulated shifts (docs/loadout.md,
"A fresh shift"): a new load's first windows converge by more than the moving limit, which is no
lone joint's fault (:attr:`JointCheck.moved_settled`: a move counts once the last windows hold
at most ``LONE_YOUNG_SHARE`` of the weighing's information); and a pair named while only two joints were compared (nothing
weighed) is judged again on a new load's sums instead of waiting for the third joint."""

from types import SimpleNamespace

from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import (
    JOINT_MOVING_SHARE, JOINT_MOVING_WINDOWS, JOINT_SAMPLES, LONE_YOUNG_SHARE)
from excavator_payload.estimators.classical.pressure_regression import PressureKernel
from excavator_payload.estimators.status import Status
from tests.estimators.classical.test_joint_check import RATED, StandIn, _windows

PAIR = "boom_head_pressure:balance,boom_rod_pressure:balance,dipper_head_pressure:balance,dipper_rod_pressure:balance"


def _move(info: float, growth: float, move: float) -> JointCheck:
    """A check whose kernel's N / I moves by ``move`` kg over JOINT_MOVING_WINDOWS windows, its
    information ``info`` growing by ``growth`` a window."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    for k in range(3 * JOINT_MOVING_WINDOWS):
        kernel.info = info + growth * k
        kernel.num = kernel.info * (4000.0 + move * k / JOINT_MOVING_WINDOWS)
        _windows(check, kernel, (None, None, None), 1)
    return check


def test_a_move_counts_for_a_lone_joint_only_once_the_weighing_is_settled():
    """The same move, 2 × the moving limit in JOINT_MOVING_WINDOWS windows: while the last windows
    hold more than LONE_YOUNG_SHARE of the information (a new load's first second) it is
    ``load_changing`` but a lone joint does not wait on it; on a weighing that holds much already
    the lone joint waits (``warming_up``), as for a boom rate's bias."""
    move = 2.0 * JOINT_MOVING_SHARE * RATED
    window = 1e-3
    young = window * JOINT_MOVING_WINDOWS / (2.0 * LONE_YOUNG_SHARE)  # the ring holds about twice the share
    converging = _move(young - 2 * JOINT_MOVING_WINDOWS * window, window, move)
    assert converging.moving and not converging.moved_settled
    settled = _move(10.0 * young, window, move)
    assert settled.moving and settled.moved_settled

    rules = PressureKernel._joint_rules
    for check, waits in ((converging, False), (settled, True)):
        regression = SimpleNamespace(joint_checked=False, joint_suspect=check.suspect,
                                     joint_moved_settled=check.moved_settled, joint_pausing=False, joint_fault="")
        kernel = SimpleNamespace(regression=regression, _lone_moved=False)
        assert rules(kernel, Status.OK) is Status.LOAD_CHANGING
        regression.joint_suspect = regression.joint_moved_settled = False  # held still again, one joint
        assert rules(kernel, Status.OK) is (Status.WARMING_UP if waits else Status.OK)


def _named_pair() -> tuple:
    """Boom and dipper compared (the bucket weighs nothing) and 300 kg apart: both named."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 700.0, None), 3 * JOINT_SAMPLES)
    assert check.fault == PAIR
    return kernel, check


def test_a_pair_named_clears_when_its_joints_agree_on_a_new_loads_sums():
    """Before, a pair cleared only once all three joints were compared (a dig keeps the bucket's
    joint out for a whole truck: 45-55 s named); now its own two agreeing on a new load's sums
    clear it (and restart the weighing, as any cleared name)."""
    kernel, check = _named_pair()
    _windows(check, kernel, (1000.0, 1000.0, None), 3 * JOINT_SAMPLES)  # the same load: sums hold the fault
    assert check.fault == PAIR
    kernel.new_loads += 1
    _windows(check, kernel, (1000.0, 1000.0, None), 3 * JOINT_SAMPLES)
    assert check.fault == "" and check.restart and check.cleared_pairs == 1


def test_a_pair_stays_named_while_it_disagrees_or_is_not_compared_again():
    """A lasting fault: the pair disagrees on the new load's sums too, and stays named; so it does
    while fewer than two joints are compared on the new sums."""
    kernel, check = _named_pair()
    kernel.new_loads += 1
    _windows(check, kernel, (1000.0, 700.0, None), 3 * JOINT_SAMPLES)
    assert check.fault == PAIR
    kernel, check = _named_pair()
    kernel.new_loads += 1
    _windows(check, kernel, (1000.0, None, None), 3 * JOINT_SAMPLES)
    assert check.fault == PAIR


def test_a_pair_clears_when_one_of_it_and_the_third_joint_agree_on_a_new_loads_sums():
    """A dig's pair (docs/findings/false-alarms.md, `shift` seed 63000): boom and bucket named, and
    on every later load the boom and the dipper are compared while the bucket never holds enough
    information to be compared again. Any two compared joints hold one of the pair: their agreeing
    on the new load's sums clears the pair (and restarts the weighing); two that disagree do not."""
    kernel, check = _named_pair()
    kernel.new_loads += 1
    _windows(check, kernel, (1000.0, None, 1000.0), 3 * JOINT_SAMPLES)
    assert check.fault == "" and check.restart and check.cleared_pairs == 1
    kernel, check = _named_pair()
    kernel.new_loads += 1
    _windows(check, kernel, (None, 700.0, 1000.0), 3 * JOINT_SAMPLES)
    assert check.fault != "" and check.cleared_pairs == 0


def test_a_pair_clears_when_its_own_two_agree_again_on_the_same_loads_sums():
    """A pair named on the edge (`shift` seed 64000: boom and dipper 176 kg apart, χ² 15.2, on a
    fresh dipper's first windows) whose own two agree again as they gather information on the same
    load clears there (and restarts the weighing), as a joint named alone clears by agreeing with
    another compared joint; before, it waited for the third joint or a new load (20 s)."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 800.0, None), 3 * JOINT_SAMPLES)
    assert check.fault == PAIR
    _windows(check, kernel, (1000.0, 1000.0, None), 6 * JOINT_SAMPLES)  # the dipper's sums come to 933 kg
    assert check.fault == "" and check.restart and check.cleared_pairs == 0
