"""Replay prescribed motions through the hydraulic machine's model and sensors.

A trajectory file is Parquet with one row per sample and the columns

``experiment``, ``time`` (s), ``boom_angle``, ``dipper_angle``, ``bucket_angle``,
``slew_angle`` (rad; boom from the house, dipper from the boom, bucket from the dipper),
``payload`` (kg: the true load in the bucket at each time; constant for one lift, or changing
within an experiment to replay a shift — a bucket filled at the dig and emptied at the dump, see
:func:`payload_passes`)

and optionally ``ground_pitch`` and ``ground_roll`` (rad; level ground where absent). Any sample
rate, even uneven, is accepted (a gap of more than 1 s and 20 samples' time is refused: split
the experiment there): each angle is interpolated by quintic pieces through its samples'
angle, rate and acceleration (continuous angle, rate and acceleration; local, so a jump of the
acceleration does not ring through the motion) and evaluated at 100 Hz between the
experiment's first and last time. A motion recorded on a real machine, or made by hand, can
so be pushed through the simulator (``excavator-payload simulate --machine cat345c-hydraulic
--motion trajectory --trajectory FILE``); its pressures are those the model needs for that
motion, and the experiment's metadata say whether it stayed within the relief pressure and the
pumps' speed.

A motion the machine cannot make is refused before anything is simulated, with the real reason
(:func:`check_trajectory_motion`): a joint outside its range; angles that come in steps (a
quantised or sample-and-hold log), whose interpolation accelerates at hundreds of rad/s² and needs
pressures far beyond the relief valve (``--smooth SECONDS`` filters them, :func:`smooth_trajectory`);
a motion faster than the pumps or the slew drive give (a replay faster than the machine flatters
the estimator; ``--allow-overspeed`` simulates it anyway, flagged); or one many times faster (an
angle in degrees, time in ms). Unknown columns are named: a misspelt optional column (``ground_pich``)
is refused, any other is reported as ignored.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError
from excavator_payload.simulation.machine_physics import (
    SAMPLE_RATE,
    arm_model,
    closing_rng,
    experiment_rows,
    machine_rngs,
    motion_physics,
)

REQUIRED = ("experiment", "time", "boom_angle", "dipper_angle", "bucket_angle", "slew_angle", "payload")
OPTIONAL = ("ground_pitch", "ground_roll")
ANGLE_COLUMNS = ("boom_angle", "dipper_angle", "bucket_angle", "slew_angle")


@dataclass
class Trajectory:
    """Prescribed motions: ``experiments`` is a list of (experiment number, its rows).

    Parameters
    ----------
    source : str
        Where the motions come from (file name), for messages.
    digest : str
        Content hash of the motions (cache keys, checkpoint settings).
    experiments : list of (int, pandas.DataFrame)
        Each experiment's number and its rows (trajectory columns, SI units).
    ignored : tuple of str
        Columns of the file that are no trajectory column (reported, not used).
    smoothed : float
        Width of the Gaussian filter applied (``--smooth``), s; 0 for none.
    warnings : tuple of str
        What :func:`check_trajectory_motion` let through with a warning, one line each.
    """

    source: str
    digest: str
    experiments: list[tuple[int, pd.DataFrame]]
    #: Columns of the file that are no trajectory column (reported, not used).
    ignored: tuple[str, ...] = ()
    #: Width of the Gaussian filter applied (--smooth, s), 0 for none.
    smoothed: float = 0.0
    #: What check_trajectory_motion let through with a warning (--allow-overspeed), one line each.
    warnings: tuple[str, ...] = ()


#: Median time between a trajectory's samples above which 'time' is not in seconds (hand-made
#: waypoints are a second or two apart; a 100 Hz log in milliseconds has 10 "s").
MAX_MEDIAN_STEP = 5.0
#: A motion asking for more than this many times the speed the pumps (or the slew drive) give
#: is a unit mistake (an angle in degrees, time in ms), not a motion a machine makes.
MAX_SPEED_SHARE = 3.0
#: Share of the pumps' (or slew drive's) speed a replayed motion may use: as the NMPC swings'.
OVERSPEED_TOLERANCE = 1.05
#: A replayed motion whose cylinder forces exceed this multiple of what the relief pressure gives
#: cannot be made by the machine (its pressures would be beyond any sensor's range).
FORCE_LIMIT = 2.0
#: Standard deviation (s) of the Gaussian filter that tells steps from motion: when filtering the
#: angles this little lowers the peak force or speed by :data:`STEP_FACTOR` or more, they come
#: from the steps between samples, not from the motion.
STEP_PROBE = 0.05
STEP_FACTOR = 2.0
#: Smallest unknown-column similarity (difflib ratio) that makes it a misspelt known column.
MISSPELT_CUTOFF = 0.8
#: A time gap longer than this and :data:`GAP_FACTOR` times the experiment's median sample interval
#: is refused (nothing says what the machine did in it), s.
MAX_GAP = 1.0
#: See :data:`MAX_GAP`.
GAP_FACTOR = 20.0
#: Slack on the machine's joint ranges (the interpolation may overshoot a recorded end stop a little), rad.
RANGE_SLACK = np.radians(1.0)


def trajectory_from_frame(frame: pd.DataFrame, source: str = "trajectory") -> Trajectory:
    """Check a trajectory table and split it into experiments (one-line errors).

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per sample with the trajectory columns (module docstring).
    source : str
        Name of the table's origin, used in messages and kept in the result.

    Returns
    -------
    Trajectory
        The experiments, in the order they first appear.

    Raises
    ------
    DatasetError
        A missing, misspelt, non-numeric or non-finite column, values out of range or in the
        wrong unit, or an experiment with too few or unordered samples.
    """
    from excavator_payload.data.io import HOUSE_TILT_LIMIT
    from excavator_payload.model.machine import MAX_PAYLOAD

    import difflib

    known = REQUIRED + OPTIONAL
    unknown = [str(c) for c in frame.columns if c not in known]
    for c in unknown:
        absent = [k for k in known if k not in frame.columns]
        # lower case first: 'Time' or 'Boom_Angle' (a spreadsheet's header) is ours in other case
        close = difflib.get_close_matches(c.strip().lower(), absent, n=1, cutoff=MISSPELT_CUTOFF)
        if close:  # a misspelt optional column was silently ignored: level ground was simulated
            raise DatasetError(f"{source}: column '{c}' is not a trajectory column; did you mean "
                               f"'{close[0]}'? (columns: {', '.join(known)})")
    missing = [c for c in REQUIRED if c not in frame.columns]
    if missing:
        raise DatasetError(f"{source}: trajectory is missing column(s) {', '.join(missing)} "
                           f"(needs {', '.join(REQUIRED)})")
    if len(frame) == 0:
        raise DatasetError(f"{source}: trajectory has no rows")
    for c in REQUIRED + tuple(c for c in OPTIONAL if c in frame.columns):
        if not pd.api.types.is_numeric_dtype(frame[c]) or pd.api.types.is_bool_dtype(frame[c]):
            raise DatasetError(f"{source}: column '{c}' must be numeric, found {frame[c].dtype}"
                               + (" (true/false, not a measurement)" if pd.api.types.is_bool_dtype(frame[c]) else ""))
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
    if (exp < 0).any():
        # accepted here before, then every experiment failed ("expected non-negative integer"):
        # an experiment's number seeds its noise
        raise DatasetError(f"{source}: column 'experiment' holds negative numbers (from {exp.min():.0f}); "
                           "experiments are numbered from 0 (the number seeds each experiment's noise)")
    experiments = []
    for exp_id, rows in frame.groupby("experiment", sort=False):
        t = rows["time"].to_numpy(dtype=float)
        if len(t) < 4:
            raise DatasetError(f"{source}: experiment {exp_id} has {len(t)} samples; at least 4 are needed")
        if not np.all(np.diff(t) > 0):
            raise DatasetError(f"{source}: 'time' must increase strictly within experiment {exp_id}")
        step = np.diff(t)
        typical = float(np.median(step))
        if typical > MAX_MEDIAN_STEP:
            raise DatasetError(f"{source}: the samples of experiment {exp_id} are {typical:.4g} s "
                               "apart (median); is 'time' in seconds?")
        gap = int(np.argmax(step))
        if step[gap] > max(MAX_GAP, GAP_FACTOR * typical):
            # a logger that stopped: whatever the interpolation draws across it is not the motion
            raise DatasetError(f"{source}: experiment {exp_id} has no samples for {step[gap]:.4g} s after "
                               f"t = {t[gap]:.4g} s (they are {typical:.3g} s apart elsewhere); split it into "
                               "two experiments there")
        experiments.append((int(exp_id), rows.reset_index(drop=True)))
    digest = hashlib.sha256(pd.util.hash_pandas_object(frame, index=False).values.tobytes()).hexdigest()[:16]
    return Trajectory(source, digest, experiments, ignored=tuple(unknown))


def smooth_trajectory(trajectory: Trajectory, seconds: float) -> Trajectory:
    """The trajectory with every angle resampled at the simulator's rate and filtered by a
    zero-phase Gaussian kernel of standard deviation ``seconds`` / 2 (``--smooth SECONDS``).

    A log whose angles come in steps (a quantised sensor, or a slow one logged at a fast rate
    and held between its samples) is interpolated through every step: accelerations of hundreds
    of rad/s² that no arm makes. The filter keeps the motion (no lag) and removes the steps;
    tilt is interpolated linearly, the payload kept.

    Parameters
    ----------
    trajectory : Trajectory
        The motions to filter.
    seconds : float
        Filter width, s (the kernel's standard deviation is half of it); in (0, 10].

    Returns
    -------
    Trajectory
        The filtered motions sampled at :data:`SAMPLE_RATE`, with a new digest.

    Raises
    ------
    DatasetError
        If ``seconds`` is not a time in (0, 10] s.
    """
    from scipy.ndimage import gaussian_filter1d

    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and 0 < seconds <= 10):
        raise DatasetError(f"--smooth must be a time in seconds between 0 and 10, got {seconds!r}")
    experiments = []
    for exp_id, rows in trajectory.experiments:
        t = rows["time"].to_numpy(dtype=float)
        n = int(np.floor((t[-1] - t[0]) * SAMPLE_RATE + 1e-9)) + 1
        time = t[0] + np.arange(n) / SAMPLE_RATE
        out = {"experiment": np.full(n, exp_id), "time": time}
        for c in ANGLE_COLUMNS:
            angles = np.interp(time, t, rows[c].to_numpy(dtype=float))
            out[c] = gaussian_filter1d(angles, sigma=0.5 * seconds * SAMPLE_RATE, mode="nearest")
        for c in OPTIONAL:
            if c in rows.columns:
                out[c] = np.interp(time, t, rows[c].to_numpy(dtype=float))
        out["payload"] = np.interp(time, t, rows["payload"].to_numpy(dtype=float))  # a load changing in time
        experiments.append((exp_id, pd.DataFrame(out)))
    digest = hashlib.sha256(f"{trajectory.digest} smoothed {seconds!r}".encode()).hexdigest()[:16]
    return Trajectory(trajectory.source, digest, experiments, trajectory.ignored, float(seconds))


def read_trajectory(path: str | Path) -> Trajectory:
    """Read and check a trajectory file (Parquet; a CSV is refused with a line saying so).

    Parameters
    ----------
    path : str or Path
        The Parquet trajectory file.

    Returns
    -------
    Trajectory
        Its experiments (see :func:`trajectory_from_frame`).

    Raises
    ------
    DatasetError
        If the file is missing, a folder, not Parquet or not a valid trajectory.
    """
    path = Path(path)
    if path.is_dir():
        raise DatasetError(f"trajectory file '{path}' is a folder; give a Parquet file")
    if not path.is_file():
        from excavator_payload.textfiles import not_a_file

        raise DatasetError(not_a_file(path, "trajectory file"))
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


def _demand(arm, q, qd, qdd, tilt, payload) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: the share of each cylinder's speed limit and of the slew rate (n, 4), and of
    the force each cylinder gives at the relief pressure (n, 3), from the machine's model."""
    m = arm.machine
    sig = arm.motion_signals(q, qd, qdd, tilt, payload)
    limits = arm.rod_speed_limits()
    rod = sig["speed"]
    speed = np.column_stack([np.where(rod >= 0, rod / limits[:, 0], -rod / limits[:, 1]),
                             np.abs(qd[:, 3]) / m.house.max_slew_rate])
    relief, back = m.hydraulics.relief_pressure, m.hydraulics.back_pressure
    push = np.array([relief * c.head_area - back * c.rod_area for c in m.cylinders])
    pull = np.array([relief * c.rod_area - back * c.head_area for c in m.cylinders])
    load = sig["load"]
    return speed, np.where(load >= 0, load / push, -load / pull)


def _step_interval(rows: pd.DataFrame, column: str) -> float:
    """Median time between the changes of a recorded angle (s; NaN when it changes fewer than 3 times)."""
    t = rows["time"].to_numpy(dtype=float)
    changes = np.flatnonzero(np.diff(rows[column].to_numpy(dtype=float)) != 0)
    return float(np.median(np.diff(t[changes + 1]))) if len(changes) >= 3 else math.nan


def check_trajectory_motion(trajectory: Trajectory, machine, allow_overspeed: bool = False) -> list[str]:
    """Refuse motions the machine cannot make, naming the real reason (module docstring):
    joints outside their ranges; angles in steps whose interpolated accelerations need far more than
    the relief pressure (or speed) gives; a motion faster than the pumps or slew drive (refused
    unless ``allow_overspeed``: then one warning line per experiment is returned); a motion many
    times faster (a unit mistake: an angle in degrees, time in ms).

    The replay would push such a motion through the model and give absurd pressures (and a
    message about pressures in the wrong unit); checked once, before any experiment is simulated.

    Parameters
    ----------
    trajectory : Trajectory
        The motions to check.
    machine : HydraulicMachine
        The machine that would replay them.
    allow_overspeed : bool
        Let a motion up to :data:`MAX_SPEED_SHARE` times faster than the pumps through, with a
        warning, instead of refusing it.

    Returns
    -------
    list of str
        One warning line per experiment let through by ``allow_overspeed``.

    Raises
    ------
    DatasetError
        For the first motion the machine cannot make, with the reason.
    """

    arm = arm_model(machine)
    ranges = machine.angle_ranges
    names = ("boom", "dipper", "bucket", "slew")
    warnings = []
    for exp_id, rows in trajectory.experiments:
        time, q, qd, qdd, tilt = interpolate(rows, SAMPLE_RATE)
        for j, name in enumerate(ANGLE_COLUMNS[:3]):
            low, high = ranges[j]
            if q[:, j].min() < low - RANGE_SLACK or q[:, j].max() > high + RANGE_SLACK:
                worst = q[:, j].min() if q[:, j].min() < low - RANGE_SLACK else q[:, j].max()
                raise DatasetError(f"{trajectory.source}: experiment {exp_id}: '{name}' reaches {worst:.3g} rad, "
                                   f"outside the machine's range [{low:.3g}, {high:.3g}] rad (between "
                                   "the samples too: a time gap makes the interpolation swing)")
        payload = np.interp(time, rows["time"].to_numpy(dtype=float), rows["payload"].to_numpy(dtype=float))
        speed, force = _demand(arm, q, qd, qdd, tilt, payload)
        too_fast, too_strong = speed.max() > OVERSPEED_TOLERANCE, force.max() > FORCE_LIMIT
        if not (too_fast or too_strong):
            continue
        stepped = False
        if not trajectory.smoothed:
            # does a little filtering take the excess away? then it comes from steps between samples
            probe = smooth_trajectory(Trajectory(trajectory.source, "", [(exp_id, rows)]), 2 * STEP_PROBE)
            _, q2, qd2, qdd2, tilt2 = interpolate(probe.experiments[0][1], SAMPLE_RATE)
            speed2, force2 = _demand(arm, q2, qd2, qdd2, tilt2, payload)
            stepped = ((too_strong and force2.max() * STEP_FACTOR <= force.max())
                       or (too_fast and speed2.max() * STEP_FACTOR <= speed.max()))
        where = trajectory.source
        if stepped:
            i, j = np.unravel_index(int(np.argmax(force)), force.shape) if too_strong else \
                np.unravel_index(int(np.argmax(speed)), speed.shape)
            interval = _step_interval(rows, ANGLE_COLUMNS[j])
            advice = max(0.1, round(2 * interval, 2)) if math.isfinite(interval) else 0.2
            need = (f"{force[i, j]:.3g} times the force its cylinder gives at the relief pressure" if too_strong
                    else f"{speed[i, j]:.3g} times the speed the pumps give")
            sample = float(np.median(np.diff(rows["time"].to_numpy(dtype=float))))
            if math.isfinite(interval) and interval <= 1.5 * sample:  # it changes at every sample
                kind = ("jump from sample to sample (sensor noise or a fine quantisation) more than a "
                        f"machine moves; smooth them with --smooth {advice:g} (seconds)")
            else:
                kind = ("come in steps (a quantised or held signal"
                        f"{f', every {interval:.3g} s' if math.isfinite(interval) else ''}), not in a motion "
                        f"the machine makes; smooth them with --smooth {advice:g} (seconds) or record them finer")
            raise DatasetError(
                f"{where}: experiment {exp_id} at t = {time[i]:.2f} s: the interpolation through the recorded "
                f"{names[j]} angle accelerates at {qdd[i, j]:.3g} rad/s², which needs {need}: the angles {kind}")
        share = float(speed.max())
        if share > MAX_SPEED_SHARE:
            raise DatasetError(f"{where}: experiment {exp_id} moves {share:.3g} times faster than "
                               "the machine's pumps or slew drive allow; are the angles (slew_angle too) "
                               "in radians and 'time' in seconds?")
        if too_strong:
            i, j = np.unravel_index(int(np.argmax(force)), force.shape)
            raise DatasetError(
                f"{where}: experiment {exp_id} at t = {time[i]:.2f} s: the {names[j]} cylinder would need "
                f"{force[i, j]:.3g} times the force it gives at the relief pressure (payload {payload[i]:g} kg, "
                f"{names[j]} acceleration {qdd[i, j]:.3g} rad/s²): a motion or payload this machine cannot "
                "make; check the payload column and the machine file")
        i, j = np.unravel_index(int(np.argmax(speed)), speed.shape)
        drive = "slew drive (house.max_slew_rate)" if j == 3 else "pumps (hydraulics.pump_flow)"
        text = (f"experiment {exp_id} at t = {time[i]:.2f} s: the {names[j]} moves at {share:.3g} times the "
                f"speed the {drive} give")
        if not allow_overspeed:
            # a replay faster than the machine flatters the estimator (issue 28): refused unless asked
            raise DatasetError(f"{where}: {text}; slow the motion down (stretch 'time'), or simulate it "
                               "anyway with --allow-overspeed (flagged in the metadata)")
        warnings.append(f"{text}: simulated anyway (--allow-overspeed); its pressures are no machine's")
    return warnings


def knot_derivatives(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rates and accelerations at the recorded samples from the quartic through five samples.

    At sample *i*, the polynomial of degree 4 through the samples *i* − 2 … *i* + 2 (the nearest
    five at the ends) gives the rate and acceleration; on an even grid of step *h*

    .. math:: \\dot q_i = \\frac{q_{i-2} - 8 q_{i-1} + 8 q_{i+1} - q_{i+2}}{12 h}, \\qquad
              \\ddot q_i = \\frac{-q_{i-2} + 16 q_{i-1} - 30 q_i + 16 q_{i+1} - q_{i+2}}{12 h^2},

    fourth-order accurate like a cubic spline on a smooth motion, but local: where the
    acceleration jumps between two samples, the samples beside it move by 1/24 of the jump and
    the rest not at all (a global spline rings through the motion instead).

    Parameters
    ----------
    t : numpy.ndarray
        Strictly increasing sample times, s, shape (n,), n ≥ 3.
    q : numpy.ndarray
        Angles at those times, rad, shape (n, k).

    Returns
    -------
    qd, qdd : numpy.ndarray
        Rates (rad/s) and accelerations (rad/s²) at the samples, shape (n, k).
    """
    n = len(t)
    width = min(5, n)
    start = np.clip(np.arange(n) - width // 2, 0, n - width)
    stencil = start[:, None] + np.arange(width)
    dt = t[stencil] - t[:, None]
    scale = np.abs(dt).max(axis=1, keepdims=True)  # well-conditioned whatever the time unit
    vander = (dt / scale)[:, None, :] ** np.arange(width)[None, :, None]  # (n, power, sample)
    # weights w with Σ_s w_s (dt_s/scale)^p = p-th derivative of (dt/scale)^p at 0: p = 1 → 1, p = 2 → 2
    rhs = np.zeros((n, width, 2))
    rhs[:, 1, 0], rhs[:, 2, 1] = 1.0, 2.0
    weights = np.linalg.solve(vander, rhs)  # (n, sample, 2)
    samples = q[stencil]  # (n, sample, k)
    qd = np.einsum("ns,nsk->nk", weights[:, :, 0], samples) / scale
    qdd = np.einsum("ns,nsk->nk", weights[:, :, 1], samples) / scale**2
    return qd, qdd


def interpolate(rows: pd.DataFrame, sample_rate: float):
    """Time grid at ``sample_rate`` and (q, q̇, q̈) (n, 4), tilt (n, 2) by quintic Hermite pieces.

    Each angle is interpolated between its samples by the quintic that takes the sample's angle,
    rate and acceleration at both ends (:func:`knot_derivatives`): continuous angle, rate and
    acceleration, and local. A global cubic spline (used before) rings where a motion's
    acceleration jumps (a lever pushed through a first-order valve): its acceleration alternates
    from sample to sample by up to half the motion's largest, which the inverse dynamics turns
    into chamber pressures no machine makes (oil compliance filters them).

    Parameters
    ----------
    rows : pandas.DataFrame
        One experiment's rows (``time`` in s, angles in rad, optional ground tilt in rad).
    sample_rate : float
        Rate of the output grid, Hz.

    Returns
    -------
    time : numpy.ndarray
        Sample times from the first recorded time, s, shape (n,).
    q, qd, qdd : numpy.ndarray
        Angles (rad), rates (rad/s) and accelerations (rad/s²) of boom, dipper, bucket and
        slew, shape (n, 4).
    tilt : numpy.ndarray
        Ground (pitch, roll), rad, interpolated linearly (0 where absent), shape (n, 2).
    """
    t = rows["time"].to_numpy(dtype=float)
    n = int(np.floor((t[-1] - t[0]) * sample_rate + 1e-9)) + 1
    time = t[0] + np.arange(n) / sample_rate
    knots = rows[list(ANGLE_COLUMNS)].to_numpy(dtype=float)
    rate, accel = knot_derivatives(t, knots)
    piece = np.clip(np.searchsorted(t, time, side="right") - 1, 0, len(t) - 2)
    h = (t[piece + 1] - t[piece])[:, None]
    s = (time - t[piece])[:, None] / h
    # power form c0 + c1 s + … + c5 s⁵ of the piece, from the two ends' angle, rate and acceleration
    c0, c1, c2 = knots[piece], rate[piece] * h, 0.5 * accel[piece] * h**2
    P = knots[piece + 1] - (c0 + c1 + c2)
    V = rate[piece + 1] * h - (c1 + 2.0 * c2)
    A = accel[piece + 1] * h**2 - 2.0 * c2
    c3, c4, c5 = 10.0 * P - 4.0 * V + 0.5 * A, -15.0 * P + 7.0 * V - A, 6.0 * P - 3.0 * V + 0.5 * A
    q = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
    qd = (c1 + s * (2.0 * c2 + s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5)))) / h
    qdd = (2.0 * c2 + s * (6.0 * c3 + s * (12.0 * c4 + s * 20.0 * c5))) / h**2
    tilt = np.zeros((n, 2))
    for j, c in enumerate(OPTIONAL):
        if c in rows.columns:
            tilt[:, j] = np.interp(time, t, rows[c].to_numpy(dtype=float))
    return time, q, qd, qdd, tilt


def simulate_trajectory_experiment(position: int, seed: int, arm, noise, offsets, trajectory: Trajectory,
                                   with_truth: bool):
    """Rows and metadata of the trajectory's experiment at ``position`` (numbered as in the file).

    Parameters
    ----------
    position : int
        Index into ``trajectory.experiments``.
    seed : int
        Base seed; noise and valve draws come from the streams of ``(seed, experiment number)``.
    arm : HydraulicArmModel
        The machine's model.
    noise : MachineNoise
        Sensor noise preset.
    offsets : dict
        The session's sensor offsets, SI units.
    trajectory : Trajectory
        The motions to replay.
    with_truth : bool
        Also add the noise-free ``true_*`` columns.

    Returns
    -------
    frame : pandas.DataFrame
        The experiment's rows.
    meta : dict
        Its description (payload in kg, peak pressure in Pa, speed share, passes of a changing load).

    Raises
    ------
    ValueError
        If the bucket angle leaves the range where the bucket linkage closes.
    """
    from excavator_payload.simulation.machine_motions import speed_share

    exp_id, rows = trajectory.experiments[position]
    time, q, qd, qdd, tilt = interpolate(rows, SAMPLE_RATE)
    if np.any(arm.linkage_margin(q) <= 0):
        raise ValueError(f"trajectory experiment {exp_id}: the bucket angle leaves the range where "
                         "the bucket linkage closes")
    load = np.interp(time, rows["time"].to_numpy(dtype=float), rows["payload"].to_numpy(dtype=float))
    passes = payload_passes(time, load) if np.ptp(load) > 0 else None
    # a changing load: the dataset's payload column is constant within an experiment, so it holds
    # the sum of its passes (a truck's load, as --motion shift); the load over time is in 'passes'
    payload = float(sum(p["payload"] for p in passes)) if passes else float(load[0])
    motion_rng, noise_rng = machine_rngs(seed, exp_id)
    physics = motion_physics(arm, time, q, qd, qdd, tilt, load,
                             motion_rng.uniform(-1, 1, 3), closing_rng(seed, exp_id))
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
    if passes is not None:
        meta["passes"] = passes
    return frame, meta


#: A pass's load is "in" above this share of its largest value (the fill ends, the release begins).
PLATEAU_SHARE = 0.98


def payload_passes(time: np.ndarray, load: np.ndarray) -> list[dict]:
    """The passes of a load that changes in time: each run where it is above 0 is one pass of
    its largest value (kg); ``fill`` is from its rise to :data:`PLATEAU_SHARE` of that, ``release``
    from the last time there to its return to 0 (s, the experiment's time), as ``--motion
    shift``'s metadata has them (``loadout`` reports against them). A load that rises from 0
    and never comes back is one pass without a release end: the experiment's end is used.

    Parameters
    ----------
    time : numpy.ndarray
        Sample times, s, shape (n,).
    load : numpy.ndarray
        Mass in the bucket at each sample, kg, shape (n,).

    Returns
    -------
    list of dict
        Per pass: ``pass`` (from 1), ``payload`` (kg), ``fill`` and ``release`` windows and
        ``start`` / ``end`` (s).
    """
    above = np.r_[False, load > 0, False]
    edges = np.flatnonzero(np.diff(above.astype(int)))
    passes = []
    for k, (a, b) in enumerate(zip(edges[::2], edges[1::2]), start=1):
        run = load[a:b]
        top = float(run.max())
        full = np.flatnonzero(run >= PLATEAU_SHARE * top)
        stop = min(b, len(time) - 1)
        passes.append({"pass": k, "payload": top,
                       "fill": [float(time[max(a - 1, 0)]), float(time[a + full[0]])],
                       "release": [float(time[a + full[-1]]), float(time[stop])],
                       "start": float(time[max(a - 1, 0)]), "end": float(time[stop])})
    return passes


def trajectory_experiment(spec, experiment: int):
    """The replayed experiment at position ``experiment`` of the run ``spec`` (the hydraulic
    platform's ``trajectory`` motion).

    Parameters
    ----------
    spec : RunSpec
        The run; its ``trajectory`` option holds the :class:`Trajectory`.
    experiment : int
        Position in the trajectory's experiments.
    """
    from excavator_payload.simulation.machine_sensors import session_offsets

    return simulate_trajectory_experiment(experiment, spec.seed, arm_model(spec.machine), spec.noise,
                                          session_offsets(spec.option("session", 0), spec.noise),
                                          spec.option("trajectory"), spec.with_truth)
