"""``excavator-payload train``, ``estimate`` and ``estimators``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from excavator_payload.data.io import read_dataset, write_estimates
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import (
    ESTIMATOR_MODULES,
    create_estimator,
    estimator_class,
    load_estimator,
)

console = Console()


def parse_extra_options(args: list[str], name: str) -> dict[str, str]:
    """``["--tuning", "thesis", "--flag"]`` -> ``{"tuning": "thesis", "flag": "true"}``."""
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


def register(app: typer.Typer) -> None:
    @app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
    def train(
        ctx: typer.Context,
        name: str = typer.Argument(..., help=f"Estimator: {', '.join(ESTIMATOR_MODULES)}."),
        data: Path = typer.Option(..., "--data", help="Training / calibration dataset (Parquet)."),
        out: Path = typer.Option(..., "--out", help="Folder to save the fitted estimator in."),
        machine: str = typer.Option(None, "--machine",
                                    help="Machine the estimator believes in: preset name or TOML file "
                                         "(default: the dataset's machine)."),
    ) -> None:
        """Fit or train an estimator and save it. Estimator options follow as --name value
        (see `excavator-payload estimators NAME`)."""
        klass = estimator_class(name)
        options = parse_extra_options(list(ctx.args), name)
        dataset = read_dataset(data)
        if machine is None and klass.NEEDS_MACHINE:
            machine = dataset.machine() or "cat345c"
        est = create_estimator(name, machine=machine, **options)
        console.print(f"training [bold]{name}[/bold] on {dataset}")
        est.fit(dataset)
        est.save(out)
        console.print(f"saved to [bold]{out}[/bold]")

    @app.command()
    def estimate(
        model: Path = typer.Option(..., "--model", help="Folder of a saved estimator."),
        data: Path = typer.Option(..., "--data", help="Dataset to estimate on (Parquet)."),
        out: Path = typer.Option(..., "--out", help="Estimates file to write (Parquet)."),
    ) -> None:
        """Estimate the payload at every sample: writes experiment, time, payload_estimate, status."""
        est = load_estimator(model)
        dataset = read_dataset(data)
        frame = est.estimate(dataset)
        write_estimates(frame, out, meta={"estimator": est.name, "model": str(model),
                                          "data": str(data)})
        n_ok = int((frame["status"] == "ok").sum())
        console.print(f"{est.name}: {len(frame)} estimates ({n_ok} ok) written to [bold]{out}[/bold]")

    @app.command()
    def estimators(name: str = typer.Argument(None, help="Show the options of this estimator.")) -> None:
        """List the estimators, or the options of one."""
        if name is None:
            for n in ESTIMATOR_MODULES:
                console.print(n)
            return
        klass = estimator_class(name)
        table = Table(title=f"{name} options")
        for col in ("option", "type", "default", "help"):
            table.add_column(col)
        for key, opt in klass.OPTIONS.items():
            choices = f" ({'|'.join(map(str, opt.choices))})" if opt.choices else ""
            table.add_row("--" + key.replace("_", "-"), opt.type.__name__, repr(opt.default), opt.help + choices)
        console.print(table)
