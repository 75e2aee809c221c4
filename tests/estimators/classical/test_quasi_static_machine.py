"""quasi-static on the machine sensor set: the boom cylinder's piston force mapped from lifts."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator, load_estimator
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.generate import simulate_dataset

MACHINE = load_machine("cat345c-hydraulic")


@pytest.fixture(scope="module")
def lifts():
    return _lifts()


def _lifts():
    """Four lifts: empty and rated at two dipper angles (noise-free)."""
    return simulate_dataset(4, seed=1, machine=MACHINE, noise="none", motion="lifts", workers=1,
                            progress=False)


def test_maps_hold_the_piston_force(lifts):
    est = create_estimator("quasi-static", MACHINE).fit(lifts)
    assert est.boom_areas == (MACHINE.boom_cylinder.head_area, MACHINE.boom_cylinder.rod_area)
    rows = lifts.frame.iloc[len(lifts.frame) // 3]
    load = (rows["boom_head_pressure"] * est.boom_areas[0] - rows["boom_rod_pressure"] * est.boom_areas[1])
    refs = est.reference_torques(rows["boom_angle"], rows["dipper_angle"])
    # a cylinder force (tens to hundreds of kN), not a torque, sits between the two maps
    assert refs is not None and 1e4 < abs(refs[0]) < 2e6
    assert min(refs) - 0.05 * abs(refs[1] - refs[0]) <= load <= max(refs) + 0.05 * abs(refs[1] - refs[0])


def test_calibration_lifts_are_weighed_back(lifts, tmp_path):
    """At the calibration speed the map is exact up to its interpolation: the lifts it was made
    from come back within 1 % of the rated payload."""
    est = create_estimator("quasi-static", MACHINE, speed_gate=True).fit(lifts)
    out = est.estimate(lifts)
    final = out.groupby("experiment", sort=False)["payload_estimate"].last().to_numpy()
    np.testing.assert_allclose(final, lifts.payloads, atol=0.01 * MACHINE.rated_payload)
    est.save(tmp_path / "qs")
    again = load_estimator(tmp_path / "qs")
    assert again.sensor_set.name == "machine" and again.boom_areas == est.boom_areas
    np.testing.assert_array_equal(again.estimate(lifts)["payload_estimate"].to_numpy(),
                                  out["payload_estimate"].to_numpy())


def test_wrong_pairs_are_refused_in_one_line(lifts):
    with pytest.raises(EstimatorError, match="need a hydraulic machine"):
        create_estimator("quasi-static", "cat345c").fit(lifts)
