"""Power balance of the arm model: d(K + P)/dt = τ·q̇ − q̇ᵀBq̇ along a simulated trajectory."""

import numpy as np
from scipy.integrate import solve_ivp

from excavator_payload.model.dynamics import ArmModel


def _torque(t, hold):
    """A smooth, non-trivial torque history around the torque that holds the start pose."""
    return hold + np.array([2e5 * np.sin(2.1 * t), -1e5 * np.cos(3.3 * t)])


def test_power_balance_along_a_trajectory():
    arm = ArmModel("cat345c")
    f = arm.casadi_function("forward_dynamics")
    energy = arm.casadi_function("energy")
    payload = 3200.0
    q0 = np.array([-0.2, -1.5])
    hold = arm.gravity_torque(q0, payload)

    def rhs(t, x):
        qdd = np.asarray(f(x[:2], x[2:], _torque(t, hold), payload)).ravel()
        return np.concatenate([x[2:], qdd])

    sol = solve_ivp(rhs, (0.0, 3.0), np.concatenate([q0, [0.3, -0.4]]), method="DOP853",
                    rtol=1e-11, atol=1e-12, dense_output=True)
    assert sol.success
    beta = np.diag([arm.machine.boom_friction, arm.machine.dipper_friction])
    h = 1e-4
    for t in np.linspace(0.2, 2.8, 14):
        e_plus = sum(float(v) for v in energy(sol.sol(t + h)[:2], sol.sol(t + h)[2:], payload))
        e_minus = sum(float(v) for v in energy(sol.sol(t - h)[:2], sol.sol(t - h)[2:], payload))
        dE_dt = (e_plus - e_minus) / (2 * h)  # central difference, error O(h²)
        x = sol.sol(t)
        qd = x[2:]
        power = _torque(t, hold) @ qd - qd @ beta @ qd
        scale = np.abs(_torque(t, hold)).max() * np.abs(qd).max()
        assert abs(dE_dt - power) < 1e-5 * scale, (t, dE_dt, power)


def test_kinetic_energy_is_the_mass_matrix_quadratic_form():
    """K = ½ q̇ᵀM(q)q̇ and the potential energy rises with the boom."""
    arm = ArmModel("cat345c")
    q = np.array([0.3, -1.0])
    qd = np.array([0.5, -0.2])
    kinetic, potential = arm.energy(q, qd, 1000.0)
    assert kinetic > 0
    # Kinetic energy is ½ q̇ᵀ M q̇.
    M = arm.mass_matrix(q, 1000.0)
    np.testing.assert_allclose(kinetic, 0.5 * qd @ M @ qd, rtol=1e-12)
    # Potential energy grows when the boom rises.
    _, higher = arm.energy(q + np.array([0.1, 0.0]), qd, 1000.0)
    assert higher > potential
