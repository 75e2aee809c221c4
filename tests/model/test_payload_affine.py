"""Torques are affine in the payload: τ = τ₀(q, q̇, q̈) + m·φ(q, q̇, q̈), φ = payload_regressor."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from excavator_payload.model.dynamics import ArmModel

ARM = ArmModel("cat345c")

angles = st.tuples(st.floats(-0.8, 1.0), st.floats(-2.6, -0.3))
rates = st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5))
accels = st.tuples(st.floats(-5, 5), st.floats(-5, 5))


@settings(max_examples=60, deadline=None)
@given(angles, rates, accels, st.floats(0, 6000), st.floats(0, 6000))
def test_torque_is_affine_in_payload(q, qd, qdd, m_a, m_b):
    q, qd, qdd = (np.array(v) for v in (q, qd, qdd))
    phi = ARM.payload_regressor(q, qd, qdd)
    tau0 = ARM.torque_empty(q, qd, qdd)
    scale = 1e3 + np.abs(tau0).max()
    for m in (m_a, m_b):
        tau = ARM.inverse_dynamics(q, qd, qdd, m)
        np.testing.assert_allclose(tau, tau0 + m * phi, rtol=1e-10, atol=1e-9 * scale)
    # φ is the slope between any two payloads.
    if abs(m_a - m_b) > 1.0:
        slope = (ARM.inverse_dynamics(q, qd, qdd, m_a) - ARM.inverse_dynamics(q, qd, qdd, m_b)) / (m_a - m_b)
        np.testing.assert_allclose(slope, phi, rtol=1e-6, atol=1e-6 * (1 + np.abs(phi).max()))


def test_regressor_is_the_tip_point_mass_dynamics():
    """φ is the torque of a 1 kg point mass at the dipper tip: at rest, g times its lever arms."""
    q = np.array([0.4, -1.1])
    phi = ARM.payload_regressor(q, np.zeros(2), np.zeros(2))
    m = ARM.machine
    x_tip = m.boom_length * np.cos(q[0]) + m.dipper_length * np.cos(q.sum())
    x_dipper = m.dipper_length * np.cos(q.sum())
    np.testing.assert_allclose(phi, m.gravity * np.array([x_tip, x_dipper]), rtol=1e-12)


def test_batch_evaluation_matches_single_samples():
    rng = np.random.default_rng(4)
    q = rng.uniform([-0.8, -2.6], [1.0, -0.3], (7, 2))
    qd = rng.uniform(-1, 1, (7, 2))
    qdd = rng.uniform(-3, 3, (7, 2))
    payload = rng.uniform(0, 5000, 7)
    batch = ARM.inverse_dynamics(q, qd, qdd, payload)
    for i in range(7):
        np.testing.assert_allclose(batch[i], ARM.inverse_dynamics(q[i], qd[i], qdd[i], payload[i]))
