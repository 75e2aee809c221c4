"""The in-memory dataset: a sample table plus per-experiment metadata."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
import pandas as pd

from excavator_payload.data.schema import (
    THESIS_SENSORS,
    SensorSet,
    detect_sensor_set,
    get_sensor_set,
)
from excavator_payload.errors import DatasetError


@dataclass
class Dataset:
    """Samples of many experiments, one row per sample of its sensor set.

    Parameters
    ----------
    frame : pandas.DataFrame
        ``experiment``, ``time``, the signals of :attr:`sensor_set`, ``payload`` (kg; absent in
        a field log, where nobody knows it) and optional ``true_*`` columns, rows grouped by
        ``experiment`` and in time order within each.
    meta : dict
        File-level metadata: ``sensor_set`` (name), ``machine`` (dict), ``noise`` (preset name), ``motion``,
        ``base_seed``, ``sample_rate``, and ``experiments``: a list of per-experiment dicts
        (``experiment``, ``seed``, ``payload``, ``start_pose``, ``target_pose``, ``status``, …).
    source : object, optional
        The file it was read from (None if made in memory); outputs must never overwrite it.
    """

    frame: pd.DataFrame
    meta: dict = field(default_factory=dict)
    #: The file it was read from (None if made in memory); outputs must never overwrite it.
    source: object = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        name = self.meta.get("sensor_set")
        if name is not None:
            sensors = get_sensor_set(name)
        else:
            sensors = detect_sensor_set(self.frame.columns) or THESIS_SENSORS
        missing = [c for c in ("experiment", "time", *sensors.signals) if c not in self.frame.columns]
        if missing:
            raise DatasetError(f"dataset ({sensors.name} sensor set) is missing column(s): "
                               f"{', '.join(missing)}")
        self._sensor_set = sensors

    @property
    def sensor_set(self) -> SensorSet:
        """The :class:`~excavator_payload.data.schema.SensorSet` whose signals this dataset holds."""
        return self._sensor_set

    @property
    def has_payload(self) -> bool:
        """Whether the true payload is known (simulated data, calibration lifts)."""
        return "payload" in self.frame.columns

    # -- structure -------------------------------------------------------------------------
    @property
    def experiment_ids(self) -> np.ndarray:
        """Experiment numbers, in file order."""
        return pd.unique(self.frame["experiment"].to_numpy())

    @property
    def n_experiments(self) -> int:
        return len(self.experiment_ids)

    @property
    def has_truth(self) -> bool:
        return all(c in self.frame.columns for c in self.sensor_set.required_truth_columns)

    @property
    def experiment_meta(self) -> dict[int, dict]:
        """Per-experiment metadata keyed by experiment number (empty dicts where unknown)."""
        by_id = {int(e["experiment"]): e for e in self.meta.get("experiments", [])}
        return {int(i): by_id.get(int(i), {}) for i in self.experiment_ids}

    def experiments(self) -> Iterator[tuple[int, pd.DataFrame]]:
        """Iterate ``(experiment number, its rows)`` in file order."""
        for exp_id, rows in self.frame.groupby("experiment", sort=False):
            yield int(exp_id), rows

    def subset(self, experiment_ids) -> "Dataset":
        """A dataset with only the given experiments (metadata filtered too).

        Parameters
        ----------
        experiment_ids : iterable of int
            Experiment numbers to keep; each must be in the dataset.

        Returns
        -------
        Dataset
            The rows and metadata of those experiments.
        """
        ids = [int(i) for i in experiment_ids]
        known = set(int(i) for i in self.experiment_ids)
        unknown = [i for i in ids if i not in known]
        if unknown:
            raise DatasetError(f"experiment(s) not in dataset: {unknown[:5]}")
        frame = self.frame[self.frame["experiment"].isin(ids)].reset_index(drop=True)
        meta = dict(self.meta)
        meta["experiments"] = [e for e in self.meta.get("experiments", []) if int(e["experiment"]) in set(ids)]
        return Dataset(frame, meta)

    def until_dump(self) -> "Dataset":
        """Each work cycle up to its dump: the rows before the ``release`` time its metadata
        holds (when the load starts to leave the bucket); the dataset itself when none has one.

        The ``payload`` column is the load carried, one per experiment, so after a dump it no
        longer is the mass in the bucket: estimators learn, and are judged, on the rows before.
        """
        release = {k: float(m["release"][0]) for k, m in self.experiment_meta.items() if m.get("release")}
        if not release:
            return self
        cut = self.frame["experiment"].map(release).fillna(np.inf).to_numpy(float)
        keep = self.frame["time"].to_numpy(float) < cut
        return Dataset(self.frame[keep].reset_index(drop=True), self.meta)

    def split(self, *counts: int) -> list["Dataset"]:
        """Consecutive splits by experiment count, e.g. ``split(100, 51)`` as appendix A.3."""
        ids = list(self.experiment_ids)
        if sum(counts) > len(ids):
            raise DatasetError(f"cannot split {len(ids)} experiments into {list(counts)}")
        out, start = [], 0
        for c in counts:
            out.append(self.subset(ids[start:start + c]))
            start += c
        return out

    def signals(self, columns=None) -> np.ndarray:
        """All rows of the given columns (default: the sensor set's signals) as floats (n_rows, n_columns).

        Parameters
        ----------
        columns : sequence of str, optional
            Column names; None: the sensor set's signals.
        """
        columns = self.sensor_set.signals if columns is None else columns
        return self.frame[list(columns)].to_numpy(dtype=float)

    def stacked(self, columns=None) -> np.ndarray:
        """Array (n_experiments, n_samples, n_columns); needs equal-length experiments.

        Parameters
        ----------
        columns : sequence of str, optional
            Column names; None: the sensor set's signals.
        """
        columns = self.sensor_set.signals if columns is None else columns
        sizes = self.frame.groupby("experiment", sort=False).size().to_numpy()
        if len(set(sizes)) != 1:
            raise DatasetError("experiments have different lengths; iterate experiments() instead")
        return self.signals(columns).reshape(len(sizes), int(sizes[0]), len(columns))

    @property
    def payloads(self) -> np.ndarray:
        """True payload per experiment (kg), in experiment order."""
        if not self.has_payload:
            raise DatasetError("the dataset has no 'payload' column (a field log?): the true "
                               "payload is needed here")
        return self.frame.groupby("experiment", sort=False)["payload"].first().to_numpy(dtype=float)

    def fingerprint(self) -> str:
        """SHA-256 (hex, 16 characters) of the experiment numbers, times and signals: estimates
        files carry it so that they are never judged against another dataset."""
        import hashlib

        h = hashlib.sha256()
        h.update(self.frame["experiment"].to_numpy().astype(np.int64).tobytes())
        h.update(np.ascontiguousarray(self.frame["time"].to_numpy(dtype=float)).tobytes())
        h.update(np.ascontiguousarray(self.signals()).tobytes())
        return h.hexdigest()[:16]

    def machine(self):
        """The :class:`~excavator_payload.model.machine.Machine` that generated the data, if known."""
        from excavator_payload.errors import MachineError
        from excavator_payload.model.machine import machine_from_dict

        m = self.meta.get("machine")
        try:
            return machine_from_dict(m) if isinstance(m, dict) else None
        except MachineError as exc:  # "machine: field ..." did not say which file
            where = f"{self.source}: " if self.source is not None else ""
            raise MachineError(f"{where}the machine in its metadata is not valid: {exc}") from None

    def __len__(self) -> int:
        return len(self.frame)

    def __repr__(self) -> str:
        return (f"Dataset({self.n_experiments} experiments, {len(self.frame)} samples, "
                f"sensors={self.sensor_set.name!r}, "
                f"noise={self.meta.get('noise')!r}, machine={self.meta.get('machine', {}).get('name')!r})")
