"""``excavator-payload demo``: the thesis end to end in one command.

1. simulate the training, validation and test sets (NMPC motions, thesis noise, truth
   columns) and the calibration lifts, with embedded defaults: nothing is downloaded;
2. fit or train every estimator (:data:`ROSTER`): the thesis' three EKFs, a tuned EKF, the
   UKF, inverse dynamics, the calibrated model, the quasi-static map and the networks Net₁,
   Net₂;
3. estimate on the test set, evaluate (:mod:`~excavator_payload.evaluation.metrics`) and
   write the report (:mod:`~excavator_payload.evaluation.report`).

Everything lands in the output folder and is cached there keyed by the settings that made
it (datasets, fitted models, estimates): a rerun, or a run after an interruption, redoes only
what is missing. An estimator that fails is reported with the reason; it does not stop the
demo.

Scales (:data:`SCALES`): ``quick`` (default; sized for ≈6 minutes on a 2-core machine),
``thesis`` (2000 simulated experiments, 100 train / 51 validation / 200 test, as in the
thesis) and ``tiny`` (seconds; for the test suite).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import pandas as pd
from rich.console import Console
from rich.markup import escape

from excavator_payload import __version__
from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset, read_estimates, write_dataset, write_estimates
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.estimators.traits import ESTIMATOR_TRAITS
from excavator_payload.execution import Execution
from excavator_payload.evaluation.metrics import (
    DEFAULT_DISCARD,
    Evaluation,
    bound_window,
    dataset_bound,
    evaluate_estimates,
)
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.lifts import simulate_lifts

#: The machine that generates all data (thesis §5.3).
TRUE_MACHINE = "cat345c"
#: Sensor noise of all data (appendix A.2).
NOISE = "thesis"


@dataclass(frozen=True)
class Scale:
    """Sizes of one demo scale (experiment counts).

    Parameters
    ----------
    train, validation, test : int
        Experiments of the training, validation and test sets.
    calibration : int
        Calibration experiments of the calibrated estimator (the first training ones).
    lifts : int
        Calibration lifts of the quasi-static map.
    pool : int
        Experiments simulated in all (≥ train + validation + test); 0: just those.
    chunk : int
        At most this many experiments per cached simulation file (what a resume redoes).
    plots : int
        Test experiments drawn like thesis Figures 7.1–7.12.
    net_options : dict
        Options given to the networks at this scale (those their class knows).
    note : str
        Sentence added to the report's headline.
    """

    train: int
    validation: int
    test: int
    calibration: int  #: calibration experiments of the calibrated estimator (≤ 10, thesis-like effort)
    lifts: int        #: calibration lifts of the quasi-static map
    pool: int = 0     #: experiments simulated in all (≥ train + validation + test), 0: just those
    chunk: int = 60   #: at most this many experiments per cached simulation file (resume granularity)
    plots: int = 6    #: test experiments drawn like thesis Figures 7.1–7.12
    net_options: dict = field(default_factory=dict)  #: options for the networks at this scale
    note: str = ""


SCALES: dict[str, Scale] = {
    "tiny": Scale(train=8, validation=4, test=6, calibration=4, lifts=4, plots=2,
                  net_options={"epochs": 2, "hidden": "4", "max_time": 10.0},
                  note="tiny: for tests only; the networks barely train"),
    # no wall-clock cap on training: a cap made the networks' figures depend on the machine's
    # load (Net₂ got 31 instead of 218 epochs in 240 s at load 7); 700 epochs take 2–3 min idle
    "quick": Scale(train=100, validation=51, test=200, calibration=10, lifts=10,
                   note="quick: the thesis' split (100 training, 51 validation, 200 test experiments) "
                        "simulated directly instead of drawn from 2000; networks trained for their "
                        "700 epochs (the whole demo takes about 6 minutes on 2 idle cores)"),
    "thesis": Scale(train=100, validation=51, test=200, calibration=10, lifts=10, pool=2000,
                    note="thesis: 2000 simulated experiments as the thesis' dataset; experiments 0–99 train, "
                         "100–150 validation (appendix A.3), 151–350 test (chapter 7's 200 simulations)"),
}


@dataclass(frozen=True)
class Entry:
    """One estimator of the demo.

    ``fit_on``: ``train``, ``train+validation`` (networks: they train on the first
    ``Scale.train`` experiments and log the validation error on the next ``Scale.validation``,
    appendix A.3), ``calibration`` (the first ``Scale.calibration`` training experiments:
    known payloads, thesis-like effort) or ``lifts``.

    Parameters
    ----------
    label : str
        Name in the tables and the report (the thesis' where it is the thesis' estimator).
    estimator : str
        Registry name of the estimator.
    machine : str or None
        Machine preset the estimator is given (``cat345c-3pct``: a 3 % wrong model).
    options : dict
        The estimator's keyword options.
    fit_on : str
        The data it is fitted on, as above.
    """

    label: str
    estimator: str
    machine: str | None = TRUE_MACHINE
    options: dict = field(default_factory=dict)
    fit_on: str = "train"

    @property
    def network(self) -> bool:
        """A network (its traits: it needs a training set): the scale's network options apply."""
        traits = ESTIMATOR_TRAITS.get(self.estimator)
        return traits is not None and traits.needs_training_set


