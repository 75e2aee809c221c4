"""Hydraulic NMPC: the chain-rule Jacobian of its interval model."""

import numpy as np

from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.hydraulic_nmpc import _dynamics, _rk4, _rk4_jacobian


def test_chain_rule_jacobian_equals_differentiating_the_unrolled_rk4():
    arm = HydraulicArmModel(load_machine("cat345c-hydraulic"))
    xdot = _dynamics(arm)
    model = _rk4(xdot, 0.25, 2, "interval")
    expected_fn, got_fn = model.jacobian(), _rk4_jacobian(xdot, 0.25, 2, "interval")
    assert [got_fn.name_out(i) for i in range(4)] == [expected_fn.name_out(i) for i in range(4)]
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = np.r_[np.array([0.3, -1.2, -0.7, 0.4]) + rng.normal(0, 0.2, 4), rng.normal(0, 0.3, 4)]
        u = rng.normal(0, 2e5, 4)
        tilt, payload = rng.normal(0, 0.05, 2), rng.uniform(0, 5000)
        xf = model(x, u, tilt, payload)
        for want, got in zip(expected_fn(x, u, tilt, payload, xf), got_fn(x, u, tilt, payload, xf)):
            want, got = np.asarray(want), np.asarray(got)
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


def test_chain_rule_jacobian_keeps_the_structural_zeros_of_the_force_lag():
    # The applied forces depend on nothing but forces and inputs: the NMPC's QP is only as
    # sparse as this pattern.
    from excavator_payload.simulation.hydraulic_nmpc import _lagged_dynamics

    jac = _rk4_jacobian(_lagged_dynamics(HydraulicArmModel(load_machine("cat345c-hydraulic")), 0.06), 0.25, 2, "interval")
    by_state, by_input = np.array(jac.sparsity_out(0)), np.array(jac.sparsity_out(1))
    np.testing.assert_array_equal(by_state[8:], np.hstack([np.zeros((4, 8), bool), np.eye(4, dtype=bool)]))
    np.testing.assert_array_equal(by_input[8:], np.eye(4, dtype=bool))
