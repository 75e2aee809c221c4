"""Figures of the report (matplotlib, Agg backend: no display needed).

Every function returns a :class:`matplotlib.figure.Figure`; :func:`save_png` writes it and
closes it. Angles and rates are drawn in degrees (the edge of the software), masses in kg.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")  # headless: reports are built on servers and in CI

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from excavator_payload.data.dataset import Dataset  # noqa: E402
from excavator_payload.evaluation.metrics import INDUSTRY_TOLERANCE, Evaluation  # noqa: E402

RAD2DEG = 180.0 / np.pi
#: One marker per estimator in the per-experiment plots (thesis Figure 7.0).
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">", "h", "p")


def save_png(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure; closed afterwards.
    path : str or Path
        PNG file to write; its folder is created.
    dpi : int
        Resolution, dots per inch.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def error_per_experiment(evaluations: Sequence[Evaluation]) -> Figure:
    """Thesis Figure 7.0: MAX and RMS error of every test experiment, one marker per estimator.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One per estimator, judged on the same dataset; the first's summary gives the rated
        payload and the discard drawn.
    """
    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for i, ev in enumerate(evaluations):
        pe = ev.per_experiment
        x = np.arange(1, len(pe) + 1)
        for ax, col in zip(axes, ("max_error", "rms_error")):
            y = pe[col].to_numpy(dtype=float)
            ax.semilogy(x, np.where(y > 0, y, np.nan), MARKERS[i % len(MARKERS)], ms=4, alpha=0.75,
                        label=ev.label, linestyle="none")
    rated = evaluations[0].summary.get("rated_payload", 5000.0) if evaluations else 5000.0
    discard = evaluations[0].summary.get("discard", 81) if evaluations else 81
    for ax, name in zip(axes, ("MAX", "RMS")):
        ax.axhline(INDUSTRY_TOLERANCE * rated, color="k", lw=0.8, ls="--",
                   label=f"1 % of rated payload ({INDUSTRY_TOLERANCE * rated:g} kg)")
        ax.set_ylabel(f"{name} error (kg)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_title(f"Errors per test experiment (first {discard} samples discarded)")
    axes[1].set_xlabel("test experiment")
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def joint_measurements(dataset: Dataset, experiment: int) -> Figure:
    """Thesis Figures 7.1, 7.3, …: the measured joint signals of one experiment.

    Parameters
    ----------
    dataset : Dataset
        Thesis-sensor-set data (boom and dipper angle, rate, acceleration and torque).
    experiment : int
        Number of the experiment drawn.
    """
    rows = _rows(dataset, experiment)
    t = rows["time"].to_numpy()
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    spec = (("angle", "angle (deg)", RAD2DEG), ("rate", "rate (deg/s)", RAD2DEG),
            ("accel", "acceleration (deg/s²)", RAD2DEG), ("torque", "torque (kN·m)", 1e-3))
    for ax, (sig, ylabel, scale) in zip(axes, spec):
        for joint, name in (("boom", "lower joint (boom)"), ("dipper", "upper joint (dipper)")):
            ax.plot(t, rows[f"{joint}_{sig}"].to_numpy() * scale, label=name, lw=1.2)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"Measurements at the joints (experiment {experiment}, "
                      f"payload {rows['payload'].iloc[0]:.0f} kg)")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    return fig


def machine_measurements(dataset: Dataset, experiment: int) -> Figure:
    """One experiment of the machine sensor set: arm angles, slew, cylinder pressures and house
    inclination (degrees and bar at this edge; the data stay SI). ``plot`` and the report draw it.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data (simulated or a field log).
    experiment : int
        Number of the experiment drawn.
    """
    rows = _rows(dataset, experiment)
    t = rows["time"].to_numpy(float)
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True, constrained_layout=True)
    ax = axes[0]
    for name, colour in (("boom", "C0"), ("dipper", "C1"), ("bucket", "C2")):
        ax.plot(t, rows[f"{name}_angle"] * RAD2DEG, colour, label=f"{name} angle")
    ax.set_ylabel("angle (°)")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1]
    if "true_slew_angle" in rows:
        slew = rows["true_slew_angle"].to_numpy(float)
        label = "slew angle (true)"
    else:  # a field log: integrate the measured slew rate
        rate = rows["slew_rate"].to_numpy(float)
        slew = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
        label = "slew angle (∫ slew rate)"
    ax.plot(t, slew * RAD2DEG, "C3", label=label)
    ax.set_ylabel("slew (°)")
    ax2 = ax.twinx()
    ax2.plot(t, rows["slew_rate"] * RAD2DEG, "C3", alpha=0.35, lw=0.8)
    ax2.set_ylabel("slew rate (°/s)", color="C3")
    ax.legend(loc="best", fontsize=8)
    ax = axes[2]
    for name, colour in (("boom", "C0"), ("dipper", "C1"), ("bucket", "C2")):
        ax.plot(t, rows[f"{name}_head_pressure"] / 1e5, colour, lw=0.8, label=f"{name} head")
        ax.plot(t, rows[f"{name}_rod_pressure"] / 1e5, colour, lw=0.8, ls="--", label=f"{name} rod")
    relief = (dataset.meta.get("machine") or {}).get("hydraulics", {}).get("relief_pressure")
    if relief:
        ax.axhline(relief / 1e5, color="k", lw=0.6, ls=":", label="relief")
    ax.set_ylabel("pressure (bar)")
    ax.legend(loc="best", fontsize=7, ncol=4)
    ax = axes[3]
    ax.plot(t, rows["house_pitch"] * RAD2DEG, "C4", label="house pitch")
    ax.plot(t, rows["house_roll"] * RAD2DEG, "C5", label="house roll")
    ax.set_ylabel("inclination (°)")
    ax.set_xlabel("time (s)")
    ax.legend(loc="best", fontsize=8)
    # a logger's file (field table, decoded CAN log) has no machine or motion: say where it came from
    machine = (dataset.meta.get("machine") or {}).get("name")
    origin = dataset.meta.get("log") or (dataset.source.name if hasattr(dataset.source, "name") else None)
    head = machine or (Path(str(origin)).name if origin else "dataset")
    what = [w for w in (dataset.meta.get("motion") or dataset.meta.get("source"),
                        f"payload {rows['payload'].iloc[0]:.0f} kg" if "payload" in rows else None) if w]
    fig.suptitle(f"{head}: experiment {experiment}" + (f" ({', '.join(what)})" if what else ""))
    return fig


def payload_estimates(dataset: Dataset, evaluations: Sequence[Evaluation], experiment: int,
                      zoom: bool = False) -> Figure:
    """Thesis Figures 7.2, 7.4, …: every estimator's estimate against the true payload.

    With ``zoom`` the y-range is ±5 % of the rated payload around the truth, so the accurate
    estimators can be told apart.

    Parameters
    ----------
    dataset : Dataset
        The test data, with the true ``payload`` column (kg).
    evaluations : sequence of Evaluation
        One per estimator, judged on the same dataset; the first's summary gives the rated
        payload and the discard drawn.
    experiment : int
        Number of the experiment drawn.
    zoom : bool
        Narrow the y-range to ±5 % of the rated payload around the truth.
    """
    mask = (dataset.frame["experiment"] == experiment).to_numpy()
    rows = dataset.frame[mask]
    t = rows["time"].to_numpy()
    truth = float(rows["payload"].iloc[0])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    release = dataset.experiment_meta.get(int(experiment), {}).get("release")
    if release:  # a work cycle: the load leaves the bucket at the dump (judged up to it)
        a, b = float(release[0]), float(release[1])
        ax.plot(t, truth * np.clip((b - t) / max(b - a, 1e-9), 0.0, 1.0), "k-", lw=2.2,
                label="payload in the bucket")
        ax.axvline(a, color="grey", ls="--", lw=1, label="dump: judged up to here")
    else:
        ax.plot(t, np.full_like(t, truth), "k-", lw=2.2, label="payload")
    for i, ev in enumerate(evaluations):
        ax.plot(t, ev.estimates[mask], lw=1.1, label=f"{ev.label} estimate",
                marker=MARKERS[i % len(MARKERS)], ms=2.5, markevery=10)
    if evaluations:
        discard = evaluations[0].summary.get("discard", 81)
        if 0 < discard < len(t):
            ax.axvline(t[discard], color="grey", ls=":", lw=1, label="start of judged samples")
    rated = evaluations[0].summary.get("rated_payload", 5000.0) if evaluations else 5000.0
    if zoom:
        ax.set_ylim(truth - 0.05 * rated, truth + 0.05 * rated)
    else:
        ax.set_ylim(-0.2 * rated, 1.4 * rated)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("payload (kg)")
    ax.set_title(f"Payload estimates (experiment {experiment}){' — zoom ±5 % of rated' if zoom else ''}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # outside: never hides a curve
    fig.tight_layout()
    return fig


def error_against_bound(evaluations: Sequence[Evaluation], dataset: Dataset) -> Figure:
    """RMS error over the test experiments at each sample time, against the RMS Cramér–Rao bound.

    An estimator on its bound curve is as good as any unbiased estimator using the same
    information can be; the curves are drawn on a log scale.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One per estimator, judged on ``dataset``; those with a bound add its curve (once per
        bound window).
    dataset : Dataset
        The test data; all its experiments must have the same number of samples, else a
        figure saying so is returned.
    """
    n_samples = dataset.frame.groupby("experiment", sort=False).size()
    fig, ax = plt.subplots(figsize=(8, 4.8))
    if len(set(n_samples)) != 1:
        ax.text(0.5, 0.5, "experiments of different lengths: not drawn", ha="center")
        return fig
    n = int(n_samples.iloc[0])
    t = dataset.frame["time"].to_numpy()[:n]
    truth = dataset.frame["payload"].to_numpy(dtype=float)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    drawn_bounds: dict = {}
    for i, ev in enumerate(evaluations):
        c = colours[i % len(colours)]
        err = (ev.estimates - truth).reshape(-1, n)
        rms = _nan_rms(err)
        ax.semilogy(t, rms, color=c, lw=1.3, label=f"{ev.label} RMS error")
        if ev.bound is not None:
            key = ev.summary.get("bound_window")
            if key not in drawn_bounds:
                b = ev.bound.reshape(-1, n)
                rb = _nan_rms(b)
                name = "whole history" if key is None else f"last {key} samples"
                ax.semilogy(t, rb, color="k", ls="--" if key is None else ":", lw=1.3,
                            label=f"Cramér–Rao bound ({name})")
                drawn_bounds[key] = True
    ax.set_xlabel("time (s)")
    ax.set_ylabel("kg")
    ax.set_title("Error against the Cramér–Rao bound (RMS over test experiments)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def calibration_curve(curve: pd.DataFrame | Mapping) -> Figure:
    """Accuracy of the calibrated estimator against the number of calibration experiments.

    ``curve`` has a column of experiment counts (``calibration_experiments``, else the first
    column) and error columns in kg (``n_*`` counts and signed ``bias`` columns are not drawn).

    Parameters
    ----------
    curve : pandas.DataFrame or mapping
        The table described above (anything ``pandas.DataFrame`` accepts).
    """
    frame = pd.DataFrame(curve)
    xcol = next((c for c in ("calibration_experiments", "n_experiments", "n_calibration", "n")
                 if c in frame.columns), frame.columns[0])
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for col in frame.columns:
        # errors only: counts and signed biases do not belong on a log scale of kg
        if (col == xcol or not pd.api.types.is_numeric_dtype(frame[col]) or col.startswith("n_")
                or "bias" in col):
            continue
        y = frame[col].to_numpy(dtype=float)
        if np.all(~np.isfinite(y)):
            continue
        ax.plot(frame[xcol].to_numpy(), y, "o-", label=col)
    ax.set_yscale("log")
    ax.set_xlabel("number of calibration experiments")
    ax.set_ylabel("error (kg)")
    ax.set_title("Calibrated estimator: accuracy against calibration effort")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def training_log(log: pd.DataFrame, title: str) -> Figure:
    """A network's training graph from its ``training_log.csv`` (every numeric column vs epoch).

    Parameters
    ----------
    log : pandas.DataFrame
        The training log; ``epoch``, ``iteration`` or ``step`` is the x axis if present, else
        the row number. Positive numeric columns are drawn on a log scale.
    title : str
        Title of the figure.
    """
    xcol = next((c for c in ("epoch", "iteration", "step") if c in log.columns), None)
    x = log[xcol].to_numpy() if xcol else np.arange(len(log))
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for col in log.columns:
        if col == xcol or not pd.api.types.is_numeric_dtype(log[col]):
            continue
        y = log[col].to_numpy(dtype=float)
        if np.any(y > 0):
            ax.semilogy(x, np.where(y > 0, y, np.nan), label=col)
    ax.set_xlabel(xcol or "epoch")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def weighing_over_time(evaluations: Mapping[str, tuple[Evaluation, Dataset]], rated: float,
                       discard_s: float = 1.0) -> Figure:
    """One panel per test set: each experiment's absolute error against time (thin lines), their
    median at each time (bold), twice the median Cramér–Rao bound (dashed: what an efficient
    estimator keeps 95 % of its errors under) and 1 % of the rated payload.

    Experiments may differ in length (work cycles): times are each experiment's own, from its
    start; the median is taken on a 0.1 s grid over the experiments still running.

    Parameters
    ----------
    evaluations : mapping of str to (Evaluation, Dataset)
        Per test set (the panel's title): one estimator's evaluation and the data it was
        judged on.
    rated : float
        Rated payload, kg: the 1 % line and the y range.
    discard_s : float
        Seconds at the start shaded as not judged.
    """
    n = max(len(evaluations), 1)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.6), sharey=True, squeeze=False)
    for ax, (name, (ev, ds)) in zip(axes[0], evaluations.items()):
        f = ds.frame
        t = f["time"].to_numpy(float)
        exp = f["experiment"].to_numpy()
        err = np.abs(ev.estimates - f["payload"].to_numpy(float))
        grid = np.arange(0.0, float(np.nanmax(t)) + 0.1, 0.1) if len(t) else np.zeros(0)
        on_grid, bound_grid = [], []
        for e in pd.unique(exp):
            rows = exp == e
            te = t[rows] - t[rows][0]
            ax.plot(te, err[rows], color="0.6", lw=0.5, alpha=0.5)
            inside = grid <= te[-1]
            on_grid.append(np.where(inside, np.interp(grid, te, err[rows], left=np.nan, right=np.nan), np.nan))
            if ev.bound is not None:
                bound_grid.append(np.where(inside, np.interp(grid, te, ev.bound[rows]), np.nan))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: no estimate yet
            if on_grid:
                ax.plot(grid, np.nanmedian(np.array(on_grid), axis=0), color="C0", lw=2,
                        label="median |error|")
            if bound_grid:
                ax.plot(grid, 2 * np.nanmedian(np.array(bound_grid), axis=0), "k--", lw=1.2,
                        label="2 × Cramér–Rao bound (median)")
        ax.axhline(INDUSTRY_TOLERANCE * rated, color="C3", lw=1, label=f"1 % of rated ({INDUSTRY_TOLERANCE * rated:g} kg)")
        ax.axvspan(0, discard_s, color="0.9", zorder=0)
        ax.set_yscale("log")
        ax.set_ylim(0.1, 10 * INDUSTRY_TOLERANCE * rated)
        ax.set_title(f"{name} (n = {len(pd.unique(exp))})", fontsize=9)
        ax.set_xlabel("time from the start (s)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("|payload error| (kg)")
    axes[0][-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle(f"{next(iter(evaluations.values()))[0].label if evaluations else ''}: error over each "
                 "test motion (grey: not judged)", fontsize=10)
    fig.tight_layout()
    return fig


def _nan_rms(x: np.ndarray) -> np.ndarray:
    """RMS over axis 0 ignoring NaN; NaN where a column has no finite value (no warning)."""
    finite = np.isfinite(x)
    count = finite.sum(axis=0)
    total = np.where(finite, x, 0.0) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, np.sqrt(total.sum(axis=0) / np.maximum(count, 1)), np.nan)


def _rows(dataset: Dataset, experiment: int) -> pd.DataFrame:
    rows = dataset.frame[dataset.frame["experiment"] == experiment]
    if rows.empty:
        from excavator_payload.errors import DatasetError

        raise DatasetError(f"experiment {experiment} is not in the dataset")
    return rows
