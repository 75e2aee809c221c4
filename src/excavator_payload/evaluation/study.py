"""Studies: a declarative grid of estimators × data conditions, run on the execution layer.

A study file (TOML) names the estimators and the axes of the grid; every combination is a
*cell*: simulate its data (fit data if the estimator learns or calibrates, and test data), fit,
estimate and judge every test experiment with :mod:`excavator_payload.evaluation.metrics`
(MAX, RMS, within 1 % of rated, efficiency against the Cramér–Rao bound for the information
the estimator uses). The result is one Parquet file with one row per test experiment per cell
(the cell's axis values as columns) and a report page.

.. code-block:: toml

    name = "robustness"
    description = "What the table shows"

    [grid]                      # a list is an axis of the grid, a single value a setting
    noise = ["thesis", "field"]           # test sensor noise preset
    motion = ["nmpc", "minimum-jerk"]     # test motion family
    machine = ["cat345c"]                 # the machine file the estimators believe in
    noise_mode = ["independent"]          # independent | frozen | frozen-mismatch
    test_experiments = [200]
    fit_experiments = [151]               # experiments the estimators fit/train/calibrate on
    seed = [0]

    [data]
    true_machine = "cat345c"    # the machine that generates every dataset
    fit_motion = "nmpc"         # motion of the fit data; "same": the cell's motion
    fit_noise = "same"          # noise of the fit data; "same": the cell's noise
    discard = 81                # samples not judged at the start of every experiment

    [[estimators]]
    name = "net1"
    label = "Net1"
    options = { epochs = 300, train_experiments = 100, validation_experiments = 51 }
    # any [grid] axis or [data] setting may be given here too: it replaces the study's for
    # this estimator (e.g. fit_motion = "lifts", fit_experiments = 10)

    [report]
    rows = "estimator"          # heatmap rows and columns (axes of the grid); other axes
    columns = "noise"           # are pooled

Noise modes: ``independent`` (a fresh draw per experiment, our simulator), ``frozen`` (the
same sequence in every experiment of fit and test data, as Simulink's noise block with its
default seed 23341) and ``frozen-mismatch`` (fit data frozen with 23341, test data with another
sequence). Data of study seed ``s``: fit experiments use base seed ``s``, test experiments base
seed ``s +`` :data:`TEST_SEED_OFFSET`, so they never share an experiment.

Everything is cached in the output folder: simulated datasets by their spec (cells share them),
fitted models by estimator, options and fit data, finished cells in ``cells/``. A rerun, after
an interruption or with a grown grid, computes only the missing cells.
"""

from __future__ import annotations

import functools
import hashlib
import json
import pickle
import time
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from excavator_payload import __version__
from excavator_payload.data.io import atomic_write_table, read_dataset, write_dataset
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.execution import Execution, Shared
# The study file and the report have rooms of their own; their public names stay importable here.
from excavator_payload.evaluation.study_file import (  # noqa: F401
    AXES, CONFIRM_CELLS, CONFIRM_EXPERIMENTS, FROZEN_SEED, MAX_CELLS, MAX_EXPERIMENTS, METRIC_COLUMNS,
    NOISE_MODES, SETTINGS, SHIPPED_STUDIES_FOLDER, TEST_SEED_OFFSET, Cell, Study, StudyError, find_study,
    load_study, parse_study, shipped_studies, study_experiments, study_size)
from excavator_payload.evaluation.study_report import build_study_report, pooled  # noqa: F401


# -- keys ---------------------------------------------------------------------------------------
def _key(obj: Any) -> str:
    """Short stable hash of JSON-able settings."""
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _machine_dict(name: str) -> dict | None:
    return _machine_json(name) and json.loads(_machine_json(name))


@functools.lru_cache(maxsize=64)
def _machine_json(name: str) -> str | None:
    """A machine's tables as JSON, read once per name (every cell's key needs them)."""
    from excavator_payload.model.machine import load_machine

    return None if name == "none" else json.dumps(load_machine(name).to_dict())


