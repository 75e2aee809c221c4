"""``excavator-payload train``, ``estimate`` and ``estimators``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.text import Text
from typer.core import TyperCommand

from excavator_payload.errors import EstimatorError

# The estimators, pandas and the data layer are imported by the commands that use them, not
# here: every command (and --help) would pay their seconds at start.

console = Console()


class _TrainCommand(TyperCommand):
    """``train``: the estimator names in its help are read from the registry when the help is
    shown, not when the command is registered."""

    def format_help(self, ctx, formatter) -> None:
        from excavator_payload.estimators.base import ESTIMATOR_MODULES

        for param in self.params:
            if param.name == "name":
                param.help = f"Estimator: {', '.join(ESTIMATOR_MODULES)}."
        super().format_help(ctx, formatter)


def parse_extra_options(args: list[str], name: str) -> dict[str, str]:
    """``["--tuning", "thesis", "--flag"]`` -> ``{"tuning": "thesis", "flag": "true"}``.

    Parameters
    ----------
    args : list of str
        The extra command-line arguments after ``train NAME``.
    name : str
        Estimator name, for error messages.

    Returns
    -------
    dict of str to str
        Option name (underscores) -> raw text (``"true"`` for a bare flag).
    """
    options: dict[str, str] = {}
    i = 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--"):
            raise EstimatorError(f"{name}: unexpected argument {arg!r} (options look like --name value)")
        key = arg[2:]
        if "=" in key:
            key, value = key.split("=", 1)
            i += 1
        elif i + 1 < len(args) and not args[i + 1].startswith("--"):
            value = args[i + 1]
            i += 2
        else:
            value = "true"
            i += 1
        options[key.replace("-", "_")] = value
    return options


#: What each non-``ok`` status of an estimates file means (printed by ``estimate``).
STATUS_MEANING = {
    "warming_up": "not enough samples yet (estimate not trusted)",
    "no_data": "no usable sample yet",
    "gap": "time jumped; the estimator bridged the hole or restarted",
    "invalid_input": "a signal was missing, NaN or infinite; sample not used",
    "out_of_range": "a signal outside its plausible range (machine file); sample not used",
    "rejected_outlier": "inconsistent with the noise model; sample not used, estimate kept",
    "reinitialised": "too many rejections in a row; the estimator restarted",
    "state_reset": "the estimator's state went non-finite; it restarted",
    "implausible": "below -10 % or above 150 % of the rated payload: not physical (signal map, units?)",
    "stale": "a signal is older than its period allows (a sensor fell silent); named in stale_signals",
    "load_changing": "the load is changing (a dump or a fill): the estimate is the load before, not now",
    "sensor_fault": "a sensor is stuck, dropped out or disagrees with its redundancy (named in the fault "
                    "column); sample not used, estimate kept, never ok (a cylinder's pressures off its "
                    "joint's balance, 'balance': weighed without that joint, or none)",
    "degraded": "weighed without a faulty sensor (named in the fault column): a link's rate replaced by "
                "its differentiated angle, sigma widened; not ok",
}


def status_breakdown(status) -> str:
    """``"960 ok, 50 warming_up"``: how many estimates have each status, most common first.

    Parameters
    ----------
    status : pandas.Series
        The ``status`` column of an estimates frame.

    Returns
    -------
    str
        The counts, comma-separated.
    """
    return counts_breakdown(status.value_counts())


def counts_breakdown(counts) -> str:
    """``"960 ok, 50 warming_up"`` from counts per status, most common first (ties in the
    order given).

    Parameters
    ----------
    counts : mapping of str to int
        Estimates per status (a ``value_counts()`` or a :class:`collections.Counter`).
    """
    return ", ".join(f"{int(n)} {name}" for name, n in sorted(counts.items(), key=lambda kv: -kv[1]))


def register(app: typer.Typer) -> None:
    """Add ``train``, ``estimate`` and ``estimators`` to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application.
    """

    @app.command(cls=_TrainCommand, context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
    def train(
        ctx: typer.Context,
        name: str = typer.Argument(..., help="Estimator (listed by `excavator-payload estimators`)."),
        data: Path = typer.Option(..., "--data", help="Training / calibration dataset (Parquet).",
                                  metavar="FILE"),
        out: Path = typer.Option(..., "--out", help="Folder to save the fitted estimator in.",
                                 metavar="DIR"),
        machine: str = typer.Option(None, "--machine",
                                    help="Machine the estimator believes in: preset name or TOML file "
                                         "(default: the dataset's machine).", metavar="NAME|FILE"),
        force: bool = typer.Option(False, "--force",
                                   help="Save a fit that says it would weigh worse than 1 % of rated."),
    ) -> None:
        """Fit or train an estimator and save it. Estimator options follow as --name value
        (see `excavator-payload estimators NAME`)."""
        from excavator_payload.data.io import check_output_path, read_dataset
        from excavator_payload.estimators.base import create_estimator, estimator_class

        klass = estimator_class(name)
        options = parse_extra_options(list(ctx.args), name)
        # Everything that can be wrong is checked before minutes of training.
        check_output_path(out, inputs=[data] + ([machine] if machine and Path(machine).exists() else []),
                          kind="folder", replaces=("estimator.json", "arrays.npz", "training_log.csv",
                                                   "training.png"))
        dataset = read_dataset(data, machine=machine)  # swapped chambers judged on the believed machine
        if machine is None and klass.NEEDS_MACHINE:
            machine = dataset.machine() or "cat345c"
        est = create_estimator(name, machine=machine, **options)
        console.print(Text.assemble("training ", (name, "bold"), f" on {dataset}"))
        est.fit(dataset)
        for warning in est.fit_warnings:
            console.print(Text.assemble(("warning: ", "bold yellow"), warning))
        for line in est.fit_report:
            console.print(line, markup=False, highlight=False)
        if est.fit_refusals and not force:
            for reason in est.fit_refusals:
                console.print(Text.assemble(("refused: ", "bold red"), reason))
            raise EstimatorError(f"{name}: not saved, it would weigh worse than 1 % of rated (above); "
                                 "train again with --force to save it anyway")
        for reason in est.fit_refusals:
            console.print(Text.assemble(("warning: ", "bold yellow"), reason, " (saved: --force)"))
        est.save(out)
        console.print(Text.assemble("saved to ", (str(out), "bold")))

    @app.command()
    def estimate(
        model: Path = typer.Option(..., "--model", help="Folder of a saved estimator.", metavar="DIR"),
        data: Path = typer.Option(..., "--data", help="Dataset to estimate on (Parquet; the true "
                                  "payload column is not needed).", metavar="FILE"),
        out: Path = typer.Option(..., "--out", help="Estimates file to write (Parquet).", metavar="FILE"),
        workers: int = typer.Option(0, "--workers",
                                    help="Local worker processes for a big dataset (0 = all cores). The "
                                         "estimates do not depend on it."),
        scheduler: str = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                      help="Run on this existing Dask cluster (default: $EXCAVATOR_PAYLOAD_SCHEDULER, "
                                           "else local worker processes)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Estimate the payload at every sample: writes experiment, time, payload_estimate, status
        and sigma (one-sigma uncertainty, kg). A big dataset (more than ~10 s of work) is split by
        experiment over worker processes (or --scheduler's cluster); a small one is estimated here."""
        from excavator_payload.data.io import PARQUET_SUFFIXES, check_output_path, read_dataset, write_estimates
        from excavator_payload.estimators.base import load_estimator
        from excavator_payload.estimators.running import estimate_in_chunks, progress_bar
        from excavator_payload.execution import Execution

        if workers < 0:
            raise EstimatorError(f"--workers must be ≥ 0, got {workers}")
        check_output_path(out, inputs=[data, model], suffixes=PARQUET_SUFFIXES)
        est = load_estimator(model)
        dataset = read_dataset(data, machine=est.machine)
        with Execution(scheduler, workers or None) as execution, progress_bar(console) as progress:
            frame = estimate_in_chunks(est, dataset, None if quiet else progress, f"{est.name}: estimating",
                                       execution=execution)
        write_estimates(frame, out, meta={"estimator": est.name, "model": str(model),
                                          "data": str(data), "data_fingerprint": dataset.fingerprint()})
        console.print(Text.assemble(f"{est.name}: {len(frame)} estimates ({status_breakdown(frame['status'])}) "
                                    "written to ", (str(out), "bold")))
        seen = [status for status in STATUS_MEANING if (frame["status"] == status).any()]
        if seen:
            console.print("; ".join(f"{status}: {STATUS_MEANING[status]}" for status in seen),
                          markup=False, highlight=False)
        for note in est.all_estimate_notes(dataset, frame):
            console.print(Text.assemble(("note: ", "bold"), note))

    @app.command()
    def estimators(name: str = typer.Argument(None, help="Show the options of this estimator.")) -> None:
        """List the estimators, or the options of one."""
        from rich.table import Table

        from excavator_payload.estimators.base import ESTIMATOR_MODULES, estimator_class

        if name is None:
            for n in ESTIMATOR_MODULES:
                console.print(n)
            return
        klass = estimator_class(name)
        table = Table(title=f"{name} options")  # option help is plain text, not markup
        for col in ("option", "type", "default", "help"):
            table.add_column(col)
        for key, opt in klass.OPTIONS.items():
            choices = f" ({'|'.join(map(str, opt.choices))})" if opt.choices else ""
            table.add_row("--" + key.replace("_", "-"), opt.type.__name__, Text(repr(opt.default)),
                          Text(opt.help + choices))
        console.print(table)
