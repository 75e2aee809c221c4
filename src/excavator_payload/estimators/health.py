"""Streaming sensor health per signal, for the ``machine`` sensor set (issue 31).

Every sample an estimator of the machine set uses passes :meth:`HealthMonitor.step` once
(:meth:`~excavator_payload.estimators.base.Estimator.step_values`); while it reports a fault
the sample is not used and the result is ``sensor_fault`` with the estimate kept (never
``ok``), naming the faulty signal(s) and kind(s) in ``StepResult.fault``, e.g.
``"boom_head_pressure:stuck"`` (several comma-separated). Each kind comes from the data and
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
  for :data:`OFFSET_SAMPLES` samples. A lasting offset or a drift faster than about
  OFFSET_LIMIT / OFFSET_TAU; while flagged the track follows only with :data:`OFFSET_TAU_FLAGGED`,
  so a lasting offset is named for tens of seconds, not for ever. Both signals named.
* ``gain`` (FMI 13): over :data:`GAIN_WINDOW` with the angle spread at least :data:`GAIN_MIN_STD`,
  the least-squares slope of (angle − integrated rate) against the angle exceeds
  :data:`GAIN_LIMIT` (a scale error of either signal; both named).

A fault stays active until its condition has been clear for :data:`HOLD` (a spike of three
frames is not half-trusted in between). Thresholds were set on clean simulated data of the
simulator's own motion families and judged on held-out ones (docs/sensor-health.md).

Cost: every rule is an incremental window (ring buffer, running sums and counts) evaluated with
a fixed handful of array operations per sample, whatever the window lengths.
"""

from __future__ import annotations

import math

import numpy as np

#: Window over which a stuck signal does not move, s.
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
OFFSET_SAMPLES = 10
#: Gain: window, s; the angle's least spread over it, rad; the largest slope of (angle −
#: integrated rate) against the angle (a 10 % scale error is 0.1); samples in a row.
GAIN_WINDOW = 2.0
GAIN_MIN_STD = 0.15
GAIN_LIMIT = 0.08
GAIN_SAMPLES = 10

