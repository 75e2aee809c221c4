"""``simulate --trajectory`` against plausible but wrong trajectories (issues 30, 31, 28).

* a recorded motion whose angles come in steps failed with "boom_head_pressure reaches 8.5e+08,
  implausible in Pa": now refused with the acceleration, where it is and the option that
  smooths, and ``--smooth SECONDS`` replays it;
* a motion faster than the pumps was simulated without a word: refused, or with
  ``--allow-overspeed`` simulated with a warning;
* a misspelt optional column was ignored (level ground simulated): named;
* negative experiment numbers passed the check and every experiment then failed: refused.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset
from excavator_payload.model.machine import load_machine

MACHINE = "cat345c-hydraulic"


def _motion(t, boom=(0.3, 0.5), dipper=(0.2, 0.7)) -> pd.DataFrame:
    return pd.DataFrame({"experiment": 0, "time": t, "boom_angle": 0.1 + boom[0] * np.sin(boom[1] * t),
                         "dipper_angle": -1.2 + dipper[0] * np.sin(dipper[1] * t),
                         "bucket_angle": -1.0 + 0.3 * np.sin(0.9 * t), "slew_angle": 0.4 * np.sin(0.4 * t),
                         "payload": 1000.0})


def _held(frame: pd.DataFrame, every: int) -> pd.DataFrame:
    """Angles of a slow sensor logged at the fast rate: each value held for ``every`` samples."""
    frame = frame.copy()
    keep = (np.arange(len(frame)) // every) * every
    for c in ("boom_angle", "dipper_angle", "bucket_angle", "slew_angle"):
        frame[c] = frame[c].to_numpy()[keep]
    return frame


def _simulate(tmp_path, frame: pd.DataFrame, *options: str):
    path = tmp_path / "trajectory.parquet"
    frame.to_parquet(path, index=False)
    out = tmp_path / "out.parquet"
    code = main(["simulate", "--machine", MACHINE, "--trajectory", str(path), "--out", str(out),
                 "--workers", "1", "--quiet", *options])
    return code, out


def _one_line(capsys, code) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    return lines[0]


def test_stepped_angles_are_refused_with_the_real_reason_and_smoothed_on_request(tmp_path, capsys):
    stepped = _held(_motion(np.arange(0, 6.0001, 0.01)), every=10)  # 10 Hz held at 100 Hz
    code, out = _simulate(tmp_path, stepped)
    line = _one_line(capsys, code)
    assert "experiment 0 at t = " in line and "accelerates at" in line and "rad/s²" in line
    assert "--smooth" in line and "every 0.1 s" in line
    assert "implausible" not in line and "in Pa" not in line and "radians" not in line  # no unit blamed
    assert not out.exists()
    code, out = _simulate(tmp_path, stepped, "--smooth", "0.2")
    capsys.readouterr()
    assert code == 0
    data = read_dataset(out)
    meta = data.meta["experiments"][0]
    assert meta["within_relief"] and meta["speed_share"] < 1.0
    relief = load_machine(MACHINE).hydraulics.relief_pressure
    assert data.frame["boom_head_pressure"].max() < relief
    # the smoothed replay keeps the motion: within a few hundredths of a radian of the true one
    smooth = _motion(data.frame["time"].to_numpy())
    assert np.abs(data.frame["boom_angle"].to_numpy() - smooth["boom_angle"].to_numpy()).max() < 0.03


def test_noisy_angles_are_called_noise_not_steps_and_smoothed_on_request(tmp_path, capsys):
    # a real log: 100 Hz angles with 1 mrad of sensor noise (they change at every sample)
    frame = _motion(np.arange(0, 6.0001, 0.01))
    rng = np.random.default_rng(0)
    for c in ("boom_angle", "dipper_angle", "bucket_angle", "slew_angle"):
        frame[c] = frame[c] + rng.normal(0.0, 0.001, len(frame))
    code, out = _simulate(tmp_path, frame)
    line = _one_line(capsys, code)
    assert "sensor noise" in line and "--smooth" in line and "steps" not in line
    assert not out.exists()
    code, out = _simulate(tmp_path, frame, "--smooth", "0.1")
    capsys.readouterr()
    assert code == 0 and read_dataset(out).meta["experiments"][0]["within_relief"]


def test_a_replay_faster_than_the_pumps_is_refused_or_flagged(tmp_path, capsys):
    fast = _motion(np.arange(0, 4.0001, 0.05), boom=(0.3, 1.2), dipper=(0.5, 1.5))
    code, out = _simulate(tmp_path, fast)
    line = _one_line(capsys, code)
    assert "times the speed the pumps" in line and "--allow-overspeed" in line and "experiment 0 at t" in line
    assert not out.exists()
    code, out = _simulate(tmp_path, fast, "--allow-overspeed")
    err = capsys.readouterr().err
    assert code == 0 and "warning: experiment 0 at t = " in err and "--allow-overspeed" in err
    assert read_dataset(out).meta["experiments"][0]["speed_share"] > 1.05


def test_a_slow_recorded_motion_replays_without_a_word(tmp_path, capsys):
    code, out = _simulate(tmp_path, _motion(np.arange(0, 4.0001, 0.1)).assign(operator="A"))
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "warning" not in captured.err
    assert "column(s) operator of the trajectory file are not trajectory columns and were ignored" in captured.err


@pytest.mark.parametrize("column,meant", [("ground_pich", "ground_pitch"), ("groundroll", "ground_roll"),
                                          ("Payload", None)])
def test_a_misspelt_column_is_named(tmp_path, capsys, column, meant):
    frame = _motion(np.arange(0, 4.0001, 0.1))
    if meant is None:  # a required column misspelt
        frame = frame.rename(columns={"payload": column})
    else:
        frame[column] = 0.05
    code, _ = _simulate(tmp_path, frame)
    line = _one_line(capsys, code)
    assert f"'{column}'" in line or "payload" in line
    if meant:
        assert f"did you mean '{meant}'" in line


def test_negative_experiment_numbers_are_refused(tmp_path, capsys):
    frame = pd.concat([_motion(np.arange(0, 4.0001, 0.1)).assign(experiment=k) for k in (-2, -1)])
    code, out = _simulate(tmp_path, frame)
    line = _one_line(capsys, code)
    assert "negative" in line and "numbered from 0" in line
    assert not out.exists()


def test_smooth_needs_a_trajectory_and_a_sane_width(tmp_path, capsys):
    code = main(["simulate", "--machine", MACHINE, "-n", "1", "--smooth", "0.2", "--out",
                 str(tmp_path / "x.parquet"), "--workers", "1", "--quiet"])
    assert "--trajectory" in _one_line(capsys, code)
    code, _ = _simulate(tmp_path, _motion(np.arange(0, 4.0001, 0.1)), "--smooth", "-1")
    assert "--smooth" in _one_line(capsys, code)
