"""The replay's interpolation: accurate on smooth motions, no ringing where an acceleration jumps."""

import numpy as np
import pandas as pd
import pytest

from excavator_payload.simulation.trajectory import ANGLE_COLUMNS, interpolate, knot_derivatives


def _rows(t, q):
    frame = pd.DataFrame({"time": t})
    for j, c in enumerate(ANGLE_COLUMNS):
        frame[c] = q[:, j]
    return frame


def _smooth(t):
    return np.stack([0.3 * np.sin(1.3 * t), -1.2 + 0.2 * np.cos(0.7 * t), 0.4 * np.sin(2.1 * t + 0.3),
                     0.8 * np.sin(0.5 * t)], axis=1)


def _smooth_accel(t):
    return np.stack([-0.3 * 1.69 * np.sin(1.3 * t), -0.2 * 0.49 * np.cos(0.7 * t),
                     -0.4 * 4.41 * np.sin(2.1 * t + 0.3), -0.8 * 0.25 * np.sin(0.5 * t)], axis=1)


@pytest.mark.parametrize("step", [0.01, 0.05])
def test_smooth_motion_is_reproduced(step):
    t = np.arange(0.0, 6.0 + 1e-9, step)
    time, q, qd, qdd, _ = interpolate(_rows(t, _smooth(t)), 100.0)
    inner = (time > 0.2) & (time < 5.8)
    assert np.abs(q - _smooth(time)).max() < 1e-6
    tolerance = 2e-4 if step == 0.01 else 2e-2  # fourth order: (h/0.01)^4-ish between the two
    assert np.abs(qdd[inner] - _smooth_accel(time[inner])).max() < tolerance


def test_uneven_samples_and_time_scale():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.006, 0.014, 600))
    q = _smooth(t)
    qd, qdd = knot_derivatives(t, q)
    inner = slice(5, -5)
    assert np.abs(qdd[inner] - _smooth_accel(t)[inner]).max() < 1e-3
    # the same samples in milliseconds give the same derivatives per millisecond
    qd_ms, qdd_ms = knot_derivatives(t * 1000.0, q)
    np.testing.assert_allclose(qd_ms * 1000.0, qd, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(qdd_ms * 1e6, qdd, rtol=1e-8, atol=1e-8)


def test_an_acceleration_jump_does_not_ring():
    # a joint at rest, then accelerating at 3 rad/s² from t0 between two samples (a lever pushed
    # through a first-order valve does this); the replay must not make the acceleration alternate
    t = np.arange(0.0, 3.0 + 1e-9, 0.01)
    t0, jump = 1.234, 3.0
    q = np.zeros((len(t), 4))
    q[:, 2] = 0.5 * jump * np.clip(t - t0, 0, None) ** 2 - 0.5
    time, _, _, qdd, _ = interpolate(_rows(t, q), 100.0)
    truth = np.where(time > t0, jump, 0.0)
    error = np.abs(qdd[:, 2] - truth)
    far = np.abs(time - t0) > 0.025  # more than two samples from the jump
    assert error[far].max() < 1e-9
    assert error.max() < jump  # beside the jump: between the two levels, give or take 1/24 of it
    assert qdd[:, 2].min() > -jump / 12 and qdd[:, 2].max() < jump * (1 + 1 / 12)
