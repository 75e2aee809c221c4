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
import itertools
import json
import math
import pickle
import shutil
import time
import tomllib
import warnings
from dataclasses import asdict, dataclass, field
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from excavator_payload import __version__
from excavator_payload.data.io import atomic_write_table, read_dataset, write_dataset
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.execution import Execution, Shared

#: Axes of the grid (list-valued in a study file) and their defaults.
AXES: dict[str, Any] = {
    "noise": "thesis",
    "motion": "nmpc",
    "machine": "cat345c",
    "noise_mode": "independent",
    "test_experiments": 200,
    "fit_experiments": 151,
    "seed": 0,
}
#: Settings that are one value per estimator (``[data]``) and their defaults.
SETTINGS: dict[str, Any] = {
    "true_machine": "cat345c",
    "fit_motion": "same",
    "fit_noise": "same",
    "discard": 81,
}
NOISE_MODES = ("independent", "frozen", "frozen-mismatch")
#: Simulink's Band-Limited White Noise block's default seed (the frozen sequence).
FROZEN_SEED = 23341
#: Test data of study seed ``s`` use base seed ``s + TEST_SEED_OFFSET`` (fit data: ``s``).
TEST_SEED_OFFSET = 1_000_003
#: Columns of the per-experiment metrics kept in the results.
METRIC_COLUMNS = ("payload", "max_error", "rms_error", "mean_error", "p90", "p95", "p99",
                  "convergence_time", "estimated_share", "efficiency", "sum_sq_efficiency",
                  "n_efficiency", "final_bound", "within_1pct")
#: Folder, inside the package, of the shipped study files (package data: they are in the wheel;
#: the repository's ``studies/`` points there).
SHIPPED_STUDIES_FOLDER = "studies"


class StudyError(ExcavatorPayloadError):
    """A study file is missing or malformed."""


# -- the study file -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """One combination of the grid: an estimator under one set of data conditions.

    Parameters
    ----------
    label : str
        Display name of the estimator (unique in the study).
    estimator : str
        Registry name of the estimator.
    options : tuple
        Its options as sorted ``(name, value)`` pairs (lists as tuples: hashable).
    machine : str
        The machine file the estimator believes in; ``none`` for estimators that need none.
    noise : str
        Sensor noise preset of the test data.
    motion : str
        Motion family of the test data.
    noise_mode : str
        ``independent``, ``frozen`` or ``frozen-mismatch`` (module docstring).
    test_experiments : int
        Number of test experiments.
    fit_experiments : int
        Experiments the estimator fits, trains or calibrates on.
    seed : int
        Study seed: fit data use base seed ``seed``, test data ``seed +``
        :data:`TEST_SEED_OFFSET`.
    true_machine : str
        The machine that generates the data.
    fit_motion : str
        Motion family of the fit data.
    fit_noise : str
        Noise preset of the fit data.
    discard : int
        Samples not judged at the start of every test experiment.
    """

    label: str
    estimator: str
    options: tuple
    machine: str
    noise: str
    motion: str
    noise_mode: str
    test_experiments: int
    fit_experiments: int
    seed: int
    true_machine: str
    fit_motion: str
    fit_noise: str
    discard: int

    def option_dict(self) -> dict:
        """The estimator options as the estimator takes them (lists, not tuples)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.options}

    def axis_values(self) -> dict:
        """The cell's grid coordinates as result columns (``estimator`` is the label, options as
        sorted JSON)."""
        return {"estimator": self.label, "estimator_name": self.estimator,
                "options": json.dumps(self.option_dict(), sort_keys=True), "machine": self.machine,
                "noise": self.noise, "motion": self.motion, "noise_mode": self.noise_mode,
                "test_experiments": self.test_experiments, "fit_experiments": self.fit_experiments,
                "seed": self.seed, "true_machine": self.true_machine, "fit_motion": self.fit_motion,
                "fit_noise": self.fit_noise, "discard": self.discard}