#: The kinds in the order of the monitor's arrays.
KINDS = ("stuck", "dropout", "disagree", "noise", "offset", "gain")
#: J1939-73 failure mode identifier of each kind.
FMI = {"stuck": 7, "dropout": 5, "disagree": 2, "noise": 2, "offset": 13, "gain": 13}

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
        # a stuck value stays within ± this of the first value of its run (2 steps: a frozen
        # value that flickers by one bit still counts)
        self.quantum = [STUCK_QUANTA * resolution[s] for s in self.signals]
        samples = lambda seconds: max(2, int(round(seconds / self.period)) + 1)  # noqa: E731
        self.n_stuck = samples(STUCK_WINDOW)
        self.n_dis = samples(DISAGREE_WINDOW)
        self.n_noise = samples(NOISE_WINDOW)
        self.n_smooth = samples(OFFSET_SMOOTH)
        self.n_gain = samples(GAIN_WINDOW)
        self.size = max(self.n_stuck, self.n_dis, self.n_noise, self.n_smooth, self.n_gain) + 1
        self.hold = int(round(HOLD / self.period))
        self.duration = (self.n_stuck - 1) * self.period
        links = [k for k in LINKS if f"{k}_angle" in idx and f"{k}_rate" in idx]
        self.link_angle = [idx[f"{k}_angle"] for k in links]
        self.link_rate = [idx[f"{k}_rate"] for k in links]
        self.angles = [idx[s] for s in self.signals if s.endswith("_angle")]
        self.pressures = [idx[s] for s in self.signals if s.endswith("_pressure")]
        self.rates = [idx[s] for s in self.signals if s.endswith("_rate")]
        # each pressure's joint rate; the unpartnered signals watch every arm joint
        self.pressure_rate = [(idx[s], idx[s.split("_")[0] + "_rate"]) for s in self.signals
                              if s.endswith("_pressure") and s.split("_")[0] + "_rate" in idx]
        self.lone = [idx[s] for s in ("slew_rate", "house_pitch", "house_roll") if s in idx]
        ref = reference or {}
        self.noise_limit = [NOISE_FACTOR * float(ref[s]) if s in ref and float(ref[s]) > 0
                            else math.inf for s in self.signals]
        self.noise_count_limit = NOISE_SHARE * self.n_noise
        self.relative = [1.0 / NOISE_PRESSURE_SCALE if s.endswith("_pressure") else 0.0 for s in self.signals]
        # alpha-beta track of angle − integrated rate, critically damped (time constant tau)
        w, wf = self.period / OFFSET_TAU, self.period / OFFSET_TAU_FLAGGED
        self.track_gains = ((2 * w, w * w / self.period), (2 * wf, wf * wf / self.period))
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new experiment, or a hole in time)."""
        self.active: dict[tuple[int, str], int] = {}  # (signal, kind) -> samples since last seen
        self.last_time: float | None = None
        self._restart()

    def _restart(self) -> None:
        """Start the windows again (after a hole in time); active faults keep their hold."""
        n, L = len(self.signals), len(self.link_angle)
        self.count = 0
        # ring of the last `size` samples: (values, each link's angle − integrated rate)
        self.ring: list = [None] * self.size
        self.noisy_ring = [0] * self.size  # bit mask of the signals noisy at each sample
        self.noise_count = [0] * n
        self.zeros = [0] * n
        self.any_zeros = False
        self.anchor = [math.nan] * n  # first value of each signal's still run, and its length
        self.run = [0] * n
        self.since_moving = {r: 1 << 30 for r in self.rates}
        self.disagreeing = [0] * L
        self.integral = [0.0] * L
        self.r_sum = [0.0] * L
        self.g_sums = [[0.0] * 4 for _ in range(L)]  # x, y, xx, xy over the gain window
        self.origin = [0.0] * L  # x origin: keeps the gain sums of squares small
        self.track = None  # [level, slope] of each link's angle − integrated rate
        self.off_run = [0] * L
        self.gain_run = [0] * L
        self.broken_until = [0] * L  # a link's track restarts while its signals are broken

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
        if self.last_time is not None and not 0 < time - self.last_time <= 1.5 * self.period:
            self._restart()
        self.last_time = time
        found = self._faults(values.tolist() if hasattr(values, "tolist") else list(values))
        active = self.active
        if active:
            for key in list(active):
                active[key] += 1
                if active[key] > self.hold:
                    del active[key]
        for key in found:
            active[key] = 0
        if not active:
            return ""
        return ",".join(f"{self.signals[i]}:{kind}" for i, kind in sorted(active))

    def _is_active(self, signal: int, kinds) -> bool:
        return any((signal, k) in self.active for k in kinds)

    def _faults(self, v: list) -> list[tuple[int, str]]:
        """The (signal, kind) conditions seen at this sample (before the hold)."""
        found: list[tuple[int, str]] = []
        size, dt, n = self.size, self.period, len(v)
        c = self.count
        prev = self.ring[(c - 1) % size] if c else None
        prev2 = self.ring[(c - 2) % size] if c >= 2 else None
        # -- per-link angle − integrated rate ---------------------------------------------
        integral = self.integral
        resid = []
        for j, (a, r) in enumerate(zip(self.link_angle, self.link_rate)):
            if prev is not None:
                integral[j] += 0.5 * dt * (prev[0][r] + v[r])
            resid.append(v[a] - integral[j])
        self.ring[c % size] = (v, resid)
        self.count = c = c + 1
        # -- per signal: still runs, zeros, noise -----------------------------------------
        quantum, anchor, run = self.quantum, self.anchor, self.run
        still = []
        for i in range(n):
            x = v[i]
            if abs(x - anchor[i]) <= quantum[i]:
                run[i] += 1
                if run[i] >= self.n_stuck - 1:
                    still.append(i)
            else:
                anchor[i] = x
                run[i] = 0
        for r in self.rates:
            self.since_moving[r] = 0 if abs(v[r]) > MOVING_RATE else self.since_moving[r] + 1
        if self.any_zeros or 0.0 in v:
            zeros = self.zeros = [z + 1 if x == 0.0 else 0 for z, x in zip(self.zeros, v)]
            self.any_zeros = 0.0 in v
            for group in (self.angles, self.pressures):
                if any(v[i] != 0.0 for i in group):
                    found += [(i, "dropout") for i in group if zeros[i] >= DROPOUT_SAMPLES]
        if prev2 is not None:
            p1, p2, limit = prev[0], prev2[0], self.noise_limit
            mask = 0
            for i in range(n):
                if abs(v[i] - 2.0 * p1[i] + p2[i]) > limit[i] * (1.0 + abs(v[i]) * self.relative[i]):
                    mask |= 1 << i
            old = self.noisy_ring[(c - self.n_noise) % size] if c > self.n_noise else 0
            self.noisy_ring[c % size] = mask
            if mask or old:
                counts = self.noise_count
                for i in range(n):
                    counts[i] += ((mask >> i) & 1) - ((old >> i) & 1)
                if c >= self.n_noise + 2:
                    found += [(i, "noise") for i in range(n) if counts[i] >= self.noise_count_limit]
        # -- disagree: angle change against the rate's integral over a short window ---------
        if c >= self.n_dis:
            first = c - self.n_dis  # ring index of the window's first sample
            window = [self.ring[(first + m) % size] for m in range(self.n_dis)]
            old_resid = window[0][1]
            for j, (a, r) in enumerate(zip(self.link_angle, self.link_rate)):
                rates = [s[0][r] for s in window]
                limit = DISAGREE_LIMIT + DISAGREE_PER_RATE_CHANGE * (max(rates) - min(rates))
                if abs(resid[j] - old_resid[j]) > limit:
                    # a one-frame spike is the outlier gate's (rejected, the estimate untouched);
                    # a disagreement that lasts two samples is the sensor's
                    self.disagreeing[j] += 1
                    if self.disagreeing[j] >= DISAGREE_SAMPLES:
                        found += [(a, "disagree"), (r, "disagree")]
                else:
                    self.disagreeing[j] = 0
        self._offset_and_gain(found, resid, v)
        if c < self.n_stuck or not still:
            return found
        # -- stuck ------------------------------------------------------------------------
        dropped = {i for i, kind in found if kind == "dropout"}
        w0 = self.ring[(c - self.n_stuck) % size][0]
        turning = {r: m < self.n_stuck for r, m in self.since_moving.items()}
        stillset = set(still)
        for a, r in zip(self.link_angle, self.link_rate):
            if a in stillset and turning[r] and a not in dropped:
                found.append((a, "stuck"))
            if r in stillset and abs(v[a] - w0[a]) > MOVING_RATE * self.duration:
                found.append((r, "stuck"))
        for p, r in self.pressure_rate:
            if p in stillset and turning[r] and p not in dropped:
                found.append((p, "stuck"))
        if any(turning[r] for r in self.link_rate):
            found += [(i, "stuck") for i in self.lone if i in stillset]
        return found

    def _offset_and_gain(self, found: list, resid: list, v: list) -> None:
        """The slow checks of each link's angle − integrated rate (``offset`` and ``gain``)."""
        c, size = self.count, self.size
        n_s, n_g = self.n_smooth, self.n_gain
        out_s = self.ring[(c - 1 - n_s) % size] if c > n_s else None
        out_g = self.ring[(c - 1 - n_g) % size] if c > n_g else None
        exact = c % size == 0  # running sums of floats drift over a long stream: redo them
        if c == 1:
            self.origin = [v[a] for a in self.link_angle]
        if c >= n_s and self.track is None:
            self.track = [[0.0, 0.0] for _ in resid]
        for j, (a, r) in enumerate(zip(self.link_angle, self.link_rate)):
            x, y = v[a] - self.origin[j], resid[j]
            g = self.g_sums[j]
            if exact:
                self.r_sum[j] = sum(self.ring[(c - 1 - m) % size][1][j] for m in range(min(c, n_s)))
                g[:] = [0.0] * 4
                for m in range(min(c, n_g)):
                    s = self.ring[(c - 1 - m) % size]
                    xs, ys = s[0][a] - self.origin[j], s[1][j]
                    g[0] += xs
                    g[1] += ys
                    g[2] += xs * xs
                    g[3] += xs * ys
            else:
                self.r_sum[j] += y
                g[0] += x
                g[1] += y
                g[2] += x * x
                g[3] += x * y
                if out_s is not None:
                    self.r_sum[j] -= out_s[1][j]
                if out_g is not None:
                    ox, oy = out_g[0][a] - self.origin[j], out_g[1][j]
                    g[0] -= ox
                    g[1] -= oy
                    g[2] -= ox * ox
                    g[3] -= ox * oy
            if c < n_s:
                continue
            smooth = self.r_sum[j] / n_s
            # a link whose angle or rate was stuck, dropped out or noisy has a meaningless
            # integral: its track starts again once that has cleared
            track = self.track[j]
            if c == n_s or (self.active and (self._is_active(a, _RESTART_KINDS)
                                             or self._is_active(r, _RESTART_KINDS))) \
                    or (found and any(i in (a, r) and k in _RESTART_KINDS for i, k in found)):
                track[0], track[1] = smooth, 0.0
                self.off_run[j] = self.gain_run[j] = 0
                self.broken_until[j] = c + n_g
                continue
            predicted = track[0] + track[1] * self.period
            error = smooth - predicted
            alpha, beta = self.track_gains[1 if self.active and self._is_active(a, _TRACK_FLAGGED) else 0]
            track[0] = predicted + alpha * error
            track[1] += beta * error
            self.off_run[j] = self.off_run[j] + 1 if abs(error) > OFFSET_LIMIT else 0
            if self.off_run[j] >= OFFSET_SAMPLES:
                found += [(a, "offset"), (r, "offset")]
            if c < n_g or c < self.broken_until[j]:
                continue
            var = g[2] / n_g - (g[0] / n_g) ** 2
            gain = (g[3] / n_g - g[0] * g[1] / n_g / n_g) / var if var >= GAIN_MIN_STD ** 2 else 0.0
            self.gain_run[j] = self.gain_run[j] + 1 if abs(gain) > GAIN_LIMIT else 0
            if self.gain_run[j] >= GAIN_SAMPLES:
                found += [(a, "gain"), (r, "gain")]

    def link_state(self) -> list[tuple[float, float]]:
        """Per link: (offset error of its track, gain-window slope; NaN when not judged), for
        measuring the margins on clean data."""
        out = []
        for j in range(len(self.link_angle)):
            g, n_g = self.g_sums[j], self.n_gain
            var = g[2] / n_g - (g[0] / n_g) ** 2
            gain = (g[3] / n_g - g[0] * g[1] / n_g / n_g) / var if var >= GAIN_MIN_STD ** 2 else math.nan
            if self.count < self.n_gain or self.count < self.broken_until[j]:
                gain = math.nan
            if self.track is None or self.count < self.n_smooth:
                out.append((math.nan, gain))
            else:
                out.append((self.r_sum[j] / self.n_smooth - self.track[j][0], gain))
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
    if sensor_set.name != "machine":
        return None
    from excavator_payload.runtime.dbc import RESOLUTION

    resolution = {s: RESOLUTION[sensor_set.units[s]] for s in sensor_set.signals}
    return HealthMonitor(sensor_set.signals, sensor_set.sample_period, resolution, reference)


