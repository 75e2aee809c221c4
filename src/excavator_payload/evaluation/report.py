"""The evaluation report: one self-contained HTML file (images embedded) plus Markdown.

``build_report`` writes into a folder

* ``report.html``: opens anywhere, every figure embedded as a base64 PNG;
* ``report.md``: the same text, figures linked by relative path;
* ``figures/*.png``: the figures;
* ``evaluation.json``: every number in the tables.

Contents: the headline table, thesis Tables 7.1 and 7.2 with the thesis' numbers beside ours,
thesis Figure 7.0 (per-experiment MAX and RMS errors), figures like thesis 7.1–7.12 for chosen
experiments, the error against the Cramér–Rao bound, the calibration curve, the networks'
training graphs, estimators that failed and why, and the settings that produced it.
"""

from __future__ import annotations

import base64
import html
import json
import os
import math
import platform
import shutil
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from excavator_payload.data.dataset import Dataset
from excavator_payload.evaluation import figures
from excavator_payload.platforms import HYDRAULIC
from excavator_payload.evaluation.metrics import (
    INDUSTRY_TOLERANCE,
    THESIS_TABLE,
    Evaluation,
    to_jsonable,
)

#: Packages whose versions are recorded so a report can be reproduced.
VERSIONED_PACKAGES = ("excavator-payload", "numpy", "scipy", "casadi", "torch", "pandas", "pyarrow",
                      "matplotlib")


