"""Held-out motion families: operator-like motions made by a generator no estimator is tuned on.

These families are for judging only (``bench_any_motion.py``); nothing in ``src/`` is tuned on
them. They differ from the simulator's own families (minimum-jerk steps, NMPC swings) in how a
motion is made: an operator model drives each lever towards a sequence of targets,

    lever_j = clip(k_j · (target_j − q_j), −share_j, share_j),   τ · d(valve_j)/dt = lever_j − valve_j,
    q̇_j = valve_j · (fastest rate of joint j at its pose, from the pump flow),

so rates follow a first-order valve (accelerations jump where a lever is pushed), targets are
overshot and corrected, the boom pauses mid-lift, dipper and bucket are trimmed all along, the
house slews 45-80°, and every lever uses up to ``share`` ≤ 0.9 of what the pumps give. The
result is a trajectory table for ``simulate --trajectory`` (100 Hz samples).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine

DEG = math.pi / 180


def _rate_limits(arm: HydraulicArmModel) -> np.ndarray:
    """Rate of each arm joint (rad/s) that the pump flow gives anywhere in its range (the
    slower rod direction at the largest moment arm), and the slew's."""
    rod = arm.rod_speed_limits().min(axis=1)
    return np.r_[rod / arm.moment_arm_range()[:, 1], arm.machine.house.max_slew_rate]


def lever_motion(rng: np.random.Generator, arm: HydraulicArmModel, duration: float = 12.0,
                 rate: float = 100.0, max_share: float = 0.9, slow: bool = False) -> np.ndarray:
    """(n, 5) time and angles (boom, dipper, bucket, slew) of one operator-driven motion."""
    r = arm.machine.angle_ranges.copy()
    r[:, 0] += 6 * DEG
    r[:, 1] -= 6 * DEG
    q = np.array([rng.uniform(r[0, 0], r[0, 0] + 20 * DEG), rng.uniform(-110, -75) * DEG,
                  rng.uniform(-60, -30) * DEG, 0.0])
    carry = np.array([rng.uniform(20 * DEG, r[0, 1]), rng.uniform(-90, -45) * DEG,
                      rng.uniform(-115, -85) * DEG])
    slew = rng.uniform(45, 80) * DEG * rng.choice([-1, 1])
    # target schedules per joint: (time, target)
    schedule: list[list[tuple[float, float]]] = [[] for _ in range(4)]
    t_lift = rng.uniform(0.3, 1.2)
    mid = q[0] + rng.uniform(0.3, 0.7) * (carry[0] - q[0])
    schedule[0] = [(t_lift, mid), (t_lift + rng.uniform(2.0, 3.5), carry[0])]
    over = rng.uniform(0.05, 0.25) * slew
    t_slew = t_lift + rng.uniform(0.0, 1.5)
    schedule[3] = [(t_slew, slew + over), (t_slew + rng.uniform(3.0, 5.0), slew)]
    for j in (1, 2):
        t = rng.uniform(0.3, 2.0)
        schedule[j].append((t, carry[j]))
        target = carry[j]
        t += rng.uniform(1.0, 2.5)
        while t < duration - 1.0:
            target = float(np.clip(target + rng.uniform(-8, 8) * DEG, r[j, 0], r[j, 1]))
            schedule[j].append((t, target))
            t += rng.uniform(0.6, 2.5)
    share = rng.uniform(0.5, max_share, 4) * (0.35 if slow else 1.0)
    gain = rng.uniform(2.0, 6.0, 4)
    tau = rng.uniform(0.08, 0.3)
    n = int(round(duration * rate)) + 1
    dt = 1.0 / rate
    out = np.empty((n, 5))
    valve = np.zeros(4)
    limits = _rate_limits(arm)
    targets = q.copy()
    for i in range(n):
        t = i * dt
        for j in range(4):
            for ts, value in schedule[j]:
                if ts <= t:
                    targets[j] = value
        lever = np.clip(gain * (targets - q), -share, share)
        # an operator eases off before an end stop rather than hitting it
        lever[:3] = np.clip(lever[:3], -gain[:3] * (q[:3] - r[:3, 0]), gain[:3] * (r[:3, 1] - q[:3]))
        lever[np.abs(targets - q) < 0.3 * DEG] = 0.0  # the operator lets go near the target
        valve += dt / tau * (lever - valve)
        out[i] = (t, *q)
        qd = valve * limits
        q = q + dt * qd
        q[:3] = np.clip(q[:3], r[:3, 0], r[:3, 1])
    return out


def lever_trajectory(n: int, seed: int, machine: str = "cat345c-hydraulic", payloads=None,
                     slow: bool = False, slope_deg: float | None = None) -> pd.DataFrame:
    """A trajectory table of ``n`` operator-driven motions (payloads uniform in 0…rated unless given)."""
    m = load_machine(machine)
    arm = HydraulicArmModel(m)
    rng = np.random.default_rng([seed, 4242])
    rows = []
    for k in range(n):
        motion = lever_motion(rng, arm, slow=slow)
        payload = float(payloads[k % len(payloads)]) if payloads is not None else rng.uniform(0, m.rated_payload)
        frame = pd.DataFrame({"experiment": k, "time": motion[:, 0], "boom_angle": motion[:, 1],
                              "dipper_angle": motion[:, 2], "bucket_angle": motion[:, 3],
                              "slew_angle": motion[:, 4], "payload": payload})
        if slope_deg is not None:
            d = rng.uniform(0, 2 * math.pi)
            frame["ground_pitch"] = math.radians(slope_deg) * math.cos(d)
            frame["ground_roll"] = math.radians(slope_deg) * math.sin(d)
        rows.append(frame)
    return pd.concat(rows, ignore_index=True)
