r"""Accuracy metrics of payload estimates: the thesis' Tables 7.1 / 7.2 and more.

For one experiment with true payload :math:`m` and estimates :math:`\hat m_k`, the error is
:math:`e_k = \hat m_k - m`. The first ``discard`` samples (81 in thesis Table 7.1, so that the
closed-loop observers have converged) are not judged; on the judged samples :math:`J`

.. math::

    \mathrm{MAX} = \max_{k\in J} |e_k|, \qquad
    \mathrm{RMS} = \sqrt{\tfrac{1}{|J|}\textstyle\sum_{k\in J} e_k^2},

the 90/95/99th percentiles of :math:`|e_k|` (appendix A.3's ``CI = prctile(abs(err),[90 95 99])``)
and the convergence time, the first time after which :math:`|e_k|` stays below 1 % of the
rated payload until the end of the experiment. Over experiments: the mean and the standard
deviation (``ddof=1``, MATLAB's ``std``) of MAX and RMS, in kg and in % of the rated payload,
and the share of experiments meeting the industry requirement :math:`\mathrm{MAX} \le 1\,\%`
of the rated payload.

Efficiency against the Cramér–Rao bound :math:`\sigma_k` (:mod:`excavator_payload.evaluation.crb`)
for the information the estimator uses:

.. math:: \eta = \sqrt{\tfrac{1}{N}\textstyle\sum_{\text{judged }k} (e_k / \sigma_k)^2},

1 being the best an unbiased estimator can do (less than 1 only by chance or through bias
towards the truth, e.g. a prior).

Estimates that are NaN (warming up, no data) are not judged; the share of judged samples that
have an estimate is reported as ``estimated_share``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import ESTIMATE_COLUMNS
from excavator_payload.errors import DatasetError
from excavator_payload.estimators.traits import ESTIMATOR_TRAITS
from excavator_payload.platforms import THESIS, platform_for
# What ``--discard`` defaults to, per sensor set (for ``--help``): the platforms'.
from excavator_payload.platforms.registry import DISCARD_DEFAULT_HELP  # noqa: F401
# Seconds not judged at the start of every machine-set experiment: the hydraulic platform's.
from excavator_payload.platforms.hydraulic import DEFAULT_DISCARD_SECONDS  # noqa: F401

#: Samples discarded at the start of every experiment of the thesis sensor set (thesis Table 7.1:
#: "the first 81 steps", at 20 Hz): the thesis platform's default discard.
DEFAULT_DISCARD = THESIS.default_discard()
#: Rated payload of the thesis machine (kg), used when the dataset names no machine.
DEFAULT_RATED_PAYLOAD = 5000.0
#: Industry requirement: the error must stay within 1 % of the rated payload.
INDUSTRY_TOLERANCE = 0.01
#: Percentiles of |error| reported per experiment (appendix A.3 ``CI``).
PERCENTILES = (90, 95, 99)


def default_discard(sensor_set) -> int:
    """Samples not judged at the start of every experiment unless told: its platform's default
    discard (:data:`DEFAULT_DISCARD` on the thesis sensor set, the first
    :data:`DEFAULT_DISCARD_SECONDS` on the machine set).

    Parameters
    ----------
    sensor_set : SensorSet or str
        The sensor set (or its name) whose platform decides.

    Returns
    -------
    int
        Number of samples.
    """
    return platform_for(sensor_set).default_discard()


#: Summary figures that are reported in kg and in % of the rated payload.
_KG_SUMMARY = ("mean_max", "std_max", "mean_rms", "std_rms")


# -- which Cramér–Rao bound applies ---------------------------------------------------------
#: Window (samples) of the information an estimator uses, by registry name, when its options
#: do not say (its traits' ``bound_window``): a focused time-delay net with delays 0…5 (thesis
#: Net₁) sees the last 6 samples; a feed-forward net only the current one. ``None``: the whole
#: history (filters, recursive least squares, NARX and layer-recurrent nets that carry state).
BOUND_WINDOWS: dict[str, int | None] = {name: t.bound_window for name, t in ESTIMATOR_TRAITS.items()}

#: Option names under which time-delay networks may declare their input delays.
_DELAY_OPTIONS = ("delays", "input_delays", "tapped_delays", "max_delay", "n_delays")


def bound_window(estimator: str | None, options: Mapping[str, Any] | None = None) -> int | None:
    """The Cramér–Rao window (samples) that applies to an estimator, ``None`` for whole history.

    For the time-delay networks the window is ``max delay + 1``, read from the estimator's
    options when they declare delays (an integer = the largest delay, or a list of delays),
    otherwise :data:`BOUND_WINDOWS`. Unknown estimators get the whole history (the smallest
    bound, so the efficiency ratio is never flattered).

    Parameters
    ----------
    estimator : str or None
        Registry name of the estimator (``None``: unknown, whole history).
    options : mapping, optional
        The estimator's options; delays declared there override the registry's window.

    Returns
    -------
    int or None
        Window in samples, or ``None`` for the whole history.
    """
    if estimator is None:
        return None
    if estimator == "quasi-static" and options and options.get("averaging") == "none":
        return 1  # a per-sample map lookup uses one sample's information
    default = BOUND_WINDOWS.get(estimator)
    if default is None or not options:
        return default
    for key in _DELAY_OPTIONS:
        if key in options and options[key] is not None:
            largest = _largest_delay(options[key])
            if largest is not None:
                return largest + 1
    return default


def _largest_delay(delays) -> int | None:
    """Largest delay of an int, a list, or MATLAB-like text (``"0:5"``, ``"1,3"``, ``"none"``)."""
    if isinstance(delays, (list, tuple, np.ndarray)):
        values = [v for v in (_largest_delay(d) for d in delays) if v is not None]
        return max(values) if values else None
    if isinstance(delays, str):
        parts = [p for p in delays.replace("[", "").replace("]", "").replace(",", " ").split() if p]
        if not parts or parts == ["none"]:
            return 0
        try:
            return max(int(float(p.split(":")[-1])) for p in parts)
        except ValueError:
            return None
    try:
        return int(delays)
    except (TypeError, ValueError):
        return None


# -- per-experiment metrics -----------------------------------------------------------------
def convergence_time(time: np.ndarray, error: np.ndarray, tolerance: float) -> float:
    """First time after which ``|error| < tolerance`` holds until the end (NaN if never).

    Time is measured from the experiment's first sample. A NaN estimate counts as not
    converged.

    Parameters
    ----------
    time : array (n_samples,)
        Sample times of one experiment, s.
    error : array (n_samples,)
        Estimate minus true payload at those times, kg (NaN where there is no estimate).
    tolerance : float
        Band, kg, that ``|error|`` must stay within.

    Returns
    -------
    float
        Seconds from the first sample, NaN if the error is outside the band at the end.
    """
    time = np.asarray(time, dtype=float)
    inside = np.abs(np.asarray(error, dtype=float)) < tolerance  # NaN compares False
    if len(inside) == 0 or not inside[-1]:
        return math.nan
    outside = np.flatnonzero(~inside)
    first = 0 if len(outside) == 0 else outside[-1] + 1
    return float(time[first] - time[0])


def experiment_metrics(time: np.ndarray, estimate: np.ndarray, payload: float,
                       discard: int = DEFAULT_DISCARD, rated_payload: float = DEFAULT_RATED_PAYLOAD,
                       bound: np.ndarray | None = None) -> dict[str, float]:
    """Metrics of one experiment.

    Parameters
    ----------
    time, estimate : array (n_samples,)
        Sample times (s) and payload estimates (kg, NaN where there is none).
    payload : float
        True payload (kg).
    discard : int
        Samples not judged at the start.
    rated_payload : float
        kg; the convergence tolerance is 1 % of it.
    bound : array (n_samples,), optional
        Cramér–Rao bound (kg) at each sample, for the efficiency terms.

    Returns
    -------
    dict
        ``max_error``, ``rms_error``, ``mean_error`` (bias), ``p90``/``p95``/``p99`` (of |e|),
        ``convergence_time`` (s), ``n_judged``, ``n_estimated`` (judged samples with an
        estimate), ``estimated_share``, ``sum_sq_efficiency`` and ``n_efficiency`` (for
        pooling :math:`\\eta` over experiments), ``efficiency`` (this experiment's :math:`\\eta`),
        ``final_bound`` (bound at the last sample, kg).
    """
    estimate = np.asarray(estimate, dtype=float)
    error = estimate - float(payload)
    judged = error[discard:]
    ok = np.isfinite(judged)
    e = judged[ok]
    out: dict[str, float] = {
        "n_judged": int(len(judged)),
        "n_estimated": int(ok.sum()),
        "estimated_share": float(ok.mean()) if len(judged) else math.nan,
    }
    if len(e):
        abs_e = np.abs(e)
        out.update(max_error=float(abs_e.max()), rms_error=float(np.sqrt(np.mean(e**2))),
                   mean_error=float(e.mean()))
        for p, v in zip(PERCENTILES, _matlab_prctile(abs_e, PERCENTILES)):
            out[f"p{p}"] = float(v)
    else:
        out.update(max_error=math.nan, rms_error=math.nan, mean_error=math.nan,
                   **{f"p{p}": math.nan for p in PERCENTILES})
    out["convergence_time"] = convergence_time(time, error, INDUSTRY_TOLERANCE * rated_payload)
    if bound is not None:
        b = np.asarray(bound, dtype=float)[discard:]
        use = ok & np.isfinite(b) & (b > 0)
        ratio = judged[use] / b[use]
        out["sum_sq_efficiency"] = float(np.sum(ratio**2))
        out["n_efficiency"] = int(use.sum())
        out["efficiency"] = float(np.sqrt(np.mean(ratio**2))) if use.any() else math.nan
        out["final_bound"] = float(np.asarray(bound, dtype=float)[-1]) if len(bound) else math.nan
    return out


def _matlab_prctile(x: np.ndarray, percentiles) -> np.ndarray:
    """Percentiles as MATLAB's ``prctile`` computes them (midpoint interpolation, clamped).

    MATLAB places the sorted values at percentages 100·(i − 0.5)/n and interpolates linearly,
    which is numpy's ``method="hazen"``.
    """
    return np.percentile(x, percentiles, method="hazen")


# -- aligning estimates with a dataset ------------------------------------------------------
def align_estimates(dataset: Dataset, estimates: pd.DataFrame, source: str = "estimates") -> np.ndarray:
    """The estimate for every row of ``dataset`` (NaN where the estimates have none).

    Rows are matched on ``experiment`` and ``time`` (to the nearest microsecond, so estimates
    written by other tools match too).

    Parameters
    ----------
    dataset : Dataset
        The rows to align to.
    estimates : pandas.DataFrame
        Estimates table with columns ``experiment``, ``time`` (s) and ``payload_estimate`` (kg).
    source : str
        Name of the estimates (a file or a label) used in error messages.

    Returns
    -------
    numpy.ndarray
        One estimate (kg) per row of ``dataset.frame``.

    Raises
    ------
    DatasetError
        If the estimates lack the required columns or share no sample with the dataset.
    """
    missing = [c for c in ESTIMATE_COLUMNS if c not in estimates.columns]
    if missing:
        raise DatasetError(f"{source}: not an estimates table, missing column(s) {', '.join(missing)}")
    if not pd.api.types.is_numeric_dtype(estimates["payload_estimate"]):
        raise DatasetError(f"{source}: column 'payload_estimate' must be numeric (kg)")

    def keys(frame):
        return pd.MultiIndex.from_arrays([
            frame["experiment"].to_numpy().astype(np.int64),
            np.round(frame["time"].to_numpy(dtype=float) * 1e6).astype(np.int64)])

    est_keys = keys(estimates)
    if est_keys.has_duplicates:
        raise DatasetError(f"{source}: has more than one estimate for some (experiment, time)")
    series = pd.Series(estimates["payload_estimate"].to_numpy(dtype=float), index=est_keys)
    aligned = series.reindex(keys(dataset.frame)).to_numpy(dtype=float)
    matched = series.index.isin(keys(dataset.frame))
    if not matched.any():
        raise DatasetError(f"{source}: no (experiment, time) matches the dataset; "
                           "were the estimates made on another dataset?")
    return aligned


# -- evaluation of one estimator ------------------------------------------------------------
@dataclass
class Evaluation:
    """The metrics of one estimator on one dataset.

    Parameters
    ----------
    label : str
        Display name (e.g. ``EKF_ideal``).
    per_experiment : pandas.DataFrame
        One row per experiment: ``experiment``, ``payload`` and :func:`experiment_metrics`.
    summary : dict
        Over experiments, see :func:`summarize`.
    estimates : numpy.ndarray
        The aligned estimate of every dataset row (for figures).
    bound : numpy.ndarray or None
        The Cramér–Rao bound (kg) of every dataset row.
    info : dict
        Where it came from (estimator name, options, model folder or estimates file).
    """

    label: str
    per_experiment: pd.DataFrame
    summary: dict
    estimates: np.ndarray
    bound: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-able: label, info, summary and the per-experiment table as records."""
        return {"label": self.label, "info": _clean(self.info), "summary": _clean(self.summary),
                "per_experiment": _clean(self.per_experiment.to_dict(orient="records"))}


def summarize(per_experiment: pd.DataFrame, rated_payload: float = DEFAULT_RATED_PAYLOAD) -> dict:
    """Figures over experiments (thesis Tables 7.1 and 7.2 and more).

    Parameters
    ----------
    per_experiment : pandas.DataFrame
        One row per experiment with the columns of :func:`experiment_metrics`.
    rated_payload : float
        Rated payload of the machine, kg: the base of the ``_pct`` figures and of the 1 %
        requirement.

    Returns
    -------
    dict
        ``n_experiments``, ``n_judged_experiments`` (with at least one judged estimate),
        ``mean_max``, ``std_max``, ``mean_rms``, ``std_rms`` (kg) and the same with ``_pct``
        (% of rated payload), ``mean_p90``/``p95``/``p99``, ``meets_requirement_share``
        (MAX ≤ 1 % of rated; experiments without estimates fail it), ``mean_convergence_time``
        (s, over converged experiments), ``converged_share``, ``estimated_share``,
        ``efficiency`` (pooled :math:`\\eta`), ``rated_payload``.
    """
    pe = per_experiment
    n = len(pe)
    mx = pe["max_error"].to_numpy(dtype=float)
    rms = pe["rms_error"].to_numpy(dtype=float)
    judged = np.isfinite(mx)

    def mean(x):
        x = x[np.isfinite(x)]
        return float(x.mean()) if len(x) else math.nan

    def std(x):
        x = x[np.isfinite(x)]
        return float(x.std(ddof=1)) if len(x) > 1 else (0.0 if len(x) == 1 else math.nan)

    s: dict[str, Any] = {
        "n_experiments": int(n),
        "n_judged_experiments": int(judged.sum()),
        "rated_payload": float(rated_payload),
        "mean_max": mean(mx), "std_max": std(mx),
        "mean_rms": mean(rms), "std_rms": std(rms),
    }
    for p in PERCENTILES:
        s[f"mean_p{p}"] = mean(pe[f"p{p}"].to_numpy(dtype=float))
    for k in _KG_SUMMARY:
        s[k + "_pct"] = 100.0 * s[k] / rated_payload
    tol = INDUSTRY_TOLERANCE * rated_payload
    s["meets_requirement_share"] = float(np.mean(judged & (np.nan_to_num(mx, nan=np.inf) <= tol))) if n else math.nan
    conv = pe["convergence_time"].to_numpy(dtype=float)
    s["converged_share"] = float(np.isfinite(conv).mean()) if n else math.nan
    s["mean_convergence_time"] = mean(conv)
    n_j = pe["n_judged"].sum()
    s["estimated_share"] = float(pe["n_estimated"].sum() / n_j) if n_j else math.nan
    if "n_efficiency" in pe:
        n_eff = pe["n_efficiency"].sum()
        s["efficiency"] = float(np.sqrt(pe["sum_sq_efficiency"].sum() / n_eff)) if n_eff else math.nan
        s["mean_final_bound"] = mean(pe["final_bound"].to_numpy(dtype=float))
    return s


def evaluate_estimates(dataset: Dataset, estimates: pd.DataFrame | np.ndarray, *, label: str = "estimator",
                       discard: int | None = None, window: int | None = None,
                       with_bound: bool = True, bound: np.ndarray | None = None,
                       rated_payload: float | None = None, info: dict | None = None) -> Evaluation:
    """Judge estimates against a dataset's true payloads.

    Parameters
    ----------
    dataset : Dataset
        The data the estimates were made on (its ``payload`` column is the truth).
    estimates : DataFrame or array
        An estimates table (``experiment``, ``time``, ``payload_estimate``) or an array
        aligned with the dataset's rows.
    label : str
        Display name of the estimator (``Evaluation.label``; also names it in error messages).
    discard : int, optional
        Samples not judged at the start of every experiment (default :func:`default_discard` of
        the dataset's sensor set: 81 on the thesis set, 100 = 1 s on the machine set).
    window : int or None
        Cramér–Rao window (see :func:`bound_window`); ``None`` the whole history.
    with_bound : bool
        Compute the Cramér–Rao bound (needs the dataset's machine and noise preset).
    bound : array, optional
        A precomputed bound for the dataset's rows (shared between estimators).
    rated_payload : float, optional
        kg; default the dataset machine's, else 5000 kg.
    info : dict, optional
        Where the estimates came from (estimator name, options, model folder or estimates
        file), kept as ``Evaluation.info``.

    Notes
    -----
    A work cycle (an experiment whose metadata has the dump's ``release`` times) is judged up to
    its dump; ``summary["judged_to_the_dump"]`` counts them.
    """
    if discard is None:
        discard = default_discard(dataset.sensor_set)
    if discard < 0:
        raise DatasetError(f"--discard must be ≥ 0, got {discard}")
    if isinstance(estimates, pd.DataFrame):
        est = align_estimates(dataset, estimates, source=label)
    else:
        est = np.asarray(estimates, dtype=float)
        if est.shape != (len(dataset.frame),):
            raise DatasetError(f"{label}: {est.shape[0] if est.ndim else 0} estimates for "
                               f"{len(dataset.frame)} dataset rows")
    if rated_payload is None:
        machine = dataset.machine()
        rated_payload = float(machine.rated_payload) if machine is not None else DEFAULT_RATED_PAYLOAD
    if bound is None and with_bound:
        bound = dataset_bound(dataset, window)
    frame = dataset.frame
    exp = frame["experiment"].to_numpy()
    time = frame["time"].to_numpy(dtype=float)
    payload = frame["payload"].to_numpy(dtype=float)
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    ends = np.r_[starts[1:], len(exp)]
    # The payload column is the load carried (one per experiment); a work cycle's load leaves
    # the bucket at its dump (the experiment's metadata ``release``). The sensors weigh one load
    # per experiment, so such an experiment is judged up to the dump: judged on, the empty
    # bucket would be held against the load's weighing (the summary counts them).
    release = {k: float(m["release"][0]) for k, m in dataset.experiment_meta.items() if m.get("release")}
    rows = []
    for a, b in zip(starts, ends):
        if int(exp[a]) in release:
            b = a + int(np.sum(time[a:b] < release[int(exp[a])]))
        m = experiment_metrics(time[a:b], est[a:b], payload[a], discard, rated_payload,
                               None if bound is None else bound[a:b])
        rows.append({"experiment": int(exp[a]), "payload": float(payload[a]), **m})
    per_experiment = pd.DataFrame(rows)
    summary = summarize(per_experiment, rated_payload)
    summary["judged_to_the_dump"] = len(release)
    summary["discard"] = int(discard)
    summary["bound_window"] = window
    return Evaluation(label, per_experiment, summary, est, bound, dict(info or {}))


def dataset_bound(dataset: Dataset, window: int | None = None) -> np.ndarray | None:
    """Cramér–Rao bound of every row, or ``None`` when the dataset lacks machine or noise info.

    Parameters
    ----------
    dataset : Dataset
        Thesis-sensor-set data naming its machine (the machine set's bound is
        :mod:`.crb_machine`'s).
    window : int or None
        Samples of information used (see :func:`bound_window`); ``None`` the whole history.

    Returns
    -------
    numpy.ndarray or None
        Bound on the payload error's std, kg, one per row.
    """
    from excavator_payload.evaluation.crb import cramer_rao_bound

    if dataset.machine() is None or not THESIS.carries(dataset):
        return None  # the machine sensor set's bound is issue 12's
    try:
        return cramer_rao_bound(dataset, window=window)
    except Exception as exc:  # noqa: BLE001 - an unknown noise preset must not stop evaluation
        from excavator_payload.errors import ExcavatorPayloadError

        if isinstance(exc, (ExcavatorPayloadError, ValueError)):
            return None
        raise


def _clean(obj):
    """JSON-able copy: numpy scalars to Python, NaN/inf to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_clean(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def to_jsonable(obj):
    """Public alias of the JSON cleaner (NaN -> null).

    Parameters
    ----------
    obj : object
        Dicts, lists, tuples, NumPy arrays and scalars, nested; keys become strings.

    Returns
    -------
    object
        A copy of plain Python values, non-finite floats as ``None``.
    """
    return _clean(obj)


# -- thesis reference figures and labels ----------------------------------------------------
#: Thesis Tables 7.1 and 7.2 (kg): mean and standard deviation of MAX and RMS errors over 200
#: test experiments, first 81 samples discarded.
THESIS_TABLE: dict[str, dict[str, float]] = {
    "Net1": {"mean_max": 0.4998, "mean_rms": 0.296, "std_max": 0.425, "std_rms": 0.293},
    "Net2": {"mean_max": 0.998, "mean_rms": 0.656, "std_max": 0.545, "std_rms": 0.415},
    "EKF_ideal": {"mean_max": 22.978, "mean_rms": 15.845, "std_max": 13.952, "std_rms": 11.439},
    "EKF_1%": {"mean_max": 86.954, "mean_rms": 72.141, "std_max": 65.614, "std_rms": 58.665},
    "EKF_3%": {"mean_max": 100.485, "mean_rms": 89.880, "std_max": 58.683, "std_rms": 54.728},
}

_EKF_THESIS_LABELS = {"cat345c": "EKF_ideal", "cat345c-1pct": "EKF_1%", "cat345c-3pct": "EKF_3%"}


def display_label(estimator: str, options: Mapping[str, Any] | None = None,
                  machine_name: str | None = None) -> str:
    """A short name for tables: the thesis' names where an estimator is the thesis' one.

    The label of the estimator's traits (``net1`` → ``Net1``, ``net2`` → ``Net2``, ``ekf`` →
    ``EKF_tuned``); ``ekf`` with ``tuning=thesis`` on ``cat345c`` / ``cat345c-1pct`` /
    ``cat345c-3pct`` → ``EKF_ideal`` / ``EKF_1%`` / ``EKF_3%``; the machine is added when it is
    not the ideal one, except to the thesis' own names.

    Parameters
    ----------
    estimator : str
        Registry name of the estimator.
    options : mapping, optional
        Its options (only ``tuning`` matters here).
    machine_name : str, optional
        Name of the machine model the estimator uses.

    Returns
    -------
    str
        The label.
    """
    options = dict(options or {})
    if estimator == "ekf" and options.get("tuning") == "thesis" and machine_name in _EKF_THESIS_LABELS:
        return _EKF_THESIS_LABELS[machine_name]
    traits = ESTIMATOR_TRAITS.get(estimator)
    label = traits.label if traits is not None else estimator
    if traits is not None and traits.thesis_name:
        return label
    if machine_name and machine_name != "cat345c":
        label += f" ({machine_name})"
    return label
