"""Replay prescribed motions through the hydraulic machine's model and sensors.

A trajectory file is Parquet with one row per sample and the columns

``experiment``, ``time`` (s), ``boom_angle``, ``dipper_angle``, ``bucket_angle``,
``slew_angle`` (rad; boom from the house, dipper from the boom, bucket from the dipper),
``payload`` (kg, constant within an experiment)

and optionally ``ground_pitch`` and ``ground_roll`` (rad; level ground where absent). Any sample
rate, even uneven, is accepted: each angle is interpolated by a cubic spline (continuous
angle, rate and acceleration) and evaluated at 100 Hz between the experiment's first and last
time. A motion recorded on a real machine, or made by hand, can so be pushed through the
simulator (``excavator-payload simulate --machine cat345c-hydraulic --motion trajectory
--trajectory FILE``); its pressures are those the model needs for that motion, and the
experiment's metadata say whether it stayed within the relief pressure and the pumps' speed.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError

REQUIRED = ("experiment", "time", "boom_angle", "dipper_angle", "bucket_angle", "slew_angle", "payload")
OPTIONAL = ("ground_pitch", "ground_roll")
ANGLE_COLUMNS = ("boom_angle", "dipper_angle", "bucket_angle", "slew_angle")


@dataclass
class Trajectory:
    """Prescribed motions: ``experiments`` is a list of (experiment number, its rows)."""

    source: str
    digest: str
    experiments: list[tuple[int, pd.DataFrame]]


def trajectory_from_frame(frame: pd.DataFrame, source: str = "trajectory") -> Trajectory:
    """Check a trajectory table and split it into experiments (one-line errors)."""
    missing = [c for c in REQUIRED if c not in frame.columns]
    if missing:
        raise DatasetError(f"{source}: trajectory is missing column(s) {', '.join(missing)} "
                           f"(needs {', '.join(REQUIRED)})")
    for c in REQUIRED + tuple(c for c in OPTIONAL if c in frame.columns):
        if not pd.api.types.is_numeric_dtype(frame[c]):
            raise DatasetError(f"{source}: column '{c}' must be numeric, found {frame[c].dtype}")
        if not np.all(np.isfinite(frame[c].to_numpy(dtype=float))):
            raise DatasetError(f"{source}: column '{c}' has NaN or infinite values")
    for c in ANGLE_COLUMNS[:3]:
        if np.abs(frame[c].to_numpy(dtype=float)).max() > 2 * np.pi:
            raise DatasetError(f"{source}: column '{c}' exceeds 2π; angles must be in radians")
    if (frame["payload"] < 0).any():
        raise DatasetError(f"{source}: column 'payload' has negative masses (kg)")
    experiments = []
    for exp_id, rows in frame.groupby("experiment", sort=False):
        t = rows["time"].to_numpy(dtype=float)
        if len(t) < 4:
            raise DatasetError(f"{source}: experiment {exp_id} has {len(t)} samples; at least 4 are needed")
        if not np.all(np.diff(t) > 0):
            raise DatasetError(f"{source}: 'time' must increase strictly within experiment {exp_id}")
        if rows["payload"].nunique() > 1:
            raise DatasetError(f"{source}: 'payload' must be constant within experiment {exp_id}")
        experiments.append((int(exp_id), rows.reset_index(drop=True)))
    digest = hashlib.sha256(pd.util.hash_pandas_object(frame, index=False).values.tobytes()).hexdigest()[:16]
    return Trajectory(source, digest, experiments)


def read_trajectory(path: str | Path) -> Trajectory:
    """Read and check a trajectory file (Parquet)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"trajectory file '{path}' does not exist")
    try:
        import pyarrow.parquet as pq

        frame = pq.read_table(path).to_pandas()
    except Exception as exc:  # pyarrow raises several types for non-Parquet input
        raise DatasetError(f"'{path}' is not a readable Parquet trajectory file: {exc}") from None
    return trajectory_from_frame(frame, str(path))


def interpolate(rows: pd.DataFrame, sample_rate: float):
    """Time grid at ``sample_rate`` and (q, q̇, q̈) (n, 4), tilt (n, 2) by cubic splines."""
    from scipy.interpolate import CubicSpline

    t = rows["time"].to_numpy(dtype=float)
    n = int(np.floor((t[-1] - t[0]) * sample_rate + 1e-9)) + 1
    time = t[0] + np.arange(n) / sample_rate
    spline = CubicSpline(t, rows[list(ANGLE_COLUMNS)].to_numpy(dtype=float), axis=0)
    q, qd, qdd = spline(time), spline(time, 1), spline(time, 2)
    tilt = np.zeros((n, 2))
    for j, c in enumerate(OPTIONAL):
        if c in rows.columns:
            tilt[:, j] = np.interp(time, t, rows[c].to_numpy(dtype=float))
    return time, q, qd, qdd, tilt


def simulate_trajectory_experiment(position: int, seed: int, arm, noise, offsets, trajectory: Trajectory,
                                   with_truth: bool):
    """Rows and metadata of the trajectory's experiment at ``position`` (numbered as in the file)."""
    from excavator_payload.simulation.machine_motions import speed_ratio
    from excavator_payload.simulation.machine_sim import (
        SAMPLE_RATE,
        experiment_rows,
        machine_rngs,
        motion_physics,
    )

    exp_id, rows = trajectory.experiments[position]
    time, q, qd, qdd, tilt = interpolate(rows, SAMPLE_RATE)
    if np.any(arm.linkage_margin(q) <= 0):
        raise ValueError(f"trajectory experiment {exp_id}: the bucket angle leaves the range where "
                         "the bucket linkage closes")
    payload = float(rows["payload"].iloc[0])
    motion_rng, noise_rng = machine_rngs(seed, exp_id)
    physics = motion_physics(arm, time, q, qd, qdd, tilt, np.full(len(time), payload),
                             motion_rng.uniform(-1, 1, 3))
    frame = experiment_rows(exp_id, time, q, qd, qdd, physics, payload, noise, offsets, noise_rng,
                            with_truth)
    machine = arm.machine
    peak = float(max(physics["head"].max(), physics["rod"].max()))
    ranges = machine.angle_ranges
    inside = bool(np.all((q[:, :3] >= ranges[:, 0]) & (q[:, :3] <= ranges[:, 1])))

    class _Replay:  # speed_ratio needs sample(); the replayed motion is already sampled
        def __init__(self):
            self.duration = float(time[-1] - time[0])

        def sample(self, _t):
            return q, qd, qdd

    meta = {"experiment": exp_id, "seed": int(seed), "payload": payload, "motion": "trajectory",
            "duration": float(time[-1] - time[0]), "peak_pressure": peak,
            "within_relief": bool(peak <= machine.hydraulics.relief_pressure),
            "speed_share": speed_ratio(arm, _Replay(), time), "within_angle_ranges": inside,
            "tilt": [float(v) for v in tilt.mean(axis=0)], "status": "ok"}
    return frame, meta
