"""Operator-like swings of the thesis' arm: reproducible, exact torques, a real pause and overshoot."""

import numpy as np
import pandas as pd
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.minimum_jerk import _arm
from excavator_payload.simulation.operator_swings import (
    OVERSHOOT, TORQUE_SHARE, operator_motion, schedule, simulate_operator_swings)

ANGLES = ["true_boom_angle", "true_dipper_angle"]
RATES = ["true_boom_rate", "true_dipper_rate"]


@pytest.fixture(scope="module")
def data():
    return simulate_operator_swings(12, seed=3, with_truth=True)


def test_same_seed_same_data_other_seed_other_data(data):
    pd.testing.assert_frame_equal(data.frame, simulate_operator_swings(12, seed=3, with_truth=True).frame)
    other = simulate_operator_swings(2, seed=4, with_truth=True)
    assert not np.allclose(other.frame[ANGLES].to_numpy(), data.subset([0, 1]).frame[ANGLES].to_numpy())
    tail = simulate_operator_swings(2, seed=3, with_truth=True, first_experiment=10)
    pd.testing.assert_frame_equal(tail.frame, data.subset([10, 11]).frame)


def test_registered_motion_gives_the_same_data(data):
    ds = simulate_dataset(12, seed=3, motion="operator", with_truth=True, workers=1, progress=False)
    pd.testing.assert_frame_equal(ds.frame, data.frame)
    assert ds.meta["motion"] == "operator"


def test_torques_are_the_inverse_dynamics_of_the_angles(data):
    machine = load_machine("cat345c")
    arm = _arm(machine)
    for k, g in data.frame.groupby("experiment"):
        q = g[ANGLES].to_numpy()
        qd = g[RATES].to_numpy()
        qdd = g[["true_boom_accel", "true_dipper_accel"]].to_numpy()
        tau = arm.inverse_dynamics(q, qd, qdd, g["payload"].iloc[0])
        np.testing.assert_allclose(g[["true_boom_torque", "true_dipper_torque"]].to_numpy(), tau, rtol=1e-9)
        # The rates and accelerations are those of the angles (not made up separately).
        t = g["time"].to_numpy()
        np.testing.assert_allclose(np.gradient(q, t, axis=0), qd, atol=0.06)
        assert np.all(np.abs(tau) <= TORQUE_SHARE * np.array([machine.boom_torque_limit,
                                                              machine.dipper_torque_limit]) + 1.0)
    noise = (data.frame["boom_torque"] - data.frame["true_boom_torque"]).std()
    assert 500 < noise < 1500  # thesis preset: σ = 1000 N·m


def test_swings_pause_overshoot_and_come_back(data):
    for meta, (k, g) in zip(data.meta["experiments"], data.frame.groupby("experiment")):
        start, target = np.array(meta["start_pose"]), np.array(meta["target_pose"])
        q = g[ANGLES].to_numpy()
        speed = np.abs(g[RATES].to_numpy()).max(axis=1)
        t = g["time"].to_numpy()
        np.testing.assert_allclose(q[0], start, atol=1e-12)
        # A pause: after moving, the arm stands still (mid-way) for at least one sample.
        moved = np.flatnonzero(speed > 0.05)
        still_between = [i for i in range(moved[0], moved[-1]) if speed[i] < 1e-9]
        assert still_between, f"experiment {k} never pauses"
        pause_at = q[still_between[0]]
        assert np.all(np.abs(pause_at - start) > 0.1 * np.abs(target - start))
        # Overshoot: each joint goes past its target in the direction of travel, then back.
        direction = np.sign(target - start)
        beyond = ((q - target) * direction).max(axis=0)
        assert np.all(beyond > 0.9 * OVERSHOOT[0]) or meta["slow_down"] > 1.0
        assert np.all(beyond > 0.0)
        # It ends near the target (the end corrections are small) and at rest.
        assert np.all(np.abs(q[-1] - target) < np.deg2rad(2.5))
        assert speed[-1] < 1e-9 or t[-1] < meta["segment_starts"][-1] + meta["segment_lengths"][-1]


def test_segments_rest_to_rest_and_schedule_drops_late_corrections():
    points = np.array([[0.0, 0.0], [0.2, -0.1], [0.5, 0.3], [0.45, 0.28], [0.46, 0.27], [0.45, 0.29]])
    rests = np.array([0.0, 0.5, 0.0, 0.2, 0.2])
    kept, starts, lengths = schedule(points, rests, np.array([1.5, 1.5, 0.6, 0.5, 0.5]), duration=5.0)
    assert len(kept) == 5 and len(lengths) == 4  # the last correction does not fit into 5 s
    np.testing.assert_allclose(starts, [0.0, 2.0, 3.5, 4.3])
    t = np.linspace(0.0, 5.0, 1001)
    q, qd, qdd = operator_motion(kept, starts, lengths, t)
    np.testing.assert_allclose(q[-1], kept[-1], atol=1e-12)
    np.testing.assert_allclose(q[np.searchsorted(t, 1.75)], kept[1], atol=1e-12)  # during the pause
    np.testing.assert_allclose(np.gradient(q, t, axis=0), qd, atol=2e-3)
    np.testing.assert_allclose(np.gradient(qd, t, axis=0), qdd, atol=5e-2)  # jerk jumps at segment ends


def test_cli_simulates_operator_swings(tmp_path):
    out = tmp_path / "x.parquet"
    assert main(["simulate", "--motion", "operator", "-n", "5", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    ds = read_dataset(out)
    assert ds.meta["motion"] == "operator" and ds.n_experiments == 5
