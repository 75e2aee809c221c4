r"""Dynamics of the hydraulic machine: boom, dipper and bucket on a slewing, tilted house.

The single symbolic source of the hydraulic machine's physics (as :mod:`.dynamics` is for the
thesis' 2-link arm): rigid-body dynamics by Lagrange, cylinder kinematics (lengths and moment
arms, the bucket through its four-bar linkage), seal friction and the pressures that produce a
cylinder force, all CasADi expressions of the machine's parameter vector
(:data:`HYDRAULIC_PARAMETER_NAMES`).

Coordinates
-----------
:math:`q = [q_1, q_2, q_3, \psi]`: boom angle (from the house's x axis, up positive), dipper
angle (relative to the boom), bucket angle (relative to the dipper) and slew angle (about the
house's vertical axis). The arm moves in the house's x–z plane; the house stands on ground
tilted by ``tilt`` = [pitch, roll] (pitch: front up, roll: left side up), so that the house
frame is :math:`R_H = R_x(\mathrm{roll})\,R_y(-\mathrm{pitch})\,R_z(\psi)` in the world.

Lagrangian
----------
Each link :math:`i` has mass :math:`m_i`, centre of mass :math:`c_i` in its frame and
principal inertia :math:`(I_u, I_y, I_w)_i` about it; the payload is a point mass at
``payload_position`` in the bucket frame. With :math:`p_H` a point in house coordinates, its
world velocity has the magnitude of :math:`\dot p_H + \dot\psi\, e_z \times p_H`, and a link's
angular velocity in its own frame is :math:`R_y(-\theta_i)^\top (0, -\dot\theta_i, \dot\psi)`
(:math:`\theta_i` its absolute angle in the arm plane). Then

.. math::

    K = \sum_i \tfrac12 m_i \|v_i\|^2 + \tfrac12 \omega_i^\top I_i \omega_i
        + \tfrac12 (J_H + m_H r_H^2)\dot\psi^2 + \tfrac12 m \|v_m\|^2, \quad
    P = -\sum_j m_j\, g_H \cdot p_{H,j}, \quad
    D = \tfrac12 \sum_k \beta_k \dot q_k^2

with :math:`g_H = R_H^\top (0, 0, -g)` gravity in the house frame, and
:math:`\tau = \frac{d}{dt}\partial_{\dot q}K - \partial_q K + \partial_q P + \partial_{\dot q}D
= M(q)\ddot q + h(q, \dot q)`. Slewing adds centrifugal and Coriolis terms on the arm joints,
tilt turns gravity (and loads the slew drive). With the bucket locked, no slew, no tilt and
uniform-bar links this is the thesis' 2-link model (tested).

Cylinders
---------
Cylinder length :math:`l_j(q)` is the distance between its two pins; the bucket cylinder's rod
pin G is the joint of the rocker (pivot E on the dipper) and the link (pin F on the bucket): the
intersection of two circles, closed form. The moment arm is :math:`\partial l_j / \partial q_j`
(CasADi's Jacobian), and by virtual work the joint torque of ``count`` cylinders with force
:math:`F` each is :math:`\tau_j = \text{count}\cdot F \cdot \partial l_j/\partial q_j`. The
force is :math:`F = p_h A_h - p_r A_r - F_f`, where seal friction

.. math::

    F_f = s\,(F_C + \mu |F_\text{load}|)\,\bigl(1 + (r_s - 1) e^{-(v/v_s)^2}\bigr) + b v

has Coulomb (:math:`F_C`, plus :math:`\mu` times the load: seals press harder at high
pressure), Stribeck (breakaway :math:`r_s F_C` at low speed) and viscous parts; :math:`s \in
[-1, 1]` is a presliding (Dahl) state that follows the sign of the motion over the presliding
displacement and *stays where it was* when the cylinder stops: stiction holds the last force.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.errors import MachineError

LINKS = ("boom", "dipper", "bucket")
CYLINDERS = ("boom_cylinder", "dipper_cylinder", "bucket_cylinder")

#: Order of the parameter vector ``p`` of every symbolic function of this module.
HYDRAULIC_PARAMETER_NAMES: tuple[str, ...] = (
    "gravity",
    "boom_length", "dipper_length", "bucket_length",
    "boom_foot_x", "boom_foot_z",
    *(f"{link}_{k}" for link in LINKS
      for k in ("mass", "com_u", "com_w", "inertia_u", "inertia_y", "inertia_w")),
    "house_mass", "house_com_x", "house_com_y", "house_com_z", "house_slew_inertia",
    "payload_u", "payload_w",
    "boom_joint_friction", "dipper_joint_friction", "bucket_joint_friction", "slew_friction",
    "boom_cylinder_parent_x", "boom_cylinder_parent_z", "boom_cylinder_child_u", "boom_cylinder_child_w",
    "dipper_cylinder_parent_u", "dipper_cylinder_parent_w", "dipper_cylinder_child_u",
    "dipper_cylinder_child_w",
    "bucket_cylinder_parent_u", "bucket_cylinder_parent_w",
    "rocker_pivot_u", "rocker_pivot_w", "rocker_length", "link_length", "bucket_point_u",
    "bucket_point_w", "linkage_branch",
    *(f"{c}_{k}" for c in CYLINDERS for k in ("count", "head_area", "rod_area", "coulomb",
                                               "load_coefficient", "static_ratio",
                                               "stribeck_velocity", "viscous")),
    "back_pressure",
)


def parameter_vector(machine) -> np.ndarray:  # a HydraulicMachine (not imported: it imports this)
    """The machine's parameters in the order of :data:`HYDRAULIC_PARAMETER_NAMES`.

    Parameters
    ----------
    machine : HydraulicMachine
        The machine.
    """
    m = machine
    v: dict[str, float] = {"gravity": m.gravity, "boom_length": m.boom.length,
                           "dipper_length": m.dipper.length, "bucket_length": m.bucket.length,
                           "boom_foot_x": m.house.boom_foot[0], "boom_foot_z": m.house.boom_foot[1]}
    for name, link in zip(LINKS, m.links):
        v.update({f"{name}_mass": link.mass, f"{name}_com_u": link.com[0], f"{name}_com_w": link.com[1],
                  f"{name}_inertia_u": link.inertia[0], f"{name}_inertia_y": link.inertia[1],
                  f"{name}_inertia_w": link.inertia[2], f"{name}_joint_friction": link.joint_friction})
    v.update({"house_mass": m.house.mass, "house_com_x": m.house.com[0], "house_com_y": m.house.com[1],
              "house_com_z": m.house.com[2], "house_slew_inertia": m.house.slew_inertia,
              "payload_u": m.payload.position[0], "payload_w": m.payload.position[1],
              "slew_friction": m.house.slew_friction})
    bc, dc, kc, lk = m.boom_cylinder, m.dipper_cylinder, m.bucket_cylinder, m.linkage
    v.update({"boom_cylinder_parent_x": bc.parent_point[0], "boom_cylinder_parent_z": bc.parent_point[1],
              "boom_cylinder_child_u": bc.child_point[0], "boom_cylinder_child_w": bc.child_point[1],
              "dipper_cylinder_parent_u": dc.parent_point[0], "dipper_cylinder_parent_w": dc.parent_point[1],
              "dipper_cylinder_child_u": dc.child_point[0], "dipper_cylinder_child_w": dc.child_point[1],
              "bucket_cylinder_parent_u": kc.parent_point[0], "bucket_cylinder_parent_w": kc.parent_point[1],
              "rocker_pivot_u": lk.rocker_pivot[0], "rocker_pivot_w": lk.rocker_pivot[1],
              "rocker_length": lk.rocker_length, "link_length": lk.link_length,
              "bucket_point_u": lk.bucket_point[0], "bucket_point_w": lk.bucket_point[1],
              "linkage_branch": float(lk.branch), "back_pressure": m.hydraulics.back_pressure})
    for name, c in zip(CYLINDERS, m.cylinders):
        v.update({f"{name}_count": c.count, f"{name}_head_area": c.head_area,
                  f"{name}_rod_area": c.rod_area, f"{name}_coulomb": c.coulomb,
                  f"{name}_load_coefficient": c.load_coefficient, f"{name}_static_ratio": c.static_ratio,
                  f"{name}_stribeck_velocity": c.stribeck_velocity, f"{name}_viscous": c.viscous})
    return np.array([float(v[k]) for k in HYDRAULIC_PARAMETER_NAMES])


def _rot2(angle):
    """2-D rotation in the arm plane (u along x, w along z)."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


