r"""Slow constant-speed boom lifts: the calibration runs of the quasi-static (industry) estimator.

Patent EP0736752A1, as the thesis' introduction describes it, calibrates with the arm moving "at
low constant angular speed" over a pre-defined range of motion at two reference payloads. Each
lift here holds the dipper at a fixed angle (relative to the boom) and raises the boom from near
the bottom to near the top of its range at ``boom_speed``:

.. math::

    \dot q_1(t) = v\,\sigma(t/T_r)\,\sigma((T - t)/T_r), \qquad
    \sigma(s) = 10s^3 - 15s^4 + 6s^5 \ (0 \le s \le 1),

a smooth ramp up during :math:`T_r` (``ramp_time``), constant speed :math:`v`, and a smooth ramp
down; :math:`q_2` stays constant. Lifts cycle through ``payloads`` (default: empty and rated,
alternating) and, per cycle, through dipper angles spread evenly over the dipper range, so that
``n_experiments = 2 × k`` lifts give both reference payloads on the same ``k`` dipper angles.
The torques are the exact inverse dynamics of the motion (``ArmModel.inverse_dynamics``) and the
sensors add noise through :func:`~excavator_payload.simulation.experiment.experiment_frame`; the
dataset has the usual schema at 20 Hz (a lift lasts longer than 5 s: ≈ 20 s at 5 °/s).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SAMPLE_RATE
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.simulation.experiment import RunSpec, experiment_frame, noise_rng
from excavator_payload.simulation.minimum_jerk import _arm
from excavator_payload.simulation.scenario import experiment_rngs
from excavator_payload.simulation.sensors import NoisePreset, get_noise_preset

DEG = math.pi / 180.0


def _smoothstep(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ(s) = 10s³ − 15s⁴ + 6s⁵ on [0, 1], its derivative and its integral ∫₀ˢ σ."""
    s = np.clip(s, 0.0, 1.0)
    value = 10 * s**3 - 15 * s**4 + 6 * s**5
    slope = 30 * s**2 - 60 * s**3 + 30 * s**4
    integral = 2.5 * s**4 - 3 * s**5 + s**6
    return value, slope, integral


def lift_motion(boom_start: float, boom_end: float, dipper_angle: float, boom_speed: float,
                ramp_time: float, sample_rate: float = SAMPLE_RATE):
    """Times and (q, q̇, q̈) arrays (n, 2) of one constant-speed lift from ``boom_start`` to ``boom_end``.

    The boom covers ``v·T_r/2`` during each ramp, so the constant-speed phase lasts
    ``(boom_end − boom_start)/v − T_r``.

    Parameters
    ----------
    boom_start, boom_end : float
        Boom angle at the start and at the end of the lift, rad.
    dipper_angle : float
        Dipper angle held during the lift, rad.
    boom_speed : float
        Constant boom speed ``v``, rad/s.
    ramp_time : float
        Duration ``T_r`` of each smooth speed ramp, s.
    sample_rate : float
        Sampling rate, Hz.

    Returns
    -------
    t : numpy.ndarray
        Sample times, s, shape (n,).
    q, qd, qdd : numpy.ndarray
        Boom and dipper angles (rad), rates (rad/s) and accelerations (rad/s²), shape (n, 2).

    Raises
    ------
    ExcavatorPayloadError
        If the lift is too short for its two ramps.
    """
    travel = boom_end - boom_start
    constant = travel / boom_speed - ramp_time
    if constant <= 0:
        raise ExcavatorPayloadError("lift too short for its ramps: lower ramp_time or boom_speed")
    duration = constant + 2 * ramp_time
    n = int(math.floor(duration * sample_rate + 1e-9)) + 1
    t = np.arange(n) / sample_rate
    v = boom_speed
    up_v, up_a, up_i = _smoothstep(t / ramp_time)
    t_down = duration - t  # time left
    dn_v, dn_a, dn_i = _smoothstep(t_down / ramp_time)
    rising = t < ramp_time
    falling = t_down < ramp_time
    rate = v * np.where(rising, up_v, np.where(falling, dn_v, 1.0))
    accel = v / ramp_time * np.where(rising, up_a, np.where(falling, -dn_a, 0.0))
    # Position: integral of the rate (analytic in the ramps).
    pos_rising = v * ramp_time * up_i
    pos_constant = v * ramp_time / 2 + v * (t - ramp_time)
    pos_falling = travel - v * ramp_time * dn_i
    pos = boom_start + np.where(rising, pos_rising, np.where(falling, pos_falling, pos_constant))
    q = np.column_stack([pos, np.full(n, dipper_angle)])
    qd = np.column_stack([rate, np.zeros(n)])
    qdd = np.column_stack([accel, np.zeros(n)])
    return t, q, qd, qdd