def versions() -> dict[str, str]:
    """Python and package versions (without importing heavy packages)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for pkg in VERSIONED_PACKAGES:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def choose_experiments(dataset: Dataset, count: int = 6) -> list[int]:
    """``count`` experiments spread over the payload range (lightest to heaviest).

    Parameters
    ----------
    dataset : Dataset
        Data with one true payload per experiment.
    count : int
        How many experiments at most (fewer if the dataset has fewer).

    Returns
    -------
    list of int
        Experiment numbers, by increasing payload.
    """
    ids = dataset.experiment_ids
    payloads = dataset.payloads
    order = np.argsort(payloads, kind="stable")
    picks = np.unique(np.round(np.linspace(0, len(ids) - 1, min(count, len(ids)))).astype(int))
    return [int(ids[order[i]]) for i in picks]


@dataclass
class ReportPaths:
    """The files :func:`build_report` wrote: ``report.html``, ``report.md``, ``evaluation.json``
    and the figures (PNG).

    Parameters
    ----------
    html : Path
        The self-contained ``report.html``.
    markdown : Path
        ``report.md``.
    json : Path
        ``evaluation.json`` with every number of the tables.
    figures : list of Path
        The figure files written under ``figures/``.
    """

    html: Path
    markdown: Path
    json: Path
    figures: list[Path] = field(default_factory=list)


@dataclass
class _Section:
    title: str
    text: str = ""                      # plain text paragraph(s)
    table: pd.DataFrame | None = None
    images: list[tuple[Path, str]] = field(default_factory=list)  # (png, caption)
    pre: str | None = None              # preformatted block (settings)


def headline_table(evaluations: Sequence[Evaluation]) -> pd.DataFrame:
    """One row per estimator: the figures a reader wants first.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One per estimator (its ``label`` and ``summary`` are used).

    Returns
    -------
    pandas.DataFrame
        The headline columns (:data:`HEADLINE_DEFINITIONS` says what they mean).
    """
    rows = []
    for ev in evaluations:
        s = ev.summary
        rows.append({
            "estimator": ev.label,
            "mean MAX (kg)": s["mean_max"], "std MAX (kg)": s["std_max"],
            "mean RMS (kg)": s["mean_rms"], "std RMS (kg)": s["std_rms"],
            "mean MAX (% rated)": s["mean_max_pct"], "mean RMS (% rated)": s["mean_rms_pct"],
            "mean p95 |e| (kg)": s["mean_p95"],
            "MAX ≤ 1 % rated (share)": s["meets_requirement_share"],
            "converged (share)": s["converged_share"],
            "mean convergence time (s)": s["mean_convergence_time"],
            "efficiency (1 = CRB)": s.get("efficiency", math.nan),
            "estimated share": s["estimated_share"],
        })
    return pd.DataFrame(rows)


#: What every headline column means (shown under the table in the report).
HEADLINE_DEFINITIONS: dict[str, str] = {
    "mean MAX / RMS (kg)": "per test experiment, the largest and the root-mean-square |estimate − true "
                           "payload| over the judged samples; then the mean (and std) over experiments "
                           "(thesis Tables 7.1 and 7.2)",
    "% rated": "the same as a percentage of the machine's rated payload",
    "mean p95 |e| (kg)": "95th percentile of |error| within each experiment, averaged",
    "MAX ≤ 1 % rated (share)": "share of experiments whose MAX error meets the industry requirement "
                               "(1 % of the rated payload); an experiment without estimates fails it",
    "converged (share)": "share of experiments whose error enters the 1 % band and stays in it until "
                         "the end of the experiment",
    "mean convergence time (s)": "over the converged experiments, the time from the experiment's "
                                 "first sample after which the error stays inside the 1 % band",
    "efficiency (1 = CRB)": "RMS over the judged samples of error ÷ Cramér–Rao bound for the "
                            "information the estimator uses: 1 is the best any unbiased estimator "
                            "can do; 2 means twice the physically possible error",
    "estimated share": "share of the judged samples at which the estimator gave an estimate at "
                       "all (not NaN: warming up, or no usable data)",
}


def interpretation(evaluations: Sequence[Evaluation]) -> str:
    """A few sentences reading the headline table (what the README says, from these numbers).

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One per estimator (its ``label`` and ``summary`` are used).

    Returns
    -------
    str
        One or two sentences per estimator.
    """
    lines = []
    for ev in evaluations:
        s = ev.summary
        eff, share = s.get("efficiency", math.nan), s.get("meets_requirement_share", math.nan)
        if not math.isfinite(s.get("mean_rms", math.nan)):
            lines.append(f"{ev.label}: no judged estimates.")
            continue
        if math.isfinite(eff) and eff <= 1.3:
            verdict = "at the physical limit: its errors are what the sensor noise allows"
        elif math.isfinite(eff) and eff <= 10:
            verdict = f"{eff:.1f}× the physically possible error: room to improve"
        elif math.isfinite(eff):
            verdict = (f"{eff:.0f}× the physically possible error: limited by its model or tuning, "
                       "not by the sensors")
        else:
            verdict = "no Cramér–Rao bound for this data"
        lines.append(f"{ev.label}: {verdict}; {share:.0%} of the experiments meet the 1 % requirement."
                     if math.isfinite(share) else f"{ev.label}: {verdict}.")
    return " ".join(lines)


def thesis_tables(evaluations: Sequence[Evaluation]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Thesis Tables 7.1 (means) and 7.2 (standard deviations), thesis and ours side by side.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        Matched to the thesis' estimators by label (``Net1``, ``EKF_ideal``, …); the others
        are not shown.

    Returns
    -------
    (pandas.DataFrame, pandas.DataFrame)
        Table 7.1 and Table 7.2, kg; NaN where an estimator was not evaluated.
    """
    ours = {ev.label: ev.summary for ev in evaluations}
    t71, t72 = [], []
    for name, ref in THESIS_TABLE.items():
        s = ours.get(name, {})
        t71.append({"estimator": name,
                    "mean MAX thesis (kg)": ref["mean_max"], "mean MAX ours (kg)": s.get("mean_max", math.nan),
                    "mean RMS thesis (kg)": ref["mean_rms"], "mean RMS ours (kg)": s.get("mean_rms", math.nan)})
        t72.append({"estimator": name,
                    "std MAX thesis (kg)": ref["std_max"], "std MAX ours (kg)": s.get("std_max", math.nan),
                    "std RMS thesis (kg)": ref["std_rms"], "std RMS ours (kg)": s.get("std_rms", math.nan)})
    return pd.DataFrame(t71), pd.DataFrame(t72)


