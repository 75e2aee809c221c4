"""The hydraulic machine's simulator: columns, sessions, reproducibility, replay, limits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import DatasetError, ExcavatorPayloadError
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation import machine_sim
from excavator_payload.simulation.generate import partial_folder, simulate_dataset
from excavator_payload.simulation.machine_sensors import get_machine_noise, session_offsets
from excavator_payload.simulation.machine_sim import (

    simulate_machine_dataset,
    simulate_machine_to_file,
)
from excavator_payload.simulation.trajectory import trajectory_from_frame

MACHINE = "cat345c-hydraulic"


@pytest.fixture(scope="module")
def cycles():
    return simulate_machine_dataset(3, seed=5, session=1, motion="work-cycle", with_truth=True)


def test_columns_are_the_machine_sensor_set(cycles):
    assert cycles.sensor_set.name == "machine"
    assert list(cycles.frame.columns) == list(MACHINE_SENSORS.columns) + list(MACHINE_SENSORS.truth_columns)
    plain = simulate_machine_dataset(1, seed=5, motion="lifts")
    assert list(plain.frame.columns) == list(MACHINE_SENSORS.columns)
    dt = np.diff(cycles.frame[cycles.frame.experiment == 0]["time"].to_numpy())
    np.testing.assert_allclose(dt, 1 / MACHINE_SENSORS.sample_rate)


def test_generated_motions_stay_within_the_hydraulics(cycles):
    machine = load_machine(MACHINE)
    for meta in cycles.meta["experiments"]:
        assert meta["within_relief"] and meta["peak_pressure"] <= machine.hydraulics.relief_pressure
        assert meta["speed_share"] <= 1.0
    f = cycles.frame
    assert f[[c for c in f.columns if c.startswith("true_") and c.endswith("pressure")]].to_numpy().min() > 0
    # the house slews and the angles stay in their ranges
    assert np.ptp(f["true_slew_angle"]) > np.radians(40)
    for j, name in enumerate(("boom", "dipper", "bucket")):
        lo, hi = machine.angle_ranges[j]
        assert f[f"true_{name}_angle"].between(lo, hi).all()


def test_sensor_offsets_differ_between_sessions_not_between_seeds():
    field = get_machine_noise("field")
    assert session_offsets(1, field) == session_offsets(1, field)
    assert session_offsets(1, field) != session_offsets(2, field)
    # Offsets only (no white noise or ripple): the error at rest is exactly the session's offset.
    offsets_only = dataclasses.replace(field, name="offsets", angle_noise=0.0, rate_noise=0.0,
                                       inclination_noise=0.0, pressure_noise=0.0, ripple_fraction=0.0)
    a = simulate_machine_dataset(1, seed=1, session=7, noise=offsets_only, motion="lifts", with_truth=True)
    b = simulate_machine_dataset(1, seed=2, session=7, noise=offsets_only, motion="lifts", with_truth=True)
    c = simulate_machine_dataset(1, seed=1, session=8, noise=offsets_only, motion="lifts", with_truth=True)

    def offset(d, name):  # at rest before the lift starts (no IMU lag or acceleration error)
        rest = d.frame[d.frame.time < 0.95]
        return float((rest[name] - rest[f"true_{name}"]).mean())

    for name in MACHINE_SENSORS.signals:
        assert offset(a, name) == pytest.approx(session_offsets(7, field)[name], rel=1e-6, abs=1e-12)
        assert offset(a, name) == pytest.approx(offset(b, name), rel=1e-6, abs=1e-12)
        assert offset(a, name) != pytest.approx(offset(c, name), rel=1e-3)
    a = simulate_machine_dataset(1, seed=1, session=7, motion="lifts")
    b = simulate_machine_dataset(1, seed=2, session=7, motion="lifts")
    # the noise itself differs between seeds
    assert not np.allclose(a.frame["boom_angle"], b.frame["boom_angle"])
    assert session_offsets(3, get_machine_noise("none")) == {s: 0.0 for s in MACHINE_SENSORS.signals}


def test_bit_identical_whatever_the_chunking():
    from excavator_payload.simulation.generate import make_spec, simulate_chunk

    spec = make_spec(3, 9, load_machine(MACHINE), "field", True, "swing", session=2)
    whole, metas, _ = simulate_chunk(spec, 0, 3)
    parts = [simulate_chunk(spec, k, 1)[0] for k in range(3)]
    pd.testing.assert_frame_equal(whole, pd.concat(parts, ignore_index=True))
    parallel = simulate_machine_dataset(3, seed=9, session=2, motion="swing", with_truth=True, workers=2)
    pd.testing.assert_frame_equal(parallel.frame, whole)


def test_trajectory_replay_reproduces_the_angles():
    t = np.arange(0, 6.0001, 0.05)  # 20 Hz
    boom = 0.1 + 0.3 * np.sin(0.5 * t)
    dipper = -1.2 + 0.2 * np.sin(0.7 * t)
    bucket = -1.0 + 0.3 * np.sin(0.9 * t)
    slew = 0.4 * np.sin(0.4 * t)
    frame = pd.DataFrame({"experiment": 4, "time": t, "boom_angle": boom, "dipper_angle": dipper,
                          "bucket_angle": bucket, "slew_angle": slew, "payload": 2000.0})
    replay = simulate_machine_dataset(1, seed=0, noise="none", motion="trajectory", with_truth=True,
                                      trajectory=trajectory_from_frame(frame))
    rows = replay.frame
    assert list(replay.experiment_ids) == [4]
    time = rows["time"].to_numpy()
    assert len(time) == 601
    np.testing.assert_allclose(rows["boom_angle"], 0.1 + 0.3 * np.sin(0.5 * time), atol=2e-5)
    np.testing.assert_allclose(rows["true_slew_angle"], 0.4 * np.sin(0.4 * time), atol=2e-5)
    np.testing.assert_allclose(rows["slew_rate"], 0.16 * np.cos(0.4 * time), atol=2e-3)
    # at the file's own sample times the spline goes through the given angles exactly
    np.testing.assert_allclose(rows["dipper_angle"].to_numpy()[::5], dipper, atol=1e-12)
    assert rows["payload"].eq(2000.0).all()
    with pytest.raises(DatasetError, match="slew_angle"):
        trajectory_from_frame(frame.drop(columns="slew_angle"))


def test_lifts_are_slow_constant_speed_boom_lifts():
    lifts = simulate_machine_dataset(2, seed=0, noise="none", motion="lifts", with_truth=True)
    assert list(lifts.payloads) == [0.0, load_machine(MACHINE).rated_payload]
    rows = lifts.frame[lifts.frame.experiment == 0]
    middle = rows[(rows.time > 5) & (rows.time < 15)]
    np.testing.assert_allclose(middle["boom_rate"], np.radians(5), rtol=1e-9)
    assert np.allclose(rows["slew_rate"], 0) and np.ptp(rows["dipper_angle"]) == 0


def test_slopes_tilt_the_house():
    slopes = simulate_machine_dataset(1, seed=3, noise="none", motion="slopes", with_truth=True)
    tilt = slopes.meta["experiments"][0]["tilt"]
    assert 0 < np.hypot(*tilt) <= np.radians(10)
    pitch = slopes.frame["house_pitch"].to_numpy()
    assert np.ptp(pitch) > 1e-3  # the house's inclination changes as it slews on the slope


def test_bad_input_gives_one_line_errors():
    with pytest.raises(ExcavatorPayloadError, match="unknown motion"):
        simulate_machine_dataset(1, motion="nmpc-ish")
    with pytest.raises(ExcavatorPayloadError, match="noise preset"):
        simulate_machine_dataset(1, noise="thesis")
    with pytest.raises(ExcavatorPayloadError, match="hydraulic machine"):
        simulate_machine_dataset(1, machine="cat345c")
    with pytest.raises(ExcavatorPayloadError, match="hydraulic machine only"):
        simulate_dataset(1, session=3, progress=False)


def test_python_api_dispatches_on_the_machine_kind():
    data = simulate_dataset(1, seed=4, machine=MACHINE, progress=False, session=2)
    assert data.sensor_set.name == "machine" and data.meta["motion"] == "swing"
    assert data.meta["noise"] == "field" and data.meta["session"] == 2


def test_interrupted_file_run_resumes(tmp_path, monkeypatch):
    out = tmp_path / "m.parquet"
    from excavator_payload.simulation import generate

    real = machine_sim.lifts_experiment
    calls = []

    def interrupted(spec, k):
        if calls:
            raise KeyboardInterrupt
        calls.append(k)
        return real(spec, k)

    monkeypatch.setattr(machine_sim, "lifts_experiment", interrupted)
    lifts = generate.MACHINE_MOTIONS["lifts"]  # the hydraulic platform's table entry, one per chunk
    monkeypatch.setitem(generate.MACHINE_MOTIONS, "lifts",
                        generate.Motion(lifts.experiment, lambda n: 1, lifts.skip_on))
    with pytest.raises(KeyboardInterrupt):
        simulate_machine_to_file(out, 2, seed=1, motion="lifts", workers=1, progress=False)
    assert not out.exists() and len(list(partial_folder(out).glob("chunk_*"))) == 1
    monkeypatch.setattr(machine_sim, "lifts_experiment", real)
    resumed = simulate_machine_to_file(out, 2, seed=1, motion="lifts", workers=1, progress=False)
    fresh = simulate_machine_dataset(2, seed=1, motion="lifts")
    pd.testing.assert_frame_equal(read_dataset(out).frame, fresh.frame)
    assert resumed.n_experiments == 2 and not partial_folder(out).exists()


def test_cli_simulates_replays_and_plots(tmp_path):
    out = tmp_path / "cycles.parquet"
    assert main(["simulate", "--machine", MACHINE, "--motion", "work-cycle", "-n", "1", "--session", "4",
                 "--out", str(out), "--quiet", "--workers", "1", "--with-truth"]) == 0
    data = read_dataset(out)
    assert data.meta["sensor_set"] == "machine" and data.meta["session"] == 4
    # replay its true motion as a trajectory file at 10 Hz
    rows = data.frame.iloc[::10]
    traj = pd.DataFrame({"experiment": rows.experiment, "time": rows.time,
                         **{c: rows[f"true_{c}"] for c in ("boom_angle", "dipper_angle", "bucket_angle")},
                         "slew_angle": rows.true_slew_angle, "payload": rows.payload})
    traj_file = tmp_path / "motion.parquet"
    traj.to_parquet(traj_file)
    replay = tmp_path / "replay.parquet"
    assert main(["simulate", "--machine", MACHINE, "--trajectory", str(traj_file), "--out", str(replay),
                 "--quiet", "--workers", "1"]) == 0
    assert read_dataset(replay).meta["motion"] == "trajectory"
    figure = tmp_path / "fig.png"
    assert main(["plot", "--data", str(out), "--out", str(figure)]) == 0
    assert figure.stat().st_size > 10_000
    assert main(["plot", "--data", str(out), "--experiment", "7", "--out", str(figure)]) == 2
    assert main(["simulate", "--out", str(tmp_path / "x.parquet"), "--session", "1", "-n", "1"]) == 2


def test_thesis_estimators_refuse_the_machine_set_in_one_line(tmp_path, capsys):
    data = tmp_path / "lifts.parquet"
    simulate_machine_to_file(data, 1, motion="lifts", workers=1, progress=False)
    # the estimators whose traits do not declare the machine set (ekf and ukf since issue 28)
    # must refuse it in one line.
    from excavator_payload.estimators.base import estimator_class, estimator_names

    thesis_only = [n for n in estimator_names() if "machine" not in estimator_class(n).SENSOR_SETS]
    if not thesis_only:
        pytest.skip("every estimator runs on the machine sensor set")
    for name in thesis_only:
        assert main(["train", name, "--data", str(data), "--out", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert "does not run on" in err and "Traceback" not in err


def test_nmpc_swings_reach_their_target_within_the_hydraulics():
    data = simulate_machine_dataset(2, seed=2, noise="none", motion="nmpc", with_truth=True)
    machine = load_machine(MACHINE)
    for meta in data.meta["experiments"]:
        assert meta["reached"] and meta["within_relief"]
        assert meta["peak_pressure"] <= machine.hydraulics.relief_pressure
        assert abs(meta["target_pose"][3]) >= np.radians(30)
        assert meta["speed_share"] <= 1.0  # these two stay within the pumps' speed
    for k, rows in data.experiments():
        target = data.meta["experiments"][k]["target_pose"]
        np.testing.assert_allclose(rows["true_slew_angle"].iloc[-1], target[3], atol=np.radians(1))
        np.testing.assert_allclose(rows["true_boom_angle"].iloc[-1], target[0], atol=np.radians(1))
        lo, hi = machine.angle_ranges[0]
        assert rows["true_boom_angle"].between(lo, hi).all()


@pytest.mark.parametrize("motion", ["swing", "nmpc"])
def test_payload_option_loads_every_experiment_with_the_same_motions(motion, tmp_path):
    """--payload KG: every experiment carries that mass (0: the empty bucket a zero check needs);
    the motions are the ones drawn without it (the draw happens all the same)."""
    drawn = simulate_machine_dataset(2, seed=5, session=2, motion=motion)
    empty = simulate_machine_dataset(2, seed=5, session=2, motion=motion, payload=0.0)
    assert set(empty.frame["payload"]) == {0.0} and set(drawn.frame["payload"]) != {0.0}
    assert [e["payload"] for e in empty.meta["experiments"]] == [0.0, 0.0]
    if motion == "swing":  # a planned motion: the same plan whatever it carries
        first = drawn.frame["experiment"] == drawn.frame["experiment"].iloc[0]
        n = int(first.sum())
        np.testing.assert_array_equal(empty.frame["boom_angle"].to_numpy()[:n] - drawn.frame["boom_angle"].to_numpy()[:n], 0.0)
    # the pressures carry the mass: the empty bucket's boom head pressure is lower
    assert empty.frame["boom_head_pressure"].mean() < drawn.frame["boom_head_pressure"].mean()
    out = tmp_path / "e.parquet"
    assert main(["simulate", "--machine", MACHINE, "-n", "1", "--payload", "2500", "--session", "2",
                 "--workers", "1", "--quiet", "--out", str(out)]) == 0
    assert set(read_dataset(out).frame["payload"]) == {2500.0}


def test_payload_option_refuses_what_it_cannot_do(tmp_path, capsys):
    for bad in ("nan", "-1", "1e9", "inf"):
        assert main(["simulate", "--machine", MACHINE, "-n", "1", "--payload", bad,
                     "--out", str(tmp_path / "x.parquet")]) == 2
        err = capsys.readouterr().err
        assert "--payload must be between 0 and the machine's maximum payload" in err and len(err.strip().splitlines()) == 1
    assert main(["simulate", "-n", "1", "--payload", "0", "--out", str(tmp_path / "x.parquet")]) == 2
    assert "hydraulic machine only" in capsys.readouterr().err
    table = pd.DataFrame({"experiment": 0, "time": np.linspace(0, 2, 21), "boom_angle": 0.1,
                          "dipper_angle": -1.5, "bucket_angle": -1.0, "slew_angle": 0.0, "payload": 100.0})
    table.to_parquet(tmp_path / "t.parquet")
    assert main(["simulate", "--machine", MACHINE, "--trajectory", str(tmp_path / "t.parquet"), "--payload", "0",
                 "--out", str(tmp_path / "y.parquet")]) == 2
    assert "payload column sets the mass" in capsys.readouterr().err
    assert not (tmp_path / "x.parquet").exists() and not (tmp_path / "y.parquet").exists()


def test_work_cycles_are_learnt_and_judged_up_to_their_dump(cycles, monkeypatch):
    """A work cycle's payload column is the load carried; its load leaves the bucket at the dump
    (metadata ``release``). Estimators learn from, and are judged on, the rows before it."""
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.evaluation.metrics import evaluate_estimates

    cut = cycles.until_dump()
    release = {int(m["experiment"]): m["release"][0] for m in cycles.meta["experiments"]}
    assert len(release) == cycles.n_experiments and 0 < len(cut.frame) < len(cycles.frame)
    for k, rows in cut.experiments():
        assert rows["time"].max() < release[k] <= cycles.frame.loc[cycles.frame["experiment"] == k, "time"].max()
    # a dataset without dumps is itself
    swings = simulate_machine_dataset(1, seed=5, session=1)
    assert swings.until_dump() is swings
    # judged up to the dump: an estimate right until then and wrong after it is right
    f = cycles.frame
    after = f["time"].to_numpy() >= f["experiment"].map(release).to_numpy()
    estimates = np.where(after, 0.0, f["payload"].to_numpy())
    ev = evaluate_estimates(cycles, estimates, discard=100, with_bound=False)
    assert ev.summary["judged_to_the_dump"] == cycles.n_experiments and ev.summary["mean_max"] == 0.0
    assert evaluate_estimates(swings, swings.frame["payload"].to_numpy(), discard=100,
                              with_bound=False).summary["judged_to_the_dump"] == 0
    # fit sees the rows before the dump only
    est = create_estimator("inverse-dynamics", "cat345c-hydraulic")
    seen = []
    original = type(est)._fit
    monkeypatch.setattr(type(est), "_fit", lambda self, ds: (seen.append(len(ds.frame)), original(self, ds))[1])
    est.fit(cycles)
    assert seen == [len(cut.frame)]


def _hand_made(**changes):
    t = np.arange(0, 6.0001, 0.1)
    frame = pd.DataFrame({"experiment": 0, "time": t, "boom_angle": 0.1 + 0.3 * np.sin(0.5 * t),
                          "dipper_angle": -1.2 + 0.2 * np.sin(0.7 * t),
                          "bucket_angle": -1.0 + 0.3 * np.sin(0.9 * t),
                          "slew_angle": 0.4 * np.sin(0.4 * t), "payload": 2000.0})
    for column, fn in changes.items():
        frame[column] = fn(frame[column]) if callable(fn) else fn
    return frame


@pytest.mark.parametrize("frame,message", [
    (_hand_made().iloc[:0], "no rows"),
    (_hand_made(experiment=0.5), "whole numbers"),
    (_hand_made(time=lambda t: t * 1000.0), "is 'time' in seconds"),
    (_hand_made(payload=1e7), "more than any excavator lifts"),
    (_hand_made(ground_pitch=5.0), "'ground_pitch' reaches 5, more than 35°"),
    (pd.concat([_hand_made().iloc[:30], _hand_made(time=lambda t: t + 3600.0).iloc[30:]]),
     r"no samples for 3600 s after t = .* split it into two experiments"),  # an hour's gap
    (pd.concat([_hand_made().iloc[:30], _hand_made(time=lambda t: t + 2.0).iloc[30:]]),
     r"no samples for 2.1 s after"),  # two seconds: the interpolation could stay in range
], ids=["no-rows", "fractional-experiment", "time-in-ms", "huge-payload", "ground-in-degrees", "time-gap",
        "short-time-gap"])
def test_trajectory_table_refusals(frame, message):
    """Each was a crash (no rows), silently renumbered (0.5 -> 0), simulated for hours (ms), or
    refused later with a message about the written dataset."""
    with pytest.raises(DatasetError, match=message):
        trajectory_from_frame(frame, "t.parquet")


@pytest.mark.parametrize("frame,message", [
    (_hand_made(boom_angle=lambda a: a + 1.5), r"'boom_angle' reaches .* outside the machine's range"),
    (_hand_made(dipper_angle=lambda a: -a), r"'dipper_angle' reaches .* outside the machine's range"),
    (_hand_made(slew_angle=np.degrees), "times faster than the machine's pumps or slew drive"),
], ids=["boom-out-of-range", "dipper-out-of-range", "slew-in-degrees"])
def test_trajectory_motion_the_machine_cannot_make_is_refused(frame, message):
    """Outside the joint ranges the replay gave 6e9 Pa and a message about pressure units; a slew
    angle in degrees was simulated at 39 times the slew drive's speed."""
    from excavator_payload.simulation.trajectory import check_trajectory_motion

    machine = load_machine(MACHINE)
    check_trajectory_motion(trajectory_from_frame(_hand_made()), machine)  # the good one: fine
    with pytest.raises(DatasetError, match=message):
        check_trajectory_motion(trajectory_from_frame(frame, "t.parquet"), machine)


