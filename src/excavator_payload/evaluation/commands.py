"""``excavator-payload evaluate``, ``report`` and ``demo``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.text import Text

from excavator_payload.errors import DatasetError, EstimatorError
from excavator_payload.platforms.registry import DISCARD_DEFAULT_HELP

# The work (pandas, the data layer, the estimators) is imported by each command when it runs:
# every command, and --help, would pay its seconds at start otherwise.

console = Console()


def register(app: typer.Typer) -> None:
    """Add ``evaluate``, ``report`` and ``demo`` to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application that gains the commands.
    """

    @app.command()
    def evaluate(
        data: Path = typer.Option(..., "--data", help="Test dataset with the true payloads (Parquet)."),
        model: list[Path] = typer.Option([], "--model", help="Saved estimator folder (repeatable).", metavar="DIR"),
        estimates: list[Path] = typer.Option([], "--estimates",
                                             help="Estimates file from `estimate` or another tool: columns "
                                                  "experiment, time, payload_estimate (repeatable).",
                                             metavar="FILE"),
        discard: int = typer.Option(None, "--discard", min=0, show_default=False,
                                    help="Samples not judged at the start of every experiment "
                                         f"({DISCARD_DEFAULT_HELP})."),
        json_out: Path = typer.Option(None, "--json", help="Write every figure to this JSON file."),
        workers: int = typer.Option(0, "--workers",
                                    help="Local worker processes estimating a big dataset (0 = all cores)."),
        scheduler: str = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                      help="Estimate on this existing Dask cluster (default: "
                                           "$EXCAVATOR_PAYLOAD_SCHEDULER, else local worker processes)."),
    ) -> None:
        """Judge estimators on a dataset: MAX/RMS errors (thesis Tables 7.1, 7.2), percentiles, convergence time, share meeting the 1 % requirement, efficiency against the Cramér–Rao bound."""  # noqa: E501
        from excavator_payload.data.io import check_output_path, read_dataset
        from excavator_payload.estimators.running import progress_bar
        from excavator_payload.evaluation.metrics import default_discard
        from excavator_payload.evaluation.sources import evaluate_sources, write_json
        from excavator_payload.evaluation.tables import summary_table
        from excavator_payload.execution import Execution

        if workers < 0:
            raise EstimatorError(f"--workers must be ≥ 0, got {workers}")
        if json_out is not None:
            check_output_path(json_out, inputs=[data, *model, *estimates], option="--json")
        dataset = read_dataset(data)
        if discard is None:
            discard = default_discard(dataset.sensor_set)
        with Execution(scheduler, workers or None) as execution, progress_bar() as progress:
            evaluations = evaluate_sources(dataset, model, estimates, discard, progress, execution)
        console.print(summary_table(evaluations, f"Payload accuracy on {data} "
                                                 f"({dataset.n_experiments} experiments, first {discard} "
                                                 "samples discarded)"))
        for ev in evaluations:
            unjudged = ev.per_experiment.loc[~np.isfinite(ev.per_experiment["max_error"].to_numpy(float)),
                                             "experiment"].tolist()
            if unjudged:
                # an experiment whose every sample was invalid (a NaN-only one) was left out of the
                # means silently while the title counted it
                names = ", ".join(map(str, unjudged[:8])) + (", …" if len(unjudged) > 8 else "")
                console.print(Text.assemble(
                    ("note: ", "bold"), f"{ev.label}: {len(unjudged)} of {len(ev.per_experiment)} experiments have "
                    f"no estimate to judge after the discarded samples (experiment {names}: every sample invalid, "
                    f"missing or NaN?); MAX and RMS are means over the other "
                    f"{len(ev.per_experiment) - len(unjudged)}, ≤1% counts them as failing"))
        dumps = evaluations[0].summary.get("judged_to_the_dump", 0) if evaluations else 0
        if dumps:
            console.print(Text.assemble(
                ("note: ", "bold"), f"{dumps} of {dataset.n_experiments} experiments are work cycles whose "
                "load leaves the bucket at the dump: each is judged up to its dump (the payload column "
                "is the load carried). Only calibrated's momentum form detects a new load by itself "
                "(--new-load); the other sensors weigh one load per experiment or CAN log segment: "
                "restart them for each load (reset(), ep_reset)."))
        if json_out is not None:
            write_json(json_out, {"data": str(data), "discard": discard,
                                  "evaluations": [ev.to_dict() for ev in evaluations]})
            console.print(Text.assemble("figures written to ", (str(json_out), "bold")))

    @app.command()
    def report(
        data: Path = typer.Option(None, "--data", help="Test dataset with the true payloads (Parquet)."),
        out: Path = typer.Option(..., "--out", help="Folder to write report.html, report.md and figures/ in "
                                 "(with --db: shift.md and pass_weights.png)."),
        db: Path = typer.Option(None, "--db", help="A shift record of `loadout --db`: write a shift report "
                                "(passes, trucks, totals, histogram of pass weights) instead."),
        rated: float = typer.Option(None, "--rated", metavar="KG",
                                    help="With --db: the rated payload to count passes within 1 % of (default: the recorded model's)."),
        kept: Path = typer.Option(None, "--kept", metavar="FILE",
                                  help="With --db: a live shift's kept trucks (the file its last line named) to "
                                  "take into the record first; <db>.unsaved.json beside it is taken in unasked."),
        model: list[Path] = typer.Option([], "--model", help="Saved estimator folder (repeatable).", metavar="DIR"),
        estimates: list[Path] = typer.Option([], "--estimates", help="Estimates file (repeatable).",
                                             metavar="FILE"),
        discard: int = typer.Option(None, "--discard", min=0, show_default=False,
                                    help="Samples not judged at the start of every experiment "
                                         f"({DISCARD_DEFAULT_HELP})."),
        experiments: str = typer.Option(None, "--experiments",
                                        help="Experiments to plot like thesis Figures 7.1–7.12, e.g. '3,17,42' "
                                             "(default: six spread over the payload range)."),
        calibration: Path = typer.Option(None, "--calibration-curve",
                                         help="CSV of the calibrated estimator's accuracy against the number "
                                              "of calibration experiments."),
        title: str = typer.Option("excavator-payload evaluation", "--title", help="Report title."),
        workers: int = typer.Option(0, "--workers",
                                    help="Local worker processes estimating a big dataset (0 = all cores)."),
        scheduler: str = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                      help="Estimate on this existing Dask cluster (default: "
                                           "$EXCAVATOR_PAYLOAD_SCHEDULER, else local worker processes)."),
    ) -> None:
        """Write a self-contained HTML report (and Markdown) with tables and figures."""
        import pandas as pd

        from excavator_payload.data.io import check_output_path, read_dataset
        from excavator_payload.estimators.running import progress_bar
        from excavator_payload.evaluation.metrics import default_discard
        from excavator_payload.evaluation.report import build_report
        from excavator_payload.evaluation.sources import evaluate_sources
        from excavator_payload.evaluation.tables import summary_table
        from excavator_payload.execution import Execution

        if workers < 0:
            raise EstimatorError(f"--workers must be ≥ 0, got {workers}")
        if db is not None:
            from excavator_payload.runtime.loadout import write_shift_report
            from excavator_payload.runtime.shift_record import open_record, unsaved_beside

            if data is not None or model or estimates:
                raise DatasetError("--db writes a shift report from the record alone; it does not go "
                                   "with --data, --model or --estimates")
            if rated is not None and not (math.isfinite(rated) and rated > 0):
                raise DatasetError(f"--rated must be a mass above 0 kg, got {rated:g}")
            check_output_path(out, inputs=[db], kind="folder", replaces=("shift.md", "pass_weights.png"))
            if kept is not None or unsaved_beside(db).is_file():
                if not db.is_file():
                    raise DatasetError(f"--db '{db}' does not exist")
                try:
                    open_record(db, kept, say=lambda line: console.print(line, markup=False, highlight=False)).close()
                except DatasetError as exc:
                    if kept is not None:
                        raise
                    # the file beside a record that cannot take it (read-only): report what is in it
                    typer.echo(f"warning: {exc}; the report shows the record without the kept trucks", err=True)
            md = write_shift_report(db, out, rated)
            console.print(Text.assemble("shift report: ", (str(md), "bold")))
            return
        if kept is not None:
            raise DatasetError("--kept goes with --db (a shift record)")
        if data is None:
            raise DatasetError("report needs --data (an evaluation) or --db (a shift report)")

        check_output_path(out, inputs=[data, *model, *estimates, calibration], kind="folder",
                          replaces=("report.html", "report.md", "evaluation.json", "figures"))
        dataset = read_dataset(data)
        if discard is None:
            discard = default_discard(dataset.sensor_set)
        chosen = None
        if experiments:
            try:
                chosen = [int(x) for x in experiments.split(",") if x.strip()]
            except ValueError:
                raise DatasetError(f"--experiments: {experiments!r} is not a comma-separated list of numbers") from None
            unknown = sorted(set(chosen) - {int(i) for i in dataset.experiment_ids})
            if unknown:
                raise DatasetError(f"--experiments: {unknown} not in {data}")
        curve = None
        if calibration is not None:
            if not calibration.is_file():
                from excavator_payload.textfiles import not_a_file

                raise DatasetError(not_a_file(calibration, "calibration curve file"))
            try:
                curve = pd.read_csv(calibration)
            except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
                raise DatasetError(f"'{calibration}' is not a readable CSV: {exc}") from None
        with Execution(scheduler, workers or None) as execution, progress_bar() as progress:
            evaluations = evaluate_sources(dataset, model, estimates, discard, progress, execution)
        training = {ev.label: Path(ev.info["model"]) for ev in evaluations if ev.info.get("model")
                    and ((Path(ev.info["model"]) / "training.png").is_file()
                         or (Path(ev.info["model"]) / "training_log.csv").is_file())}
        settings = {"data": str(data), "data_meta": {k: v for k, v in dataset.meta.items() if k != "experiments"},
                    "models": [str(m) for m in model], "estimates": [str(e) for e in estimates],
                    "discard": discard}
        paths = build_report(out, dataset, evaluations, title=title, settings=settings, experiments=chosen,
                             calibration=curve, training_dirs=training)
        console.print(summary_table(evaluations))
        console.print(Text.assemble("report: ", (str(paths.html), "bold"), f" (Markdown: {paths.markdown})"))

    @app.command()
    def demo(
        out: Path = typer.Option(Path("excavator-payload-demo"), "--out",
                                 help="Folder for datasets, models, cache and the report."),
        scale: str = typer.Option("quick", "--scale",
                                  help="quick (≈6 min on 2 cores), thesis (the thesis' full sizes) "
                                       "or tiny (seconds; for tests)."),
        workers: int = typer.Option(None, "--workers", min=1, help="Simulation worker processes (default: all cores)."),
        motion: str = typer.Option("nmpc", "--motion",
                                   help="Motion generator: nmpc (the thesis') or minimum-jerk (fast)."),
        seed: int = typer.Option(2024, "--seed", help="Base seed of all simulated data."),
        only: str = typer.Option(None, "--only",
                                 help="Comma-separated estimator labels to run (default: all), e.g. 'Net1,EKF_ideal'."),
        machine: str = typer.Option(None, "--machine",
                                    help="A hydraulic machine (e.g. cat345c-hydraulic): the calibrate → zero → "
                                         "weigh study on the machine sensor set instead of the thesis'."),
    ) -> None:
        """Simulate, fit every estimator, evaluate and write the report: the thesis end to end."""
        if machine is not None:  # issue 12: the study on the hydraulic machine
            from excavator_payload.evaluation.demo_machine import run_machine_demo

            run_machine_demo(out, machine=machine, scale=scale, seed=seed, console=console)
            return
        from excavator_payload.data.io import check_output_path
        from excavator_payload.evaluation.demo import run_demo

        check_output_path(out, kind="folder")
        if not 0 <= seed < 2**63:
            raise DatasetError(f"--seed must be in 0 … 2⁶³−1, got {seed}")
        run_demo(out, scale=scale, workers=workers, motion=motion, seed=seed,
                 only=[s.strip() for s in only.split(",")] if only else None, console=console)
