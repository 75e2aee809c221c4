"""The plant: RK4 with small substeps agrees with CVODES; accelerations are the dynamics'."""

import numpy as np

from excavator_payload.model.dynamics import ArmModel
from excavator_payload.simulation.plant import Plant, cvodes_integrator, rk4_interval

ARM = ArmModel("cat345c")


def test_rk4_plant_matches_cvodes():
    plant = Plant(ARM, sample_period=0.05)
    cvodes = cvodes_integrator(ARM, 0.05)
    rng = np.random.default_rng(0)
    for payload in (0.0, 5000.0):  # the empty bucket has the fastest mode
        for _ in range(5):
            state = np.concatenate([rng.uniform([-0.5, -1.9], [0.9, -0.6]), rng.uniform(-1, 1, 2)])
            torque = ARM.gravity_torque(state[:2], payload) + rng.uniform(-1e6, 1e6, 2)
            x_rk4 = plant.step(state, torque, payload)
            x_cv = np.asarray(cvodes(x0=state, p=np.concatenate([torque, [payload]]))["xf"]).ravel()
            # 2e-7 rad, rad/s: 300× below the thesis' smallest sensor noise (rate σ = 5.5e-5 rad/s).
            np.testing.assert_allclose(x_rk4, x_cv, rtol=0, atol=2e-7)


def test_coarse_rk4_is_measurably_worse():
    """The check can fail: one 0.05 s RK4 step is far from CVODES."""
    coarse = rk4_interval(ARM, 0.05, 1)
    cvodes = cvodes_integrator(ARM, 0.05)
    state = np.array([0.8, -0.6, 0.5, -0.8])
    torque = ARM.gravity_torque(state[:2], 0.0) + np.array([8e5, -6e5])
    x_coarse = np.asarray(coarse(state, torque, 0.0)).ravel()
    x_cv = np.asarray(cvodes(x0=state, p=np.concatenate([torque, [0.0]]))["xf"]).ravel()
    assert np.abs(x_coarse - x_cv).max() > 1e-6


def test_acceleration_is_forward_dynamics_and_zero_order_hold():
    plant = Plant(ARM)
    state = np.array([0.1, -1.2, 0.3, -0.2])
    torque = np.array([1.2e6, 1.5e5])
    qdd = plant.acceleration(state, torque, 1500.0)
    np.testing.assert_allclose(qdd, ARM.forward_dynamics(state[:2], state[2:], torque, 1500.0), rtol=1e-12)
    # Holding the gravity torque keeps the arm at rest.
    rest = np.array([0.1, -1.2, 0.0, 0.0])
    hold = ARM.gravity_torque(rest[:2], 1500.0)
    np.testing.assert_allclose(plant.step(rest, hold, 1500.0), rest, atol=1e-12)


def test_hold_is_the_step_loop_bit_for_bit():
    """``hold`` (one call per control period, through buffers) gives exactly what stepping the
    plant one sample at a time gives: states, accelerations and the state after."""
    plant = Plant(ARM)
    rng = np.random.default_rng(7)
    for _ in range(20):
        state = rng.uniform([0.3, -2.2, -0.5, -0.5], [0.9, -1.2, 0.5, 0.5])
        torque = rng.uniform(-1e6, 1e6, 2)
        payload = rng.uniform(0.0, 5000.0)
        states, accels, after = plant.hold(state, torque, payload, 3)
        x = state
        for j in range(3):
            assert np.array_equal(states[j], x)
            assert np.array_equal(accels[j], plant.acceleration(x, torque, payload))
            x = plant.step(x, torque, payload)
        assert np.array_equal(after, x)