def test_trajectory_file_that_is_csv_empty_or_a_folder(tmp_path):
    from excavator_payload.simulation.trajectory import read_trajectory

    _hand_made().to_csv(tmp_path / "t.csv", index=False)
    (tmp_path / "empty.parquet").write_bytes(b"")
    (tmp_path / "dir.parquet").mkdir()
    for name, message in (("t.csv", "must be a Parquet file"), ("empty.parquet", "it is empty"),
                          ("dir.parquet", "is a folder")):
        with pytest.raises(DatasetError, match=message):
            read_trajectory(tmp_path / name)


def test_friction_at_rest_lies_anywhere_in_the_band_set_when_the_valve_closed():
    """A standstill's seal friction is held at u·breakaway (u drawn per standstill, anywhere in
    [−1, 1]), not at ± breakaway in the direction of the last motion: on ten work cycles few
    rest samples sit at the band's edge, every one lies within it, and the friction is constant
    through a standstill whose breakaway band does not shrink."""
    from excavator_payload.simulation import machine_motions as mm

    arm = machine_sim._arm(load_machine("cat345c-hydraulic"))
    cylinders = arm.machine.cylinders
    coulomb = np.array([c.coulomb for c in cylinders])
    coefficient = np.array([c.load_coefficient for c in cylinders])
    ratio = np.array([c.static_ratio for c in cylinders])
    rest_speed = machine_sim.REST_SPEED_SHARE * np.array([c.stribeck_velocity for c in cylinders])
    shares, us = [], []
    for k in range(10):
        rng = np.random.default_rng(k)
        plan = mm.fit_to_hydraulics(arm, mm.work_cycle_motion(rng, arm))
        t = machine_sim.sample_times(plan.duration)
        q, qd, qdd = plan.sample(t)
        physics = machine_sim.motion_physics(arm, t, q, qd, qdd, plan.tilt, plan.payload_at(t),
                                             rng.uniform(-1, 1, 3), rng)
        band = (coulomb + coefficient * np.abs(physics["load"])) * ratio
        still = np.abs(physics["speeds"]) < rest_speed
        ratio_at_rest = physics["friction"][still] / band[still]
        assert np.all(np.abs(ratio_at_rest) <= 1 + 1e-9)
        shares.append(np.mean(np.abs(ratio_at_rest) > 1 - 1e-3))
        us.extend(ratio_at_rest.tolist())
        # the pressures give load + friction, the simulator's force balance
        head, rod = arm.pressures(physics["load"] + physics["friction"])
        assert np.allclose(head, physics["head"]) and np.allclose(rod, physics["rod"])
    assert np.mean(shares) < 0.2  # the held-sign rule put 40-90 % of rest samples at the edge
    assert np.std(us) > 0.3 and min(us) < -0.5 and max(us) > 0.5  # spread over the band


