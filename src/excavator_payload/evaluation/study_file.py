"""The study file: its grid of cells (:class:`Cell`, :class:`Study`), how a TOML study file is
found, read and checked, and what a study may cost before it is refused or confirmed.

The study's format and what a run does are in :mod:`excavator_payload.evaluation.study`."""

from __future__ import annotations

import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.textfiles import read_config_text


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
        raw = tomllib.loads(read_config_text(path))
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
