"""A finished study's report: results pooled over seeds, heat maps over the grid's axes and
the error against each axis, in ``report.html``."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from excavator_payload import __version__
from excavator_payload.evaluation.study_file import Study


# -- the report ---------------------------------------------------------------------------------
def pooled(frame: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Figures per group: experiments, mean MAX, mean RMS (kg), share within 1 % of rated,
    pooled efficiency (RMS of error / bound over every judged sample).

    Parameters
    ----------
    frame : pandas.DataFrame
        Per-experiment results (``results.parquet``'s columns).
    by : list of str
        Columns to group by (axes of the grid).

    Returns
    -------
    pandas.DataFrame
        One row per group: ``by`` and ``experiments``, ``mean_max_kg``, ``mean_rms_kg``,
        ``worst_max_kg``, ``within_1pct`` (share), ``efficiency``.
    """
    def figures(g: pd.DataFrame) -> pd.Series:
        n_eff = g["n_efficiency"].sum()
        return pd.Series({
            "experiments": len(g),
            "mean_max_kg": g["max_error"].mean(),
            "mean_rms_kg": g["rms_error"].mean(),
            "worst_max_kg": g["max_error"].max(),
            "within_1pct": g["within_1pct"].astype(float).mean(),
            "efficiency": math.sqrt(g["sum_sq_efficiency"].sum() / n_eff) if n_eff else math.nan,
        })

    return frame.groupby(by, sort=False).apply(figures, include_groups=False).reset_index()


def _axis_order(study: Study, axis: str, present) -> list:
    order = [v for v in study.axes.get(axis, []) if v in set(present)]
    return order + [v for v in present if v not in order]


def _heatmap(table: pd.DataFrame, study: Study, value: str, title: str, fmt, cmap: str, log: bool = False):
    import matplotlib.colors as mcolors

    from excavator_payload.evaluation.figures import plt

    rows = _axis_order(study, study.rows, table[study.rows].unique())
    cols = _axis_order(study, study.columns, table[study.columns].unique())
    grid = table.pivot(index=study.rows, columns=study.columns, values=value).reindex(index=rows, columns=cols)
    data = grid.to_numpy(float)
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(cols), 1.0 + 0.45 * len(rows)))
    finite = data[np.isfinite(data)]
    norm = None
    if log and len(finite) and finite.min() > 0:
        norm = mcolors.LogNorm(vmin=finite.min(), vmax=max(finite.max(), finite.min() * 1.01))
    image = ax.imshow(np.ma.masked_invalid(data), aspect="auto", cmap=cmap, norm=norm,
                      **({} if norm is not None else {"vmin": 0.0, "vmax": 1.0} if value == "within_1pct" else {}))
    ax.set_xticks(range(len(cols)), [str(c) for c in cols], rotation=30, ha="right")
    ax.set_yticks(range(len(rows)), [str(r) for r in rows])
    ax.set_xlabel(study.columns)
    ax.set_ylabel(study.rows)
    for i in range(len(rows)):
        for j in range(len(cols)):
            v = data[i, j]
            ax.text(j, i, "–" if not np.isfinite(v) else fmt(v), ha="center", va="center", fontsize=8,
                    color="black", bbox={"facecolor": "white", "alpha": 0.6, "lw": 0, "pad": 1})
    fig.colorbar(image, ax=ax, fraction=0.04)
    ax.set_title(title, fontsize=10)
    return fig