def test_rest_friction_holds_the_closing_value_and_slips_at_the_band():
    """A standstill of REST_MIN_SAMPLES or more holds u·breakaway from its first sample (its
    own u, in order), giving at the band's edge where the band shrinks; a two-sample dip (a
    reversal) and moving samples keep the sliding friction."""
    n_rest = machine_sim.REST_MIN_SAMPLES
    speed = np.r_[1.0, np.zeros(n_rest + 2), 1.0, 0.0, 0.0, 1.0, np.zeros(n_rest), 1.0][:, None]
    band = np.full_like(speed, 10.0)
    band[5] = 4.0
    moving = np.full_like(speed, 7.0)
    out = machine_sim.rest_friction(speed, band, np.array([0.1]), moving, np.array([[0.5], [-1.0]]))[:, 0]
    first = slice(1, n_rest + 3)
    assert out[0] == 7.0 and out[n_rest + 3] == 7.0
    assert out[5] == 4.0 and np.all(np.delete(out[first], 4) == 5.0)
    assert np.all(out[n_rest + 4:n_rest + 7] == 7.0)  # the short dip and the sample after it
    assert np.all(out[n_rest + 7:2 * n_rest + 7] == -10.0) and out[-1] == 7.0


def test_operator_motions_pause_overshoot_and_stay_within_the_pumps():
    ds = simulate_dataset(3, seed=4, machine="cat345c-hydraulic", motion="operator", with_truth=True,
                          workers=1, progress=False)
    for meta in ds.meta["experiments"]:
        assert meta["speed_share"] <= 1.0 and abs(meta["overshoot"]) > 0
        assert np.radians(45) <= abs(meta["slew"]) <= np.radians(80)
    assert ds.frame.groupby("experiment")["payload"].nunique().eq(1).all()


