"""``excavator-payload study``: a declarative grid of estimators × data conditions."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer
from rich.console import Console

from excavator_payload.errors import ExcavatorPayloadError

console = Console(stderr=True)


def register(app: typer.Typer) -> None:
    """Add the ``study`` command to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application that gains the command.
    """

    @app.command("study")
    def study(
        config: str = typer.Option(..., "--config",
                                   help="Study file (TOML), or the name of a shipped study "
                                        "(full_grid, network_robustness, calibration_curve, frozen_noise)."),
        out: Path = typer.Option(..., "--out", help="Output folder: results.parquet, report/, caches."),
        scheduler: str = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                      help="Run on this existing Dask cluster (default: $EXCAVATOR_PAYLOAD_SCHEDULER, "
                                           "else local worker processes)."),
        workers: int = typer.Option(0, "--workers", help="Local worker processes (0 = all cores)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
        yes: bool = typer.Option(False, "--yes", help="Start a big study without asking (more than "
                                 "2000 cells or 100 000 experiments)."),
    ) -> None:
        """Run a study: every cell of the grid simulated, fitted, estimated and judged; one Parquet of
        per-experiment results and a report page. Cells already computed in OUT are reused."""
        from excavator_payload.evaluation.study import (
            CONFIRM_CELLS,
            CONFIRM_EXPERIMENTS,
            load_study,
            run_study,
            study_experiments,
            study_size,
        )
        from excavator_payload.execution import Execution, interrupted_message

        if workers < 0:
            raise ExcavatorPayloadError(f"--workers must be ≥ 0, got {workers}")
        plan = load_study(config)
        # the size, said before anything starts (10⁹ experiments started without a word)
        console.print(study_size(plan), markup=False, highlight=False, soft_wrap=True)
        experiments = study_experiments(plan)
        if (len(plan.cells) > CONFIRM_CELLS or experiments > CONFIRM_EXPERIMENTS) and not yes:
            if not sys.stdin.isatty():
                raise ExcavatorPayloadError(f"a study of {len(plan.cells):,} cells and {experiments:,} experiments "
                                            f"is big (asked before more than {CONFIRM_CELLS:,} cells or "
                                            f"{CONFIRM_EXPERIMENTS:,} experiments): add --yes to start it")
            if not typer.confirm("start it?", default=False, err=True):
                raise typer.Exit(1)
        start = time.perf_counter()
        try:
            with Execution(scheduler, workers or None) as execution:
                result = run_study(plan, out, execution, progress=not quiet, console=console)
        except KeyboardInterrupt:
            console.print(interrupted_message(f"finished cells are kept in {out}/cells/; "
                                              "rerun the same command to resume"), soft_wrap=True)
            raise typer.Exit(130) from None
        typer.echo(f"{result['cells']} cells: {result['computed']} computed, {result['reused']} reused, "
                   f"{len(result['failures'])} failed")
        for cell, reason in list(result["failures"].items())[:10]:
            typer.echo(f"  failed {cell}: {reason}")
        if result["results"] is not None:
            typer.echo(f"results: {result['results']}")
        typer.echo(f"report: {result['report']}")
        typer.echo(f"wall time {time.perf_counter() - start:.1f} s")