def _rx(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def _ry(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def _rz(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


class HydraulicSymbolic:
    """CasADi symbols, expressions and functions of the hydraulic machine (see module doc).

    Symbols: ``q``, ``qd``, ``qdd``, ``tau`` (4 each: boom, dipper, bucket, slew), ``tilt`` (2:
    ground pitch, roll), ``payload`` (1), ``p`` (:data:`HYDRAULIC_PARAMETER_NAMES`).
    """

    def __init__(self) -> None:
        q, qd, qdd, tau = (ca.SX.sym(n, 4) for n in ("q", "qd", "qdd", "tau"))
        tilt = ca.SX.sym("tilt", 2)
        payload = ca.SX.sym("payload")
        p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
        P = {name: p[i] for i, name in enumerate(HYDRAULIC_PARAMETER_NAMES)}
        self.q, self.qd, self.qdd, self.tau, self.tilt, self.payload, self.p = q, qd, qdd, tau, tilt, payload, p

        # -- planar kinematics in the arm plane (house x, z) ---------------------------------
        angles = [q[0], q[0] + q[1], q[0] + q[1] + q[2]]  # absolute link angles θ_i
        foot = ca.vertcat(P["boom_foot_x"], P["boom_foot_z"])
        dipper_joint = foot + ca.mtimes(_rot2(angles[0]), ca.vertcat(P["boom_length"], 0))
        bucket_joint = dipper_joint + ca.mtimes(_rot2(angles[1]), ca.vertcat(P["dipper_length"], 0))
        origins = [foot, dipper_joint, bucket_joint]

        def in_plane(link: int, u, w):
            return origins[link] + ca.mtimes(_rot2(angles[link]), ca.vertcat(u, w))

        def to_house(xz):  # arm plane point -> 3-D house coordinates (y = 0)
            return ca.vertcat(xz[0], 0, xz[1])

        tip = in_plane(2, P["bucket_length"], 0)
        tip_jacobian = ca.jacobian(tip, q)[:, :3]
        tip_force = ca.SX.sym("tip_force", 2)  # on the teeth, in the arm plane [x, z], N
        payload_point = in_plane(2, P["payload_u"], P["payload_w"])

        # -- energies ------------------------------------------------------------------------
        slew_rate = qd[3]
        e_z = ca.DM([0, 0, 1])

        def velocity(point3):
            return ca.mtimes(ca.jacobian(point3, q), qd) + ca.cross(slew_rate * e_z, point3)

        R_house = ca.mtimes(ca.mtimes(_rx(tilt[1]), _ry(-tilt[0])), _rz(q[3]))
        gravity_house = ca.mtimes(R_house.T, ca.vertcat(0, 0, -P["gravity"]))
        kinetic, potential = 0, 0
        for i, name in enumerate(LINKS):
            m_i = P[f"{name}_mass"]
            c3 = to_house(in_plane(i, P[f"{name}_com_u"], P[f"{name}_com_w"]))
            v = velocity(c3)
            theta_rate = ca.sum1(qd[: i + 1])
            omega_house = ca.vertcat(0, -theta_rate, slew_rate)
            omega_body = ca.mtimes(_ry(-angles[i]).T, omega_house)
            inertia = ca.vertcat(P[f"{name}_inertia_u"], P[f"{name}_inertia_y"], P[f"{name}_inertia_w"])
            kinetic += 0.5 * m_i * ca.dot(v, v) + 0.5 * ca.dot(inertia, omega_body**2)
            potential -= m_i * ca.dot(gravity_house, c3)
        m3 = to_house(payload_point)
        v_m = velocity(m3)
        kinetic += 0.5 * payload * ca.dot(v_m, v_m)
        potential -= payload * ca.dot(gravity_house, m3)
        house_com = ca.vertcat(P["house_com_x"], P["house_com_y"], P["house_com_z"])
        r2 = P["house_com_x"] ** 2 + P["house_com_y"] ** 2
        kinetic += 0.5 * (P["house_slew_inertia"] + P["house_mass"] * r2) * slew_rate**2
        potential -= P["house_mass"] * ca.dot(gravity_house, house_com)
        damping = ca.vertcat(P["boom_joint_friction"], P["dipper_joint_friction"],
                             P["bucket_joint_friction"], P["slew_friction"])
        rayleigh = 0.5 * ca.dot(damping, qd**2)

        dK_dqd = ca.gradient(kinetic, qd)
        torque = (ca.mtimes(ca.jacobian(dK_dqd, q), qd) + ca.mtimes(ca.jacobian(dK_dqd, qd), qdd)
                  - ca.gradient(kinetic, q) + ca.gradient(potential, q) + ca.gradient(rayleigh, qd))
        mass_matrix = ca.hessian(kinetic, qd)[0]
        bias = ca.substitute(torque, qdd, ca.DM.zeros(4))
        qdd_forward = ca.solve(mass_matrix, tau - bias)
        regressor = ca.jacobian(torque, payload)
        torque_empty = ca.substitute(torque, payload, 0)

        # -- cylinders -----------------------------------------------------------------------
        boom_a = ca.vertcat(P["boom_cylinder_parent_x"], P["boom_cylinder_parent_z"])
        boom_b = in_plane(0, P["boom_cylinder_child_u"], P["boom_cylinder_child_w"])
        dip_a = in_plane(0, P["dipper_cylinder_parent_u"], P["dipper_cylinder_parent_w"])
        dip_b = in_plane(1, P["dipper_cylinder_child_u"], P["dipper_cylinder_child_w"])
        buck_a = in_plane(1, P["bucket_cylinder_parent_u"], P["bucket_cylinder_parent_w"])
        # Four-bar: G on the circle about E (rocker) and on the circle about F (link).
        E = in_plane(1, P["rocker_pivot_u"], P["rocker_pivot_w"])
        F = in_plane(2, P["bucket_point_u"], P["bucket_point_w"])
        a, b = P["rocker_length"], P["link_length"]
        d_vec = F - E
        d = ca.norm_2(d_vec)
        along = (a**2 - b**2 + d**2) / (2 * d)
        # Outside the linkage's reach the root would be imaginary: fmax keeps it finite, and
        # the simulator checks that motions stay inside the angle ranges where it is real.
        height = ca.sqrt(ca.fmax(a**2 - along**2, 0))
        normal = ca.vertcat(-d_vec[1], d_vec[0]) / d
        G = E + along * d_vec / d + P["linkage_branch"] * height * normal
        lengths = ca.vertcat(ca.norm_2(boom_b - boom_a), ca.norm_2(dip_b - dip_a), ca.norm_2(G - buck_a))
        length_jacobian = ca.jacobian(lengths, q)
        moment_arms = ca.vertcat(length_jacobian[0, 0], length_jacobian[1, 1], length_jacobian[2, 2])
        counts = ca.vertcat(*[P[f"{c}_count"] for c in CYLINDERS])
        head = ca.vertcat(*[P[f"{c}_head_area"] for c in CYLINDERS])
        rod = ca.vertcat(*[P[f"{c}_rod_area"] for c in CYLINDERS])

        # Cylinder force (per cylinder) that gives the arm torques: τ_j = count F_j ∂l_j/∂q_j.
        arm_torque = ca.SX.sym("arm_torque", 3)
        load_force = arm_torque / (counts * moment_arms)
        cylinder_speed = moment_arms * qd[:3]

        # Seal friction (module doc), per cylinder.
        velocity_c = ca.SX.sym("v", 3)
        state_c = ca.SX.sym("s", 3)
        load_c = ca.SX.sym("load", 3)
        def get(key):
            return ca.vertcat(*[P[f"{c}_{key}"] for c in CYLINDERS])

        stribeck = 1 + (get("static_ratio") - 1) * ca.exp(-(velocity_c / get("stribeck_velocity")) ** 2)
        friction = (state_c * (get("coulomb") + get("load_coefficient") * ca.fabs(load_c)) * stribeck
                    + get("viscous") * velocity_c)

        # The seal friction of a *moving* cylinder as an estimator can know it. Its presliding
        # state is saturated at the sign of the speed once the rod has travelled a few
        # presliding displacements (millimetres): a smooth sign, sharp beside the Stribeck
        # velocity (width v_s/10), is ±1 wherever samples are weighted (above 3 v_s); nearer
        # standstill the friction is unknown anyway (``stiction``). The friction law is of the
        # *load* force, while the pressures give the piston force = load + friction: called with
        # load = piston force − friction(piston force), one fixed-point step, it is exact to
        # load_coefficient² (4e-4). Measured on noise-free NMPC swings: the boom residual of a
        # moving cylinder is 0.2 kg of payload (median) this way, 8.4 kg with the load taken as
        # the piston force and a sign of width v_s.
        def signed_friction(speed, sign, load):
            return ca.substitute(ca.substitute(ca.substitute(friction, velocity_c, speed), state_c, sign),
                                 load_c, load)

        def moving_friction(speed, load):
            return signed_friction(speed, speed / ca.sqrt(speed**2 + (0.1 * get("stribeck_velocity")) ** 2), load)

        moving_force = ca.SX.sym("moving_force", 3)
        moving_speed = ca.SX.sym("moving_speed", 3)

        # Pressures that produce a cylinder force F = p_h A_h − p_r A_r: the loaded side carries
        # the force, the other holds the back pressure. Pushing: p_r = p_back; pulling:
        # p_h = p_back. The two meet where both chambers hold the back pressure, at
        # F₀ = p_back (A_h − A_r): below it the head side would have to fall under the back
        # pressure, which the make-up (anti-cavitation) valves do not allow — switching at F = 0
        # dipped the head pressure to p_back·A_r/A_h for a sample wherever a force crossed zero,
        # a one-frame spike no machine shows. Both satisfy the force balance exactly, so their
        # blend by a smooth step of F − F₀ (over ±1 kN) does too, and the pressures stay
        # differentiable where the loaded side changes.
        force_c = ca.SX.sym("force", 3)
        blend = 1e3
        both_back = P["back_pressure"] * (head - rod)
        pushing = 0.5 * (1 + (force_c - both_back) / ca.sqrt((force_c - both_back)**2 + blend**2))
        p_back = P["back_pressure"]
        p_head = pushing * (force_c + p_back * rod) / head + (1 - pushing) * p_back
        p_rod = pushing * p_back + (1 - pushing) * (p_back * head - force_c) / rod

        # House inclination seen by an IMU on the house: angle of its x (pitch) and y (roll)
        # axes above the horizontal.
        house_pitch = ca.asin(ca.fmin(1, ca.fmax(-1, R_house[2, 0])))
        house_roll = ca.asin(ca.fmin(1, ca.fmax(-1, R_house[2, 1])))

        self.kinetic, self.potential, self.rayleigh = kinetic, potential, rayleigh
        self.torque, self.mass_matrix, self.bias = torque, mass_matrix, bias
        self.lengths, self.moment_arms = lengths, moment_arms

        F_ = ca.Function
        qn = ["q", "qd", "qdd", "tilt", "payload", "p"]
        self.functions = {
            "inverse_dynamics": F_("hyd_inverse_dynamics", [q, qd, qdd, tilt, payload, p], [torque], qn, ["tau"]),
            "forward_dynamics": F_("hyd_forward_dynamics", [q, qd, tau, tilt, payload, p], [qdd_forward],
                                   ["q", "qd", "tau", "tilt", "payload", "p"], ["qdd"]),
            "mass_matrix": F_("hyd_mass_matrix", [q, payload, p], [mass_matrix], ["q", "payload", "p"], ["M"]),
            "payload_regressor": F_("hyd_payload_regressor", [q, qd, qdd, tilt, p], [regressor],
                                    ["q", "qd", "qdd", "tilt", "p"], ["phi"]),
            "torque_empty": F_("hyd_torque_empty", [q, qd, qdd, tilt, p], [torque_empty],
                               ["q", "qd", "qdd", "tilt", "p"], ["tau0"]),
            "energy": F_("hyd_energy", [q, qd, tilt, payload, p], [kinetic, potential],
                         ["q", "qd", "tilt", "payload", "p"], ["kinetic", "potential"]),
            "cylinder_lengths": F_("hyd_cylinder_lengths", [q, p], [lengths], ["q", "p"], ["length"]),
            "moment_arms": F_("hyd_moment_arms", [q, p], [moment_arms], ["q", "p"], ["arm"]),
            "cylinder_speeds": F_("hyd_cylinder_speeds", [q, qd, p], [cylinder_speed], ["q", "qd", "p"], ["v"]),
            "load_force": F_("hyd_load_force", [q, arm_torque, p], [load_force], ["q", "tau", "p"], ["force"]),
            "friction": F_("hyd_friction", [velocity_c, state_c, load_c, p], [friction],
                           ["v", "s", "load", "p"], ["friction"]),
            "moving_friction": F_("hyd_moving_friction", [moving_speed, moving_force, p],
                                  [moving_friction(moving_speed, moving_force)], ["v", "load", "p"], ["friction"]),
            "pressures": F_("hyd_pressures", [force_c, p], [p_head, p_rod], ["force", "p"],
                            ["head", "rod"]),
            "house_inclination": F_("hyd_house_inclination", [q, tilt], [ca.vertcat(house_pitch, house_roll)],
                                    ["q", "tilt"], ["pitch_roll"]),
            "tip_position": F_("hyd_tip_position", [q, p], [tip], ["q", "p"], ["tip"]),
            # the teeth's in-plane velocity and the arm torques of a force on them (the soil's
            # on a dig): J = ∂tip/∂q over boom, dipper, bucket; τ = Jᵀ f
            "tip_velocity": F_("hyd_tip_velocity", [q, qd, p], [ca.mtimes(tip_jacobian, qd[:3])],
                               ["q", "qd", "p"], ["v"]),
            "tip_torque": F_("hyd_tip_torque", [q, tip_force, p], [ca.mtimes(tip_jacobian.T, tip_force)],
                             ["q", "force", "p"], ["tau"]),
            "linkage_reach": F_("hyd_linkage_reach", [q, p], [a**2 - along**2], ["q", "p"], ["margin"]),
        }
        # The simulator's two calls per experiment, each one pass over the samples (compiled to
        # C by HydraulicArmModel): rigid body + cylinder kinematics, then friction + pressures.
        self.functions["motion_signals"] = F_(
            "hyd_motion_signals", [q, qd, qdd, tilt, payload, p],
            [torque, ca.substitute(load_force, arm_torque, torque[:3]), cylinder_speed, lengths,
             ca.vertcat(house_pitch, house_roll)],
            qn, ["tau", "load", "speed", "length", "inclination"])
        # Weighing from pressures (machine sensor set): the arm torques the measured pressures
        # give, τ_j = count·∂l_j/∂q_j·(p_h A_h − p_r A_r − F_f), with the seal friction's
        # presliding state replaced by a smooth sign of the rod speed (unknown to an estimator;
        # near standstill the friction is down-weighted, see ``stiction``), split as
        # τ_j − τ0_j = m φ_j.
        measured = ca.SX.sym("pressures", 6)  # boom head, rod, dipper head, rod, bucket head, rod
        piston_force = measured[0::2] * head - measured[1::2] * rod

        def piston_friction(friction_of_load):  # the load force recovered by one fixed-point step
            return friction_of_load(piston_force - friction_of_load(piston_force))

        friction_model = piston_friction(lambda load: moving_friction(cylinder_speed, load))
        lever = counts * moment_arms
        torque_from_pressures = lever * (piston_force - friction_model)
        stiction = ca.fabs(lever) * (get("coulomb") + get("load_coefficient") * ca.fabs(piston_force)) \
            * get("static_ratio")
        self.functions["pressure_regression"] = F_(
            "hyd_pressure_regression", [q, qd, qdd, tilt, measured, p],
            [torque_from_pressures - torque_empty[:3], regressor[:3], lever, cylinder_speed, stiction],
            ["q", "qd", "qdd", "tilt", "pressures", "p"],
            ["residual", "phi", "lever", "speed", "stiction"])
        # Weighing without accelerations (the integral form): Lagrange's equation read as a
        # momentum balance, d/dt ∂K/∂q̇ = τ + ∂K/∂q − ∂V/∂q − ∂R/∂q̇, integrated over a window,
        # needs angles, rates and pressures only: no differentiated rates. Momentum and forces
        # are affine in the payload; the window's residual is
        # r = [∫(τ_p + f0) dt − Δp0]/T − m [Δpm − ∫ fm dt]/T (the per-sample r = τ_p − τ0 − m φ
        # averaged over the window, with τ0 = ṗ0 − f0 and φ = ṗm − fm).
        momentum = dK_dqd[:3]
        momentum0 = ca.substitute(momentum, payload, 0)
        forces = (ca.gradient(kinetic, q) - ca.gradient(potential, q) - ca.gradient(rayleigh, qd))[:3]
        def momentum_outputs(arm_torque_from_pressures):
            return [momentum0, ca.jacobian(momentum, payload),
                    arm_torque_from_pressures + ca.substitute(forces, payload, 0), ca.jacobian(forces, payload),
                    lever, cylinder_speed, stiction,
                    # how the rates' noise enters the momentum: Σ_k (∂p0_j/∂q̇_k)², per joint j
                    ca.sum2(ca.jacobian(momentum0, qd) ** 2)]

        momentum_names = ["momentum0", "momentum_payload", "integrand0", "force_payload", "lever", "speed",
                          "stiction", "rate_gain"]
        self.functions["momentum_regression"] = F_(
            "hyd_momentum_regression", [q, qd, tilt, measured, p], momentum_outputs(torque_from_pressures),
            ["q", "qd", "tilt", "pressures", "p"], momentum_names)
        # The same with the friction's presliding state given (``sign``, one per cylinder) instead
        # of the smooth sign of the rod speed: a stopped seal holds the friction of its last
        # sliding direction (the Dahl state stays while the rod stands), which calibration knows
        # from the measured rates; 0 where no sliding has been seen yet (unknown).
        sign = ca.SX.sym("sign", 3)
        self.functions["momentum_regression_held"] = F_(
            "hyd_momentum_regression_held", [q, qd, tilt, measured, sign, p],
            momentum_outputs(lever * (piston_force - piston_friction(
                lambda load: signed_friction(cylinder_speed, sign, load)))),
            ["q", "qd", "tilt", "pressures", "sign", "p"], momentum_names)
        total_force = load_c + friction
        self.functions["cylinder_pressures"] = F_(
            "hyd_cylinder_pressures", [velocity_c, state_c, load_c, p],
            [friction, ca.substitute(ca.vertcat(p_head, p_rod), force_c, total_force)],
            ["v", "s", "load", "p"], ["friction", "pressures"])


@lru_cache(maxsize=1)
def hydraulic_symbolic() -> HydraulicSymbolic:
    """The hydraulic machine's symbolic model (built on first use, then cached)."""
    return HydraulicSymbolic()


_NATIVE: dict[str, ca.Function] = {}


def compiled_function(name: str) -> ca.Function:
    """The symbolic function ``name`` compiled to C (cached on disk, loaded once per process);
    the function itself where no compiler is available.

    Parameters
    ----------
    name : str
        A function of the hydraulic symbolic model (e.g. ``motion_signals``).
    """
    from excavator_payload.model.codegen import native

    if name not in _NATIVE:
        _NATIVE[name] = native(hydraulic_symbolic().functions[name])
    return _NATIVE[name]


#: From this many samples on, :meth:`HydraulicArmModel._call` evaluates through numpy buffers
#: (:class:`~excavator_payload.model.codegen.ColumnMap`): a swing's 1001 samples of
#: ``motion_signals`` took 9.9 ms through ``DM`` (converting, and CasADi's own column loop),
#: 0.6 ms so; the same numbers, to the bit. Fewer samples: the plain call is as fast.
_BUFFERED_SAMPLES = 16
#: Up to this many samples the mapped function and its buffers are kept per thread for the
#: next call; longer batches get their own (a few MB each, not held).
_CACHED_SAMPLES = 5000


def _mapped(f: ca.Function, n: int):
    from excavator_payload.model.codegen import ColumnMap, column_map

    return column_map(f, n) if n <= _CACHED_SAMPLES else ColumnMap(f, n)


def _cols(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.ascontiguousarray(a.reshape(-1, a.shape[-1]).T)


class HydraulicArmModel:
    """Numeric model of one hydraulic machine, evaluated in batches.

    Every method takes arrays with the coordinate on the last axis (``(..., 4)`` for ``q``,
    ``qd``, ``qdd``: boom, dipper, bucket, slew; ``(..., 2)`` for ``tilt``; ``(..., 3)`` for
    per-cylinder quantities) and broadcasts over the leading axes; one CasADi call per batch.

    Parameters
    ----------
    machine : HydraulicMachine
        The machine, loaded (:func:`excavator_payload.model.machine.load_machine`: names are
        resolved at the edge, not here).
    compiled : bool
        Use the C-compiled ``motion_signals`` and ``cylinder_pressures`` functions (see
        :func:`compiled_function`) instead of CasADi's interpreted ones.
    """

    def __init__(self, machine, compiled: bool = True):  # a HydraulicMachine (not imported: it imports this)
        if not hasattr(machine, "cylinders"):  # a 2-link arm, or a name not loaded
            raise MachineError(f"machine '{getattr(machine, 'name', machine)}' is not a hydraulic machine")
        self.machine = machine
        self.p = parameter_vector(machine)
        self._compiled = compiled
        self._bind()

    def _bind(self) -> None:
        self.sym = hydraulic_symbolic()
        self._f = dict(self.sym.functions)
        if self._compiled:
            for name in ("motion_signals", "cylinder_pressures"):
                self._f[name] = compiled_function(name)

    def __getstate__(self) -> dict:
        # CasADi's symbolic expressions do not pickle (a Dask worker receives the estimators
        # that hold this model): the functions are rebuilt from the (cached) symbolic model
        return {k: v for k, v in self.__dict__.items() if k not in ("sym", "_f")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()

    def _call(self, name: str, args: list, scalar_payload=None):
        arrays = [np.asarray(a, dtype=float) for a in args]
        shapes = [a.shape[:-1] for a in arrays]
        if scalar_payload is not None:
            shapes.append(np.shape(scalar_payload))
        lead = np.broadcast_shapes(*shapes)
        n = int(np.prod(lead)) if lead else 1
        cols = [_cols(np.broadcast_to(a, lead + a.shape[-1:])) for a in arrays]
        if scalar_payload is not None:
            cols.append(np.broadcast_to(np.asarray(scalar_payload, float), lead).reshape(1, n))
        cols.append(np.repeat(self.p[:, None], n, axis=1))
        f = self._f[name]
        if n >= _BUFFERED_SAMPLES:
            outs = _mapped(f, n)(*cols)
        else:
            out = f(*cols)
            outs = out if isinstance(out, (tuple, list)) else (out,)
        result = []
        for o in outs:
            o = np.asarray(o)
            k = o.shape[0]
            result.append(o.T.reshape(lead + ((k,) if k > 1 else ())))
        return result if len(result) > 1 else result[0]

    def _ordered(self, name, named: dict, payload=None):
        """Call ``name`` with inputs by name (payload as the scalar broadcast argument)."""
        f = self._f[name]
        order = [f.name_in(i) for i in range(f.n_in()) if f.name_in(i) not in ("payload", "p")]
        if payload is not None:
            assert [f.name_in(i) for i in range(f.n_in())][-2] == "payload"
        return self._call(name, [named[k] for k in order], payload)

    # -- rigid-body dynamics ---------------------------------------------------------------
    def inverse_dynamics(self, q, qd, qdd, tilt, payload):
        """Generalised forces [τ_boom, τ_dipper, τ_bucket, τ_slew] (N·m), shape (..., 4).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 4)
            Joint accelerations, rad/s².
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._ordered("inverse_dynamics", dict(q=q, qd=qd, qdd=qdd, tilt=tilt), payload)

    def forward_dynamics(self, q, qd, tau, tilt, payload):
        """Accelerations q̈ (rad/s²) under generalised forces ``tau``, shape (..., 4).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        tau : array_like, shape (..., 4)
            Generalised forces [τ_boom, τ_dipper, τ_bucket, τ_slew], N·m.
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._ordered("forward_dynamics", dict(q=q, qd=qd, tau=tau, tilt=tilt), payload)

    def payload_regressor(self, q, qd, qdd, tilt):
        """∂τ/∂m, so that τ = τ₀ + m·φ, shape (..., 4).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 4)
            Joint accelerations, rad/s².
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        """
        return self._ordered("payload_regressor", dict(q=q, qd=qd, qdd=qdd, tilt=tilt))

    def torque_empty(self, q, qd, qdd, tilt):
        """τ₀: the generalised forces with an empty bucket, shape (..., 4).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 4)
            Joint accelerations, rad/s².
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        """
        return self._ordered("torque_empty", dict(q=q, qd=qd, qdd=qdd, tilt=tilt))

    def mass_matrix(self, q, payload):
        """Mass matrix M(q) of boom, dipper, bucket and slew with payload ``payload`` (kg),
        kg·m², shape (..., 4, 4).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        out = self._call("mass_matrix", [q], payload)
        return out.reshape(out.shape[:-1] + (4, 4))

    def energy(self, q, qd, tilt, payload):
        """(kinetic, potential) energy, J.

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        return self._ordered("energy", dict(q=q, qd=qd, tilt=tilt), payload)

    # -- cylinders -------------------------------------------------------------------------
    def cylinder_lengths(self, q):
        """Pin-to-pin lengths of the boom, dipper and bucket cylinders, m, shape (..., 3).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        """
        return self._call("cylinder_lengths", [q])

    def moment_arms(self, q):
        """∂l_j/∂q_j of the three cylinders, m/rad, shape (..., 3).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        """
        return self._call("moment_arms", [q])

    def rod_speed_limits(self) -> np.ndarray:
        """(3, 2): the fastest each cylinder's rod extends and retracts (m/s): the pump's flow
        over the piston and the annulus area, shared by the ``count`` cylinders of a joint."""
        flow = self.machine.hydraulics.pump_flow
        return np.array([[flow / (c.count * c.head_area), flow / (c.count * c.rod_area)]
                         for c in self.machine.cylinders])

    def joint_sweep(self, j: int, points: int = 200) -> np.ndarray:
        """(points, 4) poses sweeping joint ``j`` (boom, dipper, bucket) over its angle range, the
        other joints at a mid pose: a cylinder's length, speed ratio and moment arm depend on its
        own joint's angle only.

        Parameters
        ----------
        j : int
            The joint to sweep: 0 boom, 1 dipper, 2 bucket.
        points : int, default 200
            Number of angles sampled over each joint's range.
        """
        grid = np.zeros((points, 4))
        grid[:, :3] = (-0.3, -1.3, -0.8)
        grid[:, j] = np.linspace(*self.machine.angle_ranges[j], points)
        return grid

    def moment_arm_range(self, points: int = 200) -> np.ndarray:
        """(3, 2): the smallest and largest ``|∂l_j/∂q_j|`` (m/rad) over each joint's angle range,
        on ``points`` angles (:meth:`joint_sweep`).

        Parameters
        ----------
        points : int, default 200
            Number of angles sampled over each joint's range.
        """
        out = np.zeros((3, 2))
        for j in range(3):
            arms = np.abs(self.moment_arms(self.joint_sweep(j, points))[:, j])
            out[j] = arms.min(), arms.max()
        return out

    def largest_joint_rates(self, points: int = 400) -> np.ndarray:
        """The fastest each joint can turn (rad/s; boom, dipper, bucket, slew), from the machine
        file's hydraulics: the faster of a rod's two speed limits (:meth:`rod_speed_limits`)
        at the joint's smallest moment arm over its range (:meth:`moment_arm_range`); the slew
        at ``max_slew_rate``. A joint whose arm reaches 0 in its range (a linkage at its dead
        point) has no finite limit: inf.

        Parameters
        ----------
        points : int, default 400
            Number of angles sampled over each joint's range.
        """
        smallest_arm = self.moment_arm_range(points)[:, 0]
        rod_speed = self.rod_speed_limits().max(axis=1)
        with np.errstate(divide="ignore"):
            rates = np.where(smallest_arm > 0, rod_speed / smallest_arm, np.inf)
        return np.r_[rates, self.machine.house.max_slew_rate]

    def cylinder_speeds(self, q, qd):
        """Rod speeds l̇_j (m/s, extension positive), shape (..., 3).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        """
        return self._call("cylinder_speeds", [q, qd])

    def load_force(self, q, arm_torque):
        """Force per cylinder (N) that produces the arm torques ``arm_torque`` (..., 3).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        arm_torque : array_like, shape (..., 3)
            Torques at the boom, dipper and bucket joints, N·m.
        """
        return self._call("load_force", [q, arm_torque])

    def friction(self, velocity, state, load):
        """Seal friction force per cylinder (N), opposing ``velocity`` (..., 3).

        Parameters
        ----------
        velocity : array_like, shape (..., 3)
            Rod speeds of the boom, dipper and bucket cylinders, m/s (extension positive).
        state : array_like, shape (..., 3)
            Presliding (Dahl) friction state of each cylinder, in [-1, 1].
        load : array_like, shape (..., 3)
            Load force of each cylinder, N.
        """
        return self._call("friction", [velocity, state, load])

    def pressures(self, force):
        """(head, rod) pressures, Pa, that give the cylinder force ``force`` (N), each (..., 3).

        Parameters
        ----------
        force : array_like, shape (..., 3)
            Force of each cylinder, N (push positive).
        """
        return self._call("pressures", [force])

    def house_inclination(self, q, tilt):
        """(pitch, roll) of the house (rad) at slew angle q[..., 3] on ground ``tilt``, (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        """
        q, tilt = np.asarray(q, float), np.asarray(tilt, float)
        lead = np.broadcast_shapes(q.shape[:-1], tilt.shape[:-1])
        n = int(np.prod(lead)) if lead else 1
        out = self._f["house_inclination"](_cols(np.broadcast_to(q, lead + (4,))),
                                           _cols(np.broadcast_to(tilt, lead + (2,))))
        return np.asarray(out).T.reshape(lead + (2,)) if n else np.zeros(lead + (2,))

    def tip_position(self, q):
        """Bucket teeth in the arm plane [x, z] of the house frame, m.

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        """
        return self._call("tip_position", [q])

    def tip_velocity(self, q, qd):
        """Velocity of the bucket teeth in the arm plane [x, z] of the house frame, m/s.

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        """
        return self._call("tip_velocity", [q, qd])

    def tip_torque(self, q, force):
        """Torques at the boom, dipper and bucket joints (N·m, (..., 3)) of a force on the teeth.

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        force : array_like, shape (..., 2)
            Force on the teeth in the arm plane [x, z] of the house frame, N.
        """
        return self._call("tip_torque", [q, force])

    def motion_signals(self, q, qd, qdd, tilt, payload) -> dict[str, np.ndarray]:
        """Everything the simulator needs from the rigid body and the cylinder kinematics in one
        pass: ``tau`` (..., 4), per-cylinder ``load`` force, rod ``speed`` and ``length``
        (..., 3), house ``inclination`` (..., 2).

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        qd : array_like, shape (..., 4)
            Joint rates, rad/s.
        qdd : array_like, shape (..., 4)
            Joint accelerations, rad/s².
        tilt : array_like, shape (..., 2)
            Ground tilt [pitch, roll], rad (pitch: front up, roll: left side up).
        payload : float or array_like
            Payload mass, kg; broadcasts against the leading axes.
        """
        out = self._ordered("motion_signals", dict(q=q, qd=qd, qdd=qdd, tilt=tilt), payload)
        return dict(zip(("tau", "load", "speed", "length", "inclination"), out))

    def cylinder_pressures(self, velocity, state, load):
        """(friction (..., 3), head (..., 3), rod (..., 3)): seal friction and the pressures that
        give load + friction.

        Parameters
        ----------
        velocity : array_like, shape (..., 3)
            Rod speeds of the boom, dipper and bucket cylinders, m/s (extension positive).
        state : array_like, shape (..., 3)
            Presliding (Dahl) friction state of each cylinder, in [-1, 1].
        load : array_like, shape (..., 3)
            Load force of each cylinder, N.
        """
        friction, pressures = self._call("cylinder_pressures", [velocity, state, load])
        return friction, pressures[..., :3], pressures[..., 3:]

    def linkage_margin(self, q):
        """> 0 where the bucket four-bar closes (a² − along²), m².

        Parameters
        ----------
        q : array_like, shape (..., 4)
            Joint angles [boom, dipper, bucket, slew], rad.
        """
        return self._call("linkage_reach", [q])