def test_lag_delay_is_the_delay_the_imu_filter_gives_a_ramp():
    # the IMU filter takes the current sample: a ramp comes out 5.8 ms late for tau = 10 ms at
    # 100 Hz, not 10 ms (what an oracle weighing with the simulator's own IMU dynamics must take)
    from excavator_payload.simulation.machine_sensors import _lag, lag_delay

    dt, tau, slope = 0.01, 0.01, 0.3
    t = np.arange(400) * dt
    lagged = _lag(slope * t, dt, tau)
    delay = float(np.median((slope * t[200:] - lagged[200:]) / slope))
    assert delay == pytest.approx(lag_delay(tau, dt), rel=1e-6)
    assert lag_delay(tau, dt) == pytest.approx(0.00582, abs=1e-5)
    assert abs(delay - tau) > 0.004  # not the preset's time constant
    assert lag_delay(0.0, dt) == 0.0
    with pytest.raises(ValueError, match="lag_delay"):
        lag_delay(-1.0, dt)


def test_the_truth_says_what_is_in_the_bucket_at_each_sample():
    """``true_bucket_load`` follows a shift's passes (filled, carried, released: the metadata's
    times) where ``payload`` is one figure; a file without the column still has its truth."""
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    data = simulate_machine_dataset(1, seed=3, session=1, motion="shift", truck_target=8000.0, with_truth=True)
    f, passes = data.frame, data.experiment_meta[0]["passes"]
    t, load = f["time"].to_numpy(float), f["true_bucket_load"].to_numpy(float)
    assert load[0] == 0.0 and np.all(load >= 0.0)
    for p in passes:
        carried = (t > p["fill"][1]) & (t < p["release"][0])
        assert np.allclose(load[carried], p["payload"], rtol=1e-12)
        emptied = (t > p["release"][1]) & (t < p["release"][1] + 1.0)
        assert np.all(load[emptied] == 0.0)
    assert np.ptp(f["payload"].to_numpy(float)) == 0.0  # one figure per experiment
    assert data.has_truth
    older = type(data)(f.drop(columns=["true_bucket_load"]), data.meta)
    assert older.has_truth