def flagged_signals(estimator, dataset) -> dict[str, str]:
    """The signals a fresh monitor flags anywhere in ``dataset`` (per experiment), each with its
    kinds and the first time, e.g. ``{"boom_head_pressure": "stuck at 3.20 s"}``; for commands
    that must not build on a faulty signal (``zero``).

    Parameters
    ----------
    estimator : Estimator
        A fitted estimator of the machine sensor set (its noise reference is used).
    dataset : Dataset
        The data to judge (machine sensor set).
    """
    monitor = for_sensor_set(dataset.sensor_set, getattr(estimator, "health_reference", None))
    if monitor is None:
        return {}
    frame = dataset.frame
    signals = list(dataset.sensor_set.signals)
    values = frame[signals].to_numpy(dtype=float)
    times = frame["time"].to_numpy(dtype=float)
    exps = frame["experiment"].to_numpy() if "experiment" in frame.columns else np.zeros(len(frame))
    low, high = getattr(estimator, "plausible_low", None), getattr(estimator, "plausible_high", None)
    seen: dict[str, tuple[set, float]] = {}
    last = None
    for t, x, e in zip(times, values, exps):
        if e != last:
            monitor.reset()
            last = e
        if not np.all(np.isfinite(x)) or (low is not None and not (np.all(x >= low) and np.all(x <= high))):
            continue  # the estimator skips these samples itself
        fault = monitor.step(float(t), x)
        for item in filter(None, fault.split(",")):
            signal, _, kind = item.partition(":")
            kinds, when = seen.setdefault(signal, (set(), float(t)))
            kinds.add(kind)
    return {s: f"{'/'.join(sorted(k))} at {t:.2f} s" for s, (k, t) in seen.items()}


def refuse_flagged(estimator, dataset, used_signals, command: str = "zero") -> None:
    """Raise :class:`~excavator_payload.errors.EstimatorError` (one line) when the monitor flags
    any of ``used_signals`` in ``dataset``: a result built on it would carry the fault.

    Parameters
    ----------
    estimator : Estimator
        The fitted estimator whose noise reference the monitor uses.
    dataset : Dataset
        The data the command would build on.
    used_signals : sequence of str
        The signals the command's result depends on.
    command : str
        The command's name, for the message.
    """
    from excavator_payload.errors import EstimatorError

    flagged = flagged_signals(estimator, dataset)
    bad = [f"{s} ({flagged[s]})" for s in used_signals if s in flagged]
    if bad:
        raise EstimatorError(f"{command}: the sensor health monitor flags {', '.join(bad)}; an offset "
                             f"built on it would carry the fault (fix the sensor and record again, "
                             f"or --force)")