def data_specs(cell: Cell) -> tuple:
    """The (fit, test) :class:`~excavator_payload.simulation.experiment.RunSpec` of a cell.

    Parameters
    ----------
    cell : Cell
        One cell of the grid.
    """
    from excavator_payload.simulation.generate import make_spec

    fit_frozen, test_frozen = {"independent": (None, None), "frozen": (FROZEN_SEED, FROZEN_SEED),
                               "frozen-mismatch": (FROZEN_SEED, FROZEN_SEED + 1)}[cell.noise_mode]
    fit = make_spec(cell.fit_experiments, cell.seed, cell.true_machine, cell.fit_noise, True,
                    cell.fit_motion, frozen_noise_seed=fit_frozen)
    test = make_spec(cell.test_experiments, cell.seed + TEST_SEED_OFFSET, cell.true_machine, cell.noise,
                     True, cell.motion, frozen_noise_seed=test_frozen)
    return fit, test


def spec_key(spec) -> str:
    """Cache key of a dataset: a short hash of its ``RunSpec`` and the package version (names its
    file in the study's ``data`` folder).

    Parameters
    ----------
    spec : RunSpec
        The dataset's simulation spec (:func:`data_specs`).
    """
    return _key({"spec": spec.to_dict(), "version": __version__})


def fit_key(cell: Cell, fit_spec) -> str:
    """Cache key of a fitted estimator: a short hash of the estimator, its options, the machine it
    believes in, the fit data's :func:`spec_key` and the package version (cells that share it
    share one fit).

    Parameters
    ----------
    cell : Cell
        One cell of the grid.
    fit_spec : RunSpec
        The spec of its fit data (:func:`data_specs`).
    """
    return _key({"estimator": cell.estimator, "options": cell.option_dict(),
                 "machine": _machine_dict(cell.machine), "fit_data": spec_key(fit_spec),
                 "version": __version__})


def cell_key(cell: Cell) -> str:
    """Cache key of a cell's results: a short hash of every field but the label (machines by their
    contents, not their names) and the package version.

    Parameters
    ----------
    cell : Cell
        One cell of the grid.
    """
    values = asdict(cell)
    values["machine"] = _machine_dict(cell.machine)
    values["true_machine"] = _machine_dict(cell.true_machine)
    values.pop("label")  # renaming an estimator does not change its results
    return _key({"cell": values, "version": __version__})


# -- the tasks (run on the workers) ---------------------------------------------------------------
def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}"[:300]


def fit_task(estimator: str, machine, options: dict, fit_data) -> dict:
    """Fit one estimator; returns ``{"model": pickled estimator, "seconds": fit time}`` or
    ``{"error": why}``.

    The fitted estimator travels pickled (bytes: cached as they are in ``models/``), not through
    its ``save`` folder: a fit on noise-free data legitimately holds infinite weights, which
    ``load_estimator`` refuses as corrupt.

    Parameters
    ----------
    estimator : str
        Registry name of the estimator.
    machine : Machine or None
        The machine it believes in; ``None`` for estimators that need none.
    options : dict
        Its keyword options.
    fit_data : Dataset
        The data it is fitted on.
    """
    from excavator_payload.estimators.base import create_estimator

    try:
        est = create_estimator(estimator, machine=machine, **options)
        start = time.perf_counter()
        est.fit(fit_data)
        seconds = time.perf_counter() - start
        return {"model": pickle.dumps(est, protocol=pickle.HIGHEST_PROTOCOL), "seconds": seconds}
    except Exception as exc:  # noqa: BLE001 - one estimator must not stop the study
        return {"error": "fit: " + _reason(exc)}


