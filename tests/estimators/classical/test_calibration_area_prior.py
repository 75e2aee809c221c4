"""--area-prior: the cylinder areas' prior std from the bore and rod diameters they are made of."""

import math
from dataclasses import replace

import numpy as np
import pytest

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.estimators.classical.machine_calibration.settings import area_prior_factors
from excavator_payload.model.machine import load_machine

PRIOR = "cat345c-hydraulic-3pct"


def test_area_factors_are_the_first_order_propagation_of_the_diameters_shares():
    """A relative error s on the bore and on the rod, independent, moves the piston area by 2s
    and the annulus by the root sum of squares of its two logarithmic derivatives: checked
    against finite differences of the machine file's own area properties."""
    cylinders = load_machine(PRIOR).cylinders
    factors = area_prior_factors(cylinders)
    h = 1e-6
    for name, c in zip(("boom_cylinder", "dipper_cylinder", "bucket_cylinder"), cylinders):
        for area in ("head_area", "rod_area"):
            slopes = [(getattr(replace(c, **{d: getattr(c, d) * (1 + h)}), area) / getattr(c, area) - 1) / h
                      for d in ("bore", "rod")]
            assert factors[f"{name}_{area}"] == pytest.approx(math.hypot(*slopes), rel=1e-4)
    # a thin annulus is the difference of two large circles: its area is far less certain
    assert factors["boom_cylinder_rod_area"] > 3.0 > factors["boom_cylinder_head_area"] == 2.0


def test_area_factors_refuse_a_rod_as_wide_as_the_bore():
    cylinder = load_machine(PRIOR).cylinders[0]
    wide = type("C", (), {"bore": cylinder.bore, "rod": cylinder.bore})()
    with pytest.raises(ValueError, match="rod diameter"):
        area_prior_factors([wide, *load_machine(PRIOR).cylinders[1:]])


@pytest.fixture(scope="module")
def both(machine_calibration):
    cal = machine_calibration["cal"]
    return {choice: create_estimator("calibrated", PRIOR, balance="momentum", area_prior=choice,
                                     model_std="none").fit(cal)
            for choice in ("share", "diameters")}


def test_diameters_prior_widens_only_the_areas_and_lets_them_move(both):
    """The prior of every parameter but the six areas is the same; the areas' posterior is wider
    with the diameters' prior (the data, not the prior, decide them), and the fit moves the
    annulus areas further from the file."""
    k = len(cm.CALIBRATED_PARAMETERS)
    areas = [cm.CALIBRATED_PARAMETERS.index(n) for n in cm.CALIBRATED_PARAMETERS if n.endswith("_area")]
    sd = {c: np.sqrt(np.diag(e.calibration.covariance))[:k] for c, e in both.items()}
    assert np.all(sd["diameters"][areas] > sd["share"][areas])
    rods = [cm.CALIBRATED_PARAMETERS.index(f"{c}_cylinder_rod_area") for c in ("boom", "dipper", "bucket")]
    moved = {c: np.abs(e.calibration.z[rods]) for c, e in both.items()}
    assert moved["diameters"].sum() > moved["share"].sum()


def test_a_bad_area_prior_is_refused_in_one_line():
    with pytest.raises(EstimatorError, match="area_prior|area-prior"):
        create_estimator("calibrated", PRIOR, area_prior="bore")
