"""``excavator-payload plot``: one experiment of a machine-sensor-set dataset in a figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from excavator_payload.errors import DatasetError


def plot_experiment(dataset, experiment: int, out: str | Path) -> Path:
    """Angles, slew, house inclination and cylinder pressures of one experiment (PNG/PDF/SVG).

    Degrees and bar at this edge; the data stay SI.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if dataset.sensor_set.name != "machine":
        raise DatasetError(f"plot shows machine-sensor-set data; this dataset holds the "
                           f"{dataset.sensor_set.name} set")
    ids = [int(i) for i in dataset.experiment_ids]
    if int(experiment) not in ids:
        raise DatasetError(f"experiment {experiment} is not in the dataset (it has {ids[0]}…{ids[-1]})")
    rows = dataset.frame[dataset.frame["experiment"] == int(experiment)]
    t = rows["time"].to_numpy(float)
    deg = 180 / np.pi
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True, constrained_layout=True)
    ax = axes[0]
    for name, colour in (("boom", "C0"), ("dipper", "C1"), ("bucket", "C2")):
        ax.plot(t, rows[f"{name}_angle"] * deg, colour, label=f"{name} angle")
    ax.set_ylabel("angle (°)")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1]
    if "true_slew_angle" in rows:
        slew = rows["true_slew_angle"].to_numpy(float)
        label = "slew angle (true)"
    else:  # a field log: integrate the measured slew rate
        rate = rows["slew_rate"].to_numpy(float)
        slew = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
        label = "slew angle (∫ slew rate)"
    ax.plot(t, slew * deg, "C3", label=label)
    ax.set_ylabel("slew (°)")
    ax2 = ax.twinx()
    ax2.plot(t, rows["slew_rate"] * deg, "C3", alpha=0.35, lw=0.8)
    ax2.set_ylabel("slew rate (°/s)", color="C3")
    ax.legend(loc="best", fontsize=8)
    ax = axes[2]
    for name, colour in (("boom", "C0"), ("dipper", "C1"), ("bucket", "C2")):
        ax.plot(t, rows[f"{name}_head_pressure"] / 1e5, colour, lw=0.8, label=f"{name} head")
        ax.plot(t, rows[f"{name}_rod_pressure"] / 1e5, colour, lw=0.8, ls="--", label=f"{name} rod")
    relief = (dataset.meta.get("machine") or {}).get("hydraulics", {}).get("relief_pressure")
    if relief:
        ax.axhline(relief / 1e5, color="k", lw=0.6, ls=":", label="relief")
    ax.set_ylabel("pressure (bar)")
    ax.legend(loc="best", fontsize=7, ncol=4)
    ax = axes[3]
    ax.plot(t, rows["house_pitch"] * deg, "C4", label="house pitch")
    ax.plot(t, rows["house_roll"] * deg, "C5", label="house roll")
    ax.set_ylabel("inclination (°)")
    ax.set_xlabel("time (s)")
    ax.legend(loc="best", fontsize=8)
    machine = (dataset.meta.get("machine") or {}).get("name", "?")
    payload = f", payload {rows['payload'].iloc[0]:.0f} kg" if "payload" in rows else ""
    fig.suptitle(f"{machine}: experiment {experiment} ({dataset.meta.get('motion', '?')}{payload})")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(out)  # atomic: never a half-written figure
    return out


def register(app: typer.Typer) -> None:
    """Add ``plot`` to ``app``."""

    @app.command("plot")
    def plot(
        data: Path = typer.Option(..., "--data", help="Dataset of the machine sensor set (Parquet)."),
        experiment: int = typer.Option(None, "--experiment", "-k",
                                       help="Experiment number (default: the first)."),
        out: Path = typer.Option(..., "--out", help="Figure file (.png, .pdf or .svg)."),
    ) -> None:
        """Plot one experiment of a hydraulic-machine dataset: angles, slew, pressures, inclination."""
        from excavator_payload.data.io import read_dataset

        if out.suffix.lower() not in (".png", ".pdf", ".svg"):
            raise DatasetError(f"--out must end in .png, .pdf or .svg, got '{out.name}'")
        if out.exists() and out.resolve() == Path(data).resolve():
            raise DatasetError("--out would overwrite the dataset")
        dataset = read_dataset(data)
        k = int(dataset.experiment_ids[0]) if experiment is None else experiment
        plot_experiment(dataset, k, out)
        typer.echo(f"wrote {out} (experiment {k})")
