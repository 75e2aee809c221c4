"""Export a dataset in the thesis' MATLAB layout (appendix A.2, ``Simulation.mat``).

The file holds one variable, ``dataset``: a 1×N cell array with one struct per experiment::

    dataset{exp}.input        % n×8: Pos_LA Vel_LA Accel_LA Pos_UA Vel_UA Accel_UA Torque_LA Torque_uA
    dataset{exp}.output       % n×1: payload, kg
    dataset{exp}.time         % n×1: s
    dataset{exp}.input_names  % 1×8 cell of the column names above
    dataset{exp}.input_unit   % {'deg' 'deg/s' 'deg/s^2' 'deg' 'deg/s' 'deg/s^2' 'Nm' 'Nm'}
    dataset{exp}.name         % 'dataset_excavator'
    dataset{exp}.note         % where the experiment comes from (seed, noise, machine)

``LA`` (lower arm) is the boom and ``UA`` (upper arm) the dipper; angles are converted from
the package's radians to the thesis' degrees. Read it in MATLAB with ``load('file.mat')`` or in
Python with ``scipy.io.loadmat``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import scipy.io

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.data.io import new_file_mode
from excavator_payload.errors import DatasetError

#: The thesis' column names, in the order of :data:`~excavator_payload.data.schema.SIGNALS`.
INPUT_NAMES = ("Pos_LA", "Vel_LA", "Accel_LA", "Pos_UA", "Vel_UA", "Accel_UA", "Torque_LA", "Torque_uA")
INPUT_UNITS = ("deg", "deg/s", "deg/s^2", "deg", "deg/s", "deg/s^2", "Nm", "Nm")
#: Factor from the package's SI column to the thesis' unit.
TO_THESIS_UNITS = np.array([180 / np.pi] * 6 + [1.0, 1.0])
DATASET_NAME = "dataset_excavator"


def _cell_row(strings) -> np.ndarray:
    """A 1×k object array: ``savemat`` writes it as a cell array of strings."""
    cell = np.empty((1, len(strings)), dtype=object)
    for i, s in enumerate(strings):
        cell[0, i] = s
    return cell


def dataset_to_cells(dataset: Dataset) -> np.ndarray:
    """The 1×N object array of per-experiment structs (dicts) that ``savemat`` writes.

    Parameters
    ----------
    dataset : Dataset
        A dataset of the thesis sensor set; signals are converted to the thesis' units.
    """
    experiment_meta = dataset.experiment_meta
    noise = dataset.meta.get("noise", "unknown")
    machine = (dataset.meta.get("machine") or {}).get("name", "unknown")
    motion = dataset.meta.get("motion", "unknown")
    cells = np.empty((1, dataset.n_experiments), dtype=object)
    for i, (exp_id, rows) in enumerate(dataset.experiments()):
        info = experiment_meta.get(exp_id, {})
        note = (f"experiment {exp_id}, seed {info.get('seed', dataset.meta.get('base_seed', '?'))}, "
                f"motion {motion}, noise {noise}, machine {machine}; "
                "LA = boom, UA = dipper (angle relative to the boom)")
        cells[0, i] = {
            "input": rows[list(SIGNALS)].to_numpy(dtype=float) * TO_THESIS_UNITS,
            # A field log has no true payload: NaN, as MATLAB marks a missing value.
            "output": (rows[["payload"]].to_numpy(dtype=float) if "payload" in rows.columns
                       else np.full((len(rows), 1), np.nan)),
            "time": rows[["time"]].to_numpy(dtype=float),
            "input_names": _cell_row(INPUT_NAMES),
            "input_unit": _cell_row(INPUT_UNITS),
            "name": DATASET_NAME,
            "note": note,
        }
    return cells


def export_mat(dataset: Dataset, path: str | Path) -> None:
    """Write ``dataset`` to the MATLAB file ``path`` (variable ``dataset``), atomically.

    Parameters
    ----------
    dataset : Dataset
        A dataset of the thesis sensor set, at least one experiment.
    path : str or pathlib.Path
        Destination ``.mat`` file; must not be the dataset's own source file.

    Raises
    ------
    DatasetError
        If the dataset is empty or the file cannot be written.
    """
    path = Path(path)
    if dataset.sensor_set.signals != SIGNALS:
        raise DatasetError(f"the thesis' MATLAB layout holds the thesis sensor set, not "
                           f"'{dataset.sensor_set.name}'")
    if dataset.n_experiments == 0:
        raise DatasetError("the dataset has no experiments to export")
    if path.is_dir():
        raise DatasetError(f"output '{path}' is a folder; give a file name such as data.mat")
    if dataset.source is not None:
        from excavator_payload.data.io import check_output_path

        check_output_path(path, inputs=[dataset.source])
    cells = dataset_to_cells(dataset)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise DatasetError(f"cannot write '{path}': {exc}") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            scipy.io.savemat(handle, {"dataset": cells}, do_compression=True, oned_as="column")
        os.chmod(tmp, new_file_mode())  # mkstemp makes 0600; as readable as the other outputs
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
