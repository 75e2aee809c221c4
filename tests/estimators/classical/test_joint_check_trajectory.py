"""The joint check's trajectory test (machine_calibration/joint_check.py, ``JointCheck._trajectory``):
a joint whose own weighing moves beyond what its information allows since
:data:`TRAJECTORY_WINDOWS` windows back is named, though the other joints, with little information,
do not outvote it; a joint that weighs one mass with noise as its σ says is not, nor one that
moves while the kernel sees the load change; the name clears once the joint holds still, and the
weighing then restarts. Driven window by window through a
stand-in kernel that keeps the per-joint sums the check reads."""

import math

import numpy as np

from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import (
    JOINT_INFO_INFLATION, TRAJECTORY_WINDOWS)

RATED = 5000.0
BOOM = "boom_head_pressure:balance,boom_rod_pressure:balance"


class Kernel:
    """What :meth:`JointCheck.update` reads of a :class:`CalibratedKernel`, with its per-joint sums."""

    forgetting = 1.0
    new_loads = settles = 0
    changing = False
    ready = True
    dumping = False
    num_short = info_short = 0.0  # the short memory sees no load change

    def __init__(self):
        self.num_joint, self.info_joint = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.num = self.info = 0.0

    def window(self, check, masses, infos):
        d_num = [i * m for m, i in zip(masses, infos)]
        for j in range(3):
            self.num_joint[j] += d_num[j]
            self.info_joint[j] += infos[j]
        self.num, self.info = sum(self.num_joint), sum(self.info_joint)
        check.update(self, d_num, list(infos))

    def _without(self, j):
        info = self.info - self.info_joint[j]
        return ((self.num - self.num_joint[j]) / info, info) if info > 0.0 else (math.nan, 0.0)


def _run(boom_mass, windows, seed=0, boom_info=0.02, other_info=0.002):
    """The boom weighs ``boom_mass(k)`` kg in window k (with the window's noise, σ from its
    information and the check's inflation), the dipper and bucket 2000 kg on little information."""
    rng = np.random.default_rng(seed)
    kernel, check = Kernel(), JointCheck(RATED, 2.5)
    faults = []
    for k in range(windows):
        infos = (boom_info, other_info, other_info)
        noise = [rng.normal(0.0, math.sqrt(JOINT_INFO_INFLATION / i) / 5.0) for i in infos]
        kernel.window(check, (boom_mass(k) + noise[0], 2000.0 + noise[1], 2000.0 + noise[2]), infos)
        faults.append(check.fault)
        if check.restart:  # the kernel starts the weighing again
            check.restart = False
            kernel.__init__()
            kernel.new_loads += 1
            faults[-1] = "restart"
    return faults


def test_a_joint_that_weighs_one_mass_is_not_named():
    for seed in range(5):
        assert not any(_run(lambda k: 2000.0, 600, seed))


def test_a_drifting_boom_is_named_though_the_others_agree_and_clears_with_a_restart():
    """Windows 200-350: the boom's windows weigh 3 kg more each (a scale error that grows): its
    weighing moves 15+ kg within TRAJECTORY_WINDOWS windows; then they weigh 2000 kg again."""
    ramp = lambda k: 2000.0 + (3.0 * (k - 200) if 200 < k <= 350 else 0.0)  # noqa: E731
    faults = _run(ramp, 700)
    named = [k for k, f in enumerate(faults) if f == BOOM]
    assert named and 200 < named[0] < 300
    restart = faults.index("restart")
    assert restart > named[-1] >= 350 and not any(f for f in faults[restart + 1:] if f != "restart")


def test_nothing_is_named_while_the_load_changes():
    kernel, check = Kernel(), JointCheck(RATED, 2.5)
    kernel.changing = True
    for k in range(350):
        kernel.window(check, (2000.0 + max(0, k - 200) * 3.0, 2000.0, 2000.0), (0.02, 0.002, 0.002))
        assert check.fault == ""
    assert check.drift_joint == 0  # it drifts: only held



def _drift_names(hold):
    """Windows in which the trajectory test has a joint named, the boom drifting 3 kg a window in
    windows 200-350 and the monitor naming a signal in those windows when ``hold``."""
    kernel, check = Kernel(), JointCheck(RATED, 2.5)
    named = []
    for k in range(600):
        if hold and 200 <= k < 350:
            check.hold_trajectory()
        boom = 2000.0 + 3.0 * (k - 200 if 200 < k <= 350 else 0.0)
        kernel.window(check, (boom, 2000.0, 2000.0), (0.02, 0.002, 0.002))
        if check.drift_named:
            named.append(k)
    return named


def test_nothing_is_named_while_the_monitor_names_a_signal_and_for_its_windows_after():
    """The same drift named while the monitor is quiet is not named by the trajectory test while
    the monitor names a signal (a substitute weighs), nor in the TRAJECTORY_WINDOWS windows after."""
    assert _drift_names(False) and _drift_names(False)[0] < 350
    assert not [k for k in _drift_names(True) if k < 350 + TRAJECTORY_WINDOWS - 1]
