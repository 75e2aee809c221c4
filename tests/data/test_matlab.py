"""MATLAB export in the thesis' layout (appendix A.2), read back with scipy.io.loadmat."""

import numpy as np
import pytest
import scipy.io

from excavator_payload.data.matlab import INPUT_NAMES, INPUT_UNITS, export_mat
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import DatasetError


def test_export_reads_back_in_thesis_layout(mj_dataset, tmp_path):
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:4])
    path = tmp_path / "data.mat"
    export_mat(ds, path)
    cells = scipy.io.loadmat(path)["dataset"]
    assert cells.shape == (1, 4)  # 1×N cell array
    for i, (exp_id, rows) in enumerate(ds.experiments()):
        s = cells[0, i]
        assert set(s.dtype.names) == {"input", "output", "time", "input_names", "input_unit", "name", "note"}
        inp = s["input"][0, 0]
        assert inp.shape == (len(rows), 8)
        si = rows[list(SIGNALS)].to_numpy()
        np.testing.assert_allclose(inp[:, :6], np.degrees(si[:, :6]), rtol=1e-12)  # rad -> deg
        np.testing.assert_allclose(inp[:, 6:], si[:, 6:], rtol=1e-12)  # N·m stays N·m
        np.testing.assert_allclose(s["output"][0, 0].ravel(), rows["payload"].to_numpy())
        assert s["output"][0, 0].shape == (len(rows), 1)
        np.testing.assert_allclose(s["time"][0, 0].ravel(), rows["time"].to_numpy())
        assert [str(c[0]) for c in s["input_names"][0, 0].ravel()] == list(INPUT_NAMES)
        assert [str(c[0]) for c in s["input_unit"][0, 0].ravel()] == list(INPUT_UNITS)
        assert str(s["name"][0, 0][0]) == "dataset_excavator"
        assert f"experiment {exp_id}" in str(s["note"][0, 0][0])


def test_export_is_as_readable_as_the_other_outputs(mj_dataset, tmp_path):
    """The .mat file was 0600 (a private temporary file renamed) where a dataset is 0644."""
    import os
    import stat

    from excavator_payload.data.io import write_dataset

    ds = mj_dataset.subset(mj_dataset.experiment_ids[:1])
    previous = os.umask(0o022)
    try:
        export_mat(ds, tmp_path / "data.mat")
        write_dataset(ds, tmp_path / "data.parquet")
    finally:
        os.umask(previous)
    mode = stat.S_IMODE((tmp_path / "data.mat").stat().st_mode)
    assert mode == 0o644 == stat.S_IMODE((tmp_path / "data.parquet").stat().st_mode)


def test_thesis_column_order():
    assert INPUT_NAMES == ("Pos_LA", "Vel_LA", "Accel_LA", "Pos_UA", "Vel_UA", "Accel_UA",
                           "Torque_LA", "Torque_uA")
    assert INPUT_UNITS == ("deg", "deg/s", "deg/s^2", "deg", "deg/s", "deg/s^2", "Nm", "Nm")


def test_export_to_a_folder_is_an_error(mj_dataset, tmp_path):
    with pytest.raises(DatasetError, match="folder"):
        export_mat(mj_dataset, tmp_path)
