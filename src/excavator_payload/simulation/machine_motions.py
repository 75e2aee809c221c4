r"""Motions of the hydraulic machine, planned within what its hydraulics can do.

A motion is, per coordinate (boom, dipper, bucket, slew), a sum of rest-to-rest minimum-jerk
steps that may overlap in time, as an operator moves several levers at once:

.. math::

    q_j(t) = q_j(0) + \sum_k \Delta_{jk}\,\sigma\!\left(\frac{t - t_{jk}}{T_{jk}}\right), \qquad
    \sigma(s) = 10s^3 - 15s^4 + 6s^5 \text{ on } [0, 1]

(smooth: angles, rates and accelerations are continuous). A planned motion is then checked
against the machine's hydraulics: the rod speed of each cylinder may not exceed what one
pump's flow gives (``pump_flow`` / piston area when extending, / annulus area when retracting,
shared by ``count`` cylinders), the slew rate may not exceed ``max_slew_rate``; if it does, the
whole motion is slowed down uniformly (time stretched) until it fits. Poses stay inside the
angle ranges (which fit the strokes) and the simulator rejects and redraws motions whose
pressures would exceed the relief pressure.

Motions
-------
``swing``       loaded swing from a digging pose to a dumping pose while slewing 30-180°, 8 s.
``work-cycle``  operator-like cycle: curl at the end of the dig, lift while slewing, pause
                with small corrections, dump (the load leaves the bucket), return; 12-20 s.
``slopes``      work cycles on ground tilted up to 10° in a random direction.
``lifts``       slow constant-speed boom lifts (calibration runs): dipper and bucket held,
                no slew, payloads alternating empty / rated.
``operator``    a loaded lift-and-slew as an operator makes it: the boom lifted in two moves with
                a pause between, a slew of 45-80° that overshoots and is corrected, dipper and
                bucket trimmed all along, up to 90 % of the pumps' speed; 9-15 s.
``shift``       one truck loaded: 2-6 work cycles one after another (:func:`shift_motion`), each
                with its own fill, entering the bucket during the curl and leaving at the dump,
                with the operator's pauses between passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from excavator_payload.model.hydraulic import HydraulicArmModel
# the shift's pass counts and least fill: the platform checks --truck-target against them
from excavator_payload.platforms.hydraulic import SHIFT_LEAST_FILL, SHIFT_PASSES

DEG = np.pi / 180.0
SAMPLE_RATE = 100.0


@dataclass
class Step:
    """One step of coordinate ``joint`` by ``delta`` from ``start`` over ``duration``.

    Minimum-jerk by default; with ``ramp`` (s) a constant-speed move whose speed ramps up and
    down smoothly (σ of the rate) over ``ramp`` at both ends, as the calibration lifts.

    Parameters
    ----------
    joint : int
        Coordinate moved: 0 boom, 1 dipper, 2 bucket (relative), 3 slew.
    start : float
        Time the step begins, s.
    duration : float
        Duration of the step, s.
    delta : float
        Change of the coordinate over the step, rad.
    ramp : float, optional
        Duration of the speed ramps of a constant-speed move, s; ``None``: minimum-jerk.
    """

    joint: int
    start: float
    duration: float
    delta: float
    ramp: float | None = None

    def profile(self, time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Displacement, rate and acceleration of this step at ``time``.

        Parameters
        ----------
        time : numpy.ndarray
            Sample times, s, shape (n,).

        Returns
        -------
        pos, rate, accel : numpy.ndarray
            Displacement from the start angle (rad), rate (rad/s) and acceleration (rad/s²),
            shape (n,).
        """
        tau = time - self.start
        D = self.duration
        if self.ramp is None:
            s = np.clip(tau / D, 0.0, 1.0)
            inside = (tau > 0) & (tau < D)
            return (self.delta * (10 * s**3 - 15 * s**4 + 6 * s**5),
                    inside * self.delta * (30 * s**2 - 60 * s**3 + 30 * s**4) / D,
                    inside * self.delta * (60 * s - 180 * s**2 + 120 * s**3) / D**2)
        r = self.ramp
        v = self.delta / (D - r)

        def smooth(x):
            x = np.clip(x, 0.0, 1.0)
            return (10 * x**3 - 15 * x**4 + 6 * x**5, 30 * x**2 - 60 * x**3 + 30 * x**4,
                    2.5 * x**4 - 3 * x**5 + x**6)

        up_v, up_a, up_i = smooth(tau / r)
        dn_v, dn_a, dn_i = smooth((D - tau) / r)
        before, after = tau <= 0, tau >= D
        rising, falling = (tau > 0) & (tau < r), (tau > D - r) & (tau < D)
        pos = np.where(rising, v * r * up_i, np.where(falling, self.delta - v * r * dn_i,
                                                       v * r / 2 + v * (tau - r)))
        pos = np.where(before, 0.0, np.where(after, self.delta, pos))
        rate = np.where(before | after, 0.0, v * np.where(rising, up_v, np.where(falling, dn_v, 1.0)))
        accel = np.where(rising, v / r * up_a, np.where(falling, -v / r * dn_a, 0.0))
        return pos, rate, accel