@dataclass
class Study:
    """A parsed study file.

    Parameters
    ----------
    name : str
        The study's name (default the file's stem).
    description : str
        What the study shows (goes into the report).
    cells : list of Cell
        Every combination of the grid.
    axes : dict of str to list
        Every axis (``estimator`` first) with the values it takes in the grid.
    rows, columns : str
        Axes of the report's heatmap rows and columns; the other axes are pooled.
    source : str
        Where the study came from (its file), for messages and the report.
    config : dict
        The parsed TOML as read (saved in the report's settings).
    """

    name: str
    description: str
    cells: list[Cell]
    axes: dict[str, list]           #: every axis with the values it takes in the grid
    rows: str = "estimator"
    columns: str = "noise"
    source: str = ""
    config: dict = field(default_factory=dict)


def shipped_studies() -> dict[str, Traversable]:
    """The study files shipped in the package, ``{name: file}``, read through
    :mod:`importlib.resources` (so they are found in an installed wheel as in the sources)."""
    folder = resources.files("excavator_payload") / SHIPPED_STUDIES_FOLDER
    if not folder.is_dir():
        return {}
    return {entry.name[:-len(".toml")]: entry for entry in folder.iterdir()
            if entry.name.endswith(".toml") and entry.is_file()}


def find_study(config: str | Path) -> Path | Traversable:
    """The study file ``config``: a path, or the name of a shipped study (``full_grid`` or
    ``full_grid.toml``, see :func:`shipped_studies`).

    Parameters
    ----------
    config : str or Path
        A study file, or a shipped study's name.

    Returns
    -------
    Path or importlib.resources.abc.Traversable
        The study file.

    Raises
    ------
    StudyError
        When it is neither, listing the shipped studies.
    """
    path = Path(config)
    if path.is_file():
        return path
    shipped = shipped_studies()
    name = str(config)
    name = name[:-len(".toml")] if name.endswith(".toml") else name
    if name in shipped:
        return shipped[name]
    raise StudyError(f"study file '{config}' does not exist"
                     + (f" (shipped studies: {', '.join(sorted(shipped))})" if shipped else ""))


def load_study(config: str | Path) -> Study:
    """Parse and check a study file; names (estimators, noise presets, motions, machines) are
    checked here, at the edge, so that a typo fails before anything runs.

    Parameters
    ----------
    config : str or Path
        A study file (TOML), or a shipped study's name (:func:`find_study`).

    Returns
    -------
    Study
        The parsed study.

    Raises
    ------
    StudyError
        Naming the bad key or value.
    """
    path = find_study(config)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise StudyError(f"{path}: not a valid TOML file ({exc})") from None
    return parse_study(raw, source=str(path))


def _as_list(key: str, value, where: str) -> list:
    values = value if isinstance(value, list) else [value]
    if not values:
        raise StudyError(f"{where}: '{key}' is an empty list")
    return values


def _check_value(key: str, value, where: str):
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import MOTIONS
    from excavator_payload.simulation.sensors import PRESETS

    if key in ("noise", "fit_noise"):
        if not (value in PRESETS or (key == "fit_noise" and value == "same")):
            raise StudyError(f"{where}: unknown {key} '{value}': choose one of {', '.join(PRESETS)}")
    elif key in ("motion", "fit_motion"):
        if not (value in MOTIONS or (key == "fit_motion" and value == "same")):
            raise StudyError(f"{where}: unknown {key} '{value}': choose one of {', '.join(MOTIONS)}")
    elif key in ("machine", "true_machine"):
        try:
            load_machine(value)
        except ExcavatorPayloadError as exc:
            raise StudyError(f"{where}: {key}: {exc}") from None
    elif key == "noise_mode":
        if value not in NOISE_MODES:
            raise StudyError(f"{where}: unknown noise_mode '{value}': choose one of {', '.join(NOISE_MODES)}")
    elif key in ("test_experiments", "fit_experiments", "seed", "discard"):
        low = 0 if key in ("seed", "discard") else 1
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise StudyError(f"{where}: {key} must be a whole number ≥ {low}, got {value!r}")
    return value