#: Every estimator the demo runs, labelled as in the thesis where it is the thesis' one.
ROSTER: tuple[Entry, ...] = (
    Entry("Net1", "net1", fit_on="train+validation"),
    Entry("Net2", "net2", fit_on="train+validation"),
    Entry("EKF_ideal", "ekf", "cat345c", {"tuning": "thesis"}),
    Entry("EKF_1%", "ekf", "cat345c-1pct", {"tuning": "thesis"}),
    Entry("EKF_3%", "ekf", "cat345c-3pct", {"tuning": "thesis"}),
    Entry("EKF_tuned", "ekf", "cat345c"),
    Entry("UKF", "ukf", "cat345c"),
    Entry("inverse-dynamics", "inverse-dynamics", "cat345c"),
    Entry("calibrated (3% model)", "calibrated", "cat345c-3pct", fit_on="calibration"),  # first N train exps
    Entry("quasi-static", "quasi-static", "cat345c", fit_on="lifts"),
)


# -- small helpers --------------------------------------------------------------------------
def _key(obj: Any) -> str:
    """Short stable hash of JSON-able settings (cache keys)."""
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _safe(label: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in label)


def _concat(parts: Sequence[Dataset]) -> Dataset:
    if len(parts) == 1:
        return parts[0]
    meta = dict(parts[0].meta)
    meta["experiments"] = [e for p in parts for e in p.meta.get("experiments", [])]
    return Dataset(pd.concat([p.frame for p in parts], ignore_index=True), meta)


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}"[:400]


# -- data -----------------------------------------------------------------------------------
def simulate(n: int, first: int, seed: int, motion: str, execution: Execution) -> Dataset:
    """Simulate experiments ``first … first+n−1`` of base seed ``seed`` (truth columns on) through
    ``execution`` (the demo's one execution layer: one cluster for all its chunks).

    Parameters
    ----------
    n : int
        Number of experiments.
    first : int
        Number of the first experiment (its seed is derived from ``seed`` and its number).
    seed : int
        Base seed.
    motion : str
        ``nmpc`` or ``minimum-jerk``.
    execution : Execution
        Where the simulations run.

    Returns
    -------
    Dataset
        Thesis-sensor-set data of :data:`TRUE_MACHINE` with :data:`NOISE`, truth columns on.
    """
    if motion not in ("nmpc", "minimum-jerk"):
        raise ExcavatorPayloadError(f"unknown motion '{motion}': choose nmpc or minimum-jerk")
    return simulate_dataset(n, seed, TRUE_MACHINE, NOISE, with_truth=True, motion=motion,
                            first_experiment=first, execution=execution)


