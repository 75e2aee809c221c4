"""The health monitor's noise, offset and gain kinds (estimators.health): silent on clean data
of other motions, a noisy signal / a lasting angle offset / a rate's scale error named with the
right kind, a one-frame glitch not taken for noise, the noise reference saved with the model."""

import numpy as np
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

SIGNALS = list(MACHINE_SENSORS.signals)


@pytest.fixture(scope="module")
def fitting():
    return simulate_machine_dataset(2, seed=11)


@pytest.fixture(scope="module")
def reference(fitting):
    return health.noise_reference(fitting.frame, SIGNALS)


@pytest.fixture(scope="module")
def work():
    """Clean operator motion (another generator, seed and session than the fitting data)."""
    return simulate_machine_dataset(2, seed=31, session=2, motion="operator")


def _faults(reference, frame):
    """The monitor's fault string per sample of one experiment's frame."""
    mon = health.for_sensor_set(MACHINE_SENSORS, reference)
    x = frame[SIGNALS].to_numpy(float)
    t = frame["time"].to_numpy(float)
    return np.array([mon.step(t[i], x[i]) for i in range(len(t))], dtype=object)


def _one(work, e=0):
    return work.frame[work.frame["experiment"] == work.frame["experiment"].unique()[e]].reset_index(drop=True)


def _moving(frame, rate, share=0.3):
    r = np.abs(frame[rate].to_numpy())
    return int(np.flatnonzero(r > share * r.max())[0])


def test_reference_is_per_signal_and_positive(reference):
    assert set(reference) == set(SIGNALS)
    assert all(v > 0 for v in reference.values())


def test_clean_work_of_another_motion_raises_nothing(reference, work):
    for e in range(2):
        assert not any(_faults(reference, _one(work, e)))


@pytest.mark.parametrize("signal,sigma", [("dipper_head_pressure", 1.0e6), ("boom_angle", np.radians(0.75)),
                                          ("house_roll", np.radians(0.3))])
def test_noise_is_named_noise(reference, work, signal, sigma):
    frame = _one(work)
    a = len(frame) // 3
    v = frame[signal].to_numpy(float).copy()
    v[a:a + 150] += sigma * np.random.default_rng(1).standard_normal(150)
    frame[signal] = v
    faults = _faults(reference, frame)
    named = np.array([f"{signal}:noise" in f for f in faults])
    assert not named[:a].any()
    first = int(np.flatnonzero(named)[0])
    assert a <= first <= a + 60  # a share of a 0.5 s window, judged every 5 samples
    assert named[a + 60:a + 150].all()


def test_one_glitch_frame_is_not_noise(reference, work):
    frame = _one(work)
    a = len(frame) // 2
    v = frame["boom_head_pressure"].to_numpy(float).copy()
    v[a] += 5e6  # 50 bar for one frame: the outlier gate's, not a noisy transmitter
    frame["boom_head_pressure"] = v
    assert not any("noise" in f for f in _faults(reference, frame))


def test_lasting_angle_offset_stays_named(reference, work):
    """A 5° step that lasts: 'disagree' sees only its edge (0.1 s window + 0.2 s hold); the
    offset against the integrated rate keeps it named for seconds."""
    frame = _one(work)
    a = _moving(frame, "dipper_rate")
    b = min(len(frame), a + 300)
    v = frame["dipper_angle"].to_numpy(float).copy()
    v[a:b] += np.radians(5)
    frame["dipper_angle"] = v
    faults = _faults(reference, frame)
    offset = np.array(["dipper_angle:offset" in f for f in faults])
    assert offset[a:a + 30].any()
    assert offset[a + 50:b].all()  # long after the edge: still named
    assert "dipper_rate:offset" in faults[a + 100]  # both of the pair: the data cannot tell which


def test_rate_scale_error_is_named_gain_or_offset(reference, work):
    """A rate reading 25 % high while its joint sweeps: the angle no longer follows its integral."""
    frame = _one(work)
    a = _moving(frame, "boom_rate", 0.1)
    v = frame["boom_rate"].to_numpy(float).copy()
    v[a:] *= 1.25
    frame["boom_rate"] = v
    faults = _faults(reference, frame)
    named = np.array([("boom_rate:gain" in f) or ("boom_rate:offset" in f) for f in faults])
    assert not named[:a].any()
    assert named[a:].any()


@pytest.mark.parametrize("rate", ["boom_rate", "bucket_rate"])
def test_a_lasting_rate_bias_is_named_offset_once_the_track_slopes(reference, work, rate):
    """A rate reading 1 °/s high from a move on, to the end: the track of angle − integrated
    rate (τ = 4 s) absorbs it and the offset check never names it; its slope passes 0.5 °/s and
    the rate is named offset (7 s after the onset here), nothing before the onset nor on the
    clean run. The boom's own level limit (``LINK_OFFSET_LIMIT``) names a boom rate's bias
    sooner than the slope does."""
    frame = _one(work)
    a = _moving(frame, rate, 0.1)
    v = frame[rate].to_numpy(float).copy()
    v[a:] += np.radians(1.0)
    frame[rate] = v
    faults = _faults(reference, frame)
    named = np.array([f"{rate}:offset" in f for f in faults])
    assert not named[:a].any()
    assert named[a:].any()
    assert not any(_faults(reference, _one(work)))
    limit, own = health.OFFSET_SLOPE_LIMIT, health.LINK_OFFSET_LIMIT
    try:  # the boom's own level limit off: named by the slope alone, later
        health.LINK_OFFSET_LIMIT = {}
        by_slope = np.array([f"{rate}:offset" in f for f in _faults(reference, frame)])
        health.OFFSET_SLOPE_LIMIT = np.inf  # and the bound lifted too: the same bias goes unnamed
        lifted = np.array([f"{rate}:offset" in f for f in _faults(reference, frame)])
    finally:
        health.OFFSET_SLOPE_LIMIT, health.LINK_OFFSET_LIMIT = limit, own
    assert not lifted.any()
    assert by_slope.any()
    if rate == "boom_rate":  # the boom's own limit (LINK_OFFSET_LIMIT) names it sooner
        assert np.argmax(named) < np.argmax(by_slope)
    else:
        assert (named == by_slope).all()


def test_noise_reference_is_saved_and_a_noisy_signal_never_ok(fitting, work, tmp_path):
    est = create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(fitting)
    est.save(tmp_path / "m")
    loaded = load_estimator(tmp_path / "m")
    assert loaded.health_reference == pytest.approx(est.health_reference)
    frame = _one(work)
    a = len(frame) // 3
    v = frame["boom_head_pressure"].to_numpy(float).copy()
    v[a:a + 200] += 1.5e6 * np.random.default_rng(2).standard_normal(200)
    frame["boom_head_pressure"] = v
    out = loaded.estimate(Dataset(frame, work.meta))
    flagged = out["fault"].str.contains("boom_head_pressure:noise", regex=False).to_numpy()
    first = int(np.flatnonzero(flagged)[0])
    status = out["status"].to_numpy()
    assert (status[flagged] == Status.SENSOR_FAULT.value).all()
    assert not (status[first:a + 200] == "ok").any()