def parse_study(raw: dict, source: str = "study") -> Study:
    """A :class:`Study` from the parsed TOML ``raw`` (see the module docstring).

    Parameters
    ----------
    raw : dict
        The study file as ``tomllib`` parsed it.
    source : str
        Where it came from, used in error messages and as the default name.

    Returns
    -------
    Study
        Every cell of the grid, names checked.

    Raises
    ------
    StudyError
        Naming the bad key or value, or when the grid is too big (:data:`MAX_CELLS`,
        :data:`MAX_EXPERIMENTS`).
    """
    from excavator_payload.estimators.base import estimator_class
    from excavator_payload.evaluation.metrics import display_label

    known_top = {"name", "description", "grid", "data", "estimators", "report"}
    unknown = sorted(set(raw) - known_top)
    if unknown:
        raise StudyError(f"{source}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known_top))}")
    grid, data, report = raw.get("grid", {}), raw.get("data", {}), raw.get("report", {})
    for table, name, allowed in ((grid, "[grid]", AXES), (data, "[data]", SETTINGS),
                                 (report, "[report]", {"rows": 0, "columns": 0})):
        if not isinstance(table, dict):
            raise StudyError(f"{source}: {name} must be a table")
        bad = sorted(set(table) - set(allowed))
        if bad:
            raise StudyError(f"{source}: {name}: unknown key(s) {', '.join(bad)}; known: {', '.join(allowed)}")
    entries = raw.get("estimators")
    if not isinstance(entries, list) or not entries:
        raise StudyError(f"{source}: no [[estimators]]: name at least one estimator")

    cells: list[Cell] = []
    labels: set[str] = set()
    planned = 0
    for i, entry in enumerate(entries, start=1):
        where = f"{source}: estimator #{i}"
        if not isinstance(entry, dict) or "name" not in entry:
            raise StudyError(f"{where}: give its registry 'name' (see `excavator-payload estimators`)")
        bad = sorted(set(entry) - {"name", "label", "options"} - set(AXES) - set(SETTINGS))
        if bad:
            raise StudyError(f"{where}: unknown key(s) {', '.join(bad)}")
        try:
            klass = estimator_class(str(entry["name"]))
        except ExcavatorPayloadError as exc:
            raise StudyError(f"{where}: {exc}") from None
        options = entry.get("options", {})
        if not isinstance(options, dict):
            # dict("epochs=3") crashed with an internal error
            raise StudyError(f"{where}: 'options' must be a table, e.g. options = {{ epochs = 300 }}, got "
                             f"{type(options).__name__} {options!r}")
        options = dict(options)
        unknown_options = sorted(set(options) - set(klass.OPTIONS))
        if unknown_options:
            raise StudyError(f"{where} ({entry['name']}): unknown option(s) {', '.join(unknown_options)}; "
                             f"known: {', '.join(klass.OPTIONS)}")
        if "progress" in klass.OPTIONS:
            options.setdefault("progress", False)  # a worker has no terminal to draw on
        axes = {k: [_check_value(k, v, where) for v in _as_list(k, entry.get(k, grid.get(k, d)), where)]
                for k, d in AXES.items()}
        if not klass.NEEDS_MACHINE:
            axes["machine"] = ["none"]  # believes in no machine file: one cell, not one per file
        settings = {k: _check_value(k, entry.get(k, data.get(k, d)), where) for k, d in SETTINGS.items()}
        machine_name = axes["machine"][0] if len(axes["machine"]) == 1 else None
        label = str(entry.get("label") or display_label(klass.name, options,
                                                          None if machine_name == "none" else machine_name))
        base, n = label, 2
        while label in labels:
            label, n = f"{base} #{n}", n + 1
        labels.add(label)
        frozen_options = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in options.items()))
        planned += math.prod(len(v) for v in axes.values())
        if planned > MAX_CELLS:  # counted before the grid is built: a 10⁶-cell grid hung here
            raise StudyError(f"{source}: the grid has at least {planned:,} cells, more than the {MAX_CELLS:,} one "
                             "study may have; split the study or shorten its axes")
        for combo in itertools.product(*axes.values()):
            values = dict(zip(axes, combo))
            cells.append(Cell(
                label=label, estimator=klass.name, options=frozen_options,
                machine=str(values["machine"]), noise=values["noise"], motion=values["motion"],
                noise_mode=values["noise_mode"], test_experiments=int(values["test_experiments"]),
                fit_experiments=int(values["fit_experiments"]), seed=int(values["seed"]),
                true_machine=str(settings["true_machine"]),
                fit_motion=values["motion"] if settings["fit_motion"] == "same" else settings["fit_motion"],
                fit_noise=values["noise"] if settings["fit_noise"] == "same" else settings["fit_noise"],
                discard=int(settings["discard"])))
    all_axes = {"estimator": list(dict.fromkeys(c.label for c in cells))}
    for axis in AXES:
        all_axes[axis] = list(dict.fromkeys(getattr(c, axis) for c in cells))
    varying = [a for a in all_axes if a != "estimator" and len(all_axes[a]) > 1]
    rows = report.get("rows", "estimator")
    columns = report.get("columns", varying[0] if varying else "noise")
    for key, axis in (("rows", rows), ("columns", columns)):
        if axis not in all_axes:
            raise StudyError(f"{source}: [report] {key} = '{axis}' is not an axis: choose one of "
                             f"{', '.join(all_axes)}")
    study = Study(str(raw.get("name", Path(source).stem)), str(raw.get("description", "")), cells,
                  all_axes, rows, columns, source, raw)
    experiments = study_experiments(study)
    if experiments > MAX_EXPERIMENTS:
        raise StudyError(f"{source}: the study simulates {experiments:.3g} experiments over {len(cells):,} "
                         f"cells, more than the {MAX_EXPERIMENTS:.0e} one run may ask for; lower "
                         "test_experiments / fit_experiments or split the study")
    return study


