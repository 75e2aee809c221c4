"""``excavator-payload zero``: the commercial "check zero" of a calibrated machine-set model
(or of a ``balance-net`` model, which estimates its own offsets the same way).

A short empty-bucket motion re-estimates the sensor offsets that drifted since calibration
(:func:`excavator_payload.estimators.classical.calibrated_machine.zero_offsets`); everything
else the calibration identified stays. The result goes to a new model folder: the calibrated
one is never overwritten (``--out`` equal to ``--model`` is refused), and an offset built on a
signal the sensor health monitor flags in the motion is refused too (``--force`` zeroes anyway
and says which; :func:`excavator_payload.estimators.health_screen.refuse_flagged`).

The motion should move the boom, the dipper and the bucket: offsets are read from moving
joints only (stiction leaves a still joint's force unknown), so a boom lift re-zeroes the boom's
pressures only (what that costs: docs/findings/any-motion.md, *The zero motion*). It prints the weighing error the zero predicts and refuses (exit 2, nothing saved;
``--force`` saves it) a zero that leaves a cylinder's offsets undetermined or would weigh worse
than 1 % of rated (:mod:`~excavator_payload.estimators.classical.zero_quality`).
"""

from __future__ import annotations

from pathlib import Path

import typer

from excavator_payload.errors import EstimatorError


def zero_model(model: str | Path, data: str | Path, out: str | Path, force: bool = False):
    """Load ``model``, re-estimate its offsets from ``data`` (empty bucket), save to ``out``.

    Returns the zeroed estimator; its ``zero_warnings`` say how many samples the check could
    not use (and, with ``force``, which signals the health monitor flagged), its
    ``zero_refusals`` why it would weigh worse than 1 % of rated.

    Parameters
    ----------
    model : str or Path
        Folder of the calibrated model.
    data : str or Path
        Parquet of the empty-bucket motion.
    out : str or Path
        New folder for the zeroed model.
    force : bool
        Zero and save even when the sensor health monitor flags a signal of ``data`` (an offset
        built on a faulty signal carries the fault into every later weighing) or when the zero
        would weigh worse than 1 % of rated (:class:`EstimatorError` otherwise, nothing saved).
    """
    from excavator_payload.data.io import read_dataset
    from excavator_payload.estimators import health_screen
    from excavator_payload.estimators.base import load_estimator
    from excavator_payload.estimators.classical import calibrated_machine

    model, out = Path(model), Path(out)
    check_zero_output(model, data, out)
    estimator = load_estimator(model)
    offset_table(estimator)  # a model zero can check, before the data are read
    dataset = read_dataset(data, machine=estimator.machine)
    if "payload" not in dataset.frame.columns:
        dataset.frame["payload"] = 0.0  # a zero check is an empty-bucket motion by definition
    notes = []
    if force:
        flagged = health_screen.flagged_signals(estimator, dataset)
        if flagged:
            notes.append("zero: --force: built on signals the health monitor flags: "
                         + ", ".join(f"{s} ({w})" for s, w in flagged.items()))
    else:
        # every signal feeds the offsets (the rates and angles say which cylinder moved)
        health_screen.refuse_flagged(estimator, dataset, dataset.sensor_set.signals, "zero")
    if getattr(estimator, "calibration", None) is not None:
        # flagged signals were judged above (refused, or --force with a note)
        estimator.zero_warnings = calibrated_machine.zero(estimator, dataset, force=True) + notes
    else:  # a learned model (balance-net) re-estimates its own offsets
        estimator.zero_warnings = estimator.zero(dataset) + notes
    if estimator.zero_refusals and not force:
        reasons = "; ".join(r[len("zero: "):] for r in estimator.zero_refusals)
        raise EstimatorError(f"zero refused, not saved: {reasons} "
                             "(--force saves it anyway)")
    estimator.save(out)
    return estimator


def check_zero_output(model: Path, data: str | Path, out: Path) -> None:
    """Refuse an ``--out`` that is ``--model``, inside it, the data, a file or a full folder.

    Parameters
    ----------
    model : Path
        The calibrated model folder (``--model``).
    data : str or Path
        The empty-bucket data file (``--data``).
    out : Path
        The folder to write (``--out``).
    """
    from excavator_payload.data.io import check_output_path

    if out.resolve() == Path(model).resolve():
        raise EstimatorError("--out must differ from --model: the zero check writes a new model folder "
                             "and keeps the calibrated one")
    check_output_path(out, inputs=[model, data], kind="folder")
    if out.exists() and any(out.iterdir()):
        raise EstimatorError(f"--out '{out}' exists and is not empty; choose a new folder")


def register(app: typer.Typer) -> None:
    """Add the ``zero`` command to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application.
    """

    @app.command("zero")
    def zero(
        model: Path = typer.Option(..., "--model", help="Calibrated model folder (train calibrated "
                                   "on machine-sensor-set lifts), or a balance-net model."),
        data: Path = typer.Option(..., "--data", help="Parquet of a short empty-bucket motion."),
        out: Path = typer.Option(..., "--out", help="New model folder for the zeroed model "
                                 "(not --model: the calibrated model is kept)."),
        force: bool = typer.Option(False, "--force", help="Zero and save even when the sensor "
                                   "health monitor flags a signal of --data, or when the zero would "
                                   "weigh worse than 1 % of rated or did not determine every "
                                   "cylinder's offsets (the reasons become warnings)."),
    ) -> None:
        """Check zero: re-estimate the sensor offsets from an empty-bucket motion, keep the rest."""
        check_zero_output(model, data, out)  # before anything is loaded
        before = load_offsets(model)
        estimator = zero_model(model, data, out, force=force)
        after = offset_table(estimator)
        for warning in estimator.zero_warnings + [f"{r} (saved: --force)" for r in estimator.zero_refusals]:
            typer.echo(f"warning: {warning}", err=True)
        for line in estimator.zero_report:
            typer.echo(line)
        for (name, a), (_, b) in zip(before, after):
            unit, scale = (("kPa", 1e-3) if name.endswith("pressure") else ("N·m", 1.0)
                           if name.endswith("torque") else ("°", 57.29577951308232))
            typer.echo(f"{name:22s} {a * scale:+9.3f} → {b * scale:+9.3f} {unit}")
        typer.echo(f"zeroed model: {out}")


def offset_table(estimator) -> list[tuple[str, float]]:
    """``(signal, offset)`` pairs of a model that ``zero`` can check (Pa for pressures, rad for
    angles); :class:`EstimatorError` for any other model.

    Parameters
    ----------
    estimator : Estimator
        A ``calibrated`` model of the machine sensor set, or a ``balance-net`` model.
    """
    if getattr(estimator, "calibration", None) is not None:
        from excavator_payload.estimators.classical.calibrated_machine import OFFSET_SIGNALS

        return list(zip(OFFSET_SIGNALS, estimator.calibration.offsets.copy()))
    if callable(getattr(estimator, "offset_table", None)):
        return estimator.offset_table()
    raise EstimatorError(f"zero needs a 'calibrated' model fitted on machine-sensor-set data or a "
                         f"'balance-net' model, this is a '{estimator.name}' model")


def load_offsets(model: Path) -> list[tuple[str, float]]:
    """:func:`offset_table` of the model saved in folder ``model``.

    Parameters
    ----------
    model : Path
        Folder of a saved ``calibrated`` or ``balance-net`` model.
    """
    from excavator_payload.estimators.base import load_estimator

    return offset_table(load_estimator(model))
