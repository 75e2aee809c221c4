"""The joint check's dump rule (machine_calibration/joint_check.py, the kernel's ``dumping``): while
the bucket opens fast the check names nothing new and does not sum what the joints weigh; and
nothing new is named before the weighing is ready. The check is driven window by window through a
stand-in kernel (the attributes :meth:`JointCheck.update` reads), the kernel's ``dumping`` by the
bucket rate of the samples it is given."""

import copy
import math

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.settings import (
    DUMP_HOLD, DUMP_OPENING_RATE, JOINT_SAMPLES)
from excavator_payload.estimators.classical.pressure_regression import RATES

RATED = 5000.0
INFO = 1e-2  # kg^-2 per window and joint: σ_j = (9 / I_j)^½ well under 1 % of rated after a few windows


class StandIn:
    """What :meth:`JointCheck.update` reads of a :class:`CalibratedKernel`: one load, steady."""

    forgetting = 1.0
    new_loads = 0
    changing = False
    ready = True
    dumping = False
    num = info = num_short = info_short = 0.0  # no load change seen by the memories

    def _without(self, j):
        return math.nan, 0.0


def _windows(check, kernel, masses, count, info=(INFO, INFO, INFO)):
    """``count`` windows in which joint j weighs ``masses[j]`` kg (no information where None)."""
    for _ in range(count):
        d_info = [i if m is not None else 0.0 for m, i in zip(masses, info)]
        d_num = [i * m if m is not None else 0.0 for m, i in zip(masses, d_info)]
        check.update(kernel, d_num, d_info)


def test_a_dump_names_nothing_though_the_joints_part():
    """The dipper, moving in the dump, weighs 300 kg less than the standing boom and bucket: outside
    a dump that names the dipper; while the bucket dumps nothing is named and its windows are not
    summed."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    _windows(check, kernel, (1000.0, 700.0, 1000.0), 3 * JOINT_SAMPLES)
    assert check.fault == "dipper_head_pressure:balance,dipper_rod_pressure:balance"  # the rule matters

    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel.dumping = True
    _windows(check, kernel, (1000.0, 700.0, 1000.0), 3 * JOINT_SAMPLES)
    assert check.fault == "" and not check.checked
    assert check.info == [0.0, 0.0, 0.0]  # the dump's windows are not summed


def test_after_a_dump_the_check_starts_from_nothing():
    """The stale joint: the dipper weighed in the dump's last windows (the old load going) and then
    stands; the boom and bucket, moving again, weigh the empty bucket. Had the check summed the
    dump's windows it would compare the dipper's 2 900 kg with 0 kg and name both; without them
    the two moving joints agree."""
    for seen in (False, True):  # seen: the kernel's dumping (False: as if the rule were not there)
        kernel, check = StandIn(), JointCheck(RATED, 2.5)
        _windows(check, kernel, (3000.0, 3000.0, 3000.0), 50)
        kernel.dumping = seen
        _windows(check, kernel, (None, 2900.0, None), 50)
        kernel.new_loads += 1  # the new-load test restarts the weighing while the bucket still dumps
        _windows(check, kernel, (None, 2900.0, None), 20)
        kernel.dumping = False
        _windows(check, kernel, (0.0, None, 0.0), 50)
        if seen:
            assert check.fault == "" and check.checked
        else:
            assert check.fault != ""


def test_nothing_new_is_named_before_the_weighing_is_ready():
    """A new load's first windows (the fill, a dig: soil on the bucket) part the joints; the kernel
    is not ready (the boom not yet weighed): nothing is named then, and a disagreement that lasts is
    named at once when it is ready."""
    kernel, check = StandIn(), JointCheck(RATED, 2.5)
    kernel.ready = False
    _windows(check, kernel, (None, 15000.0, 14000.0), 3 * JOINT_SAMPLES)
    assert check.fault == "" and check.chi2 > 15.0
    kernel.ready = True
    _windows(check, kernel, (None, 15000.0, 14000.0), 1)
    assert check.fault != ""


@pytest.fixture(scope="module")
def kernel(machine_calibration):
    est = create_estimator("calibrated", "cat345c-hydraulic-3pct", balance="momentum")
    est.fit(machine_calibration["cal"])
    return copy.deepcopy(est.kernel.regression)


def test_the_kernel_dumps_while_the_bucket_opens_fast(kernel, machine_calibration):
    """``dumping`` from the first sample whose bucket rate passes DUMP_OPENING_RATE (opening) until
    DUMP_HOLD s after the last one; a bucket curling as fast, or opening a little slower, is no dump."""
    f = machine_calibration["zero"].frame
    values = f[list(MACHINE_SENSORS.signals)].to_numpy(float)[:600].copy()
    values[:, RATES[2]] = 0.0
    values[200:230, RATES[2]] = 1.05 * DUMP_OPENING_RATE
    values[400:430, RATES[2]] = -3.0 * DUMP_OPENING_RATE  # curling
    values[500:530, RATES[2]] = 0.95 * DUMP_OPENING_RATE
    hold = int(round(DUMP_HOLD * MACHINE_SENSORS.sample_rate))
    kernel.reset()
    seen = []
    for i, v in enumerate(values):
        kernel.update(i / MACHINE_SENSORS.sample_rate, v)
        seen.append(kernel.dumping)
    seen = np.array(seen)
    assert not seen[:200].any() and seen[200:229 + hold].all() and not seen[229 + hold:].any()


def test_on_by_default_beside_the_imu_dynamics():
    """The default ``calibrated`` runs the check (with the health monitor) and re-estimates the IMU
    dynamics beside it; ``--joint-check off`` still turns it off."""
    from excavator_payload.estimators.classical.machine_calibration.weighing import imu_nuisance_on

    est = create_estimator("calibrated", "cat345c-hydraulic-3pct")
    assert est.options["joint_check"] == "on" and est.health
    assert imu_nuisance_on(est.options, "momentum")
    assert create_estimator("calibrated", "cat345c-hydraulic-3pct", joint_check="off").options["joint_check"] == "off"
