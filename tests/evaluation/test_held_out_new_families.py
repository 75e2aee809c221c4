"""benchmarks/held_out_motions.py's session-22 families (trench, grade, jerky) are motions the
machine can make: inside the joint ranges, no faster than the pumps and slew drive (the replay's
check refuses them otherwise), within the relief pressure where the generator promises it, with
light and heavy loads in turn; and each is what its name says."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from held_out_motions import (HEAVY_LOAD, LIGHT_LOAD, _relief_share, grade_trajectory,  # noqa: E402
                              jerky_trajectory, trench_trajectory)

from excavator_payload.model.hydraulic import HydraulicArmModel  # noqa: E402
from excavator_payload.model.machine import load_machine  # noqa: E402
from excavator_payload.simulation.trajectory import check_trajectory_motion, trajectory_from_frame  # noqa: E402

MACHINE = "cat345c-hydraulic"


@pytest.mark.parametrize("make", [trench_trajectory, grade_trajectory, jerky_trajectory])
def test_the_machine_can_make_them(make):
    table = make(2, 145003)
    machine = load_machine(MACHINE)
    # raises for a joint out of range, a motion faster than the pumps (no allow_overspeed) or
    # forces twice the relief pressure's
    assert check_trajectory_motion(trajectory_from_frame(table), machine) == []
    loads = table.groupby("experiment")["payload"].first().to_numpy()
    assert LIGHT_LOAD[0] <= loads[0] <= LIGHT_LOAD[1] and HEAVY_LOAD[0] <= loads[1] <= min(HEAVY_LOAD[1], 5000.0)


def test_each_is_what_its_name_says():
    arm = HydraulicArmModel(load_machine(MACHINE))
    trench, grade, jerky = (make(2, 145004) for make in (trench_trajectory, grade_trajectory, jerky_trajectory))
    # trench: the boom nearly held, the dipper pulled through tens of degrees, no slew beyond trims
    for _, g in trench.groupby("experiment"):
        assert np.ptp(g["boom_angle"]) < np.radians(12) and np.ptp(g["dipper_angle"]) > np.radians(30)
        assert np.abs(g["slew_angle"]).max() < np.radians(6)
    # grade: the bucket held while the teeth move along a line (before the lift and slew)
    for _, g in grade.groupby("experiment"):
        still = g["slew_angle"].abs().to_numpy() < 1e-9
        bucket = g["bucket_angle"].to_numpy()[still]
        assert np.ptp(bucket[: len(bucket) // 2]) < 1e-9
    # jerky: slams within the relief pressure, accelerations of rad/s² on the arm
    for k, g in jerky.groupby("experiment"):
        motion = g[["time", "boom_angle", "dipper_angle", "bucket_angle", "slew_angle"]].to_numpy()
        assert _relief_share(arm, motion, float(g["payload"].iloc[0])) <= 0.95
        rate = np.gradient(motion[:, 1:3], motion[:, 0], axis=0)
        assert np.abs(np.gradient(rate, motion[:, 0], axis=0)).max() > 1.0
