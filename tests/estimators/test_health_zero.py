"""``excavator-payload zero`` refuses an offset built on a signal the sensor health monitor
flags (one line, exit 2), and zeroes anyway with ``--force``, saying which signal."""

import copy

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import write_dataset
from excavator_payload.estimators.health_screen import flagged_signals


@pytest.fixture(scope="module")
def files(tmp_path_factory, machine_calibration):
    d = tmp_path_factory.mktemp("zero")
    est = copy.deepcopy(machine_calibration["fitted"])  # calibration_data(3, seed=5), differentiated
    est.save(d / "model")
    zero = machine_calibration["zero"]  # zero_data(seed=6)
    write_dataset(zero, d / "clean.parquet")
    frame = zero.frame.copy()
    rate = np.abs(frame["boom_rate"].to_numpy())
    a = int(np.flatnonzero(rate > 0.5 * rate.max())[0])
    v = frame["boom_head_pressure"].to_numpy(float).copy()
    v[a:a + 100] = v[a - 1]  # a transmitter frozen for 1 s while the boom moves
    frame["boom_head_pressure"] = v
    write_dataset(Dataset(frame, zero.meta), d / "stuck.parquet")
    return d, est, zero


def test_clean_zero_motion_is_not_flagged(files):
    _, est, zero = files
    assert flagged_signals(est, zero) == {}


def test_zero_refuses_a_flagged_signal(files, capsys):
    d, _, _ = files
    code = main(["zero", "--model", str(d / "model"), "--data", str(d / "stuck.parquet"),
                 "--out", str(d / "refused")])
    err = capsys.readouterr().err
    assert code == 2
    assert "boom_head_pressure (stuck" in err and "--force" in err
    assert len(err.strip().splitlines()) == 1
    assert not (d / "refused").exists()


def test_zero_with_force_goes_on_and_says_so(files, capsys):
    d, _, _ = files
    code = main(["zero", "--model", str(d / "model"), "--data", str(d / "stuck.parquet"),
                 "--out", str(d / "forced"), "--force"])
    captured = capsys.readouterr()
    assert code == 0
    assert "--force: built on signals the health monitor flags: boom_head_pressure" in captured.err
    assert (d / "forced").is_dir()