def _lift_levels(spec: RunSpec) -> list[float]:
    payloads = spec.option("payloads")
    levels = [0.0, spec.machine.rated_payload] if payloads is None else [float(p) for p in payloads]
    if not levels or any(not math.isfinite(p) or p < 0 for p in levels):
        raise ExcavatorPayloadError("simulate_lifts: payloads must be finite and >= 0 kg")
    return levels


def lift_experiment(spec: RunSpec, experiment: int) -> tuple[pd.DataFrame, dict]:
    """Rows and metadata of lift ``experiment`` of the run ``spec`` (``spec.n_experiments`` lifts).

    Parameters
    ----------
    spec : RunSpec
        The run; ``spec.options`` may set ``payloads``, ``boom_speed_deg``, ``ramp_time`` and
        ``margin_deg`` (see :func:`simulate_lifts`).
    experiment : int
        Lift number; it picks the payload level and the dipper angle.

    Returns
    -------
    frame : pandas.DataFrame
        The lift's rows.
    meta : dict
        Its payload (kg), start and target poses (rad), boom speed (rad/s), ramp time (s).
    """
    machine = spec.machine
    boom_speed_deg = float(spec.option("boom_speed_deg", 5.0))
    ramp_time = float(spec.option("ramp_time", 1.0))
    margin = float(spec.option("margin_deg", 5.0)) * DEG
    if not boom_speed_deg > 0:
        raise ExcavatorPayloadError("simulate_lifts: boom_speed_deg must be > 0")
    levels = _lift_levels(spec)
    n_lines = math.ceil(max(spec.n_experiments, experiment + 1) / len(levels))
    boom_lo, boom_hi = machine.boom_angle_range[0] + margin, machine.boom_angle_range[1] - margin
    dip_lo, dip_hi = machine.dipper_angle_range[0] + margin, machine.dipper_angle_range[1] - margin
    dipper_angles = (np.linspace(dip_lo, dip_hi, n_lines) if n_lines > 1
                     else np.array([(dip_lo + dip_hi) / 2]))
    speed = boom_speed_deg * DEG
    t, q, qd, qdd = lift_motion(boom_lo, boom_hi, 0.0, speed, ramp_time)
    k = experiment
    payload = levels[k % len(levels)]
    dipper = float(dipper_angles[k // len(levels)])
    q[:, 1] = dipper
    tau = _arm(machine).inverse_dynamics(q, qd, qdd, payload)
    _, rng_noise = experiment_rngs(spec.seed, k)
    frame = experiment_frame(k, t, q, qd, qdd, tau, payload, spec.noise, noise_rng(spec, rng_noise),
                             spec.with_truth)
    return frame, {"experiment": k, "seed": int(spec.seed), "payload": payload,
                   "start_pose": [float(boom_lo), dipper], "target_pose": [float(boom_hi), dipper],
                   "boom_speed": speed, "ramp_time": float(ramp_time), "status": "ok"}


def simulate_lifts(n_experiments: int, seed: int = 0, machine: Machine | str = "cat345c",
                   noise: str | NoisePreset = "thesis", with_truth: bool = False,
                   payloads: Sequence[float] | None = None, boom_speed_deg: float = 5.0,
                   ramp_time: float = 1.0, margin_deg: float = 5.0) -> Dataset:
    """Dataset of slow constant-speed boom lifts (calibration runs of ``quasi-static``).

    Parameters
    ----------
    n_experiments : int
        Number of lifts.
    seed : int
        Base seed of the sensor noise (per-lift streams, see ``experiment_rngs``).
    machine, noise, with_truth
        As for every simulator.
    payloads : sequence of float, optional
        Payloads (kg) the lifts cycle through; default ``(0, rated payload)``.
    boom_speed_deg : float
        Constant boom speed, °/s (a few °/s: quasi-static).
    ramp_time : float
        Duration of the smooth speed ramps at both ends, s.
    margin_deg : float
        Lifts and dipper angles stay this far inside the machine's angle ranges, °.
    """
    if n_experiments < 1:
        raise ExcavatorPayloadError("simulate_lifts: n_experiments must be at least 1")
    machine = load_machine(machine)
    preset = get_noise_preset(noise)
    options = (("boom_speed_deg", float(boom_speed_deg)), ("ramp_time", float(ramp_time)),
               ("margin_deg", float(margin_deg)))
    if payloads is not None:
        options += (("payloads", tuple(float(p) for p in payloads)),)
    spec = RunSpec("lifts", int(seed), machine, preset, bool(with_truth), int(n_experiments), options=options)
    frames, metas = [], []
    for k in range(n_experiments):
        frame, meta = lift_experiment(spec, k)
        frames.append(frame)
        metas.append(meta)
    meta = {"machine": machine.to_dict(), "noise": preset.name, "motion": "lifts",
            "base_seed": int(seed), "sample_rate": SAMPLE_RATE, "experiments": metas}
    return Dataset(pd.concat(frames, ignore_index=True), meta)