#: A study with more cells is refused (split it); counted before the grid is built.
MAX_CELLS = 100_000
#: A study simulating more experiments is refused.
MAX_EXPERIMENTS = 10_000_000
#: Beyond these the ``study`` command asks before it starts (or needs ``--yes``).
CONFIRM_CELLS = 2_000
CONFIRM_EXPERIMENTS = 100_000


def study_experiments(study: Study) -> int:
    """Experiments the study simulates: each distinct dataset (cells share fit and test data
    with the same machine, noise, motion, size, seed and noise mode) counted once.

    Parameters
    ----------
    study : Study
        A parsed study (:func:`load_study`).

    Returns
    -------
    int
        Number of experiments.
    """
    datasets = {}
    for c in study.cells:
        datasets[("fit", c.true_machine, c.fit_noise, c.fit_motion, c.fit_experiments, c.seed,
                  c.noise_mode)] = c.fit_experiments
        datasets[("test", c.true_machine, c.noise, c.motion, c.test_experiments, c.seed,
                  c.noise_mode)] = c.test_experiments
    return int(sum(datasets.values()))


def study_size(study: Study) -> str:
    """One line: cells, estimators, experiments to simulate.

    Parameters
    ----------
    study : Study
        A parsed study (:func:`load_study`).
    """
    return (f"study '{study.name}': {len(study.cells):,} cells ({len(study.axes['estimator'])} estimator(s)), "
            f"{study_experiments(study):,} experiments to simulate (fewer if cached)")


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


