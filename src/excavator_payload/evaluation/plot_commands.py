"""``excavator-payload plot``: one experiment of a machine-sensor-set dataset in a figure."""

from __future__ import annotations

from pathlib import Path

import typer

from excavator_payload.errors import DatasetError
from excavator_payload.platforms import HYDRAULIC, platform_for


def plot_experiment(dataset, experiment: int, out: str | Path) -> Path:
    """Angles, slew, house inclination and cylinder pressures of one experiment (PNG/PDF/SVG),
    :func:`excavator_payload.evaluation.figures.machine_measurements`.

    Parameters
    ----------
    dataset : Dataset
        Data of the hydraulic machine's sensor set.
    experiment : int
        Number of the experiment to draw; must be in the dataset.
    out : str or Path
        Figure file; the suffix picks the format. Written atomically, folders created.

    Returns
    -------
    Path
        The file written.
    """
    from excavator_payload.evaluation.figures import machine_measurements

    if platform_for(dataset) is not HYDRAULIC:  # the figure draws cylinders and a slewing house
        raise DatasetError(f"plot shows machine-sensor-set data; this dataset holds the "
                           f"{dataset.sensor_set.name} set")
    ids = [int(i) for i in dataset.experiment_ids]
    if int(experiment) not in ids:
        raise DatasetError(f"experiment {experiment} is not in the dataset (it has {ids[0]}…{ids[-1]})")
    fig = machine_measurements(dataset, int(experiment))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
    fig.savefig(tmp, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    tmp.replace(out)  # atomic: never a half-written figure
    return out


def register(app: typer.Typer) -> None:
    """Add ``plot`` to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application that gains the command.
    """

    @app.command("plot")
    def plot(
        data: Path = typer.Option(..., "--data", help="Dataset of the machine sensor set (Parquet)."),
        experiment: int = typer.Option(None, "--experiment", "-k",
                                       help="Experiment number (default: the first)."),
        out: Path = typer.Option(..., "--out", help="Figure file (.png, .pdf or .svg)."),
    ) -> None:
        """Plot one experiment of a hydraulic-machine dataset: angles, slew, pressures, inclination."""
        from excavator_payload.data.io import check_output_path, read_dataset

        if out.suffix.lower() not in (".png", ".pdf", ".svg"):
            raise DatasetError(f"--out must end in .png, .pdf or .svg, got '{out.name}'")
        if out.exists() and out.resolve() == Path(data).resolve():
            raise DatasetError("--out would overwrite the dataset")
        check_output_path(out, inputs=[data])  # under a file: "File exists ('x')" before
        dataset = read_dataset(data)
        k = int(dataset.experiment_ids[0]) if experiment is None else experiment
        plot_experiment(dataset, k, out)
        typer.echo(f"wrote {out} (experiment {k})")
