"""The in-memory dataset: a sample table plus per-experiment metadata."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
import pandas as pd

from excavator_payload.data.schema import COLUMNS, SIGNALS, TRUTH_COLUMNS
from excavator_payload.errors import DatasetError


@dataclass
class Dataset:
    """Samples of many experiments, one row per 20 Hz sample.

    Attributes
    ----------
    frame : pandas.DataFrame
        Columns :data:`~excavator_payload.data.schema.COLUMNS` (plus optional ``true_*``),
        sorted by ``experiment`` then ``time``.
    meta : dict
        File-level metadata: ``machine`` (dict), ``noise`` (preset name), ``motion``,
        ``base_seed``, ``sample_rate``, and ``experiments``: a list of per-experiment dicts
        (``experiment``, ``seed``, ``payload``, ``start_pose``, ``target_pose``, ``status``, …).
    """

    frame: pd.DataFrame
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [c for c in COLUMNS if c not in self.frame.columns]
        if missing:
            raise DatasetError(f"dataset is missing column(s): {', '.join(missing)}")

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
        return all(c in self.frame.columns for c in TRUTH_COLUMNS)

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
        """A dataset with only the given experiments (metadata filtered too)."""
        ids = [int(i) for i in experiment_ids]
        known = set(int(i) for i in self.experiment_ids)
        unknown = [i for i in ids if i not in known]
        if unknown:
            raise DatasetError(f"experiment(s) not in dataset: {unknown[:5]}")
        frame = self.frame[self.frame["experiment"].isin(ids)].reset_index(drop=True)
        meta = dict(self.meta)
        meta["experiments"] = [e for e in self.meta.get("experiments", []) if int(e["experiment"]) in set(ids)]
        return Dataset(frame, meta)

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

    def signals(self, columns=SIGNALS) -> np.ndarray:
        """All rows of the given columns as a float array (n_rows, n_columns)."""
        return self.frame[list(columns)].to_numpy(dtype=float)

    def stacked(self, columns=SIGNALS) -> np.ndarray:
        """Array (n_experiments, n_samples, n_columns); needs equal-length experiments."""
        sizes = self.frame.groupby("experiment", sort=False).size().to_numpy()
        if len(set(sizes)) != 1:
            raise DatasetError("experiments have different lengths; iterate experiments() instead")
        return self.signals(columns).reshape(len(sizes), int(sizes[0]), len(columns))

    @property
    def payloads(self) -> np.ndarray:
        """True payload per experiment (kg), in experiment order."""
        return self.frame.groupby("experiment", sort=False)["payload"].first().to_numpy(dtype=float)

    def machine(self):
        """The :class:`~excavator_payload.model.machine.Machine` that generated the data, if known."""
        from excavator_payload.model.machine import Machine

        m = self.meta.get("machine")
        return Machine.from_dict(m) if isinstance(m, dict) else None

    def __len__(self) -> int:
        return len(self.frame)

    def __repr__(self) -> str:
        return (f"Dataset({self.n_experiments} experiments, {len(self.frame)} samples, "
                f"noise={self.meta.get('noise')!r}, machine={self.meta.get('machine', {}).get('name')!r})")
