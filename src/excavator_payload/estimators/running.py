"""Running a fitted estimator over a dataset: a few experiments at a time, with a progress bar,
and on the execution layer's workers when the dataset is big enough to gain from them."""

from __future__ import annotations

import math
import time

import pandas as pd
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from excavator_payload.data.dataset import Dataset

console = Console()


def progress_bar(console_: Console | None = None) -> Progress:
    """The progress bar of the estimating and evaluating commands.

    Parameters
    ----------
    console_ : rich.console.Console, optional
        Where it is drawn (default: standard output).
    """
    return Progress(TextColumn("[progress.description]{task.description}"), BarColumn(),
                    MofNCompleteColumn(), TimeElapsedColumn(), console=console_ or console,
                    transient=False)


#: A dataset goes to the execution layer only if estimating the rest of it here would take
#: longer than this (extrapolated from its first chunk, which is always estimated here): starting
#: local workers costs 1–3 s and each worker then imports the estimators (torch: 1–2 s) and
#: rebuilds the estimator's compiled functions, so two workers gain nothing on less. Measured on
#: the demo's 200 test experiments (2 cores, loaded): UKF ~5 s, the EKFs ~1 s, the others less,
#: so a demo-sized test set stays here and 1000+ experiments of the UKF go to the workers.
PARALLEL_MIN_SECONDS = 10.0
#: At most this many tasks per dataset on a cluster (bigger chunks for bigger datasets).
MAX_ESTIMATE_TASKS = 200


def estimate_task(estimator, dataset: Dataset) -> pd.DataFrame:
    """One chunk of experiments estimated on a worker (the unit of work of the execution layer).

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator.
    dataset : Dataset
        The chunk of experiments.

    Returns
    -------
    pandas.DataFrame
        As :meth:`Estimator.estimate`.
    """
    return estimator.estimate(dataset)


def estimate_in_chunks(estimator, dataset: Dataset, progress: Progress | None = None,
                       description: str = "estimating", chunk: int = 10, execution=None) -> pd.DataFrame:
    """``estimator.estimate(dataset)`` a few experiments at a time, advancing a progress bar.

    Estimators reset at every experiment, so chunking gives the same estimates. With an
    ``execution`` (:class:`~excavator_payload.execution.Execution`), when the first chunk shows
    that the rest would take more than :data:`PARALLEL_MIN_SECONDS` here, the rest is split by
    experiment into chunks that run on its workers (the estimator is sent once); the estimates
    are the same, in the same order.

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator.
    dataset : Dataset
        Data to estimate on.
    progress : rich.progress.Progress or None
        Progress bar to advance per experiment (None: none).
    description : str
        Label of the progress task.
    chunk : int
        Experiments per chunk.
    execution : Execution or None
        Execution layer to run the rest on in parallel (None: here, serially).

    Returns
    -------
    pandas.DataFrame
        As :meth:`Estimator.estimate`.
    """
    ids = list(dataset.experiment_ids)
    task = (progress.add_task(escape(description), total=len(ids))  # labels hold paths: not markup
            if progress is not None else None)
    parts = [ids[start:start + chunk] for start in range(0, len(ids), chunk)]
    frames = []
    for index, part in enumerate(parts):
        start = time.perf_counter()
        frames.append(estimator.estimate(dataset.subset(part) if len(ids) > chunk else dataset))
        if progress is not None:
            progress.advance(task, len(part))
        rest = ids[sum(len(p) for p in parts[:index + 1]):]
        if index == 0 and execution is not None and rest \
                and (time.perf_counter() - start) * len(rest) / len(part) > PARALLEL_MIN_SECONDS:
            frames.extend(_estimate_on_layer(estimator, dataset, rest, execution, progress, task, chunk))
            break
    return pd.concat(frames, ignore_index=True)


def _estimate_on_layer(estimator, dataset: Dataset, ids: list, execution, progress: Progress | None, task,
                       chunk: int) -> list[pd.DataFrame]:
    """Experiments ``ids`` of ``dataset`` estimated in chunks through ``execution``, in order."""
    from excavator_payload.execution import Shared

    chunk = max(chunk, math.ceil(len(ids) / MAX_ESTIMATE_TASKS))
    parts = [ids[start:start + chunk] for start in range(0, len(ids), chunk)]

    def advance(index, _frame):
        if progress is not None:
            progress.advance(task, len(parts[index]))

    # The caller's progress bar is advanced here: the layer's own bar stays off (one live display).
    shared = Shared(estimator)
    return execution.map(estimate_task, [(shared, dataset.subset(part)) for part in parts],
                         on_done=advance, progress=False)