def score_task(cell: Cell, model: bytes, test_data) -> dict:
    """Estimate on the test data and judge every experiment; ``{"rows": DataFrame}`` or
    ``{"error": why}``.

    Parameters
    ----------
    cell : Cell
        One cell of the grid.
    model : bytes
        The fitted estimator, pickled (:func:`fit_task`).
    test_data : Dataset
        The cell's test data, with the true payloads.
    """
    from excavator_payload.evaluation.metrics import INDUSTRY_TOLERANCE, bound_window, evaluate_estimates

    try:
        est = pickle.loads(model)
        start = time.perf_counter()
        estimates = est.estimate(test_data)
        seconds = time.perf_counter() - start
        window = bound_window(cell.estimator, est.options)
        with warnings.catch_warnings():
            # Noise-free torques: the bound is 0 (infinite information) and is not judged.
            warnings.simplefilter("ignore", RuntimeWarning)
            evaluation = evaluate_estimates(test_data, estimates, label=cell.label, discard=cell.discard,
                                            window=window)
        rows = evaluation.per_experiment.copy()
        rated = evaluation.summary["rated_payload"]
        rows["within_1pct"] = np.nan_to_num(rows["max_error"].to_numpy(float), nan=np.inf) <= INDUSTRY_TOLERANCE * rated
        for column in METRIC_COLUMNS:
            if column not in rows:
                rows[column] = np.nan
        rows = rows[["experiment", *METRIC_COLUMNS]]
        for name, value in reversed(list(cell.axis_values().items())):
            rows.insert(0, name, value)
        rows["bound_window"] = -1 if window is None else int(window)
        rows["estimate_seconds"] = seconds
        return {"rows": rows}
    except Exception as exc:  # noqa: BLE001
        return {"error": "estimate: " + _reason(exc)}


# -- running a study -------------------------------------------------------------------------------
def _write_frame(frame: pd.DataFrame, path: Path) -> None:
    atomic_write_table(pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False), path)


