"""The headline figures of evaluations as a console table."""

from __future__ import annotations

import math
from typing import Sequence

from rich import box
from rich.console import Console
from rich.table import Table
from rich.text import Text

from excavator_payload.evaluation.metrics import Evaluation


def summary_table(evaluations: Sequence[Evaluation], title: str = "Payload accuracy",
                  width: int | None = None) -> Table:
    """A rich table of the headline figures.

    On a terminal narrower than 110 columns only the essential columns are shown (numbers are
    never cut short); the full set is in ``--json`` and the report.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One row each, in this order, labelled by ``Evaluation.label``.
    title : str
        Title shown above the table.
    width : int, optional
        Terminal width in columns that decides the compact layout; default the console's.

    Returns
    -------
    rich.table.Table
        The table, with a caption explaining its columns.
    """
    width = Console().width if width is None else width
    compact = width < 110
    columns = [("estimator", "estimator"), ("MAX", "mean_max"), ("±", "std_max"), ("RMS", "mean_rms"),
               ("±", "std_rms"), ("MAX%", "mean_max_pct"), ("p95", "mean_p95"),
               ("≤1%", "meets_requirement_share"), ("conv", "mean_convergence_time"),
               ("eff", "efficiency"), ("est", "estimated_share")]
    if compact:
        columns = [c for c in columns if c[1] in ("estimator", "mean_max", "std_max", "mean_rms",
                                                  "meets_requirement_share", "efficiency")]
    legend = {"MAX": "MAX, RMS: mean over experiments (kg), ± their std",
              "MAX%": "MAX%: of the rated payload", "p95": "p95: of |error| (kg)",
              "≤1%": "≤1%: share of experiments with MAX ≤ 1 % of rated",
              "conv": "conv: convergence time (s)", "eff": "eff: RMS of error/Cramér–Rao bound",
              "est": "est: judged samples with an estimate"}
    caption = "; ".join(legend[c] for c, _ in columns if c in legend)
    table = Table(title=Text(title), box=box.SIMPLE_HEAD, pad_edge=False, caption=caption)
    for col, _ in columns:
        table.add_column(col, justify="left" if col == "estimator" else "right", no_wrap=True)

    formats = {"mean_max_pct": "{:.2g}", "meets_requirement_share": "{:.0%}",
               "mean_convergence_time": "{:.2f}", "estimated_share": "{:.0%}"}

    def f(x, fmt="{:.3g}"):
        return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)

    for ev in evaluations:
        s = ev.summary
        table.add_row(*[Text(ev.label) if key == "estimator" else f(s.get(key), formats.get(key, "{:.3g}"))
                        for _, key in columns])
    return table
