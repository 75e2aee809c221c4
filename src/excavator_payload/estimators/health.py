"""Streaming sensor health per signal, for the ``machine`` sensor set (issue 31).

Every sample an estimator of the machine set uses passes :meth:`HealthMonitor.step` once
(:meth:`~excavator_payload.estimators.base.Estimator.step_values`); while it reports a fault
the sample is not used and the result is ``sensor_fault`` with the estimate kept (never
``ok``), naming the faulty signal(s) and kind(s) in ``StepResult.fault``, e.g.
``"boom_head_pressure:stuck"`` (several comma-separated); where only link rates, cylinder
pressures and link angles the estimator can weigh without are named, it weighs on with their
substitutes instead (a rate: its angle's slope; a pressure: its joint dropped from the weighing;
a stuck or dropped-out angle: the last healthy one plus the integrated rate, for a bounded
time), ``degraded`` (:meth:`HealthMonitor.substitute`). Each kind comes from the data and
the model's redundancy (a link's angle against its own rate, a cylinder's pressures against
its joint's motion, the fitting data's noise):

* ``stuck`` (J1939 FMI 7): the signal changes by no more than :data:`STUCK_QUANTA` of its bus
  resolution over :data:`STUCK_WINDOW` while the arm moves: an angle whose rate says it turns,
  a rate whose angle turns, a pressure whose joint moves; the slew rate and the house's pitch
  and roll (no partner) while any arm joint moves. The sensor noise (angles 17, pressures 300
  resolution steps) never stays inside two steps for 0.3 s; a frozen transmitter does.
* ``dropout`` (FMI 5, current below normal / open circuit: a pulled connector reads 0): an angle
  or pressure at exactly 0 for :data:`DROPOUT_SAMPLES` samples in a row while another of its
  group is not; a rate at exactly 0 that long while its angle turns.
* ``disagree`` (FMI 2, data erratic): a link's angle change over :data:`DISAGREE_WINDOW` against
  the integral of its rate differs by more than :data:`DISAGREE_LIMIT` (widened while the joint
  accelerates); both are named (the data cannot tell which one lies). Catches a jumping angle
  and runs of agreeing bad frames, which no single-frame test sees.
* ``noise`` (FMI 2): over :data:`NOISE_WINDOW`, at least :data:`NOISE_SHARE` of the samples'
  second differences exceed :data:`NOISE_FACTOR` × what the fitting data showed for that signal
  (:func:`noise_reference`; its 99th percentile). A share, not a sum of squares: one glitch
  frame (the outlier gate's) never makes a noisy window. Off for a model saved without a
  reference.
* ``offset`` (FMI 13, out of calibration): a link's angle minus its integrated rate, smoothed
  over :data:`OFFSET_SMOOTH`, leaves its own slow track (a level and a slope following it with
  time constant :data:`OFFSET_TAU`: the gyro's bias ramps it) by more than :data:`OFFSET_LIMIT`
  (boom, dipper: :data:`LINK_OFFSET_LIMIT`) for :data:`OFFSET_SAMPLES` samples, or the track's slope
  passes :data:`OFFSET_SLOPE_LIMIT` (a rate's lasting bias, which the track would absorb). A
  lasting offset or a drift faster than about OFFSET_LIMIT / OFFSET_TAU; while flagged the track
  follows only with :data:`OFFSET_TAU_FLAGGED`, so a lasting offset is named for tens of seconds,
  not for ever. Both signals named. The size of the house's tilt (hypot of pitch and roll: on a
  slope they turn into each other as the house slews, the size does not) against its own track
  the same way (beyond :data:`TILT_OFFSET_LIMIT`), both named.
* ``gain`` (FMI 13): over :data:`GAIN_WINDOW` with the angle spread at least :data:`GAIN_MIN_STD`,
  the least-squares slope of (angle − integrated rate) against the angle exceeds
  :data:`GAIN_LIMIT` (a scale error of either signal; both named). The slew rate the same way
  against the slew angle the house tilt's direction says, on a slope
  (:mod:`~excavator_payload.estimators.health_slew`; the slew rate and both tilts named).

* ``balance`` (FMI 13) is not this monitor's: the ``calibrated`` estimator's kernel names a
  cylinder's head and rod pressures when its joint's share of the weighing disagrees with the
  other joints' (:meth:`~excavator_payload.estimators.classical.machine_calibration.kernel
  .CalibratedKernel._check_joints`; option ``joint_check``, on by default): a pressure
  offset, drift or gain error.

A fault stays active until its condition has been clear for :data:`HOLD` (a spike of three
frames is not half-trusted in between). Thresholds were set on clean simulated data of the
simulator's own motion families and judged on held-out ones (docs/sensor-health.md).

Cost: per sample, the dropout and disagree rules (a few operations per link in plain Python:
numpy's call overhead dominates on 15 values); stuck, noise, offset and gain every
:data:`EVERY` samples on the ring buffer's windows, staggered (running totals: the 2 s gain
window is never summed again).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from excavator_payload.estimators.health_slew import (SLEW_GAIN_EVALUATIONS, SLEW_GAIN_LIMIT, house_terms,
                                                     slew_gain_slope)
from excavator_payload.platforms import HYDRAULIC

#: Window over which a stuck signal does not move, s (0.2 s, tried in the time-to-name work,
#: named the clean house tilt of a truck-loading shift stuck: docs/sensor-health.md "Time to name").
STUCK_WINDOW = 0.3
#: A stuck signal's span over the window is at most this many bus resolution steps (a frozen
#: value that flickers by one bit still counts).
STUCK_QUANTA = 2.0
#: A joint moves when its rate exceeds this, rad/s: 6 sigma of the rate sensors' offset and
#: noise (0.1 °/s each) is 0.02 rad/s.
MOVING_RATE = 0.03
#: Samples in a row at exactly 0 that make a dropout.
DROPOUT_SAMPLES = 3
#: Window of the angle-against-integrated-rate check, s.
DISAGREE_WINDOW = 0.1
#: Allowed angle-minus-integrated-rate difference over the window: this (rad) plus
#: :data:`DISAGREE_PER_RATE_CHANGE` × the rate's span over the window (s). While a joint
#: accelerates hard, the IMU's acceleration leak moves the angle without its rate (clean
#: operator motion: up to 0.12 rad, 0.027 rad beyond 0.4 × the rate's span); measured on clean
#: data of every motion family, docs/sensor-health.md.
DISAGREE_LIMIT = 0.035
DISAGREE_PER_RATE_CHANGE = 0.5
#: A fault stays active until its condition has been clear this long, s.
HOLD = 0.2
#: Samples in a row an angle and its rate must disagree: one is a glitch for the outlier gate.
DISAGREE_SAMPLES = 2
#: Noise: window, s; a sample is noisy when its second difference exceeds this factor times the
#: fitting data's 99th percentile for the signal; noisy when this share of the window is.
NOISE_WINDOW = 0.5
NOISE_QUANTILE = 0.99
NOISE_FACTOR = 3.0
NOISE_SHARE = 0.4
#: A pressure's second difference is judged relative to 1 + |p| / this (Pa): the pump's ripple
#: grows with the pressure, the transmitter's noise does not.
NOISE_PRESSURE_SCALE = 1.0e6
#: Offset: angle − integrated rate smoothed over this, s; its track's time constant, s (and
#: while flagged); the deviation that counts, rad, and for how many samples in a row.
OFFSET_SMOOTH = 0.5
OFFSET_TAU = 4.0
OFFSET_TAU_FLAGGED = 30.0
OFFSET_LIMIT = 0.035
OFFSET_SAMPLES = 5
#: A link's own offset limit, rad, where its angle carries less acceleration leak than the bucket's
#: (clean tuning data: the boom within 0.0104 rad, the dipper 0.0153, the bucket 0.030): a boom
#: rate's bias or scale error moves the weighing most (docs/sensor-health.md, "Each link its own
#: offset limit").
LINK_OFFSET_LIMIT = {"boom": 0.015, "dipper": 0.025}
#: The house tilt's size against its own track: the deviation that counts, rad. No link's IMU
#: acceleration leak in it: on the clean tuning data it stays between 0.007 and 0.01 rad (the
#: links' reach 0.0225), so 0.015, not the links' 0.035 (docs/sensor-health.md "Time to name").
TILT_OFFSET_LIMIT = 0.015
#: A track whose slope (rad/s) passes this is a rate's lasting bias (or an angle's drift) the
#: track would otherwise absorb: 0.5 °/s, five times the largest on clean data (0.105 °/s, the
#: field preset's gyro bias is 0.1 °/s; docs/sensor-health.md). Counted with the offset's run.
OFFSET_SLOPE_LIMIT = math.radians(0.5)
#: Gain: window, s; the angle's least spread over it, rad; the largest slope of (angle −
#: integrated rate) against the angle (a 10 % scale error is 0.1); samples in a row.
GAIN_WINDOW = 2.0
GAIN_MIN_STD = 0.15
GAIN_LIMIT = 0.08
GAIN_SAMPLES = 10
#: Suspect (not named, not ``ok``): a link's or the tilt's offset error, its track's slope or
#: its gain slope beyond this share of its limit (:data:`OFFSET_LIMIT`, :data:`OFFSET_SLOPE_LIMIT`,
#: :data:`GAIN_LIMIT`) at the last evaluation: the statistic is rising but not decided.
SUSPECT_SHARE = 0.5

#: Degraded weighing (:meth:`HealthMonitor.substitute`): while the monitor names nothing but
#: link rates, each with one of these kinds (its angle healthy), the estimator weighs on with
#: each named rate replaced by its angle's least-squares slope over the last
#: :data:`SUBSTITUTE_WINDOW` (s; 21 samples at 100 Hz: the length with the least error against
#: the true rate on clean tuning data, 0.37/2.3/4.7 °/s rms for boom/dipper/bucket,
#: docs/sensor-health.md). ``disagree``, ``offset`` and ``gain`` name the angle too: no substitute.
#: A cylinder pressure named with one of these kinds is set to 0 and its joint dropped from the
#: weighing of an estimator that weighs without it (``degraded_pressures``; :meth:`named_joints`).
SUBSTITUTE_KINDS = ("stuck", "dropout", "noise")
SUBSTITUTE_WINDOW = 0.2
#: A link's angle named with one of these kinds (its rate healthy) is replaced by the last
#: healthy angle plus the rate integrated since (:meth:`HealthMonitor.substitute`): the
#: reference is the angle − integrated rate averaged over :data:`SUBSTITUTE_WINDOW` ending
#: :data:`STUCK_WINDOW` before the angle was named, for at most :data:`ANGLE_SUBSTITUTE_LIMIT`
#: (s; the gyro's bias drifts the integral: docs/sensor-health.md), then no substitute.
ANGLE_SUBSTITUTE_KINDS = ("stuck", "dropout")
ANGLE_SUBSTITUTE_LIMIT = 5.0
#: A named house tilt (pitch or roll, any kind: it has no partner that says which lies) is
#: replaced by its mean over :data:`SUBSTITUTE_WINDOW` ending :data:`TILT_SUBSTITUTE_BACK` s
#: before it was first named (before a drifting tilt is named: 0.6–0.8 s, docs/sensor-health.md),
#: for at most :data:`TILT_SUBSTITUTE_LIMIT` s, and while the house has not slewed so far since
#: that the frozen tilt could be off by more than :data:`TILT_OFFSET_LIMIT` (on a slope, pitch
#: and roll turn into each other as the house slews: the size of the reference times the slew
#: angle bounds the error); then no substitute (the weighing stops, and after the gap restarts).
TILT_SUBSTITUTE_BACK = 1.0
TILT_SUBSTITUTE_LIMIT = 5.0
#: While degraded, sigma is the estimator's own times this: on degraded samples of the tuning
#: data (benchmarks/bench_faults.py, seed 9300, rates) |error| <= 2 sigma held on 88 % of them
#: with the own sigma, 95 % with 1.5 times it, 97 % with 2 (docs/sensor-health.md). A factor, not
#: the substitute's noise fed to the model: one rule for every estimator of the set, in C alike.
DEGRADED_SIGMA_FACTOR = 2.0
#: ... plus the estimate's move since the degraded samples began (a stuck rate's slope moved a
#: young weighing 50 kg under a sigma of 16 kg). :meth:`.Estimator.jump_limit`: no ``ok`` estimate
#: moves more than this share of rated from the one before (clean work: 1.1 kg at most; a bucket
#: pressure's drift 16 kg a sample, ``ok`` 52 kg off; docs/sensor-health.md).
JUMP_SHARE = 0.001

#: Stuck, noise, offset and gain are judged every this many samples (staggered; their windows
#: are 0.3 s and more, and :data:`HOLD` bridges the samples in between).
EVERY = 5

#: The kinds in the order of the monitor's arrays.
KINDS = ("stuck", "dropout", "disagree", "noise", "offset", "gain")
#: J1939-73 failure mode identifier of each kind.
FMI = {"stuck": 7, "dropout": 5, "disagree": 2, "noise": 2, "offset": 13, "gain": 13,
       # the calibrated kernel's joint check (machine_calibration.kernel.CalibratedKernel
       # ._check_joints): a cylinder's pressures off its joint's balance, lastingly: a wrong
       # zero or scale (13 out of calibration), not data that jump about (2 erratic)
       "balance": 13}

LINKS = ("boom", "dipper", "bucket")
# kinds after which a link's angle − integrated rate is meaningless: its track starts again
_RESTART_KINDS = ("stuck", "dropout", "noise")
# kinds under which a link's track follows only slowly (a lasting offset stays named)
_TRACK_FLAGGED = ("offset", "gain", "disagree")


class HealthMonitor:
    """Per-signal fault detection on a stream of machine-set samples (see the module docstring).

    Parameters
    ----------
    signals : tuple of str
        The sensor set's signals in column order.
    period : float
        Sample period, s.
    resolution : mapping
        Bus resolution per signal (the generated DBC's scale), SI units per bit.
    reference : mapping or None
        The fitting data's 99th percentile of each signal's |second difference|
        (:func:`noise_reference`); None or a missing signal: no noise check on it.
    """

    def __init__(self, signals, period: float, resolution, reference=None) -> None:
        self.signals = tuple(signals)
        self.period = float(period)
        idx = {s: i for i, s in enumerate(self.signals)}
        self.quantum = np.array([STUCK_QUANTA * resolution[s] for s in self.signals])
        samples = lambda seconds: max(2, int(round(seconds / self.period)) + 1)  # noqa: E731
        self.n_stuck = samples(STUCK_WINDOW)
        self.n_dis = samples(DISAGREE_WINDOW)
        self.n_smooth = samples(OFFSET_SMOOTH)
        self.n_gain = samples(GAIN_WINDOW)
        self.n_sub = samples(SUBSTITUTE_WINDOW)
        self.n_angle_limit = int(round(ANGLE_SUBSTITUTE_LIMIT / self.period))
        self.n_tilt_back = int(round(TILT_SUBSTITUTE_BACK / self.period))
        self.n_tilt_limit = int(round(TILT_SUBSTITUTE_LIMIT / self.period))
        centred = np.arange(self.n_sub) - (self.n_sub - 1) / 2
        #: weights of the least-squares slope over the last n_sub samples, oldest first, 1/s
        self.sub_weights = centred / float(centred @ centred) / self.period
        self.every = EVERY
        self.n_blocks = max(1, int(round(NOISE_WINDOW / self.period / self.every)))
        self.size = max(self.n_stuck, self.n_dis, self.n_smooth, self.n_gain, self.n_sub, self.every + 2) + 1
        if self.n_tilt_back + self.n_sub >= self.size:
            raise ValueError("health: TILT_SUBSTITUTE_BACK reaches past the monitor's windows")
        self.hold = int(round(HOLD / self.period))
        self.duration = (self.n_stuck - 1) * self.period
        links = [k for k in LINKS if f"{k}_angle" in idx and f"{k}_rate" in idx]
        self.offset_limit = [float(LINK_OFFSET_LIMIT.get(k, OFFSET_LIMIT)) for k in links]
        self.link_angle = [idx[f"{k}_angle"] for k in links]
        self.link_rate = [idx[f"{k}_rate"] for k in links]
        self.angles = [idx[s] for s in self.signals if s.endswith("_angle")]
        self.pressures = [idx[s] for s in self.signals if s.endswith("_pressure")]
        self.rates = [idx[s] for s in self.signals if s.endswith("_rate")]
        # each pressure's joint rate; the unpartnered signals watch every arm joint
        self.pressure_rate = [(idx[s], idx[s.split("_")[0] + "_rate"]) for s in self.signals
                              if s.endswith("_pressure") and s.split("_")[0] + "_rate" in idx]
        # each link cylinder's pressure: its joint (boom 0, dipper 1, bucket 2)
        self.pressure_joint = {idx[s]: LINKS.index(s.split("_")[0]) for s in self.signals
                               if s.endswith("_pressure") and s.split("_")[0] in LINKS}
        self.lone = [idx[s] for s in ("slew_rate", "house_pitch", "house_roll") if s in idx]
        # the house's tilt: pitch and roll turn into each other as the house slews on a slope,
        # the size of the tilt does not
        self.tilts = [idx[s] for s in ("house_pitch", "house_roll")] \
            if "house_pitch" in idx and "house_roll" in idx else []
        self.slew = idx.get("slew_rate")
        # the slew rate's partner on a slope: the tilt's direction (health_slew); named together
        self.slew_watched = [*self.tilts, self.slew] if self.tilts and self.slew is not None else []
        ref = reference or {}
        self.noise_limit = np.array([NOISE_FACTOR * float(ref[s]) if s in ref and float(ref[s]) > 0
                                     else np.inf for s in self.signals])
        # the limit grows with |value| for pressures (× 1 + |p| / NOISE_PRESSURE_SCALE)
        self.noise_relative = np.array([lim / NOISE_PRESSURE_SCALE if s.endswith("_pressure")
                                        and np.isfinite(lim) else 0.0
                                        for s, lim in zip(self.signals, self.noise_limit)])
        self.noise_count_limit = NOISE_SHARE * self.n_blocks * self.every
        self.noise_checked = np.isfinite(self.noise_limit).any()
        # alpha-beta track of angle − integrated rate, critically damped (time constant tau),
        # updated every `every` samples
        step = self.every * self.period
        self.track_gains = tuple((2 * step / tau, (step / tau) ** 2 / step)
                                 for tau in (OFFSET_TAU, OFFSET_TAU_FLAGGED))
        self.offset_evaluations = max(1, -(-OFFSET_SAMPLES // self.every))
        self.gain_evaluations = max(1, -(-GAIN_SAMPLES // self.every))
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new experiment, or a hole in time)."""
        self.active: dict[tuple[int, str], int] = {}  # (signal, kind) -> samples since last seen
        self.previous: set = set()  # the signals named after the sample before the last
        self.last_time: float | None = None
        # per link while its angle is named: the substitute's reference (angle − integrated
        # rate; NaN: none to be had) and the samples since it was taken; None while not named
        self.angle_ref: list = [None] * len(self.link_angle)
        self.angle_age = [0] * len(self.link_angle)
        self.angle_clean = [0] * len(self.link_angle)  # samples since the angle was last named
        # while a tilt is named: its substitute's reference (pitch, roll; NaN: none to be had),
        # the slew rates summed since the reference's centre, the samples since it was taken
        self.tilt_ref: tuple | None = None
        self.tilt_turn = 0.0
        self.tilt_age = 0
        self.tilt_clean = 0  # samples since a tilt was last named
        self._restart()

    def _restart(self) -> None:
        """Start the windows again (after a hole in time); active faults keep their hold."""
        n, L = len(self.signals), len(self.link_angle)
        self.count = 0
        # the integral starts again: a reference taken is lost (no substitute until not named)
        self.angle_ref = [None if ref is None else math.nan for ref in getattr(self, "angle_ref", [None] * L)]
        self.angle_clean = [0] * L
        if getattr(self, "tilt_ref", None) is not None:
            self.tilt_ref = (math.nan, math.nan)  # its samples are gone with the hole in time
        self.tilt_clean = 0
        # the last `size` samples, written twice (at k and k + size) so that any window is one
        # ordered slice; and per sample each link's (angle − integrated rate, cumulative sums)
        self.buffer = np.zeros((2 * self.size, n))
        self.house = np.zeros((2 * self.size, 3))  # the slew check's house_terms, as the buffer
        self.ring: list = [None] * self.size
        self.prev: list | None = None
        self.noise_blocks: deque = deque()
        self.noise_count = np.zeros(n, np.int64)
        self.zeros = [0] * n
        self.any_zeros = False
        self.since_moving = {r: 1 << 30 for r in self.rates}
        self.rate_window = [deque(maxlen=self.n_dis) for _ in range(L)]  # each link's last rates
        self.disagreeing = [0] * L
        self.integral = [0.0] * L
        self.origin: list | None = None  # angle origin: keeps the gain sums of squares small
        self.cum = [(0.0, 0.0, 0.0, 0.0)] * L  # running totals of y, x, x², x·y per link
        self.tilt_cum = [0.0]  # running total of the house's tilt (hypot of pitch and roll)
        self.tilt_track: list = [None]
        self.tilt_run = [0]
        self.track = None  # [level, slope] of each link's angle − integrated rate
        self.off_run = [0] * L
        self.gain_run = [0] * L
        self.broken_until = [0] * L  # a link's gain is not judged until its windows are clean
        self.suspect_links = [False] * L  # at the link's last evaluation (see SUSPECT_SHARE)
        self.suspect_tilt = False
        self.slew_run = 0
        self.slew_broken_until = 0  # the slew check waits for a window free of other faults
        self.slew_slope = math.nan  # at its last evaluation (NaN: not judged)

    def step(self, time: float, values) -> str:
        """Judge one finite, plausible sample; the active faults as ``"signal:kind,..."``
        (empty when healthy).

        Parameters
        ----------
        time : float
            Sample time, s.
        values : array-like
            The signals in :attr:`signals` order, SI units.
        """
        self.previous = {i for i, _ in self.active}  # named after the last sample
        if self.last_time is not None and not 0 < time - self.last_time <= 1.5 * self.period:
            self._restart()
        self.last_time = time
        found = self._faults(np.asarray(values, dtype=float))
        active = self.active
        if active:
            for key in list(active):
                active[key] += 1
                if active[key] > self.hold:
                    del active[key]
        for key in found:
            active[key] = 0
        self._angle_references()
        if self.tilts and self.slew is not None:
            self._tilt_reference()
        if not active:
            return ""
        return ",".join(f"{self.signals[i]}:{kind}" for i, kind in sorted(active))

    def suspect(self) -> str:
        """The signals whose slow statistic (offset error, track slope, gain slope) is past
        :data:`SUSPECT_SHARE` of its limit at its last evaluation and that are not named now,
        as ``"signal:suspect,..."`` (empty: none); after :meth:`step`."""
        out = set()
        for j, (a, r) in enumerate(zip(self.link_angle, self.link_rate)):
            if self.suspect_links[j]:
                out.update((a, r))
        if self.suspect_tilt:
            out.update(self.tilts)
        named = {i for i, _ in self.active}
        return ",".join(f"{self.signals[i]}:suspect" for i in sorted(out - named))

    def _angle_references(self) -> None:
        """Per link: take the angle substitute's reference when its angle is first named (the
        mean of angle − integrated rate over :attr:`n_sub` samples ending :attr:`n_stuck`
        samples back, none of them named), count the samples since, forget it once the angle is
        no longer named."""
        back = self.n_stuck + self.n_sub
        for j, a in enumerate(self.link_angle):
            named = any((a, kind) in self.active for kind in KINDS)
            if not named:
                self.angle_ref[j] = None
                self.angle_clean[j] += 1
                continue
            if self.angle_ref[j] is None:
                if self.count > back and self.angle_clean[j] >= back:
                    total = 0.0
                    for k in range(self.n_stuck + 1, back + 1):  # oldest last; C sums the same samples
                        total += self.ring[(self.count - k) % self.size][0][j]
                    self.angle_ref[j] = total / self.n_sub
                else:
                    self.angle_ref[j] = math.nan
                self.angle_age[j] = 0
            self.angle_age[j] += 1
            self.angle_clean[j] = 0

    def _tilt_reference(self) -> None:
        """Take the tilt substitute's reference when a tilt is first named (pitch and roll
        averaged over :attr:`n_sub` samples ending :attr:`n_tilt_back` samples back, none of them
        named; and the slew rates from that window's centre on, summed), then add each sample's
        slew rate and count its age; forget it once no tilt is named."""
        if not any(i in self.tilts for i, _ in self.active):
            self.tilt_ref = None
            self.tilt_clean += 1
            return
        end = (self.count - 1) % self.size + self.size + 1  # one past the newest sample
        if self.tilt_ref is None:
            back = self.n_tilt_back + self.n_sub
            if self.count > back and self.tilt_clean >= back:
                pitch = roll = turn = 0.0
                for row in self.buffer[end - back:end - self.n_tilt_back].tolist():  # oldest first, as C
                    pitch += row[self.tilts[0]]
                    roll += row[self.tilts[1]]
                for row in self.buffer[end - back + self.n_sub // 2:end].tolist():
                    turn += row[self.slew]
                self.tilt_ref = (pitch / self.n_sub, roll / self.n_sub)
                self.tilt_turn = turn
            else:
                self.tilt_ref = (math.nan, math.nan)
            self.tilt_age = 0
        else:
            self.tilt_turn += float(self.buffer[end - 1, self.slew])
        self.tilt_age += 1
        self.tilt_clean = 0

    def _tilt_value(self) -> tuple | None:
        """The named tilts' substitute (pitch, roll), or None: no reference, too old, or the
        house has slewed too far since (see :data:`TILT_SUBSTITUTE_LIMIT`)."""
        ref = self.tilt_ref
        if ref is None or math.isnan(ref[0]) or self.tilt_age > self.n_tilt_limit:
            return None
        if math.hypot(ref[0], ref[1]) * abs(self.tilt_turn * self.period) > TILT_OFFSET_LIMIT:
            return None
        return ref

    def _is_active(self, signal: int, kinds) -> bool:
        return any((signal, k) in self.active for k in kinds)

    def _faults(self, values: np.ndarray) -> list[tuple[int, str]]:
        """The (signal, kind) conditions seen at this sample (before the hold)."""
        found: list[tuple[int, str]] = []
        size, dt = self.size, self.period
        v = values.tolist()
        c = self.count
        k = c % size
        self.buffer[k] = self.buffer[k + size] = values
        if self.slew_watched:
            self.house[k] = self.house[k + size] = house_terms(v[self.tilts[0]], v[self.tilts[1]])
        # -- per link: angle − integrated rate, and running totals for offset and gain ------
        prev, integral = self.prev, self.integral
        if self.origin is None:
            self.origin = [v[a] for a in self.link_angle]
        half = 0.5 * dt
        resid, cum = [], []
        for j, a, r, o, (sy, sx, sxx, sxy) in zip(range(3), self.link_angle, self.link_rate, self.origin,
                                                  self.cum):
            if prev is not None:
                integral[j] += half * (prev[r] + v[r])
            y = v[a] - integral[j]
            x = v[a] - o
            resid.append(y)
            cum.append((sy + y, sx + x, sxx + x * x, sxy + x * y))
        self.cum = cum
        if self.tilts:
            self.tilt_cum = tilt_cum = [self.tilt_cum[0] + math.hypot(v[self.tilts[0]], v[self.tilts[1]])]
        else:
            tilt_cum = self.tilt_cum
        self.ring[k] = (resid, cum, tilt_cum)
        self.prev = v
        self.count = c = c + 1
        end = k + size + 1  # one past the newest sample in the buffer
        # -- every sample: moving joints, dropouts, angle against rate -----------------------
        since = self.since_moving
        for r in self.rates:
            since[r] = 0 if not -MOVING_RATE <= v[r] <= MOVING_RATE else since[r] + 1
        if self.any_zeros or 0.0 in v:
            zeros = self.zeros = [z + 1 if x == 0.0 else 0 for z, x in zip(self.zeros, v)]
            self.any_zeros = 0.0 in v
            for group in (self.angles, self.pressures):
                if any(v[i] != 0.0 for i in group):
                    found += [(i, "dropout") for i in group if zeros[i] >= DROPOUT_SAMPLES]
        for window, r in zip(self.rate_window, self.link_rate):
            window.append(v[r])
        if c >= self.n_dis:
            old_resid = self.ring[(c - self.n_dis) % size][0]
            for j, a, r, window in zip(range(3), self.link_angle, self.link_rate, self.rate_window):
                limit = DISAGREE_LIMIT + DISAGREE_PER_RATE_CHANGE * (max(window) - min(window))
                if abs(resid[j] - old_resid[j]) > limit:
                    # a one-frame spike is the outlier gate's (rejected, the estimate untouched);
                    # a disagreement that lasts two samples is the sensor's
                    self.disagreeing[j] += 1
                    if self.disagreeing[j] >= DISAGREE_SAMPLES:
                        found += [(a, "disagree"), (r, "disagree")]
                else:
                    self.disagreeing[j] = 0
        # -- every `every` samples, staggered: stuck, noise, offset and gain ----------------
        phase = c % self.every
        if phase == 0 and c >= self.n_stuck:
            self._stuck(found, v, end)
        elif phase == 1 and self.noise_checked and c > self.every + 2:
            self._noise(found, end)
        elif phase == 2 and c >= self.n_smooth:
            self._offset_and_gain(found, c)
        elif phase == 3 and c >= self.n_smooth and self.tilts:
            self._tilt_offset(found, c)
        elif phase == 4 and c >= self.n_gain and self.slew_watched:
            self._slew_gain(found, end, c)
        return found

    def _slew_gain(self, found: list, end: int, c: int) -> None:
        """The slew rate against the slew angle the house tilt's direction says
        (:func:`~excavator_payload.estimators.health_slew.slew_gain_slope`): ``gain`` on the slew
        rate and both tilts, kept while no window is judged. Not judged while any of them is named
        with another kind, nor until the window holds no sample of that."""
        watched = self.slew_watched
        if any(i in watched and kind != "gain" for i, kind in found) \
                or (self.active and any(i in watched and kind != "gain" for i, kind in self.active)):
            self.slew_broken_until = c + self.n_gain
        if c < self.slew_broken_until:
            self.slew_run, self.slew_slope = 0, math.nan
            return
        self.slew_slope = slope = slew_gain_slope(self.house[end - self.n_gain:end],
                                                  self.buffer[end - self.n_gain:end, self.slew], self.period,
                                                  GAIN_MIN_STD)
        self.slew_run = self.slew_run + 1 if abs(slope) > SLEW_GAIN_LIMIT else 0  # NaN: not judged
        # once named, a scale error stays named until a judged window clears it: at rest, or on
        # level ground, the house says nothing, and weighing on would restart with the bad rate
        if self.slew_run >= SLEW_GAIN_EVALUATIONS or (math.isnan(slope) and (self.slew, "gain") in self.active):
            found += [(i, "gain") for i in watched]

    def _stuck(self, found: list, v: list, end: int) -> None:
        w = self.buffer[end - self.n_stuck:end]
        still = (w.max(axis=0) - w.min(axis=0)) <= self.quantum
        if not still.any():
            return
        still = set(np.flatnonzero(still).tolist())
        first = w[0]
        turning = {r: m < self.n_stuck for r, m in self.since_moving.items()}
        dropped = {i for i, kind in found if kind == "dropout"}
        zeros = self.zeros
        for a, r in zip(self.link_angle, self.link_rate):
            if a in still and turning[r] and a not in dropped:
                found.append((a, "stuck"))
            if abs(v[a] - first[a]) > MOVING_RATE * self.duration:
                if r in still:
                    found.append((r, "stuck"))
                elif zeros[r] >= DROPOUT_SAMPLES:
                    found.append((r, "dropout"))
        for p, r in self.pressure_rate:
            if p in still and turning[r] and p not in dropped:
                found.append((p, "stuck"))
        if any(turning[r] for r in self.link_rate):
            found += [(i, "stuck") for i in self.lone if i in still]
        # a frozen value stays named while it stays frozen, moving or not: at rest it would
        # otherwise be weighed with again (a stuck dipper angle: 482 kg 'ok' once the arm stopped)
        if self.active:
            found += [(i, "stuck") for i in still if (i, "stuck") in self.active]

    def _noise(self, found: list, end: int) -> None:
        # the last `every` second differences; a share of the window's beyond the limit
        w = self.buffer[end - self.every - 2:end]
        d2 = np.abs(w[2:] - 2.0 * w[1:-1] + w[:-2])
        block = (d2 > self.noise_limit + np.abs(w[2:]) * self.noise_relative).sum(axis=0)
        self.noise_blocks.append(block)
        self.noise_count += block
        if len(self.noise_blocks) > self.n_blocks:
            self.noise_count -= self.noise_blocks.popleft()
        if len(self.noise_blocks) == self.n_blocks:
            noisy = self.noise_count >= self.noise_count_limit
            if noisy.any():
                found += [(i, "noise") for i in np.flatnonzero(noisy).tolist()]

    def _window_sums(self, j: int, m: int, c: int) -> tuple:
        """Sums of y, x, x², x·y of link j over its last m samples."""
        now = self.ring[(c - 1) % self.size][1][j]
        if c <= m:
            return now
        then = self.ring[(c - 1 - m) % self.size][1][j]
        return tuple(p - q for p, q in zip(now, then))

    def _offset_and_gain(self, found: list, c: int) -> None:
        """The slow checks of each link's angle − integrated rate (``offset`` and ``gain``)."""
        n_s, n_g = self.n_smooth, self.n_gain
        if self.track is None:
            self.track = [None] * len(self.link_angle)
        for j, (a, r) in enumerate(zip(self.link_angle, self.link_rate)):
            smooth = self._window_sums(j, n_s, c)[0] / min(c, n_s)
            track = self.track[j]
            # a link whose angle or rate was stuck, dropped out or noisy has a meaningless
            # integral: its track starts again once that has cleared
            if track is None or (self.active and (self._is_active(a, _RESTART_KINDS)
                                                  or self._is_active(r, _RESTART_KINDS))) \
                    or (found and any(i in (a, r) and kind in _RESTART_KINDS for i, kind in found)):
                self.track[j] = [smooth, 0.0]
                self.off_run[j] = self.gain_run[j] = 0
                self.broken_until[j] = c + n_g
                self.suspect_links[j] = False
                continue
            predicted = track[0] + track[1] * self.every * self.period
            error = smooth - predicted
            alpha, beta = self.track_gains[1 if self.active and self._is_active(a, _TRACK_FLAGGED) else 0]
            track[0] = predicted + alpha * error
            track[1] += beta * error
            limit = self.offset_limit[j]
            self.off_run[j] = self.off_run[j] + 1 if (abs(error) > limit
                                                      or abs(track[1]) > OFFSET_SLOPE_LIMIT) else 0
            if self.off_run[j] >= self.offset_evaluations:
                found += [(a, "offset"), (r, "offset")]
            gain = self._gain(j, c)
            self.suspect_links[j] = (abs(error) > SUSPECT_SHARE * limit
                                     or abs(track[1]) > SUSPECT_SHARE * OFFSET_SLOPE_LIMIT
                                     or abs(gain) > SUSPECT_SHARE * GAIN_LIMIT)
            self.gain_run[j] = self.gain_run[j] + 1 if abs(gain) > GAIN_LIMIT else 0
            if self.gain_run[j] >= self.gain_evaluations:
                found += [(a, "gain"), (r, "gain")]

    def _tilt_offset(self, found: list, c: int) -> None:
        """The size of the house's tilt (hypot of pitch and roll) against its own slow track:
        no rate to compare with; the machine tilts only when it travels, and slowly. Both
        named (the data cannot tell which)."""
        n_s, pitch, roll = self.n_smooth, self.tilts[0], self.tilts[1]
        now = self.ring[(c - 1) % self.size][2][0]
        then = self.ring[(c - 1 - n_s) % self.size][2][0] if c > n_s else 0.0
        smooth = (now - then) / min(c, n_s)
        track = self.tilt_track[0]
        if track is None or (self.active and (self._is_active(pitch, _RESTART_KINDS)
                                              or self._is_active(roll, _RESTART_KINDS))) \
                or (found and any(f in self.tilts and kind in _RESTART_KINDS for f, kind in found)):
            self.tilt_track[0] = [smooth, 0.0]
            self.tilt_run[0] = 0
            self.suspect_tilt = False
            return
        predicted = track[0] + track[1] * self.every * self.period
        error = smooth - predicted
        alpha, beta = self.track_gains[1 if self.active and (pitch, "offset") in self.active else 0]
        track[0] = predicted + alpha * error
        track[1] += beta * error
        self.tilt_run[0] = self.tilt_run[0] + 1 if abs(error) > TILT_OFFSET_LIMIT else 0
        self.suspect_tilt = abs(error) > SUSPECT_SHARE * TILT_OFFSET_LIMIT
        if self.tilt_run[0] >= self.offset_evaluations:
            found += [(pitch, "offset"), (roll, "offset")]

    def _gain(self, j: int, c: int) -> float:
        """Least-squares slope of link j's angle − integrated rate against its angle over the
        gain window (0 while the window is short or the angle hardly moved)."""
        if c < self.n_gain or c < self.broken_until[j]:
            return 0.0
        m = self.n_gain
        sy, sx, sxx, sxy = self._window_sums(j, m, c)
        var = sxx / m - (sx / m) ** 2
        return (sxy / m - sx * sy / m / m) / var if var >= GAIN_MIN_STD ** 2 else 0.0

    def substitute(self, values, rates=None, pressures=(), angles=(), tilts=()):
        """The sample with each named link rate replaced by its angle's slope (and each named
        cylinder pressure of ``pressures`` by 0: its joint is dropped from the weighing, see
        :meth:`named_joints`), when the active faults (after the last :meth:`step`) allow
        weighing on; None when they do not.

        Weighing goes on only while every active fault is a link's rate or an allowed pressure,
        each with a kind of :data:`SUBSTITUTE_KINDS`, and the windows hold :attr:`n_sub` samples
        since the last restart; the slope is the least-squares one over those samples (raw
        values, as the monitor saw them).

        Parameters
        ----------
        values : numpy.ndarray
            The sample just judged, in :attr:`signals` order.
        rates : collection of str or None
            The link rates the estimator weighs on without (its ``DEGRADED_RATES``); None: every
            link's.
        pressures : collection of str
            The cylinder pressures whose joint the estimator weighs on without (its
            ``degraded_pressures()``); empty: none.
        angles : collection of str
            The link angles it weighs on with the integrated rate (its ``degraded_angles()``):
            while named with a kind of :data:`ANGLE_SUBSTITUTE_KINDS` (and maybe ``disagree``,
            its rate then too, with nothing else: the rate is weighed as measured), for at most
            :data:`ANGLE_SUBSTITUTE_LIMIT` after the angle was named; empty: none.
        tilts : collection of str
            The house tilts it weighs on with their value from before the fault (its
            ``degraded_tilts()``), named with any kind, within :data:`TILT_SUBSTITUTE_LIMIT`;
            empty: none.

        Returns
        -------
        numpy.ndarray or None
            A copy with the substitutes, or None (no substitute: the sample is not used).
        """
        if not self.active or self.count < self.n_sub:
            return None
        allowed = self.substitutable(rates)
        dropped = self.droppable(pressures)
        integrated = self.integrable(angles)
        lost = self._lost_angles(integrated)
        explained = [self.link_rate[self.link_angle.index(a)] for a in lost]
        frozen = [i for i in self.tilts if self.signals[i] in tilts]
        for i, kind in self.active:
            if i in frozen:
                continue  # any kind: its value from before the fault (below)
            if i in lost:
                if kind not in ANGLE_SUBSTITUTE_KINDS and kind != "disagree":
                    return None
            elif i in explained:
                if kind != "disagree":
                    return None  # the pair's disagreement is the lost angle's doing; nothing else
            elif kind not in SUBSTITUTE_KINDS or (i not in allowed and i not in dropped):
                return None
        end = (self.count - 1) % self.size + self.size + 1  # one past the newest sample
        window = self.buffer[end - self.n_sub:end]
        out = np.array(values, dtype=float)
        for i in {i for i, _ in self.active}:
            if i in frozen:
                tilt = self._tilt_value()
                if tilt is None:
                    return None
                out[i] = tilt[self.tilts.index(i)]
                continue
            if i in dropped:
                out[i] = 0.0  # its joint is not weighed (named_joints); 0 never stands out as a spike
                continue
            if i in explained:
                continue  # the rate is weighed as measured
            if i in lost:  # the reference + the rate integrated since, for a bounded time
                j = self.link_angle.index(i)
                ref = self.angle_ref[j]
                if ref is None or math.isnan(ref) or self.angle_age[j] > self.n_angle_limit:
                    return None
                out[i] = ref + self.integral[j]
                continue
            a = self.link_angle[self.link_rate.index(i)]
            slope = 0.0
            for w, x in zip(self.sub_weights.tolist(), window[:, a].tolist()):
                slope += w * x  # summed oldest first, as the C export does
            out[i] = slope
        return out

    def substitutable(self, rates=None) -> list[int]:
        """Column indices of the link rates that :meth:`substitute` may replace.

        Parameters
        ----------
        rates : collection of str or None
            Link rate names allowed (None: every link's rate).
        """
        return [r for r in self.link_rate if rates is None or self.signals[r] in rates]

    def droppable(self, pressures=()) -> list[int]:
        """Column indices of the cylinder pressures (of a link's joint) in ``pressures``: those
        :meth:`substitute` may drop.

        Parameters
        ----------
        pressures : collection of str
            Pressure names allowed (empty: none).
        """
        return [i for i in self.pressure_joint if self.signals[i] in pressures]

    def _lost_angles(self, integrated: list) -> list[int]:
        """The angles of ``integrated`` named stuck or dropped out (:data:`ANGLE_SUBSTITUTE_KINDS`)."""
        return [a for a in integrated if any((a, kind) in self.active for kind in ANGLE_SUBSTITUTE_KINDS)]

    def integrable(self, angles=()) -> list[int]:
        """Column indices of the link angles in ``angles``: those :meth:`substitute` may replace
        by the integrated rate.

        Parameters
        ----------
        angles : collection of str
            Angle names allowed (empty: none).
        """
        return [a for a in self.link_angle if self.signals[a] in angles]

    def named_joints(self, pressures=()) -> tuple[bool, ...]:
        """Per link joint (boom, dipper, bucket): whether one of its cylinder's pressures in
        ``pressures`` is named now (after the last :meth:`step`): the joint the estimator drops
        from the weighing while degraded.

        Parameters
        ----------
        pressures : collection of str
            Pressure names the estimator weighs on without.
        """
        named = {self.pressure_joint[i] for i, _ in self.active if i in self.droppable(pressures)}
        return tuple(j in named for j in range(len(LINKS)))

    def newly_named_joints(self, pressures=()) -> tuple[bool, ...]:
        """Per link joint (boom, dipper, bucket): whether a signal named now and not after the
        sample before concerns it (after the last :meth:`step`): a pressure of ``pressures``
        its own joint, any other signal (an angle, a rate, a tilt) every joint. The estimator
        forgets those joints' recent samples (they carry the fault from before its name).

        Parameters
        ----------
        pressures : collection of str
            Pressure names the estimator weighs on without.
        """
        droppable = self.droppable(pressures)
        new = {i for i, _ in self.active} - self.previous
        if any(i not in droppable for i in new):
            return (True,) * len(LINKS)
        joints = {self.pressure_joint[i] for i in new}
        return tuple(j in joints for j in range(len(LINKS)))

    def cleared_joints(self, pressures=()) -> tuple[bool, ...]:
        """Per link joint: whether a signal named after the sample before and not now ends a
        substitute (after :meth:`step`): any signal but a pressure of ``pressures`` every joint;
        such a pressure none (its joint's samples were dropped, not substituted).

        Parameters
        ----------
        pressures : collection of str
            Pressure names the estimator weighs on without.
        """
        droppable = self.droppable(pressures)
        gone = self.previous - {i for i, _ in self.active}
        return (any(i not in droppable for i in gone),) * len(LINKS)

    def link_state(self) -> list[tuple[float, float]]:
        """Per link: (offset error of its track, gain-window slope), for measuring the margins
        on clean data (NaN where not judged)."""
        c, out = self.count, []
        for j in range(len(self.link_angle)):
            if self.track is None or self.track[j] is None or c < self.n_smooth:
                out.append((math.nan, math.nan))
                continue
            smooth = self._window_sums(j, self.n_smooth, c)[0] / self.n_smooth
            gain = self._gain(j, c) if c >= self.n_gain and c >= self.broken_until[j] else math.nan
            out.append((smooth - self.track[j][0], gain))
        return out


def noise_reference(frame, signals, experiment: str = "experiment") -> dict[str, float]:
    """Each signal's 99th percentile of |second difference| sample to sample in ``frame`` (the
    fitting data), within experiments; the family the ``noise`` check compares with.

    Parameters
    ----------
    frame : pandas.DataFrame
        Samples in time order per experiment, with ``signals`` and an ``experiment`` column.
    signals : sequence of str
        The signals to measure.
    experiment : str
        The column that separates experiments (second differences never span two).
    """
    values = frame[list(signals)].to_numpy(dtype=float)
    relative = np.array([1.0 / NOISE_PRESSURE_SCALE if s.endswith("_pressure") else 0.0 for s in signals])
    with np.errstate(invalid="ignore"):  # an infinite sample is NaN here, and dropped below
        d2 = np.abs(values[2:] - 2 * values[1:-1] + values[:-2]) / (1.0 + np.abs(values[2:]) * relative)
    if experiment in frame.columns:
        e = frame[experiment].to_numpy()
        d2 = d2[(e[2:] == e[1:-1]) & (e[1:-1] == e[:-2])]
    out = {}
    for j, s in enumerate(signals):
        col = d2[:, j]
        col = col[np.isfinite(col)]
        if len(col) >= 100:
            out[s] = float(np.quantile(col, NOISE_QUANTILE))
    return out


def for_sensor_set(sensor_set, reference=None) -> HealthMonitor | None:
    """A monitor for ``sensor_set`` (the machine set only; None for the others).

    Parameters
    ----------
    sensor_set : SensorSet
        The estimator's sensor set.
    reference : mapping or None
        :func:`noise_reference` of the fitting data (None: no noise check).
    """
    if not HYDRAULIC.carries(sensor_set):
        return None
    from excavator_payload.data.schema import RESOLUTION

    resolution = {s: RESOLUTION[sensor_set.units[s]] for s in sensor_set.signals}
    return HealthMonitor(sensor_set.signals, sensor_set.sample_period, resolution, reference)
