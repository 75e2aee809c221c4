"""The ground tilt's one source (model/ground_tilt.py): floats and CasADi symbols give the same
numbers, the clamp holds, and the estimators' copy (pressure_regression.ground_tilt) agrees."""

import math

import casadi as ca
import numpy as np
import pytest

from excavator_payload.estimators.classical.pressure_regression import ground_tilt as kernel_tilt
from excavator_payload.model.ground_tilt import ground_tilt
from excavator_payload.runtime.export_c.casadi_code import ground_tilt_symbolic

GRID = [(p, r) for p in np.linspace(-1.5, 1.5, 13) for r in np.linspace(-1.55, 1.55, 11)]


def test_floats_and_symbols_agree_and_match_the_kernels_copy():
    pitch, roll = ca.SX.sym("pitch"), ca.SX.sym("roll")
    symbolic = ca.Function("tilt", [pitch, roll], [ground_tilt_symbolic(pitch, roll)])
    for p, r in GRID:
        want = ground_tilt(p, r)
        assert kernel_tilt(p, r) == want
        np.testing.assert_allclose(np.array(symbolic(p, r)).ravel(), want, rtol=1e-15, atol=1e-15)


def test_the_inverse_of_the_house_inclination_and_its_clamp():
    # a ground pitch p under roll r tilts the house by asin(cos r sin p): the inverse returns p
    p, r = 0.2, 0.1
    assert ground_tilt(math.asin(math.cos(r) * math.sin(p)), r)[0] == pytest.approx(p, abs=1e-12)
    # more house pitch than the roll allows: clamped to ±90°, not a math domain error
    assert ground_tilt(1.4, 1.5)[0] == pytest.approx(math.pi / 2)
    assert ground_tilt(-1.4, 1.5)[0] == pytest.approx(-math.pi / 2)
    assert math.isfinite(ground_tilt(0.3, math.pi / 2)[0])