@dataclass
class Motion:
    """A planned motion: initial pose, steps, duration, ground tilt, payload (kg, maybe over time).

    Parameters
    ----------
    initial : numpy.ndarray
        Initial pose (boom, dipper, bucket relative, slew), rad, shape (4,).
    steps : list of Step
        The steps, possibly overlapping in time.
    duration : float
        Duration of the motion, s.
    tilt : numpy.ndarray
        Ground tilt (pitch, roll), rad, shape (2,).
    payload : float
        Mass in the bucket, kg.
    release : tuple of float, optional
        Times (s) between which the load leaves the bucket (linearly).
    info : dict
        Description of the motion for the dataset's metadata.
    loads : list of tuple, optional
        Loads one after another (a shift): ``(fill start, fill end, release start, release
        end, kg)`` each, times in s; overrides ``payload`` / ``release`` in :meth:`payload_at`.
    soil : list of tuple, optional
        The soil's resistance on the teeth over each cut: ``(cut start, cut end, N)``, times in
        s (:meth:`soil_force`).
    """

    initial: np.ndarray  # (4,) rad
    steps: list[Step]
    duration: float
    tilt: np.ndarray = field(default_factory=lambda: np.zeros(2))
    payload: float = 0.0
    release: tuple[float, float] | None = None  # the load leaves the bucket between these times
    info: dict = field(default_factory=dict)
    #: loads one after another (a shift): (fill start, fill end, release start, release end, kg)
    #: each; the mass enters linearly over its fill and leaves over its release. Overrides
    #: ``payload`` / ``release`` in :meth:`payload_at`.
    loads: list[tuple[float, float, float, float, float]] | None = None
    #: the soil's resistance on the teeth while the bucket cuts (a shift's digs): (cut start,
    #: cut end, N) each; see :meth:`soil_force`
    soil: list[tuple[float, float, float]] | None = None

    def soil_force(self, time: np.ndarray, tip_velocity: np.ndarray) -> np.ndarray:
        """Force of the soil on the teeth, N, in the arm plane [x, z], shape (n, 2): over each
        cut a resistance against the teeth's motion, R·sin²(π (t − a)/(b − a)) (the teeth enter
        and leave the cut), along −v/max(|v|, :data:`SOIL_SPEED`) so that it fades where they stop.

        Parameters
        ----------
        time : numpy.ndarray
            Sample times, s, shape (n,).
        tip_velocity : numpy.ndarray
            The teeth's in-plane velocity, m/s, shape (n, 2).
        """
        force = np.zeros((len(time), 2))
        speed = np.maximum(np.linalg.norm(tip_velocity, axis=1), SOIL_SPEED)
        for a, b, resistance in self.soil or ():
            inside = (time >= a) & (time <= b)
            size = resistance * np.sin(np.pi * (time[inside] - a) / (b - a)) ** 2
            force[inside] = -(size / speed[inside])[:, None] * tip_velocity[inside]
        return force

    def stretched(self, factor: float) -> "Motion":
        """The same motion ``factor`` times slower.

        Parameters
        ----------
        factor : float
            Time stretch (> 1: slower); step times, durations, ramps and load windows scale by it.
        """
        steps = [Step(s.joint, s.start * factor, s.duration * factor, s.delta,
                      None if s.ramp is None else s.ramp * factor) for s in self.steps]
        release = None if self.release is None else (self.release[0] * factor, self.release[1] * factor)
        loads = None if self.loads is None else [
            (a * factor, b * factor, c * factor, d * factor, m) for a, b, c, d, m in self.loads]
        soil = None if self.soil is None else [(a * factor, b * factor, r) for a, b, r in self.soil]
        return Motion(self.initial.copy(), steps, self.duration * factor, self.tilt.copy(),
                      self.payload, release, dict(self.info), loads, soil)

    def sample(self, time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, q̈) at ``time``, each (n, 4).

        Parameters
        ----------
        time : numpy.ndarray
            Sample times, s, shape (n,).

        Returns
        -------
        q, qd, qdd : numpy.ndarray
            Angles (rad), rates (rad/s) and accelerations (rad/s²), shape (n, 4).
        """
        n = len(time)
        q = np.tile(self.initial, (n, 1)).astype(float)
        qd = np.zeros((n, 4))
        qdd = np.zeros((n, 4))
        for st in self.steps:
            pos, rate, accel = st.profile(time)
            q[:, st.joint] += pos
            qd[:, st.joint] += rate
            qdd[:, st.joint] += accel
        return q, qd, qdd

    def payload_at(self, time: np.ndarray) -> np.ndarray:
        """Mass in the bucket at ``time`` (falls linearly to 0 over the release window).

        Parameters
        ----------
        time : numpy.ndarray
            Sample times, s, shape (n,).

        Returns
        -------
        numpy.ndarray
            Payload mass, kg, shape (n,).
        """
        if self.loads is not None:
            mass = np.zeros(len(time))
            for a, b, c, d, m in self.loads:
                mass += m * np.clip((time - a) / (b - a), 0.0, 1.0) * np.clip((d - time) / (d - c), 0.0, 1.0)
            return mass
        if self.release is None:
            return np.full(len(time), float(self.payload))
        a, b = self.release
        return self.payload * np.clip((b - time) / (b - a), 0.0, 1.0)


def speed_share(arm: HydraulicArmModel, q: np.ndarray, qd: np.ndarray) -> float:
    """Largest share of the hydraulic speed limits a sampled motion uses (> 1: too fast).

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model (rod speed limits, slew rate limit).
    q, qd : numpy.ndarray
        Angles (rad) and rates (rad/s) of boom, dipper, bucket and slew, shape (n, 4).

    Returns
    -------
    float
        Largest ratio of a rod speed to its pump-flow limit, or of the slew rate to
        ``max_slew_rate``.
    """
    m = arm.machine
    speeds = arm.cylinder_speeds(q, qd)
    ratios = []
    for j, (v_out, v_in) in enumerate(arm.rod_speed_limits()):
        ratios.append(np.max(np.where(speeds[:, j] >= 0, speeds[:, j] / v_out, -speeds[:, j] / v_in)))
    ratios.append(np.max(np.abs(qd[:, 3])) / m.house.max_slew_rate)
    return float(max(ratios))


def speed_ratio(arm: HydraulicArmModel, motion: Motion, time: np.ndarray) -> float:
    """Largest share of the hydraulic speed limits the motion uses (> 1: too fast).

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model.
    motion : Motion
        The planned motion.
    time : numpy.ndarray
        Times (s) at which the motion is sampled for the check.

    Returns
    -------
    float
        As :func:`speed_share`.
    """
    q, qd, _ = motion.sample(time)
    return speed_share(arm, q, qd)


def fit_to_hydraulics(arm: HydraulicArmModel, motion: Motion) -> Motion:
    """``motion``, slowed down uniformly if it asks for more speed than the pumps give.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model.
    motion : Motion
        The planned motion; its ``info`` receives ``time_stretch`` and ``speed_share``.

    Returns
    -------
    Motion
        ``motion`` itself when it fits, else a stretched copy.
    """
    time = np.arange(0.0, motion.duration + 1e-9, 0.02)
    ratio = speed_ratio(arm, motion, time)
    if ratio > 1.0:
        motion = motion.stretched(ratio * 1.01)
        motion.info["time_stretch"] = ratio * 1.01
    else:
        motion.info["time_stretch"] = 1.0
    motion.info["speed_share"] = min(ratio, 1.0 / 1.01) if ratio > 1 else ratio
    return motion


def _uniform(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def shortest_duration(arm: HydraulicArmModel, joint: int, start: float, delta: float) -> float:
    """Shortest minimum-jerk step of ``joint`` from ``start`` by ``delta`` that the hydraulics
    allow on its own: rod speed ≤ pump flow / area (each cylinder moves only its joint, so
    its moment arm depends on that joint's angle alone), slew rate ≤ ``max_slew_rate``.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine's model.
    joint : int
        Coordinate moved: 0 boom, 1 dipper, 2 bucket, 3 slew.
    start : float
        Angle of the joint at the start of the step, rad.
    delta : float
        Change of the angle, rad.

    Returns
    -------
    float
        Shortest duration of the step, s.
    """
    m = arm.machine
    s = np.linspace(0.0, 1.0, 41)
    shape = 30 * s**2 - 60 * s**3 + 30 * s**4  # σ'(s)
    if joint == 3:
        return float(1.875 * abs(delta) / m.house.max_slew_rate)
    q = np.zeros((len(s), 4))
    q[:, :3] = (-0.3, -1.3, -0.8)
    q[:, joint] = start + delta * (10 * s**3 - 15 * s**4 + 6 * s**5)
    rod_speed_per_time = arm.moment_arms(q)[:, joint] * delta * shape  # × 1/T
    v_out, v_in = arm.rod_speed_limits()[joint]
    limit = np.where(rod_speed_per_time >= 0, v_out, v_in)
    return float(np.max(np.abs(rod_speed_per_time) / limit))


def _step(rng, arm, joint, begin, start_angle, delta, lo, hi) -> Step:
    """A step that takes a drawn operator's time, but never less than the hydraulics allow."""
    shortest = 1.1 * shortest_duration(arm, joint, start_angle, delta)
    return Step(joint, begin, max(_uniform(rng, lo, hi), shortest), float(delta))


def _inside(machine, margin=5 * DEG):
    r = machine.angle_ranges.copy()
    r[:, 0] += margin
    r[:, 1] -= margin
    return r


def dig_pose(rng, machine) -> np.ndarray:
    """End of a dig: boom low, dipper pulled in, bucket curled.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the draws.
    machine : HydraulicMachine
        The machine (its boom angle range).

    Returns
    -------
    numpy.ndarray
        Pose (boom, dipper, bucket, slew = 0), rad.
    """
    r = _inside(machine)
    return np.array([_uniform(rng, r[0, 0], r[0, 0] + 25 * DEG), _uniform(rng, -110 * DEG, -75 * DEG),
                     _uniform(rng, -60 * DEG, -30 * DEG), 0.0])


def carry_pose(rng, machine) -> np.ndarray:
    """Over the truck: boom high, dipper half out, bucket curled in to hold the load.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the draws.
    machine : HydraulicMachine
        The machine (its boom angle range).

    Returns
    -------
    numpy.ndarray
        Pose (boom, dipper, bucket, slew = 0), rad.
    """
    r = _inside(machine)
    return np.array([_uniform(rng, 25 * DEG, r[0, 1]), _uniform(rng, -90 * DEG, -45 * DEG),
                     _uniform(rng, -115 * DEG, -85 * DEG), 0.0])


def swing_motion(rng, arm: HydraulicArmModel) -> Motion:
    """A loaded swing while slewing 30-180°, from a digging to a dumping pose.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the motion's draws (poses, timing, payload).
    arm : HydraulicArmModel
        The machine's model (speed limits of the steps).

    Returns
    -------
    Motion
        The planned swing.
    """
    machine = arm.machine
    start = dig_pose(rng, machine)
    target = carry_pose(rng, machine)
    target[3] = _uniform(rng, 30 * DEG, 180 * DEG) * rng.choice([-1, 1])
    steps = []
    t0 = _uniform(rng, 0.3, 0.8)
    end = 0.0
    for j in range(4):
        steps.append(_step(rng, arm, j, t0 + _uniform(rng, 0.0, 0.6), start[j], target[j] - start[j],
                           2.0, 3.5))
        end = max(end, steps[-1].start + steps[-1].duration)
    payload = _uniform(rng, 0.0, machine.max_payload)
    return Motion(start, steps, end + _uniform(rng, 1.0, 1.5), payload=payload,
                  info={"start_pose": start.tolist(), "target_pose": target.tolist()})


def work_cycle_motion(rng, arm: HydraulicArmModel, tilt=np.zeros(2)) -> Motion:
    """Curl, lift while slewing, pause with corrections, dump, return (module doc).

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the motion's draws.
    arm : HydraulicArmModel
        The machine's model.
    tilt : numpy.ndarray
        Ground tilt (pitch, roll), rad.

    Returns
    -------
    Motion
        The planned cycle, kept inside the angle ranges.
    """
    machine = arm.machine
    start = dig_pose(rng, machine)
    start[2] = _uniform(rng, -20 * DEG, 10 * DEG)  # bucket still open at the end of the cut
    carry = carry_pose(rng, machine)
    slew = _uniform(rng, 45 * DEG, 160 * DEG) * rng.choice([-1, 1])
    steps: list[Step] = []
    t = _uniform(rng, 0.3, 0.8)
    # 1. curl the bucket and pull the dipper in: the end of the dig
    curl = _step(rng, arm, 2, t, start[2], carry[2] - start[2], 1.0, 2.0)
    pull = _uniform(rng, -10 * DEG, 0.0)
    steps += [curl, Step(1, t, curl.duration, pull)]
    # 2. lift while slewing (starts before the curl is over), dipper out meanwhile
    t_lift = t + 0.6 * curl.duration
    lift = _step(rng, arm, 0, t_lift, start[0], carry[0] - start[0], 2.5, 4.0)
    swing = _step(rng, arm, 3, t_lift + _uniform(rng, 0.0, 0.8), 0.0, slew, 2.5, 4.0)
    dipper = _step(rng, arm, 1, t_lift + 0.3 * lift.duration, start[1] + pull,
                   carry[1] - start[1] - pull, 1.5, 3.0)
    steps += [lift, swing, dipper]
    t = max(s.start + s.duration for s in steps) + _uniform(rng, 0.2, 0.8)
    # 3. pause over the truck with small corrections (where stiction bites)
    pause = _uniform(rng, 1.0, 2.5)
    for _ in range(int(rng.integers(1, 4))):
        joint = int(rng.integers(0, 3))
        steps.append(Step(joint, t + _uniform(rng, 0.0, pause - 0.6), 0.5, _uniform(rng, -2 * DEG, 2 * DEG)))
    t += pause
    # 4. dump: bucket opens, dipper out a little; the load leaves the bucket meanwhile
    dump = _step(rng, arm, 2, t, carry[2], _uniform(rng, 100 * DEG, 120 * DEG), 1.0, 2.0)
    steps += [dump, Step(1, t, dump.duration, _uniform(rng, 5 * DEG, 15 * DEG))]
    release = (t + 0.3 * dump.duration, t + dump.duration)
    t += dump.duration + _uniform(rng, 0.2, 0.6)
    # 5. return: slew back, boom down, bucket ready to dig
    back = _step(rng, arm, 3, t, slew, -slew, 2.5, 4.0)
    lower = _step(rng, arm, 0, t + 0.3, carry[0], start[0] - carry[0], 2.5, 4.0)
    ready = _step(rng, arm, 2, t + 0.5, carry[2] + dump.delta, _uniform(rng, -40 * DEG, -10 * DEG), 1.5, 3.0)
    steps += [back, lower, ready]
    duration = max(s.start + s.duration for s in steps) + _uniform(rng, 0.5, 1.0)
    payload = _uniform(rng, 0.0, machine.max_payload)
    motion = Motion(start, steps, duration, tilt=np.asarray(tilt, float), payload=payload,
                    release=release, info={"start_pose": start.tolist(), "carry_pose": carry.tolist(),
                                           "slew": slew})
    return _clip_to_ranges(motion, machine)


#: The soil's resistance on the teeth over a shift's cut, N (drawn per pass): a 45 t machine's
#: bucket breaks out at about 250 kN; filling through a cut takes a share of it.
SOIL_RESISTANCE = (20e3, 60e3)
#: Below this teeth speed (m/s) the soil's resistance fades with it (no force without motion).
SOIL_SPEED = 0.05


def shift_passes(rng, truck_target: float, machine) -> list[float]:
    """Fills (kg) of the passes that load a truck of ``truck_target`` kg.

    As many passes as a bucket at 90 % of rated needs (2-6), each of the target's share
    × 0.85-1.10 (the operator's fill varies), within 20 % of rated … the maximum payload:
    the truck's true load is their sum, near but not at the target, as on a real site.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the fill draws.
    truck_target : float
        Load the truck aims at, kg.
    machine : HydraulicMachine
        The machine (rated and maximum payload).

    Returns
    -------
    list of float
        Fill of each pass, kg.
    """
    rated = float(machine.rated_payload)
    n = int(np.clip(np.ceil(truck_target / (0.9 * rated)), *SHIFT_PASSES))
    share = truck_target / n
    return [float(np.clip(share * _uniform(rng, 0.85, 1.10), SHIFT_LEAST_FILL * rated, machine.max_payload))
            for _ in range(n)]


def shift_motion(rng, arm: HydraulicArmModel, truck_target: float) -> Motion:
    """One truck: work cycles (:func:`work_cycle_motion`) chained in time.

    Between two passes the operator pauses 0.5-4 s, then moves the arm from where the return
    left it to the next cut (each joint a minimum-jerk step the hydraulics allow). Each pass's
    fill enters the bucket during its curl and leaves during its dump's release window
    (:attr:`Motion.loads`). ``info["passes"]``: per pass its fill and times.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the motion's draws.
    arm : HydraulicArmModel
        The machine's model.
    truck_target : float
        Load the truck aims at, kg (see :func:`shift_passes`).

    Returns
    -------
    Motion
        The chained passes, with :attr:`Motion.loads` set.
    """
    machine = arm.machine
    fills = shift_passes(rng, truck_target, machine)
    steps: list[Step] = []
    loads: list[tuple[float, float, float, float, float]] = []
    passes: list[dict] = []
    initial = pose = None
    end = 0.0
    for i, fill in enumerate(fills):
        cycle = work_cycle_motion(rng, arm)
        if i == 0:
            initial, offset = cycle.initial.copy(), 0.0
        else:
            offset = end + _uniform(rng, 0.5, 4.0)  # the operator's pause between passes
            moved = offset
            for j in range(3):
                delta = float(cycle.initial[j] - pose[j])
                if abs(delta) > 1e-9:
                    st = _step(rng, arm, j, offset, pose[j], delta, 1.0, 2.0)
                    steps.append(st)
                    moved = max(moved, st.start + st.duration)
            offset = moved + _uniform(rng, 0.2, 0.6)
        steps += [Step(st.joint, st.start + offset, st.duration, st.delta, st.ramp) for st in cycle.steps]
        curl = cycle.steps[0]  # the cut's end: the bucket curls the load in
        fill_window = (offset + curl.start, offset + curl.start + curl.duration)
        release = (offset + cycle.release[0], offset + cycle.release[1])
        loads.append((*fill_window, *release, fill))
        passes.append({"pass": i + 1, "payload": fill, "start": offset, "fill": list(fill_window),
                       "release": list(release), "end": offset + cycle.duration})
        q, _, _ = cycle.sample(np.array([cycle.duration]))
        pose = q[0]
        end = offset + cycle.duration
    # the soil's resistance on each cut, drawn after the motion so that it leaves the motion's
    # draws as they were
    soil = []
    for p in passes:
        p["soil_resistance"] = _uniform(rng, *SOIL_RESISTANCE)
        soil.append((*p["fill"], p["soil_resistance"]))
    return Motion(initial, steps, end, payload=float(sum(fills)), loads=loads,
                  info={"truck_target": float(truck_target), "passes": passes}, soil=soil)


def _paced_step(rng, arm, joint, begin, start_angle, delta, share) -> Step:
    """A minimum-jerk step that uses ``share`` of what the hydraulics allow (operators push
    the levers hard: up to 90 % of the pumps' speed)."""
    return Step(joint, begin, max(shortest_duration(arm, joint, start_angle, delta) / share, 0.25),
                float(delta))


def operator_motion(rng, arm: HydraulicArmModel, tilt=np.zeros(2)) -> Motion:
    """A loaded lift and slew with a pause, an overshoot and continuous trims (module doc).

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the motion's draws.
    arm : HydraulicArmModel
        The machine's model.
    tilt : numpy.ndarray
        Ground tilt (pitch, roll), rad.

    Returns
    -------
    Motion
        The planned motion, kept inside the angle ranges.
    """
    machine = arm.machine
    start = dig_pose(rng, machine)
    carry = carry_pose(rng, machine)
    share = lambda: _uniform(rng, 0.5, 0.9)  # noqa: E731 - each move its own lever push
    steps: list[Step] = []
    t = _uniform(rng, 0.3, 1.0)
    # the boom in two moves with a pause between (the operator checks the swing path)
    split = _uniform(rng, 0.3, 0.7)
    first = _paced_step(rng, arm, 0, t, start[0], split * (carry[0] - start[0]), share())
    pause = _uniform(rng, 0.4, 1.5)
    second = _paced_step(rng, arm, 0, first.start + first.duration + pause, start[0] + first.delta,
                         (1 - split) * (carry[0] - start[0]), share())
    steps += [first, second]
    # the slew: past the target, then back (overshoot and correction)
    slew = _uniform(rng, 45 * DEG, 80 * DEG) * rng.choice([-1, 1])
    over = _uniform(rng, 0.05, 0.2) * slew
    swing = _paced_step(rng, arm, 3, t + _uniform(rng, 0.2, 1.2), 0.0, slew + over, share())
    back = _paced_step(rng, arm, 3, swing.start + swing.duration + _uniform(rng, 0.1, 0.6), slew + over,
                       -over, share())
    steps += [swing, back]
    end = max(s.start + s.duration for s in steps)
    # dipper and bucket: towards the carry pose, then trimmed all along
    for joint in (1, 2):
        main = _paced_step(rng, arm, joint, t + _uniform(rng, 0.0, 2.0), start[joint],
                           carry[joint] - start[joint], share())
        steps.append(main)
        angle = carry[joint]
        tt = _uniform(rng, 0.5, 1.5)
        while tt < end + 1.0:
            delta = _uniform(rng, -6 * DEG, 6 * DEG)
            trim = _paced_step(rng, arm, joint, tt, angle, delta, share())
            steps.append(trim)
            angle += delta
            tt += trim.duration * _uniform(rng, 0.5, 1.5) + _uniform(rng, 0.0, 1.0)
    duration = max(s.start + s.duration for s in steps) + _uniform(rng, 0.5, 1.0)
    payload = _uniform(rng, 0.0, machine.max_payload)
    motion = Motion(start, steps, duration, tilt=np.asarray(tilt, float), payload=payload,
                    info={"start_pose": start.tolist(), "carry_pose": carry.tolist(), "slew": slew,
                          "overshoot": over})
    return _clip_to_ranges(motion, machine)


def reach_motion(rng, arm: HydraulicArmModel, waypoints: int = 4) -> Motion:
    """A calibration motion that takes every joint through most of its range, the joints moving
    at once: each of boom, dipper and bucket steps through ``waypoints`` targets drawn over its
    whole range (5° inside the ends), the house slews back and forth by up to 90°, every step at
    50–90 % of the pumps' speed and the joints' steps unrelated in time.

    Swings leave the dipper's and bucket's ranges partly unvisited and never combine the joints
    the way a busy operator does; a calibration from them weighs such motions 10–30 kg off
    (findings: "Every joint at once"). This is the motion to add.

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the motion's draws.
    arm : HydraulicArmModel
        The machine's model.
    waypoints : int
        Targets per joint after the start.

    Returns
    -------
    Motion
        The planned motion, kept inside the angle ranges.
    """
    machine = arm.machine
    r = _inside(machine)
    start = np.array([_uniform(rng, r[j, 0], r[j, 1]) for j in range(3)] + [0.0])
    steps: list[Step] = []
    for joint in range(4):
        angle, t = float(start[joint]), _uniform(rng, 0.2, 1.0)
        for _ in range(waypoints):
            if joint < 3:
                target = _uniform(rng, r[joint, 0], r[joint, 1])
            else:
                target = _uniform(rng, -90 * DEG, 90 * DEG)
            step = _paced_step(rng, arm, joint, t, angle, target - angle, _uniform(rng, 0.5, 0.9))
            steps.append(step)
            angle = target
            t = step.start + step.duration + _uniform(rng, 0.0, 0.6)
    duration = max(s.start + s.duration for s in steps) + _uniform(rng, 0.5, 1.0)
    payload = _uniform(rng, 0.0, machine.max_payload)
    motion = Motion(start, steps, duration, payload=payload, info={"start_pose": start.tolist()})
    return _clip_to_ranges(motion, machine)


def _clip_to_ranges(motion: Motion, machine) -> Motion:
    """Shrink steps that would leave an angle range (corrections near an end).

    For each joint that leaves its range, the step that carries it out is halved: the last step
    of that joint started before the worst excursion and moving towards it (not simply the
    joint's last step, which in a work cycle is the return and moves the other way).
    """
    r = _inside(machine, 1 * DEG)
    time = np.linspace(0, motion.duration, 400)
    # The first 8 rounds halve the latest step towards the excursion (motions inside the
    # machine's ranges after them are as they always were). A drift of many small trims (an
    # `operator` motion's bucket, 19° past its range in 1 of 40 draws) outlasts them and was
    # returned out of the machine's range: then the largest such step is halved until the motion
    # is inside the ranges themselves.
    hard = _inside(machine, 0.0)
    for round_ in range(8 + MAX_EXTRA_CLIP_ROUNDS):
        q, _, _ = motion.sample(time)
        ok = True
        if round_ >= 8:
            r = hard
        for j in range(3):
            over, under = q[:, j].max() - r[j, 1], r[j, 0] - q[:, j].min()
            if over <= 0 and under <= 0:
                continue
            ok = False
            sign = 1.0 if over >= under else -1.0
            worst = time[int(np.argmax(q[:, j]) if sign > 0 else np.argmin(q[:, j]))]
            candidates = [st for st in motion.steps
                          if st.joint == j and st.start < worst and st.delta * sign > 0]
            if candidates:
                key = (lambda st: st.start) if round_ < 8 else (lambda st: abs(st.delta))
                max(candidates, key=key).delta *= 0.5
        if ok:
            return motion
    return motion


#: Rounds of :func:`_clip_to_ranges` after its first 8 (each halves the largest step towards the
#: excursion: 19° of drift needs a few dozen).
MAX_EXTRA_CLIP_ROUNDS = 200


def slope_tilt(rng) -> np.ndarray:
    """Ground tilt of up to 10° in a random direction: [pitch, roll].

    Parameters
    ----------
    rng : numpy.random.Generator
        Stream of the draws.

    Returns
    -------
    numpy.ndarray
        (pitch, roll), rad.
    """
    slope = _uniform(rng, 0.0, 10 * DEG)
    direction = _uniform(rng, 0.0, 2 * np.pi)
    return np.array([slope * np.cos(direction), slope * np.sin(direction)])


def lift_motion(k: int, machine, n_dipper_angles: int = 5, boom_speed: float = 5 * DEG) -> Motion:
    """Calibration lift ``k``: the boom from low to high at constant speed (ramps of 1 s).

    Payloads alternate empty / rated (even / odd ``k``); each pair uses the next of
    ``n_dipper_angles`` dipper angles spread over -120°…-40°; bucket held curled, no slew,
    level ground (as the thesis' lifts, EP0736752A1).

    Parameters
    ----------
    k : int
        Lift number; it picks the payload and the dipper angle.
    machine : HydraulicMachine
        The machine (boom angle range, rated payload).
    n_dipper_angles : int
        Number of dipper angles the lifts cycle through.
    boom_speed : float
        Constant boom speed, rad/s.

    Returns
    -------
    Motion
        The planned lift.
    """
    r = _inside(machine)
    dippers = np.linspace(-120 * DEG, -40 * DEG, n_dipper_angles)
    dipper = float(dippers[(k // 2) % n_dipper_angles])
    start = np.array([r[0, 0], dipper, -90 * DEG, 0.0])
    travel = float(r[0, 1] - r[0, 0])
    ramp = 1.0
    move = travel / boom_speed + ramp
    steps = [Step(0, 1.0, move, travel, ramp=ramp)]
    payload = 0.0 if k % 2 == 0 else machine.rated_payload
    return Motion(start, steps, move + 2.0, payload=payload,
                  info={"start_pose": start.tolist(), "boom_speed": boom_speed, "dipper": dipper})