def run_study(study: Study, out: str | Path, execution: Execution, progress: bool = True,
              console=None) -> dict:
    """Run the missing cells of ``study``, write ``out/results.parquet`` and the report.

    Parameters
    ----------
    study : Study
        The parsed study.
    out : str or Path
        Output folder: ``data/``, ``models/``, ``cells/`` (caches), ``results.parquet``,
        ``report/``.
    execution : Execution
        Where simulations, fits and scoring run.
    progress : bool
        Show progress bars.
    console : rich.console.Console, optional
        Where status lines go; default standard error.

    Returns
    -------
    dict
        ``results`` (path), ``report`` (path), ``cells`` (total), ``computed``, ``reused``,
        ``failures`` (``{cell description: reason}``), ``timings_s``.
    """
    from rich.console import Console

    console = console or Console(stderr=True)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out '{out}' is a file; give a folder")
    for sub in ("data", "models", "cells"):
        try:
            (out / sub).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StudyError(f"cannot write to '{out}': {exc}") from None
    timings: dict[str, float] = {}
    keys = {cell: cell_key(cell) for cell in study.cells}
    pending = [c for c in study.cells if not (out / "cells" / f"{keys[c]}.parquet").is_file()]
    reused = len(study.cells) - len(pending)
    failures: dict[str, str] = {}
    console.print(f"study '{study.name}': {len(study.cells)} cells, {reused} already computed, "
                  f"{len(pending)} to run on {execution.where}", soft_wrap=True)

    # 1. data: every dataset a pending cell needs, each simulated once (cached by its spec)
    t0 = time.perf_counter()
    specs: dict[str, Any] = {}
    cell_data: dict[Cell, tuple[str, str]] = {}
    for cell in pending:
        fit_spec, test_spec = data_specs(cell)
        fk, tk = spec_key(fit_spec), spec_key(test_spec)
        specs[fk], specs[tk] = fit_spec, test_spec
        cell_data[cell] = (fk, tk)
    datasets = {}
    for key in list(specs):
        path = out / "data" / f"{key}.parquet"
        if path.is_file():
            try:
                datasets[key] = read_dataset(path)
                continue
            except ExcavatorPayloadError:
                path.unlink()  # a damaged cache file is simply made again
    missing = {k: s for k, s in specs.items() if k not in datasets}
    if missing:
        from excavator_payload.simulation.generate import simulate_many

        n = sum(s.n_experiments for s in missing.values())
        console.print(f"simulating {len(missing)} dataset(s), {n} experiments", soft_wrap=True)
        for key, ds in simulate_many(missing, execution, progress, "simulating").items():
            write_dataset(ds, out / "data" / f"{key}.parquet")
            datasets[key] = ds
    timings["data"] = time.perf_counter() - t0

    # 2. fits: one per estimator, options, machine and fit data
    t0 = time.perf_counter()
    fits: dict[str, tuple] = {}
    for cell in pending:
        fk = fit_key(cell, specs[cell_data[cell][0]])
        fits.setdefault(fk, (cell, cell_data[cell][0]))
    models: dict[str, bytes] = {}
    to_fit = []
    for fk, (cell, data_key) in fits.items():
        path = out / "models" / f"{fk}.pickle"
        if path.is_file():
            models[fk] = path.read_bytes()
        else:
            to_fit.append(fk)
    if to_fit:
        from excavator_payload.model.machine import load_machine

        console.print(f"fitting {len(to_fit)} estimator(s)", soft_wrap=True)
        shared = {k: Shared(ds) for k, ds in datasets.items()}
        tasks = []
        for fk in to_fit:
            cell, data_key = fits[fk]
            machine = None if cell.machine == "none" else load_machine(cell.machine)
            tasks.append((cell.estimator, machine, cell.option_dict(), shared[data_key]))

        def fitted(index, result):
            fk = to_fit[index]
            if "error" in result:
                failures[fits[fk][0].label + " (fit)"] = result["error"]
                return
            path = out / "models" / f"{fk}.pickle"
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_bytes(result["model"])
            tmp.replace(path)
            models[fk] = result["model"]

        execution.map(fit_task, tasks, on_done=fitted, description="fitting", progress=progress)
    timings["fit"] = time.perf_counter() - t0

    # 3. estimate and judge every pending cell whose fit succeeded
    t0 = time.perf_counter()
    runnable = [c for c in pending if fit_key(c, specs[cell_data[c][0]]) in models]
    for cell in pending:
        if cell not in runnable:
            failures.setdefault(_describe(cell), failures.get(cell.label + " (fit)", "fit failed"))
    if runnable:
        shared_models = {fk: Shared(m) for fk, m in models.items()}
        shared_data = {k: Shared(ds) for k, ds in datasets.items()}
        tasks = [(cell, shared_models[fit_key(cell, specs[cell_data[cell][0]])], shared_data[cell_data[cell][1]])
                 for cell in runnable]

        def scored(index, result):
            cell = runnable[index]
            if "error" in result:
                failures[_describe(cell)] = result["error"]
                return
            _write_frame(result["rows"], out / "cells" / f"{keys[cell]}.parquet")

        execution.map(score_task, tasks, on_done=scored, weights=[c.test_experiments for c in runnable],
                      description="estimating and judging", progress=progress)
    timings["estimate"] = time.perf_counter() - t0

    # 4. one Parquet of the grid's cells, and the report
    t0 = time.perf_counter()
    frames = []
    for cell in study.cells:
        path = out / "cells" / f"{keys[cell]}.parquet"
        if path.is_file():
            frame = pd.read_parquet(path)
            frame["estimator"] = cell.label  # the label may have changed since
            frame.insert(0, "cell", keys[cell])
            frames.append(frame)
    results_path = out / "results.parquet"
    results = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    if frames:
        _write_frame(results, results_path)
    failures = {k: v for k, v in failures.items() if not k.endswith(" (fit)")}
    report = build_study_report(study, results, out / "report", failures=failures,
                                timings={**timings, "report": 0.0})
    timings["report"] = time.perf_counter() - t0
    return {"results": results_path if frames else None, "report": report, "cells": len(study.cells),
            "computed": len(pending) - len([c for c in pending if _describe(c) in failures]),
            "reused": reused, "failures": failures, "timings_s": timings}


def _describe(cell: Cell) -> str:
    return (f"{cell.label} | noise={cell.noise} motion={cell.motion} machine={cell.machine} "
            f"mode={cell.noise_mode} fit={cell.fit_experiments} test={cell.test_experiments} seed={cell.seed}")
