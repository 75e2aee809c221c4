"""Samples on the model's clock from messages at their own rates (issue 30)."""

import math

import numpy as np
import pytest

from excavator_payload.runtime.assembly import SampleAssembler

T = 0.01
SIGNALS = ("a", "b", "slow")


def _assembler(**kw):
    return SampleAssembler(SIGNALS, T, {"A": [0], "B": [1], "S": [2]}, {"A": T, "B": T, "S": 10 * T}, **kw)


def _feed(asm, frames):
    out = []
    for name, t, value in sorted(frames, key=lambda f: f[1]):
        index = {"A": 0, "B": 1, "S": 2}[name]
        out += asm.add(name, t, [(index, value)])
    return out + asm.flush()


def test_lock_step_gives_one_sample_per_tick_with_the_frames_values():
    frames = [(m, 1.0 + k * T, k + off) for k in range(50) for m, off in (("A", 0.0), ("B", 0.5))]
    frames += [("S", 1.0 + k * T, 100.0 + k) for k in range(0, 50, 10)]
    out = _feed(_assembler(), frames)
    assert len(out) == 50
    np.testing.assert_allclose([s.time for s in out], 1.0 + T * np.arange(50), atol=1e-12)
    np.testing.assert_array_equal([s.values[0] for s in out], np.arange(50))
    # the slow signal is held between its frames, never stale
    np.testing.assert_array_equal([s.values[2] for s in out], 100.0 + 10 * (np.arange(50) // 10))
    assert all(s.stale == () for s in out)


def test_jitter_keeps_each_frame_on_its_tick():
    rng = np.random.default_rng(0)
    frames = []
    for k in range(300):
        for m in ("A", "B"):
            frames.append((m, 5.0 + k * T + float(np.clip(rng.normal(0, 0.0015), -0.004, 0.004)), float(k)))
        if k % 10 == 0:
            frames.append(("S", 5.0 + k * T + float(rng.normal(0, 0.002)), float(k)))
    out = _feed(_assembler(), frames)
    assert len(out) == 300
    values = np.array([s.values for s in out])
    # every fast value on its own tick: the jitter (up to 0.4 of a period) moves none
    assert np.mean(values[:, 0] == np.arange(300)) > 0.99
    assert np.mean(values[:, 1] == np.arange(300)) > 0.99
    # the ticks stay evenly spaced (phase-locked, not jittering)
    steps = np.diff([s.time for s in out])
    assert np.abs(steps - T).max() < 0.02 * T


def test_a_silent_signal_is_stale_by_name_after_its_period_times_the_tolerance():
    frames = [(m, k * T, float(k)) for k in range(60) for m in ("A", "B")]
    frames += [("S", k * T, 1.0) for k in (0, 10, 20)]  # then silent
    out = _feed(_assembler(tolerance=2.5), frames)
    stale = [s.stale for s in out]
    # last frame at 0.2 s, period 0.1 s: stale once older than 0.25 s, at the tick after 0.45 s
    first = next(k for k, s in enumerate(stale) if s)
    assert out[first].time == pytest.approx(0.46) and stale[first] == ("slow",)
    assert all(s == ("slow",) for s in stale[first:])
    assert all(math.isnan(s.values[2]) for s in out[first:]) and out[first - 1].values[2] == 1.0


def test_a_lost_fast_frame_is_held_and_an_empty_tick_skipped():
    frames = [(m, k * T, float(k)) for k in range(20) for m in ("A", "B") if not (k == 5 and m == "B")]
    frames = [f for f in frames if not 10 * T - 1e-9 < f[1] < 10 * T + 1e-9]  # tick 10: nothing at all
    out = _feed(_assembler(), frames + [("S", 0.0, 1.0)])
    times = np.round([s.time / T for s in out]).astype(int)
    assert 10 not in times and len(out) == 19
    at5 = out[list(times).index(5)]
    assert at5.values[0] == 5 and at5.values[1] == 4 and at5.stale == ()


def test_time_going_back_restarts_the_clock():
    asm = _assembler()
    out = _feed(asm, [(m, 100 + k * T, 1.0) for k in range(5) for m in ("A", "B", "S")])
    out2 = _feed(asm, [(m, 3 + k * T, 2.0) for k in range(5) for m in ("A", "B", "S")])
    assert len(out) == 5 and len(out2) == 5 and out2[0].time == pytest.approx(3.0)