# -- the report ---------------------------------------------------------------------------------
def pooled(frame: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Figures per group: experiments, mean MAX, mean RMS (kg), share within 1 % of rated,
    pooled efficiency (RMS of error / bound over every judged sample).

    Parameters
    ----------
    frame : pandas.DataFrame
        Per-experiment results (``results.parquet``'s columns).
    by : list of str
        Columns to group by (axes of the grid).

    Returns
    -------
    pandas.DataFrame
        One row per group: ``by`` and ``experiments``, ``mean_max_kg``, ``mean_rms_kg``,
        ``worst_max_kg``, ``within_1pct`` (share), ``efficiency``.
    """
    def figures(g: pd.DataFrame) -> pd.Series:
        n_eff = g["n_efficiency"].sum()
        return pd.Series({
            "experiments": len(g),
            "mean_max_kg": g["max_error"].mean(),
            "mean_rms_kg": g["rms_error"].mean(),
            "worst_max_kg": g["max_error"].max(),
            "within_1pct": g["within_1pct"].astype(float).mean(),
            "efficiency": math.sqrt(g["sum_sq_efficiency"].sum() / n_eff) if n_eff else math.nan,
        })

    return frame.groupby(by, sort=False).apply(figures, include_groups=False).reset_index()


def _axis_order(study: Study, axis: str, present) -> list:
    order = [v for v in study.axes.get(axis, []) if v in set(present)]
    return order + [v for v in present if v not in order]


def _heatmap(table: pd.DataFrame, study: Study, value: str, title: str, fmt, cmap: str, log: bool = False):
    import matplotlib.colors as mcolors

    from excavator_payload.evaluation.figures import plt

    rows = _axis_order(study, study.rows, table[study.rows].unique())
    cols = _axis_order(study, study.columns, table[study.columns].unique())
    grid = table.pivot(index=study.rows, columns=study.columns, values=value).reindex(index=rows, columns=cols)
    data = grid.to_numpy(float)
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(cols), 1.0 + 0.45 * len(rows)))
    finite = data[np.isfinite(data)]
    norm = None
    if log and len(finite) and finite.min() > 0:
        norm = mcolors.LogNorm(vmin=finite.min(), vmax=max(finite.max(), finite.min() * 1.01))
    image = ax.imshow(np.ma.masked_invalid(data), aspect="auto", cmap=cmap, norm=norm,
                      **({} if norm is not None else {"vmin": 0.0, "vmax": 1.0} if value == "within_1pct" else {}))
    ax.set_xticks(range(len(cols)), [str(c) for c in cols], rotation=30, ha="right")
    ax.set_yticks(range(len(rows)), [str(r) for r in rows])
    ax.set_xlabel(study.columns)
    ax.set_ylabel(study.rows)
    for i in range(len(rows)):
        for j in range(len(cols)):
            v = data[i, j]
            ax.text(j, i, "–" if not np.isfinite(v) else fmt(v), ha="center", va="center", fontsize=8,
                    color="black", bbox={"facecolor": "white", "alpha": 0.6, "lw": 0, "pad": 1})
    fig.colorbar(image, ax=ax, fraction=0.04)
    ax.set_title(title, fontsize=10)
    return fig


def _error_against(results: pd.DataFrame, study: Study, axis: str):
    from excavator_payload.evaluation.figures import MARKERS, plt

    table = pooled(results, ["estimator", axis])
    values = _axis_order(study, axis, table[axis].unique())
    numeric = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values)
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for i, (label, g) in enumerate(table.groupby("estimator", sort=False)):
        g = g.set_index(axis).reindex(values)
        x = np.array(values, float) if numeric else np.arange(len(values))
        ax.plot(x, g["mean_rms_kg"].to_numpy(float), marker=MARKERS[i % len(MARKERS)], label=str(label))
    if not numeric:
        ax.set_xticks(range(len(values)), [str(v) for v in values])
    ax.set_yscale("log")
    ax.set_xlabel(axis)
    ax.set_ylabel("mean RMS error (kg)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f"error against {axis} (other axes pooled)", fontsize=10)
    return fig


def build_study_report(study: Study, results: pd.DataFrame, out_dir: Path, failures: dict | None = None,
                       timings: dict | None = None) -> Path:
    """``out_dir/report.html`` (figures embedded, PNGs in ``figures/`` beside it) and
    ``report.md``; returns the HTML path.

    Parameters
    ----------
    study : Study
        The study (its axes order the heatmaps).
    results : pandas.DataFrame
        Per-experiment results of the finished cells (may be empty).
    out_dir : Path
        Report folder; its ``figures/`` is replaced.
    failures : dict, optional
        Cell description -> reason it failed (shown).
    timings : dict, optional
        Stage -> seconds, shown in the settings.
    """
    from excavator_payload.evaluation import figures
    from excavator_payload.evaluation.report import _atomic_text, _render_html, _render_markdown, _Section

    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    shutil.rmtree(fig_dir, ignore_errors=True)
    fig_dir.mkdir(parents=True, exist_ok=True)
    sections = [_Section("Study", text=(study.description + " " if study.description else "")
                         + f"{len(study.cells)} cells from {study.source}; errors judged after the first "
                         f"{study.cells[0].discard} samples of every test experiment. Efficiency: RMS of "
                         "(error ÷ Cramér–Rao bound) over every judged sample, 1 = the physical limit for "
                         "the information the estimator uses; within 1 %: share of test experiments whose "
                         "MAX error is ≤ 1 % of the rated payload.")]
    if len(results):
        by = list(dict.fromkeys(["estimator", study.rows, study.columns]))
        table = pooled(results, by)
        eff = _heatmap(table, study, "efficiency", f"efficiency (1 = Cramér–Rao bound) by {study.rows} × "
                       f"{study.columns}", lambda v: f"{v:.3g}", "viridis_r", log=True)
        within = _heatmap(table, study, "within_1pct", f"share within 1 % of rated by {study.rows} × "
                          f"{study.columns}", lambda v: f"{100 * v:.0f}%", "RdYlGn")
        images = [(figures.save_png(eff, fig_dir / "heatmap_efficiency.png"), "Efficiency over the grid"),
                  (figures.save_png(within, fig_dir / "heatmap_within_1pct.png"),
                   "Share of test experiments within 1 % of rated payload")]
        sections.append(_Section(f"Heatmaps ({study.rows} × {study.columns})",
                                 text="Axes not shown are pooled.", images=images))
        axis_images = []
        for axis in [a for a in study.axes if a != "estimator" and len(results[a].unique()) > 1]:
            path = figures.save_png(_error_against(results, study, axis), fig_dir / f"error_vs_{axis}.png")
            axis_images.append((path, f"Mean RMS error against {axis}"))
        if axis_images:
            sections.append(_Section("Error against each axis", images=axis_images))
        varying = [a for a in study.axes if a != "estimator" and len(results[a].unique()) > 1]
        summary = pooled(results, ["estimator", *varying])
        summary["within_1pct"] = (100 * summary["within_1pct"]).round(1)
        sections.append(_Section("Every cell", text="within_1pct in %; kg otherwise.", table=summary))
    else:
        sections.append(_Section("No results", text="No cell finished; see the failures below."))
    if failures:
        sections.append(_Section("Failures", table=pd.DataFrame(
            {"cell": list(failures), "reason": list(failures.values())})))
    settings = {"study": study.config, "source": study.source, "version": __version__,
                "timings_s": {k: round(v, 2) for k, v in (timings or {}).items()}}
    sections.append(_Section("Settings", pre=json.dumps(settings, indent=2, default=str)))
    html_path = out_dir / "report.html"
    _atomic_text(html_path, _render_html(f"Study: {study.name}", sections, out_dir))
    _atomic_text(out_dir / "report.md", _render_markdown(f"Study: {study.name}", sections, out_dir))
    return html_path
