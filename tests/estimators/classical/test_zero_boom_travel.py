"""The zero check refuses an empty motion that hardly moved the boom (issue 28): its offsets take
up the model's error at that one boom pose, though its own posterior says it determined them
(docs/findings/machine-calibration.md, "Which empty motions a zero accepts")."""

import copy
import math

import numpy as np
import pandas as pd
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import create_estimator
from excavator_payload.estimators.classical import zero_quality as zq
from excavator_payload.estimators.classical.machine_calibration.settings import MIN_ZERO_BOOM_TRAVEL
from excavator_payload.evaluation import demo_machine as dm

DEG = math.pi / 180


def sines(boom_amplitude_deg: float, boom_hz: float, seed: int = 9) -> Dataset:
    """14 s of an empty arm whose joints all follow sines at once (the arm never stops): the
    boom ±``boom_amplitude_deg`` about −10° at ``boom_hz``, the dipper ±10°, the bucket ±25°, the
    slew ±40°."""
    t = np.arange(0, 14.0, 0.01)
    table = pd.DataFrame({
        "experiment": 0, "time": t,
        "boom_angle": -10 * DEG + boom_amplitude_deg * DEG * np.sin(2 * math.pi * boom_hz * t),
        "dipper_angle": -90 * DEG + 10 * DEG * np.sin(2 * math.pi * 0.2 * t + 1.0),
        "bucket_angle": -60 * DEG + 25 * DEG * np.sin(2 * math.pi * 0.2 * t + 2.0),
        "slew_angle": 40 * DEG * np.sin(2 * math.pi * 0.1 * t), "payload": 0.0})
    return dm.simulate_trajectory(table, seed, dm.SESSION_WORK)


@pytest.fixture(scope="module")
def setup():
    """4 calibration swings (session 1) and the calibrated estimator; two empty sine motions
    (session 2): the boom ±3° at 0.4 Hz (6° of travel, at 0.13 rad/s, 60 % of what the pump
    gives it) and ±15° at 0.07 Hz (30°)."""
    cal = create_estimator("calibrated", "cat345c-hydraulic-3pct", model_std="none").fit(dm.calibration_data(4, seed=5))
    return dict(calibrated=cal, small=sines(3.0, 0.4), large=sines(15.0, 0.07))


def test_boom_travel_is_the_percentile_range_of_the_measured_boom_angle(setup):
    """6° of sine travel reads 5.5-6°; one stray sample 30° off does not count."""
    ds = setup["small"]
    travel = zq.boom_travel(ds)
    assert 5.5 * DEG < travel <= 6.05 * DEG
    frame = ds.frame.copy()
    frame.loc[500, "boom_angle"] += 30 * DEG
    assert zq.boom_travel(Dataset(frame, ds.meta)) == pytest.approx(travel, abs=0.1 * DEG)


def test_a_zero_that_hardly_moved_the_boom_is_refused_with_what_to_do(setup):
    """The boom moved 6°: its cylinder moved all along and the posterior determined every
    cylinder's offsets and predicts a weighing error within 1 % of rated (main accepted it), but
    the zero is refused, naming the boom's travel and how to move it; with 30° of boom travel the
    same motion is not refused."""
    est = copy.deepcopy(setup["calibrated"])
    est.zero(setup["small"])
    assert np.all(est.zero_quality.determined < zq.DETERMINED_SHARE)
    assert est.zero_quality.predicted_error < zq.MAX_ERROR_SHARE * dm.RATED_PAYLOAD
    reasons = [r for r in est.zero_refusals if "boom through only" in r]
    assert len(reasons) == 1 and len(est.zero_refusals) == 1
    assert f"{math.degrees(MIN_ZERO_BOOM_TRAVEL):.0f}° or more" in reasons[0]
    assert "raising and lowering the boom" in reasons[0]
    good = copy.deepcopy(setup["calibrated"])
    good.zero(setup["large"])
    assert good.zero_refusals == []


def test_cli_refuses_a_zero_that_hardly_moved_the_boom(setup, tmp_path, capsys):
    """excavator-payload zero: exit 2 with one error line that says how far the boom moved and
    how to repeat the zero, nothing saved; --force saves it with the reason as a warning."""
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset

    setup["calibrated"].save(tmp_path / "model")
    write_dataset(setup["small"], tmp_path / "small.parquet")
    args = ["zero", "--model", str(tmp_path / "model"), "--data", str(tmp_path / "small.parquet")]
    assert main([*args, "--out", str(tmp_path / "z1")]) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "zero refused" in err
    assert "moved the boom through only 6°" in err and "raising and lowering the boom" in err
    assert not (tmp_path / "z1").exists()
    assert main([*args, "--out", str(tmp_path / "z2"), "--force"]) == 0
    assert "boom through only" in capsys.readouterr().err and (tmp_path / "z2" / "estimator.json").exists()
