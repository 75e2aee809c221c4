"""Command-line commands of this role (registered into :mod:`excavator_payload.cli`).

``excavator-payload simulate`` generates a dataset, ``excavator-payload export-mat`` writes a
dataset in the thesis' MATLAB layout (appendix A.2).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.console import Console

from excavator_payload.errors import ExcavatorPayloadError

console = Console(stderr=True)


def _motion_help() -> str:
    """``--motion``'s help from the platforms' motion families (a family added there shows here)."""
    from excavator_payload.platforms import HYDRAULIC, THESIS

    def listed(platform):
        return ", ".join(f"{name} ({'default: ' if name == platform.default_motion else ''}{motion.description})"
                         for name, motion in platform.motions.items())

    return f"Thesis arm: {listed(THESIS)}. A hydraulic machine (--machine): {listed(HYDRAULIC)}."


def register(app: typer.Typer) -> None:
    """Add this role's commands to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application that receives ``simulate`` and ``export-mat``.
    """

    @app.command("simulate")
    def simulate(
        out: Path = typer.Option(..., "--out", help="Output dataset file (Parquet)."),
        experiments: int = typer.Option(200, "--experiments", "-n", help="Number of experiments."),
        seed: int = typer.Option(0, "--seed", help="Base seed (same seed, same data)."),
        machine: str = typer.Option("cat345c", "--machine",
                                    help="Machine preset (cat345c, cat345c-1pct, cat345c-3pct, "
                                         "cat345c-hydraulic, cat345c-hydraulic-3pct) or TOML file."),
        noise: str = typer.Option(None, "--noise",
                                  help="Sensor noise preset: thesis (default), none or field; for a "
                                       "hydraulic machine field (default) or none."),
        with_truth: bool = typer.Option(False, "--with-truth", help="Also store the noise-free true_* columns."),
        workers: int = typer.Option(0, "--workers",
                                    help="Local worker processes (0 = all cores). The data do not depend on it."),
        scheduler: str = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                      help="Run on this existing Dask cluster (default: $EXCAVATOR_PAYLOAD_SCHEDULER, "
                                           "else local worker processes)."),
        motion: str = typer.Option(None, "--motion", help=_motion_help()),
        session: int = typer.Option(0, "--session",
                                    help="Hydraulic machine: working session, draws the sensor offsets "
                                         "(independently of --seed)."),
        trajectory: Path = typer.Option(None, "--trajectory",
                                        help="Hydraulic machine: replay the motions of this Parquet file "
                                             "(experiment, time, boom/dipper/bucket/slew_angle, payload)."),
        payload: float = typer.Option(None, "--payload", metavar="KG",
                                      help="Hydraulic machine: every experiment carries this mass (kg) "
                                           "instead of a drawn one; 0 makes an empty-bucket motion for "
                                           "`zero`."),
        smooth: float = typer.Option(None, "--smooth", metavar="SECONDS",
                                     help="With --trajectory: filter the angles (zero-phase Gaussian, "
                                          "standard deviation SECONDS/2) before the spline; for logs "
                                          "whose angles come in steps."),
        allow_overspeed: bool = typer.Option(False, "--allow-overspeed",
                                             help="With --trajectory: simulate motions faster than the "
                                                  "pumps or slew drive give (refused otherwise), with a "
                                                  "warning per experiment."),
        truck_target: float = typer.Option(None, "--truck-target", metavar="KG",
                                           help="Hydraulic machine, --motion shift: the load each truck "
                                                "(experiment) aims at; its passes' fills are drawn towards "
                                                "it (default: 4 passes at 90 % of rated)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Simulate experiments (thesis §5.3) and write them to a dataset file.

        An interrupted run keeps its finished experiments in OUT.partial/; run the same command again to resume.
        """
        from excavator_payload.data.io import PARQUET_SUFFIXES, check_output_path
        from excavator_payload.execution import Execution, interrupted_message
        from excavator_payload.simulation.generate import make_spec, simulate_spec_to_file, summary

        # Before any simulation: `--out x.csv` wrote Parquet under a .csv name without a word.
        check_output_path(out, inputs=[trajectory], suffixes=PARQUET_SUFFIXES)
        if workers < 0:
            raise ExcavatorPayloadError(f"--workers must be ≥ 0, got {workers}")
        # Names (machine, noise preset, motion, trajectory file) are resolved once, here, into
        # a run description; objects travel inside, down to the workers.
        spec = make_spec(experiments, seed, machine, noise, with_truth, motion,
                         session=session, trajectory=trajectory, payload=payload, smooth=smooth,
                         allow_overspeed=allow_overspeed, truck_target=truck_target)
        motion, noise = spec.motion, spec.noise.name
        replayed = spec.option("trajectory")
        if replayed is not None:
            for line in replayed.warnings:
                console.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)
            if replayed.ignored:
                console.print(f"note: column(s) {', '.join(replayed.ignored)} of the trajectory file are "
                              "not trajectory columns and were ignored", markup=False, highlight=False,
                              soft_wrap=True)
        start = time.perf_counter()
        try:
            with Execution(scheduler, workers or None) as execution:
                dataset = simulate_spec_to_file(out, spec, progress=not quiet, execution=execution)
        except KeyboardInterrupt:
            # Click would turn Ctrl-C into a bare "Aborted!": say what is kept instead.
            console.print(interrupted_message(f"finished chunks are kept in {out}.partial/; "
                                              "rerun the same command to resume"), soft_wrap=True)
            raise typer.Exit(130) from None
        info = summary(dataset, time.perf_counter() - start)
        typer.echo(f"wrote {info['written']} experiment{'' if info['written'] == 1 else 's'} to {out} "
                   f"({motion}, noise={noise}, seed={seed})")
        skipped = info["skipped"]
        if skipped:
            typer.echo(f"skipped {len(skipped)} experiment(s):")
            for s in skipped[:10]:
                typer.echo(f"  #{s['experiment']}: {s['reason']}")
            if len(skipped) > 10:
                typer.echo(f"  … and {len(skipped) - 10} more (see the file's metadata)")
        else:
            typer.echo("skipped 0 experiments")
        if info["reached_share"] is not None:
            end = (dataset.meta.get("experiments") or [{}])[0].get("duration", 5.0)  # thesis: 5 s
            typer.echo(f"reached the target (within 1°, at rest) by {end:g} s: {100 * info['reached_share']:.1f} %")
        typer.echo(f"wall time {info['wall_time']:.1f} s")

    @app.command("export-mat")
    def export_mat(
        data: Path = typer.Option(..., "--data", help="Dataset file (Parquet)."),
        out: Path = typer.Option(..., "--out", help="MATLAB file to write (.mat)."),
    ) -> None:
        """Write a dataset in the thesis' MATLAB layout (appendix A.2): dataset{exp}.input …"""
        from excavator_payload.data.io import read_dataset
        from excavator_payload.data.matlab import export_mat as write_mat

        dataset = read_dataset(data)
        write_mat(dataset, out)
        typer.echo(f"wrote {dataset.n_experiments} experiment{'' if dataset.n_experiments == 1 else 's'} to {out} "
                   "(variable 'dataset')")
