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


#: Median time between a trajectory's samples above which 'time' is not in seconds (hand-made
#: waypoints are a second or two apart; a 100 Hz log in milliseconds has 10 "s").
MAX_MEDIAN_STEP = 5.0
#: A motion asking for more than this many times the speed the pumps (or the slew drive) give
#: is a unit mistake (an angle in degrees, time in ms), not a motion a machine makes.
MAX_SPEED_SHARE = 3.0
#: Slack on the machine's joint ranges (the spline may overshoot a recorded end stop a little), rad.
RANGE_SLACK = np.radians(1.0)


def trajectory_from_frame(frame: pd.DataFrame, source: str = "trajectory") -> Trajectory:
    """Check a trajectory table and split it into experiments (one-line errors)."""
    from excavator_payload.data.io import HOUSE_TILT_LIMIT
    from excavator_payload.model.machine import MAX_PAYLOAD

    missing = [c for c in REQUIRED if c not in frame.columns]
    if missing:
        raise DatasetError(f"{source}: trajectory is missing column(s) {', '.join(missing)} "
                           f"(needs {', '.join(REQUIRED)})")
    if len(frame) == 0:
        raise DatasetError(f"{source}: trajectory has no rows")
    for c in REQUIRED + tuple(c for c in OPTIONAL if c in frame.columns):
        if not pd.api.types.is_numeric_dtype(frame[c]):
            raise DatasetError(f"{source}: column '{c}' must be numeric, found {frame[c].dtype}")
        if not np.all(np.isfinite(frame[c].to_numpy(dtype=float))):
            raise DatasetError(f"{source}: column '{c}' has NaN or infinite values")
    for c in ANGLE_COLUMNS[:3]:
        if np.abs(frame[c].to_numpy(dtype=float)).max() > 2 * np.pi:
            raise DatasetError(f"{source}: column '{c}' exceeds 2π; angles must be in radians")
    for c in OPTIONAL:
        if c in frame.columns and np.abs(frame[c].to_numpy(dtype=float)).max() > HOUSE_TILT_LIMIT:
            raise DatasetError(f"{source}: column '{c}' reaches {np.abs(frame[c]).max():.4g}, more than "
                               "35° of ground tilt; angles must be in radians")
    if (frame["payload"] < 0).any():
        raise DatasetError(f"{source}: column 'payload' has negative masses (kg)")
    if (frame["payload"] > MAX_PAYLOAD).any():
        raise DatasetError(f"{source}: column 'payload' reaches {frame['payload'].max():.4g} kg, more "
                           f"than any excavator lifts ({MAX_PAYLOAD:g} kg)")
    exp = frame["experiment"].to_numpy(dtype=float)
    if not np.all(exp == np.round(exp)):
        raise DatasetError(f"{source}: column 'experiment' must hold whole numbers")
    experiments = []
    for exp_id, rows in frame.groupby("experiment", sort=False):
        t = rows["time"].to_numpy(dtype=float)
        if len(t) < 4:
            raise DatasetError(f"{source}: experiment {exp_id} has {len(t)} samples; at least 4 are needed")
        if not np.all(np.diff(t) > 0):
            raise DatasetError(f"{source}: 'time' must increase strictly within experiment {exp_id}")
        if np.median(np.diff(t)) > MAX_MEDIAN_STEP:
            raise DatasetError(f"{source}: the samples of experiment {exp_id} are {np.median(np.diff(t)):.4g} s "
                               "apart (median); is 'time' in seconds?")
        if rows["payload"].nunique() > 1:
            raise DatasetError(f"{source}: 'payload' must be constant within experiment {exp_id}")
        experiments.append((int(exp_id), rows.reset_index(drop=True)))
    digest = hashlib.sha256(pd.util.hash_pandas_object(frame, index=False).values.tobytes()).hexdigest()[:16]
    return Trajectory(source, digest, experiments)


def read_trajectory(path: str | Path) -> Trajectory:
    """Read and check a trajectory file (Parquet; a CSV is refused with a line saying so)."""
    path = Path(path)
    if path.is_dir():
        raise DatasetError(f"trajectory file '{path}' is a folder; give a Parquet file")
    if not path.is_file():
        raise DatasetError(f"trajectory file '{path}' does not exist")
    with open(path, "rb") as handle:
        head = handle.read(4)
    if head != b"PAR1":
        what = "it is empty" if head == b"" else "it is not Parquet (a CSV or text file?)"
        raise DatasetError(f"trajectory file '{path}': {what}; a trajectory must be a Parquet file "
                           "(pandas: pd.read_csv(...).to_parquet(...))")
    try:
        import pyarrow.parquet as pq

        frame = pq.read_table(path).to_pandas()
    except Exception as exc:  # pyarrow raises several types for non-Parquet input
        raise DatasetError(f"'{path}' is not a readable Parquet trajectory file: {exc}") from None
    return trajectory_from_frame(frame, str(path))


def check_trajectory_motion(trajectory: Trajectory, machine) -> None:
    """Refuse motions the machine cannot make: joints outside their ranges, or a motion many
    times faster than its pumps and slew drive allow (an angle in degrees, time in ms).

    The replay would push such a motion through the model and give absurd pressures (or a
    message about pressures in the wrong unit); checked once, before any experiment is simulated.
    """
    from excavator_payload.simulation.machine_motions import speed_share
    from excavator_payload.simulation.machine_sim import SAMPLE_RATE, _arm

    arm = _arm(machine)
    ranges = machine.angle_ranges
    for exp_id, rows in trajectory.experiments:
        _, q, qd, _, _ = interpolate(rows, SAMPLE_RATE)
        for j, name in enumerate(ANGLE_COLUMNS[:3]):
            low, high = ranges[j]
            if q[:, j].min() < low - RANGE_SLACK or q[:, j].max() > high + RANGE_SLACK:
                worst = q[:, j].min() if q[:, j].min() < low - RANGE_SLACK else q[:, j].max()
                raise DatasetError(f"{trajectory.source}: experiment {exp_id}: '{name}' reaches {worst:.3g} rad, "
                                   f"outside the machine's range [{low:.3g}, {high:.3g}] rad (between "
                                   "the samples too: a time gap makes the spline swing)")
        share = speed_share(arm, q, qd)
        if share > MAX_SPEED_SHARE:
            raise DatasetError(f"{trajectory.source}: experiment {exp_id} moves {share:.3g} times faster than "
                               "the machine's pumps or slew drive allow; are the angles (slew_angle too) "
                               "in radians and 'time' in seconds?")


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
    from excavator_payload.simulation.machine_motions import speed_share
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
                             motion_rng.uniform(-1, 1, 3), motion_rng)
    frame = experiment_rows(exp_id, time, q, qd, qdd, physics, payload, noise, offsets, noise_rng,
                            with_truth)
    machine = arm.machine
    peak = float(max(physics["head"].max(), physics["rod"].max()))
    ranges = machine.angle_ranges
    inside = bool(np.all((q[:, :3] >= ranges[:, 0]) & (q[:, :3] <= ranges[:, 1])))

    meta = {"experiment": exp_id, "seed": int(seed), "payload": payload, "motion": "trajectory",
            "duration": float(time[-1] - time[0]), "peak_pressure": peak,
            "within_relief": bool(peak <= machine.hydraulics.relief_pressure),
            "speed_share": speed_share(arm, q, qd), "within_angle_ranges": inside,
            "tilt": [float(v) for v in tilt.mean(axis=0)], "status": "ok"}
    return frame, meta