def _error_against(results: pd.DataFrame, study: Study, axis: str):
    from excavator_payload.evaluation.figures import MARKERS, plt

    table = pooled(results, ["estimator", axis])
    values = _axis_order(study, axis, table[axis].unique())
    numeric = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values)
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for i, (label, g) in enumerate(table.groupby("estimator", sort=False)):
        g = g.set_index(axis).reindex(values)
        x = np.array(values, float) if numeric else np.arange(len(values))
        ax.plot(x, g["mean_rms_kg"].to_numpy(float), marker=MARKERS[i % len(MARKERS)], label=str(label))
    if not numeric:
        ax.set_xticks(range(len(values)), [str(v) for v in values])
    ax.set_yscale("log")
    ax.set_xlabel(axis)
    ax.set_ylabel("mean RMS error (kg)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f"error against {axis} (other axes pooled)", fontsize=10)
    return fig


def build_study_report(study: Study, results: pd.DataFrame, out_dir: Path, failures: dict | None = None,
                       timings: dict | None = None) -> Path:
    """``out_dir/report.html`` (figures embedded, PNGs in ``figures/`` beside it) and
    ``report.md``; returns the HTML path.

    Parameters
    ----------
    study : Study
        The study (its axes order the heatmaps).
    results : pandas.DataFrame
        Per-experiment results of the finished cells (may be empty).
    out_dir : Path
        Report folder; its ``figures/`` is replaced.
    failures : dict, optional
        Cell description -> reason it failed (shown).
    timings : dict, optional
        Stage -> seconds, shown in the settings.
    """
    from excavator_payload.evaluation import figures
    from excavator_payload.evaluation.report import _atomic_text, _render_html, _render_markdown, _Section

    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    shutil.rmtree(fig_dir, ignore_errors=True)
    fig_dir.mkdir(parents=True, exist_ok=True)
    sections = [_Section("Study", text=(study.description + " " if study.description else "")
                         + f"{len(study.cells)} cells from {study.source}; errors judged after the first "
                         f"{study.cells[0].discard} samples of every test experiment. Efficiency: RMS of "
                         "(error ÷ Cramér–Rao bound) over every judged sample, 1 = the physical limit for "
                         "the information the estimator uses; within 1 %: share of test experiments whose "
                         "MAX error is ≤ 1 % of the rated payload.")]
    if len(results):
        by = list(dict.fromkeys(["estimator", study.rows, study.columns]))
        table = pooled(results, by)
        eff = _heatmap(table, study, "efficiency", f"efficiency (1 = Cramér–Rao bound) by {study.rows} × "
                       f"{study.columns}", lambda v: f"{v:.3g}", "viridis_r", log=True)
        within = _heatmap(table, study, "within_1pct", f"share within 1 % of rated by {study.rows} × "
                          f"{study.columns}", lambda v: f"{100 * v:.0f}%", "RdYlGn")
        images = [(figures.save_png(eff, fig_dir / "heatmap_efficiency.png"), "Efficiency over the grid"),
                  (figures.save_png(within, fig_dir / "heatmap_within_1pct.png"),
                   "Share of test experiments within 1 % of rated payload")]
        sections.append(_Section(f"Heatmaps ({study.rows} × {study.columns})",
                                 text="Axes not shown are pooled.", images=images))
        axis_images = []
        for axis in [a for a in study.axes if a != "estimator" and len(results[a].unique()) > 1]:
            path = figures.save_png(_error_against(results, study, axis), fig_dir / f"error_vs_{axis}.png")
            axis_images.append((path, f"Mean RMS error against {axis}"))
        if axis_images:
            sections.append(_Section("Error against each axis", images=axis_images))
        varying = [a for a in study.axes if a != "estimator" and len(results[a].unique()) > 1]
        summary = pooled(results, ["estimator", *varying])
        summary["within_1pct"] = (100 * summary["within_1pct"]).round(1)
        sections.append(_Section("Every cell", text="within_1pct in %; kg otherwise.", table=summary))
    else:
        sections.append(_Section("No results", text="No cell finished; see the failures below."))
    if failures:
        sections.append(_Section("Failures", table=pd.DataFrame(
            {"cell": list(failures), "reason": list(failures.values())})))
    settings = {"study": study.config, "source": study.source, "version": __version__,
                "timings_s": {k: round(v, 2) for k, v in (timings or {}).items()}}
    sections.append(_Section("Settings", pre=json.dumps(settings, indent=2, default=str)))
    html_path = out_dir / "report.html"
    _atomic_text(html_path, _render_html(f"Study: {study.name}", sections, out_dir))
    _atomic_text(out_dir / "report.md", _render_markdown(f"Study: {study.name}", sections, out_dir))
    return html_path