def build_report(out_dir: str | Path, dataset: Dataset, evaluations: Sequence[Evaluation], *,
                 title: str = "excavator-payload evaluation", settings: Mapping | None = None,
                 experiments: Sequence[int] | None = None, failures: Mapping[str, str] | None = None,
                 calibration: pd.DataFrame | None = None, training_dirs: Mapping[str, Path] | None = None,
                 notes: Sequence[str] = ()) -> ReportPaths:
    """Write the report into ``out_dir`` and return the paths.

    Parameters
    ----------
    out_dir : str or Path
        Folder to write into (created; its ``figures`` folder is replaced).
    dataset : Dataset
        The test data the evaluations were made on.
    evaluations : sequence of Evaluation
        One per estimator (see :func:`~excavator_payload.evaluation.metrics.evaluate_estimates`).
    title : str
        Title of the HTML and Markdown reports (also saved in ``evaluation.json``).
    settings : mapping
        What produced the report (machine, noise, seeds, sizes, commands); versions are added.
    experiments : sequence of int, optional
        Experiments to draw like thesis Figures 7.1–7.12 (default: six spread over the payloads).
    failures : mapping
        Estimator label -> why it failed (shown, not hidden).
    calibration : DataFrame, optional
        The calibrated estimator's accuracy against the number of calibration experiments.
    training_dirs : mapping
        Network label -> its save folder (``training.png`` or ``training_log.csv`` inside).
    notes : sequence of str
        Sentences appended to the headline paragraph.
    """
    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    if fig_dir.exists():
        shutil.rmtree(fig_dir)  # stale figures of an earlier report must not linger
    fig_dir.mkdir(parents=True)
    evaluations = list(evaluations)
    failures = dict(failures or {})
    experiments = list(experiments) if experiments is not None else choose_experiments(dataset)
    settings = {**dict(settings or {}), "versions": versions(),
                "generated": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    sections: list[_Section] = []
    written: list[Path] = []

    def fig(figure, name):
        path = figures.save_png(figure, fig_dir / name)
        written.append(path)
        return path

    rated = evaluations[0].summary["rated_payload"] if evaluations else 5000.0
    discard = evaluations[0].summary.get("discard", 81) if evaluations else 81
    intro = (f"{len(evaluations)} estimator(s) judged on {dataset.n_experiments} test experiments "
             f"(noise preset '{dataset.meta.get('noise')}', motion '{dataset.meta.get('motion')}'); the first "
             f"{discard} samples of every experiment are discarded as in thesis Table 7.1. Rated payload "
             f"{rated:g} kg; the industry requirement is MAX ≤ {INDUSTRY_TOLERANCE * rated:g} kg. "
             "Efficiency: RMS of error ÷ Cramér–Rao bound over the judged samples (1 is the best an "
             "unbiased estimator can do with the information it uses).")
    sections.append(_Section("Headline", intro + "".join(" " + n for n in notes),
                             table=headline_table(evaluations) if evaluations else None))
    if evaluations:
        sections.append(_Section("How to read the headline",
                                 interpretation(evaluations) + " Columns: "
                                 + "; ".join(f"{k}: {v}" for k, v in HEADLINE_DEFINITIONS.items()) + "."))
    if failures:
        sections.append(_Section("Estimators that failed",
                                 table=pd.DataFrame({"estimator": list(failures),
                                                     "reason": list(failures.values())})))
    from excavator_payload.platforms import THESIS, platform_for

    if platform_for(dataset) is THESIS:  # the thesis' tables compare like with like only there
        t71, t72 = thesis_tables(evaluations)
        sections.append(_Section("Thesis Table 7.1: mean of MAX and RMS errors",
                                 "Thesis: 200 NMPC test experiments, first 81 samples discarded. Ours: as in "
                                 "the headline. Empty cells: estimator not run or failed.", table=t71))
        sections.append(_Section("Thesis Table 7.2: standard deviation of MAX and RMS errors", table=t72))
    if evaluations:
        sections.append(_Section("Thesis Figure 7.0: errors per experiment",
                                 images=[(fig(figures.error_per_experiment(evaluations), "fig7_0_errors.png"),
                                          "MAX and RMS error of every test experiment (log scale)")]))
        crb_img = fig(figures.error_against_bound(evaluations, dataset), "error_vs_crb.png")
        sections.append(_Section("Error against the Cramér–Rao bound",
                                 "RMS error over the test experiments at each time, against the bound "
                                 "for the information used (whole history for filters and recurrent "
                                 "nets, the delay window for time-delay nets).",
                                 images=[(crb_img, "error against Cramér–Rao bound")]))
    for k, exp in enumerate(experiments, start=1):
        if HYDRAULIC.carries(dataset):  # pressures and IMUs, not joint torques
            imgs = [(fig(figures.machine_measurements(dataset, exp), f"fig_exp{exp}_signals.png"),
                     "angles, slew, cylinder pressures and house inclination")]
        else:
            imgs = [(fig(figures.joint_measurements(dataset, exp), f"fig_exp{exp}_joints.png"),
                     f"measurements at the joints (like thesis Figure 7.{2 * k - 1})")]
        if evaluations:
            imgs.append((fig(figures.payload_estimates(dataset, evaluations, exp), f"fig_exp{exp}_payload.png"),
                         f"payload estimates (like thesis Figure 7.{2 * k})"))
            imgs.append((fig(figures.payload_estimates(dataset, evaluations, exp, zoom=True),
                             f"fig_exp{exp}_payload_zoom.png"), "payload estimates, zoomed"))
        payload = float(dataset.frame.loc[dataset.frame["experiment"] == exp, "payload"].iloc[0])
        sections.append(_Section(f"Simulation n°{k}: experiment {exp} (payload {payload:.0f} kg)", images=imgs))
    if calibration is not None and len(calibration):
        sections.append(_Section("Calibrated estimator: accuracy against calibration experiments",
                                 table=pd.DataFrame(calibration),
                                 images=[(fig(figures.calibration_curve(calibration), "calibration_curve.png"),
                                          "accuracy against the number of calibration experiments")]))
    for label, directory in (training_dirs or {}).items():
        directory = Path(directory)
        png, log = directory / "training.png", directory / "training_log.csv"
        safe = "".join(ch if ch.isalnum() else "_" for ch in label)
        if png.is_file():
            target = fig_dir / f"training_{safe}.png"
            shutil.copyfile(png, target)
            written.append(target)
            sections.append(_Section(f"Training graph: {label}", images=[(target, f"{label} training")]))
        elif log.is_file():
            try:
                frame = pd.read_csv(log)
                path = fig(figures.training_log(frame, f"{label} training"), f"training_{safe}.png")
                sections.append(_Section(f"Training graph: {label}", images=[(path, f"{label} training")]))
            except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
                sections.append(_Section(f"Training graph: {label}", f"training log unreadable: {exc}"))
    sections.append(_Section("Settings (to reproduce this report)",
                             pre=json.dumps(to_jsonable(settings), indent=2)))

    json_path = out_dir / "evaluation.json"
    _atomic_text(json_path, json.dumps(to_jsonable({
        "title": title, "settings": settings, "failures": failures,
        "evaluations": [ev.to_dict() for ev in evaluations]}), indent=2))
    html_path = out_dir / "report.html"
    md_path = out_dir / "report.md"
    _atomic_text(html_path, _render_html(title, sections, out_dir))
    _atomic_text(md_path, _render_markdown(title, sections, out_dir))
    return ReportPaths(html_path, md_path, json_path, written)


# -- rendering ------------------------------------------------------------------------------
def _fmt(value) -> str:
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            return "–"
        a = abs(value)
        if a != 0 and (a < 1e-3 or a >= 1e5):
            return f"{value:.3e}"
        if a < 1:
            return f"{value:.4g}"
        return f"{value:.3f}".rstrip("0").rstrip(".")  # keeps the thesis' three decimals
    return str(value)


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:0.85em;margin:0.8em 0}
th,td{border:1px solid #bbb;padding:3px 7px;text-align:right}th{background:#eee}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:0.85em;color:#555}pre{background:#f6f6f6;padding:1em;overflow-x:auto;font-size:0.8em}
"""


def _render_html(title: str, sections: list[_Section], out_dir: Path) -> str:
    parts = [f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec.title)}</h2>")
        if sec.text:
            parts.append(f"<p>{html.escape(sec.text)}</p>")
        if sec.table is not None:
            t = sec.table
            parts.append("<table><thead><tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in t.columns)
                         + "</tr></thead><tbody>")
            for row in t.itertuples(index=False):
                parts.append("<tr>" + "".join(
                    f"<td>{html.escape(_fmt(v))}</td>" if isinstance(v, (int, float, np.number))
                    else f"<td style='text-align:left'>{html.escape(_fmt(v))}</td>" for v in row) + "</tr>")
            parts.append("</tbody></table>")
        for path, caption in sec.images:
            data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
            rel = Path(path).relative_to(out_dir).as_posix()
            parts.append(f"<figure><img src='data:image/png;base64,{data}' alt='{html.escape(caption)}' "
                         f"data-file='{html.escape(rel)}'><figcaption>{html.escape(caption)}</figcaption></figure>")
        if sec.pre is not None:
            parts.append(f"<pre>{html.escape(sec.pre, quote=False)}</pre>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def _render_markdown(title: str, sections: list[_Section], out_dir: Path) -> str:
    lines = [f"# {title}", ""]
    for sec in sections:
        lines += [f"## {sec.title}", ""]
        if sec.text:
            lines += [sec.text, ""]
        if sec.table is not None:
            t = sec.table
            lines.append("| " + " | ".join(str(c) for c in t.columns) + " |")
            lines.append("|" + "|".join("---" for _ in t.columns) + "|")
            for row in t.itertuples(index=False):
                lines.append("| " + " | ".join(_fmt(v).replace("|", "\\|") for v in row) + " |")
            lines.append("")
        for path, caption in sec.images:
            lines += [f"![{caption}]({Path(path).relative_to(out_dir).as_posix()})", ""]
        if sec.pre is not None:
            lines += ["```json", sec.pre, "```", ""]
    return "\n".join(lines)


def _atomic_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # private: concurrent runs never share it
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
