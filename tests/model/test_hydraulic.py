"""Physics of the hydraulic machine's symbolic model on known answers."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.hydraulic import (
    HYDRAULIC_PARAMETER_NAMES,
    HydraulicArmModel,
    parameter_vector,
)
from excavator_payload.model.machine import load_machine

IDX = {n: i for i, n in enumerate(HYDRAULIC_PARAMETER_NAMES)}
LEVEL = np.zeros(2)


@pytest.fixture(scope="module")
def machine():
    return load_machine("cat345c-hydraulic")


@pytest.fixture(scope="module")
def arm(machine):
    return HydraulicArmModel(machine)


def with_parameters(arm: HydraulicArmModel, **values) -> HydraulicArmModel:
    """A copy of ``arm`` with some entries of its parameter vector replaced."""
    out = copy.copy(arm)
    out.p = arm.p.copy()
    for name, value in values.items():
        out.p[IDX[name]] = value
    return out


def random_states(rng, n, machine, slew=True):
    r = machine.angle_ranges
    q = np.column_stack([rng.uniform(*r[j], n) for j in range(3)] + [rng.uniform(-3, 3, n)])
    qd = rng.normal(0, 0.4, (n, 4))
    qdd = rng.normal(0, 1.0, (n, 4))
    if not slew:
        qd[:, 3] = qdd[:, 3] = 0
    return q, qd, qdd


def test_two_link_special_case_gives_the_thesis_torques(arm, machine):
    """Bucket locked, no slew, level, uniform bars, bucket and payload at the dipper tip:
    boom and dipper torques equal the thesis' 2-link model's."""
    thesis = ArmModel("cat345c")
    t = thesis.machine
    special = with_parameters(
        arm, boom_length=t.boom_length, dipper_length=t.dipper_length,
        boom_mass=t.boom_mass, boom_com_u=t.boom_length / 2, boom_com_w=0.0,
        boom_inertia_y=t.boom_inertia, dipper_mass=t.dipper_mass, dipper_com_u=t.dipper_length / 2,
        dipper_com_w=0.0, dipper_inertia_y=t.dipper_inertia, bucket_mass=t.bucket_mass,
        bucket_com_u=0.0, bucket_com_w=0.0, bucket_inertia_y=0.0, payload_u=0.0, payload_w=0.0,
        boom_joint_friction=t.boom_friction, dipper_joint_friction=t.dipper_friction,
        gravity=t.gravity)
    rng = np.random.default_rng(1)
    q, qd, qdd = random_states(rng, 50, machine, slew=False)
    qd[:, 2] = qdd[:, 2] = 0  # bucket locked
    payload = rng.uniform(0, 5000, 50)
    tau = special.inverse_dynamics(q, qd, qdd, LEVEL, payload)
    expected = thesis.inverse_dynamics(q[:, :2], qd[:, :2], qdd[:, :2], payload)
    np.testing.assert_allclose(tau[:, :2], expected, rtol=1e-9, atol=1e-6)
    # The general machine differs (centres of mass off the bar, a bucket that is a body).
    general = arm.inverse_dynamics(q, qd, qdd, LEVEL, payload)
    assert np.max(np.abs(general[:, :2] - expected)) > 1e4


def test_static_equilibrium_against_a_hand_calculation(arm, machine):
    """Arm still at a pose: boom torque = g·Σ m·(horizontal lever), and the boom cylinders'
    head pressure holds it through the moment arm computed by hand from the pins."""
    q1, q2, q3 = 0.2, -1.3, -0.9
    q = np.array([q1, q2, q3, 0.0])
    payload = 3000.0
    g = machine.gravity
    th = np.cumsum([q1, q2, q3])
    rot = lambda a, v: np.array([np.cos(a) * v[0] - np.sin(a) * v[1], np.sin(a) * v[0] + np.cos(a) * v[1]])  # noqa: E731
    foot = np.array(machine.house.boom_foot)
    joints = [foot, foot + rot(th[0], [machine.boom.length, 0])]
    joints.append(joints[1] + rot(th[1], [machine.dipper.length, 0]))
    coms = [joints[i] + rot(th[i], link.com) for i, link in enumerate(machine.links)]
    payload_at = joints[2] + rot(th[2], machine.payload.position)
    masses = [link.mass for link in machine.links]
    boom_torque = g * (sum(m * (c[0] - foot[0]) for m, c in zip(masses, coms)) + payload * (payload_at[0] - foot[0]))
    tau = arm.inverse_dynamics(q, np.zeros(4), np.zeros(4), LEVEL, payload)
    assert tau[0] == pytest.approx(boom_torque, rel=1e-10)
    # Moment arm of the boom cylinders by hand: dl/dq = (b − a)·(∂b/∂q)/l, ∂b/∂q ⟂ (b − foot).
    cyl = machine.boom_cylinder
    a = np.array(cyl.parent_point)
    b = foot + rot(th[0], cyl.child_point)
    l = np.linalg.norm(b - a)
    db = np.array([-(b - foot)[1], (b - foot)[0]])
    lever = (b - a) @ db / l
    assert arm.moment_arms(q)[0] == pytest.approx(lever, rel=1e-10)
    force = boom_torque / (cyl.count * lever)
    head, rod = arm.pressures(arm.load_force(q, tau[:3]))
    assert force > 0  # the boom cylinders push
    back = machine.hydraulics.back_pressure
    # Head side carries the load, rod side holds the back pressure (up to the 1 kN blend).
    assert head[0] * cyl.head_area - rod[0] * cyl.rod_area == pytest.approx(force, rel=1e-9)
    assert head[0] == pytest.approx((force + back * cyl.rod_area) / cyl.head_area, rel=1e-5)
    assert rod[0] == pytest.approx(back, rel=1e-4)


def test_energy_balance_of_a_free_swing_with_friction_off(arm, machine):
    """No forces, no friction, slewing and tilted: kinetic + potential energy stays constant."""
    free = with_parameters(arm, slew_friction=0.0, boom_joint_friction=0.0,
                           dipper_joint_friction=0.0, bucket_joint_friction=0.0)
    tilt = np.array([0.08, -0.05])
    payload = 2500.0
    x = np.array([0.3, -1.2, -0.8, 0.0, 0.3, -0.4, 0.6, 0.5])
    f = lambda s: np.concatenate([s[4:], free.forward_dynamics(s[:4], s[4:], np.zeros(4), tilt, payload)])  # noqa: E731
    energy = lambda s: sum(free.energy(s[:4], s[4:], tilt, payload))  # noqa: E731
    e0 = energy(x)
    h = 2e-3
    for _ in range(500):  # 1 s of RK4
        k1 = f(x); k2 = f(x + h / 2 * k1); k3 = f(x + h / 2 * k2); k4 = f(x + h * k3)  # noqa: E702
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    kinetic, _ = free.energy(x[:4], x[4:], tilt, payload)
    assert kinetic > 1e3  # it really moved
    assert abs(energy(x) - e0) < 1e-6 * abs(e0) + 1e-3
    # With friction the energy falls.
    damped = with_parameters(free, slew_friction=5e4, boom_joint_friction=5e4)
    xd = np.array([0.3, -1.2, -0.8, 0.0, 0.3, -0.4, 0.6, 0.5])
    fd = lambda s: np.concatenate([s[4:], damped.forward_dynamics(s[:4], s[4:], np.zeros(4), tilt, payload)])  # noqa: E731
    for _ in range(100):
        k1 = fd(xd); k2 = fd(xd + h / 2 * k1); k3 = fd(xd + h / 2 * k2); k4 = fd(xd + h * k3)  # noqa: E702
        xd = xd + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert sum(damped.energy(xd[:4], xd[4:], tilt, payload)) < e0 - 100


def test_moment_arms_are_finite_differences_of_cylinder_lengths(arm, machine):
    rng = np.random.default_rng(3)
    q, _, _ = random_states(rng, 30, machine)
    h = 1e-6
    arms = arm.moment_arms(q)
    for j in range(3):
        dq = np.zeros(4)
        dq[j] = h
        fd = (arm.cylinder_lengths(q + dq)[:, j] - arm.cylinder_lengths(q - dq)[:, j]) / (2 * h)
        np.testing.assert_allclose(arms[:, j], fd, rtol=1e-6, atol=1e-8)
    # Each cylinder moves only its own joint.
    for j in range(3):
        for k in range(4):
            if k != j:
                dq = np.zeros(4)
                dq[k] = 1e-3
                np.testing.assert_allclose(arm.cylinder_lengths(q + dq)[:, j], arm.cylinder_lengths(q)[:, j])


def test_preset_angle_ranges_fit_the_strokes_and_keep_moment_arm_signs(arm, machine):
    for j, cyl in enumerate(machine.cylinders):
        grid = np.linspace(*machine.angle_ranges[j], 400)
        q = np.tile([0.2, -1.3, -0.8, 0.0], (400, 1))
        q[:, j] = grid
        lengths = arm.cylinder_lengths(q)[:, j]
        arms = arm.moment_arms(q)[:, j]
        assert lengths.min() > cyl.stroke[0] and lengths.max() < cyl.stroke[1]
        assert np.all(np.abs(arms) > 0.1) and len(set(np.sign(arms))) == 1
    assert np.all(arm.linkage_margin(q) > 0)


def test_slewing_adds_the_centrifugal_torque(arm, machine):
    """Payload only (links massless): τ_boom(ψ̇) − τ_boom(0) = m ψ̇² x (z − z_foot)."""
    massless = {f"{link}_{k}": 0.0 for link in ("boom", "dipper", "bucket")
                for k in ("mass", "inertia_u", "inertia_y", "inertia_w")}
    point = with_parameters(arm, **massless)
    q = np.array([0.4, -1.0, -0.6, 0.3])
    m, rate = 4000.0, 0.6
    qd = np.array([0, 0, 0, rate])
    th = np.cumsum(q[:3])
    foot = np.array(machine.house.boom_foot)
    pos = (foot + machine.boom.length * np.array([np.cos(th[0]), np.sin(th[0])])
           + machine.dipper.length * np.array([np.cos(th[1]), np.sin(th[1])]))
    u, w = machine.payload.position
    pos = pos + np.array([np.cos(th[2]) * u - np.sin(th[2]) * w, np.sin(th[2]) * u + np.cos(th[2]) * w])
    spinning = point.inverse_dynamics(q, qd, np.zeros(4), LEVEL, m)
    still = point.inverse_dynamics(q, np.zeros(4), np.zeros(4), LEVEL, m)
    expected = m * rate**2 * pos[0] * (pos[1] - foot[1])
    assert spinning[0] - still[0] == pytest.approx(expected, rel=1e-9)
    # and no slew torque at constant slew rate without friction
    assert spinning[3] == pytest.approx(machine.house.slew_friction * rate, rel=1e-9, abs=1e-6)


def test_tilt_rotates_gravity(arm, machine):
    """Pitching the ground by α is, for the arm joints at slew 0, the same as raising the boom by α;
    rolling it loads the slew drive when the arm points sideways."""
    rng = np.random.default_rng(4)
    q, _, _ = random_states(rng, 20, machine, slew=False)
    q[:, 3] = 0
    alpha = 0.1
    tilted = arm.inverse_dynamics(q, np.zeros(4), np.zeros(4), np.array([alpha, 0.0]), 1000.0)
    shifted = q.copy()
    shifted[:, 0] += alpha
    level = arm.inverse_dynamics(shifted, np.zeros(4), np.zeros(4), LEVEL, 1000.0)
    np.testing.assert_allclose(tilted[:, :3], level[:, :3], rtol=1e-9, atol=1e-6)
    assert np.all(np.abs(arm.inverse_dynamics(q, np.zeros(4), np.zeros(4), LEVEL, 1000.0)[:, 3]) < 1e-6)
    rolled = arm.inverse_dynamics(q, np.zeros(4), np.zeros(4), np.array([0.0, 0.1]), 1000.0)
    assert np.all(np.abs(rolled[:, 3]) > 1e3)
    # The house IMU reads the ground's pitch at slew 0 and its roll after a quarter turn.
    incl = arm.house_inclination(np.array([[0, 0, 0, 0.0], [0, 0, 0, np.pi / 2]]), np.array([0.1, 0.0]))
    np.testing.assert_allclose(incl, [[0.1, 0.0], [0.0, -0.1]], atol=1e-12)


def test_payload_enters_affinely(arm, machine):
    rng = np.random.default_rng(5)
    q, qd, qdd = random_states(rng, 20, machine)
    tilt = np.array([0.05, 0.02])
    tau = arm.inverse_dynamics(q, qd, qdd, tilt, 1234.0)
    np.testing.assert_allclose(tau, arm.torque_empty(q, qd, qdd, tilt)
                               + 1234.0 * arm.payload_regressor(q, qd, qdd, tilt), rtol=1e-9, atol=1e-6)


def test_parameter_vector_names_every_parameter(machine):
    assert len(parameter_vector(machine)) == len(HYDRAULIC_PARAMETER_NAMES)


def test_pressure_regression_of_a_moving_cylinder_is_exact_on_noise_free_data(machine):
    """The weighing residual of the symbolic model vanishes (to the load coefficient squared)
    on the simulator's noise-free pressures wherever the cylinders move: the friction law is
    of the load force, recovered from the piston force by one fixed-point step."""
    from excavator_payload.estimators.classical import calibrated_machine as cm
    from excavator_payload.model.hydraulic import HydraulicArmModel
    from excavator_payload.simulation.generate import simulate_dataset

    ds = simulate_dataset(2, seed=5, machine=machine, motion="swing", noise="none",
                          with_truth=True, workers=1, progress=False)
    f = ds.frame
    cal = cm.MachineCalibration(HydraulicArmModel(machine, compiled=False))
    qdd = f[["true_boom_accel", "true_dipper_accel", "true_bucket_accel", "true_slew_accel"]].to_numpy(float)
    r, _, _, speed, _ = cal.evaluate(f[list(cm.SIGNALS)].to_numpy(float), qdd, f["payload"].to_numpy(float), cal.z)
    kg = r / cal._payload_sensitivity
    v_s = np.array([c.stribeck_velocity for c in machine.cylinders])
    moving = np.abs(speed) > 3 * v_s
    assert moving.sum() > 100
    assert np.percentile(np.abs(kg[moving]), 95) < 1.0  # the old |piston force| law: ~8 kg