def simulate_lift_data(n: int, seed: int) -> Dataset:
    """Calibration lifts for the quasi-static map (``simulation.lifts.simulate_lifts``).

    Parameters
    ----------
    n : int
        Number of lifts.
    seed : int
        Seed of the lifts.
    """
    return simulate_lifts(n, seed, TRUE_MACHINE, NOISE, with_truth=True)


class Demo:
    """One demo run: settings, cache folders and what happened (timings, failures, notes).

    Parameters
    ----------
    out : Path
        Output folder; ``data``, ``models``, ``estimates`` and ``report`` are created in it.
    scale : str
        A key of :data:`SCALES`.
    workers : int or None
        Worker processes of the simulations; ``None`` the default.
    motion : str
        ``nmpc`` or ``minimum-jerk``.
    seed : int
        Base seed of every simulation.
    console : rich.console.Console
        Where progress is printed.
    """

    def __init__(self, out: Path, scale: str, workers: int | None, motion: str, seed: int,
                 console: Console) -> None:
        if scale not in SCALES:
            raise ExcavatorPayloadError(f"unknown scale '{scale}': choose one of {', '.join(SCALES)}")
        self.out = Path(out)
        self.scale_name = scale
        self.scale = SCALES[scale]
        self.workers = workers
        #: The execution layer of the demo's simulations, opened by :func:`run_demo` (a local
        #: cluster starts on first use only: nothing starts when every dataset is cached).
        self.execution: Execution | None = None
        self.motion = motion
        self.seed = int(seed)
        self.console = console
        self.timings: dict[str, float] = {}
        self.failures: dict[str, str] = {}
        self.notes: list[str] = [self.scale.note] if self.scale.note else []
        for sub in ("data", "models", "estimates", "report"):
            (self.out / sub).mkdir(parents=True, exist_ok=True)
        (self.out / "failures.log").unlink(missing_ok=True)  # this run's failures only

    # -- datasets ------------------------------------------------------------------------
    def _data_settings(self, first: int, n: int) -> dict:
        return {"what": "experiments", "first": first, "n": n, "seed": self.seed, "motion": self.motion,
                "machine": load_machine(TRUE_MACHINE).to_dict(), "noise": NOISE, "version": __version__}

    def experiments(self, name: str, first: int, n: int) -> Dataset:
        """Experiments ``first … first+n−1``, simulated in cached chunks.

        Parameters
        ----------
        name : str
            What they are for (``train``, ``test``, …), shown in progress lines.
        first : int
            Number of the first experiment.
        n : int
            Number of experiments.
        """
        parts = []
        n_chunks = -(-n // self.scale.chunk)
        size = -(-n // n_chunks)  # equal chunks of at most Scale.chunk experiments
        starts = list(range(first, first + n, size))
        for i, a in enumerate(starts):
            m = min(size, first + n - a)
            path = self.out / "data" / f"{self.motion}-{a:05d}-{a + m - 1:05d}-{_key(self._data_settings(a, m))}.parquet"
            if path.is_file():
                try:
                    parts.append(read_dataset(path))
                    continue
                except ExcavatorPayloadError:
                    path.unlink()  # a damaged cache file is simply made again
            self.console.print(f"  simulating {name}: experiments {a}–{a + m - 1} "
                               f"({i + 1}/{len(starts)}, {self.motion})")
            ds = simulate(m, a, self.seed, self.motion, self.execution)
            write_dataset(ds, path)
            parts.append(ds)
        return _concat(parts)

    def lifts(self) -> Dataset:
        """The quasi-static map's calibration lifts at this scale, simulated once and cached in
        the ``data`` folder."""
        settings = {"what": "lifts", "n": self.scale.lifts, "seed": self.seed + 1,
                    "machine": load_machine(TRUE_MACHINE).to_dict(), "noise": NOISE, "version": __version__}
        path = self.out / "data" / f"lifts-{_key(settings)}.parquet"
        if path.is_file():
            try:
                return read_dataset(path)
            except ExcavatorPayloadError:
                path.unlink()
        self.console.print(f"  simulating {self.scale.lifts} calibration lifts")
        ds = simulate_lift_data(self.scale.lifts, self.seed + 1)  # simulated in this process
        write_dataset(ds, path)
        return ds

    # -- estimators ----------------------------------------------------------------------
    def options_for(self, entry: Entry, klass) -> dict:
        """The entry's options plus the scale's network options the class knows.

        Parameters
        ----------
        entry : Entry
            The estimator of the demo.
        klass : type
            Its estimator class (its ``OPTIONS`` filter the scale's network options).

        Returns
        -------
        dict
            Keyword options for the estimator.
        """
        options = dict(entry.options)
        if entry.network:
            options.update({k: v for k, v in self.scale.net_options.items() if k in klass.OPTIONS})
            options.update({k: v for k, v in {"train_experiments": self.scale.train,
                                              "validation_experiments": self.scale.validation}.items()
                            if k in klass.OPTIONS})
        return {k: v for k, v in options.items() if k in klass.OPTIONS or k in entry.options}

    def fit(self, entry: Entry, data: dict[str, Dataset | None], data_keys: dict[str, str]):
        """Fit (or load the cached fit of) one estimator; returns (estimator, model folder).

        Parameters
        ----------
        entry : Entry
            The estimator of the demo.
        data : dict of str to Dataset or None
            The data by ``Entry.fit_on`` name; ``None`` where it could not be made.
        data_keys : dict of str to str
            Cache key of each of those data sets.
        """
        from excavator_payload.estimators.base import create_estimator, estimator_class, load_estimator

        klass = estimator_class(entry.estimator)
        options = self.options_for(entry, klass)
        machine = entry.machine if klass.NEEDS_MACHINE or entry.machine != TRUE_MACHINE else None
        fit_data = data.get(entry.fit_on)
        if fit_data is None:
            raise ExcavatorPayloadError(f"its {entry.fit_on} data could not be made "
                                        f"({self.failures.get('data: ' + entry.fit_on, 'unknown reason')})")
        key = _key({"estimator": entry.estimator, "options": options,
                    "machine": load_machine(machine).to_dict() if machine else None,
                    "fit_on": data_keys[entry.fit_on],
                    "version": __version__, "code": _source_key(klass)})
        folder = self.out / "models" / f"{_safe(entry.label)}-{key}"
        if (folder / "estimator.json").is_file():
            try:
                return load_estimator(folder), folder
            except ExcavatorPayloadError:
                shutil.rmtree(folder, ignore_errors=True)
        est = create_estimator(entry.estimator, machine=machine, **options)
        est.fit(fit_data)
        # A private temporary folder: two demos on one output folder never mix their files.
        tmp = folder.with_name(f"{folder.name}.partial-{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        est.save(tmp)
        _save_training_graph(est, tmp)
        shutil.rmtree(folder, ignore_errors=True)
        try:
            tmp.rename(folder)  # only complete fits are ever cached
        except OSError:  # another demo cached the same fit in between: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
        return est, folder

    def estimate(self, entry: Entry, est, folder: Path, test: Dataset, test_key: str) -> pd.DataFrame:
        """Estimates on the test set (cached next to the model's key).

        Parameters
        ----------
        entry : Entry
            The estimator of the demo (its label and name).
        est : Estimator
            The fitted estimator.
        folder : Path
            Its model folder (its name keys the cache).
        test : Dataset
            The test set.
        test_key : str
            Cache key of the test set.

        Returns
        -------
        pandas.DataFrame
            Estimates table (``experiment``, ``time``, ``payload_estimate``).
        """
        from excavator_payload.estimators.running import estimate_in_chunks, progress_bar

        path = self.out / "estimates" / f"{folder.name}-{test_key}.parquet"
        if path.is_file():
            try:
                return read_estimates(path)
            except ExcavatorPayloadError:
                path.unlink()
        with progress_bar(self.console) as progress:
            frame = estimate_in_chunks(est, test, progress, f"  {entry.label}: estimating")
        write_estimates(frame, path, meta={"estimator": entry.estimator, "model": str(folder)})
        return frame


#: Parts of the package a fit depends on (whole sub-packages: a change in a shared module such
#: as ``_kalman.py`` or ``trainbr.py`` must invalidate every cached fit that imports it).
FIT_SOURCES = ("estimators", "model", "data", "simulation/sensors.py")


def _source_key(obj=None) -> str:
    """Hash of every source file a fit depends on (:data:`FIT_SOURCES`), whatever ``obj`` is."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    try:
        for part in FIT_SOURCES:
            path = root / part
            files = sorted(p for p in path.rglob("*") if p.suffix in (".py", ".toml")) if path.is_dir() else [path]
            for f in files:
                digest.update(str(f.relative_to(root)).encode())
                digest.update(f.read_bytes())
    except OSError:
        return "unknown"
    return digest.hexdigest()[:12]


def _save_training_graph(est, folder: Path) -> None:
    """Networks that keep a training history but wrote no graph get one drawn from the log."""
    log = folder / "training_log.csv"
    if (folder / "training.png").is_file() or not log.is_file():
        return
    from excavator_payload.evaluation import figures

    try:
        figures.save_png(figures.training_log(pd.read_csv(log), f"{est.name} training"), folder / "training.png")
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError):
        pass  # the report says when a training graph is missing


def _calibration_curve(demo: Demo, data: dict[str, Dataset | None], test: Dataset) -> pd.DataFrame | None:
    """Accuracy of the calibrated estimator against the number of calibration experiments
    (``estimators.classical.calibrated.calibration_curve``; 0 = the uncalibrated 3 % model)."""
    from excavator_payload.estimators.classical import calibrated

    train = data.get("train")
    # The curve goes beyond the fitted estimator's calibration set (issue 3: 1, 2, 5, 10, 20
    # experiments) as far as the training set allows.
    top = train.n_experiments
    counts = sorted({c for c in (0, 1, 2, 5, 10, 20, min(demo.scale.calibration, top)) if c <= top})
    key = _key({"counts": counts, "train": demo._data_settings(0, train.n_experiments),
                "test": demo._data_settings(train.n_experiments, test.n_experiments),
                "test_ids": [int(i) for i in test.experiment_ids], "code": _source_key(calibrated)})
    path = demo.out / "estimates" / f"calibration-curve-{key}.csv"
    if path.is_file():
        try:
            return pd.read_csv(path)
        except (pd.errors.ParserError, pd.errors.EmptyDataError):
            path.unlink()
    curve = pd.DataFrame(calibrated.calibration_curve(train, test, counts=counts, machine="cat345c-3pct",
                                                      progress=True))
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    curve.to_csv(tmp, index=False)
    tmp.replace(path)
    return curve


# -- the demo -------------------------------------------------------------------------------
def run_demo(out: str | Path = "excavator-payload-demo", scale: str = "quick", workers: int | None = None,
             motion: str = "nmpc", seed: int = 2024, only: Sequence[str] | None = None,
             console: Console | None = None) -> dict:
    """Run the demo; returns ``{"report": Path, "evaluations": [...], "failures": {...}}``.

    Parameters
    ----------
    out : str or Path
        Output folder (cache and report).
    scale : str
        A key of :data:`SCALES`: ``tiny``, ``quick`` or ``thesis``.
    workers : int, optional
        Worker processes of the simulations; default the execution layer's.
    motion : str
        ``nmpc`` or ``minimum-jerk``.
    seed : int
        Base seed; the lifts use ``seed + 1``.
    only : sequence of str, optional
        Labels of :data:`ROSTER` to run (default all); an unknown label is refused.
    console : rich.console.Console, optional
        Where progress goes; default a new console.

    Returns
    -------
    dict
        ``report`` (the HTML path), ``markdown``, ``evaluations``, ``failures`` and ``timings`` (s).
    """
    from excavator_payload.evaluation.tables import summary_table
    from excavator_payload.evaluation.report import build_report, choose_experiments

    console = console or Console()
    demo = Demo(Path(out), scale, workers, motion, seed, console)
    sc = demo.scale
    roster = list(ROSTER)
    if only:
        known = {e.label for e in ROSTER}
        unknown = [o for o in only if o not in known]
        if unknown:
            raise ExcavatorPayloadError(f"--only: unknown estimator(s) {unknown}; choose from {sorted(known)}")
        roster = [e for e in ROSTER if e.label in only]
    t_start = time.perf_counter()

    # 1. data
    console.rule(f"[bold]1/4 data[/bold] ({scale} scale, {motion} motions)")
    t0 = time.perf_counter()
    total = max(sc.pool, sc.train + sc.validation + sc.test)
    first_test = sc.train + sc.validation
    with Execution(workers=workers) as demo.execution:
        train = demo.experiments("train", 0, sc.train)
        validation = demo.experiments("validation", sc.train, sc.validation)
        test = demo.experiments("test", first_test, sc.test)
        if total > first_test + sc.test:  # the rest of the thesis' 2000-experiment pool
            demo.experiments("pool", first_test + sc.test, total - first_test - sc.test)
    demo.execution = None
    data: dict[str, Dataset | None] = {"train": train, "validation": validation,
                                       "train+validation": _concat([train, validation]),
                                       "calibration": train.split(min(sc.calibration, sc.train))[0]}
    data_keys = {"train": _key(demo._data_settings(0, sc.train)),
                 "validation": _key(demo._data_settings(sc.train, sc.validation)),
                 "train+validation": _key(demo._data_settings(0, sc.train + sc.validation)),
                 "calibration": _key(demo._data_settings(0, min(sc.calibration, sc.train)))}
    test_key = _key(demo._data_settings(first_test, sc.test))
    if any(e.fit_on == "lifts" for e in roster):
        try:
            data["lifts"] = demo.lifts()
            data_keys["lifts"] = _key({"lifts": sc.lifts, "seed": seed + 1})
        except Exception as exc:  # noqa: BLE001 - the other estimators still run
            data["lifts"] = None
            data_keys["lifts"] = "none"
            demo.failures["data: lifts"] = _reason(exc)
            console.print(f"  [yellow]calibration lifts failed[/yellow]: {escape(_reason(exc))}")
    demo.timings["data"] = time.perf_counter() - t0

    # 2. fit
    console.rule("[bold]2/4 fit / train[/bold]")
    fitted = []
    for i, entry in enumerate(roster, start=1):
        console.print(f"[bold]{escape(entry.label)}[/bold] ({entry.estimator}, {i}/{len(roster)})")
        t0 = time.perf_counter()
        try:
            est, folder = demo.fit(entry, data, data_keys)
            fitted.append((entry, est, folder))
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # noqa: BLE001 - one estimator must not stop the demo
            demo.failures[entry.label] = "fit: " + _reason(exc)
            _log_failure(demo.out, entry.label, exc)
            console.print(f"  [red]failed[/red]: {escape(_reason(exc))}")
        demo.timings[f"fit {entry.label}"] = time.perf_counter() - t0

    # 3. estimate + evaluate
    console.rule(f"[bold]3/4 estimate on {test.n_experiments} test experiments and evaluate[/bold]")
    evaluations: list[Evaluation] = []
    bounds: dict = {}
    for entry, est, folder in fitted:
        t0 = time.perf_counter()
        try:
            frame = demo.estimate(entry, est, folder, test, test_key)
            window = bound_window(entry.estimator, est.options)
            if window not in bounds:
                bounds[window] = dataset_bound(test, window)
            evaluations.append(evaluate_estimates(
                test, frame, label=entry.label, window=window, bound=bounds[window],
                info={"estimator": entry.estimator, "options": est.options, "machine": entry.machine,
                      "model": str(folder), "fit_on": entry.fit_on}))
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # noqa: BLE001
            demo.failures[entry.label] = "estimate: " + _reason(exc)
            _log_failure(demo.out, entry.label, exc)
            console.print(f"  [red]{escape(entry.label)} failed[/red]: {escape(_reason(exc))}")
        demo.timings[f"estimate {entry.label}"] = time.perf_counter() - t0

    curve = None
    if any(e.estimator == "calibrated" for e in roster):
        t0 = time.perf_counter()
        try:
            curve = _calibration_curve(demo, data, test)
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # noqa: BLE001
            demo.failures["calibration curve"] = _reason(exc)
            console.print(f"  [yellow]calibration curve failed[/yellow]: {escape(_reason(exc))}")
        demo.timings["calibration curve"] = time.perf_counter() - t0

    # 4. report
    console.rule("[bold]4/4 report[/bold]")
    t0 = time.perf_counter()
    training = {e.label: f for e, _, f in fitted if e.network and any(ev.label == e.label for ev in evaluations)}
    demo.timings["total before report"] = time.perf_counter() - t_start
    settings = {
        "command": f"excavator-payload demo --out {out} --scale {scale} --motion {motion} --seed {seed}"
                   + (f" --workers {workers}" if workers else "") + (f" --only {','.join(only)}" if only else ""),
        "scale": scale, "sizes": asdict(sc), "motion": motion, "base_seed": seed,
        "experiment_numbers": {"train": [0, sc.train - 1], "validation": [sc.train, first_test - 1],
                               "test": [first_test, first_test + sc.test - 1],
                               "calibration": [0, min(sc.calibration, sc.train) - 1], "simulated": total},
        "lifts_seed": seed + 1, "true_machine": load_machine(TRUE_MACHINE).to_dict(), "noise": NOISE,
        "estimators": [{"label": e.label, "estimator": e.estimator, "machine": e.machine,
                        "options": e.options, "fit_on": e.fit_on} for e in roster],
        "workers": workers, "timings_s": {k: round(v, 2) for k, v in demo.timings.items()},
    }
    paths = build_report(demo.out / "report", test, evaluations, title="excavator-payload demo",
                         settings=settings, failures=demo.failures, calibration=curve,
                         experiments=choose_experiments(test, sc.plots),
                         training_dirs=training, notes=demo.notes)
    demo.timings["report"] = time.perf_counter() - t0
    console.print(summary_table(evaluations, f"Payload accuracy on {test.n_experiments} test experiments "
                                             f"(first {DEFAULT_DISCARD} samples discarded)"))
    for label, reason in demo.failures.items():
        console.print(f"[red]failed[/red] {escape(label)}: {escape(reason)}")
    console.print(f"total {time.perf_counter() - t_start:.0f} s; report: [bold]{escape(str(paths.html))}[/bold]")
    return {"report": paths.html, "markdown": paths.markdown, "evaluations": evaluations,
            "failures": dict(demo.failures), "timings": dict(demo.timings)}


def _log_failure(out: Path, label: str, exc: BaseException) -> None:
    """Keep the full traceback of a failed estimator for its author (the console shows one line)."""
    log = out / "failures.log"
    with log.open("a", encoding="utf-8") as fh:
        fh.write(f"--- {label} ({time.strftime('%Y-%m-%d %H:%M:%S')})\n")
        fh.write("".join(traceback.format_exception(exc)))
