"""The soil's force on the teeth while a shift's bucket cuts: it opposes the teeth's motion, acts
only over the cuts, and the cylinders hold its torques (τ = Jᵀf from the symbolic model)."""

import numpy as np
import pytest

from excavator_payload.model.machine import load_machine
from excavator_payload.simulation import machine_motions as mm
from excavator_payload.simulation.machine_physics import arm_model, motion_physics


@pytest.fixture(scope="module")
def arm():
    return arm_model(load_machine("cat345c-hydraulic"))


def test_tip_torque_does_the_work_of_the_force(arm):
    """Virtual work: τ·q̇ = f·v at any pose, rate and force; and v is the derivative of the
    teeth's position."""
    rng = np.random.default_rng(3)
    q = np.column_stack([rng.uniform(0.2, 0.9, 20), rng.uniform(-2.2, -1.0, 20),
                         rng.uniform(-2.0, 0.3, 20), rng.uniform(-1, 1, 20)])
    qd, f = rng.normal(size=(20, 4)), rng.normal(scale=1e4, size=(20, 2))
    v, tau = arm.tip_velocity(q, qd), arm.tip_torque(q, f)
    np.testing.assert_allclose(np.sum(tau * qd[:, :3], axis=1), np.sum(f * v, axis=1), rtol=1e-10)
    h = 1e-6
    np.testing.assert_allclose(v, (arm.tip_position(q + h * qd) - arm.tip_position(q - h * qd)) / (2 * h),
                               rtol=1e-6, atol=1e-9)


def test_a_shift_cuts_against_the_soil(arm):
    """Each pass's cut carries a drawn resistance; the force opposes the teeth's velocity, never
    exceeds it, is zero outside the cuts; the cylinders' load forces change by exactly the
    force's torques, and only over the cuts."""
    plan = mm.fit_to_hydraulics(arm, mm.shift_motion(np.random.default_rng(8), arm, 12000.0))
    assert plan.soil and len(plan.soil) == len(plan.info["passes"])
    assert all(mm.SOIL_RESISTANCE[0] <= r <= mm.SOIL_RESISTANCE[1] for _, _, r in plan.soil)
    time = np.arange(0.0, plan.duration, 0.01)
    q, qd, qdd = plan.sample(time)
    v = arm.tip_velocity(q, qd)
    force = plan.soil_force(time, v)
    inside = np.zeros(len(time), bool)
    for a, b, r in plan.soil:
        cut = (time >= a) & (time <= b)
        inside |= cut
        assert np.linalg.norm(force[cut], axis=1).max() <= r * (1 + 1e-12)
        assert np.linalg.norm(force[cut], axis=1).max() > 0.5 * r  # the teeth move through the cut
    assert not np.any(force[~inside])
    assert np.all(np.sum(force * v, axis=1) <= 1e-9)  # it takes work, never gives it
    payload = plan.payload_at(time)
    free = motion_physics(arm, time, q, qd, qdd, plan.tilt, payload, np.zeros(3))
    cut = motion_physics(arm, time, q, qd, qdd, plan.tilt, payload, np.zeros(3), tip_force=force)
    np.testing.assert_allclose(cut["load"] - free["load"], -arm.load_force(q, arm.tip_torque(q, force)),
                               rtol=1e-9, atol=1e-6)
    assert np.abs(cut["load"] - free["load"])[inside].max() > 1e4  # tens of kN on a cylinder
    np.testing.assert_array_equal(cut["load"][~inside], free["load"][~inside])
