"""Evaluating fitted estimators and estimates files on a test dataset: the work behind
``excavator-payload evaluate`` and ``report`` (:mod:`.commands`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

from rich.progress import Progress

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_estimates, read_metadata
from excavator_payload.errors import DatasetError, EstimatorError
from excavator_payload.estimators.running import estimate_in_chunks
from excavator_payload.evaluation.metrics import (
    Evaluation,
    bound_window,
    dataset_bound,
    default_discard,
    display_label,
    evaluate_estimates,
    to_jsonable,
)
from excavator_payload.platforms import HYDRAULIC


def _model_options(model_dir: Path) -> tuple[str | None, dict, str | None]:
    """Estimator name, options and machine name from a saved model's ``estimator.json``."""
    try:
        cfg = json.loads((model_dir / "estimator.json").read_text(encoding="utf-8"))
        return cfg.get("estimator"), dict(cfg.get("options") or {}), (cfg.get("machine") or {}).get("name")
    except (OSError, ValueError, AttributeError):
        return None, {}, None


def _unique(label: str, taken: set) -> str:
    out, k = label, 2
    while out in taken:
        out, k = f"{label} #{k}", k + 1
    taken.add(out)
    return out


def evaluate_sources(dataset: Dataset, models: Sequence[Path] = (), estimates: Sequence[Path] = (),
                     discard: int | None = None, progress: Progress | None = None,
                     execution=None) -> list[Evaluation]:
    """Evaluate saved models (run on ``dataset``, through ``execution`` if it is big: see
    :func:`estimate_in_chunks`) and estimates files, in the order given; ``discard`` defaults to
    :func:`~excavator_payload.evaluation.metrics.default_discard` of the dataset's sensor set.

    Parameters
    ----------
    dataset : Dataset
        Test data with the true ``payload`` column (kg).
    models : sequence of Path
        Saved estimator folders, each run on ``dataset``.
    estimates : sequence of Path
        Estimates files (``experiment``, ``time``, ``payload_estimate``) made on this very dataset.
    discard : int, optional
        Samples not judged at the start of every experiment; default by sensor set.
    progress : rich.progress.Progress, optional
        Progress bar to advance while the models estimate.
    execution : Execution, optional
        Workers that share the estimating of a big dataset; ``None`` runs here.

    Returns
    -------
    list of Evaluation
        One per model, then one per estimates file, with unique labels.
    """
    from excavator_payload.estimators.base import load_estimator

    if not models and not estimates:
        raise EstimatorError("nothing to evaluate: give --model DIR and/or --estimates FILE")
    if not dataset.has_payload:
        raise DatasetError("the dataset has no 'payload' column (a field log?): judging needs the "
                           "true payloads")
    if discard is None:
        discard = default_discard(dataset.sensor_set)
    longest = int(dataset.frame.groupby("experiment", sort=False).size().max())
    if discard >= longest:
        # the table said '0 %' within 1 % of experiments none of which was judged
        raise DatasetError(f"--discard {discard} leaves no sample to judge: the longest experiment has "
                           f"{longest} samples")
    evaluations: list[Evaluation] = []
    bounds: dict = {}
    taken: set = set()

    machine_bound = None
    if HYDRAULIC.carries(dataset):  # issue 12: the bound from a calibrated model given
        from excavator_payload.evaluation.crb_machine import dataset_machine_bound

        for model in models:
            machine_bound = dataset_machine_bound(dataset, load_estimator(model))
            if machine_bound is not None:
                break

    def bound_for(window):
        if machine_bound is not None:  # the machine set's bound is of the whole history
            return machine_bound
        if window not in bounds:
            bounds[window] = dataset_bound(dataset, window)
        return bounds[window]

    for model in models:
        est = load_estimator(model)
        name, options, machine = est.name, est.options, est.machine.name if est.machine else None
        label = _unique(display_label(name, options, machine), taken)
        frame = estimate_in_chunks(est, dataset, progress, f"{label}: estimating", execution=execution)
        window = bound_window(name, options)
        evaluations.append(evaluate_estimates(dataset, frame, label=label, discard=discard, window=window,
                                              bound=bound_for(window),
                                              info={"estimator": name, "options": options,
                                                    "machine": machine, "model": str(model)}))
    fingerprint = dataset.fingerprint() if estimates else None
    for path in estimates:
        frame = read_estimates(path)
        meta = read_metadata(path)
        made_on = meta.get("data_fingerprint")
        if made_on is not None and made_on != fingerprint:
            raise DatasetError(f"'{path}' holds estimates made on another dataset "
                               f"({meta.get('data', 'unknown file')}), not on this one")
        name, options, machine = meta.get("estimator"), {}, None
        if meta.get("model"):
            n2, options, machine = _model_options(Path(meta["model"]))
            name = name or n2
        label = _unique(display_label(name, options, machine) if name else Path(path).stem, taken)
        window = bound_window(name, options)
        evaluations.append(evaluate_estimates(dataset, frame, label=label, discard=discard, window=window,
                                              bound=bound_for(window),
                                              info={"estimator": name, "options": options,
                                                    "machine": machine, "estimates": str(path)}))
    return evaluations


def write_json(path: Path, payload: dict) -> None:
    """Write ``payload`` as indented JSON (NaN as null) to ``path``, creating its folder; written
    to a private temporary file and renamed, so a reader never sees half a file.

    Parameters
    ----------
    path : Path
        The JSON file to write.
    payload : dict
        JSON-like content; NumPy/pandas values are converted by :func:`to_jsonable`.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # private: concurrent runs never share it
    tmp.write_text(json.dumps(to_jsonable(payload), indent=2), encoding="utf-8")
    tmp.replace(path)
