"""``excavator-payload loadout``: a shift's passes and trucks weighed, shown and recorded
(:mod:`excavator_payload.runtime.loadout`)."""

from __future__ import annotations

import math
from pathlib import Path

import typer
from rich.console import Console

from excavator_payload.errors import DatasetError

console = Console()


def register(app: typer.Typer) -> None:
    """Add ``loadout`` to ``app``."""

    @app.command("loadout")
    def loadout(
        model: Path = typer.Option(..., "--model", help="Saved estimator folder (calibrated and zeroed).",
                                   metavar="DIR"),
        data: Path = typer.Option(..., "--data", help="Dataset of the shift (Parquet): each experiment one "
                                  "truck, or a log split at gaps of 30 s or more."),
        db: Path = typer.Option(..., "--db", help="SQLite shift record to append to (created if missing); "
                                "rerunning the same data replaces its rows, never doubles them."),
        target: float = typer.Option(None, "--target", metavar="KG",
                                     help="Each truck's target load (default: the data's, if it has one)."),
        out: Path = typer.Option(None, "--out", help="Also write every pass to this Parquet file."),
    ) -> None:
        """Weigh every bucket pass before its dump, total each truck against its target, record the shift."""
        from excavator_payload.data.io import check_output_path, read_dataset
        from excavator_payload.estimators.base import load_estimator
        from excavator_payload.runtime.loadout import (
            ShiftRecord, file_key, passes_frame, run_loadout, truck_table)

        if target is not None and not (math.isfinite(target) and target > 0):
            raise DatasetError(f"--target must be a mass above 0 kg, got {target:g}")
        if out is not None:
            if out.suffix.lower() != ".parquet":
                raise DatasetError(f"--out must end in .parquet, got '{out.name}'")
            check_output_path(out, inputs=[data, db])
        if db.exists() and db.resolve() == Path(data).resolve():
            raise DatasetError("--db would overwrite the dataset")
        estimator = load_estimator(model)
        dataset = read_dataset(data)
        if dataset.sensor_set.name != "machine":
            raise DatasetError(f"loadout weighs the machine sensor set's passes; {data} holds the "
                               f"{dataset.sensor_set.name} set")
        record = ShiftRecord(db)

        def show(truck):
            console.print(truck_table(truck))
            line = f"truck {truck.truck}: {len(truck.passes)} passes, total {truck.total:,.0f} kg"
            if truck.target is not None:
                line += f" of {truck.target:,.0f} kg target ({truck.target - truck.total:,.0f} kg left)"
            if truck.unweighed:
                line += f"; {truck.unweighed} pass(es) not weighed"
            console.print(line)

        try:
            trucks = run_loadout(estimator, dataset, record, file_key(data), target, on_truck=show,
                                 data_name=str(data), model_name=str(model))
        finally:
            record.close()
        n_pass = sum(len(t.passes) for t in trucks)
        n_bad = sum(t.unweighed for t in trucks)
        console.print(f"{len(trucks)} trucks, {n_pass} passes ({n_bad} not weighed), "
                      f"{sum(t.total for t in trucks):,.0f} kg; recorded in {db}")
        if out is not None:
            frame = passes_frame(trucks)
            tmp = out.with_name(f".{out.name}.tmp")
            frame.to_parquet(tmp, index=False)
            tmp.replace(out)
            console.print(f"passes written to {out}")
