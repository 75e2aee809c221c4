"""Streaming sensor health per signal, for the ``machine`` sensor set (issue 31).

Every sample an estimator of the machine set uses passes :meth:`HealthMonitor.step` once
(:meth:`~excavator_payload.estimators.base.Estimator.step_values`); while it reports a fault
the sample is not used and the result is ``sensor_fault`` with the estimate kept (never
``ok``), naming the faulty signal(s) and kind(s) in ``StepResult.fault``, e.g.
``"boom_head_pressure:stuck"`` (several comma-separated). Three kinds, each from the data and
the model's redundancy (a link's angle against its own rate, a cylinder's pressures against
its joint's motion):

* ``stuck`` (J1939 FMI 7): the signal changes by no more than :data:`STUCK_QUANTA` of its bus
  resolution over :data:`STUCK_WINDOW` while the arm moves: an angle whose rate says it turns,
  a rate whose angle turns, a pressure whose joint moves; the slew rate and the house's pitch
  and roll (no partner) while any arm joint moves. The sensor noise (angles 17, pressures 300
  resolution steps) never stays inside two steps for 0.3 s; a frozen transmitter does.
* ``dropout`` (FMI 5, current below normal / open circuit: a pulled connector reads 0): an angle
  or pressure at exactly 0 for :data:`DROPOUT_SAMPLES` samples in a row while another of its
  group is not; a rate at exactly 0 that long while its angle turns.
* ``disagree`` (FMI 2, data erratic): a link's angle change over :data:`DISAGREE_WINDOW` against
  the integral of its rate differs by more than :data:`DISAGREE_LIMIT` (widened while the joint accelerates); both are named (the
  data cannot tell which one lies). Catches a jumping or offset angle and runs of agreeing bad
  frames, which no single-frame test sees.

A fault stays active until its condition has been clear for :data:`HOLD` (a spike of three
frames is not half-trusted in between). The thresholds were measured on clean simulated data
of every motion family (docs/sensor-health.md).
"""

from __future__ import annotations

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

#: J1939-73 failure mode identifier of each kind.
FMI = {"stuck": 7, "dropout": 5, "disagree": 2}

LINKS = ("boom", "dipper", "bucket")


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
    """

    def __init__(self, signals, period: float, resolution) -> None:
        self.signals = tuple(signals)
        self.period = float(period)
        idx = {s: i for i, s in enumerate(self.signals)}
        self.quantum = np.array([STUCK_QUANTA * resolution[s] for s in self.signals])
        self.n_stuck = max(2, int(round(STUCK_WINDOW / self.period)) + 1)
        self.n_dis = max(2, int(round(DISAGREE_WINDOW / self.period)) + 1)
        self.hold = int(round(HOLD / self.period))
        self.links = [(idx[f"{k}_angle"], idx[f"{k}_rate"]) for k in LINKS
                      if f"{k}_angle" in idx and f"{k}_rate" in idx]
        self.angles = [idx[s] for s in self.signals if s.endswith("_angle")]
        self.pressures = [idx[s] for s in self.signals if s.endswith("_pressure")]
        # each pressure's joint rate; the unpartnered signals watch every arm joint
        self.pressure_rate = {idx[s]: idx[s.split("_")[0] + "_rate"] for s in self.signals
                              if s.endswith("_pressure") and s.split("_")[0] + "_rate" in idx}
        self.lone = [idx[s] for s in ("slew_rate", "house_pitch", "house_roll") if s in idx]
        self.arm_rates = [r for _, r in self.links]
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new experiment, or a hole in time)."""
        # ring buffer written twice (at k and k + n) so the last n samples are one ordered slice
        self.size = max(self.n_stuck, self.n_dis)
        self.buffer = np.zeros((2 * self.size, len(self.signals)))
        self.pos = 0
        self.count = 0
        self.zeros = np.zeros(len(self.signals), int)
        self.active: dict[tuple[int, str], int] = {}  # (signal, kind) -> samples since last seen
        self.disagreeing: dict[int, int] = {}  # angle -> samples in a row its rate disagrees
        self.last_time: float | None = None

    def step(self, time: float, values: np.ndarray) -> str:
        """Judge one finite, plausible sample; the active faults as ``"signal:kind,..."``
        (empty when healthy)."""
        if self.last_time is not None and not 0 < time - self.last_time <= 1.5 * self.period:
            self.count = 0
            self.zeros[:] = 0
        self.last_time = time
        k = self.pos = (self.pos + 1) % self.size
        self.buffer[k] = self.buffer[k + self.size] = values
        self.count += 1
        found = self._faults(values)
        for key in list(self.active):
            self.active[key] += 1
            if self.active[key] > self.hold:
                del self.active[key]
        for key in found:
            self.active[key] = 0
        if not self.active:
            return ""
        return ",".join(f"{self.signals[i]}:{kind}" for i, kind in sorted(self.active))

    def _faults(self, values: np.ndarray) -> list[tuple[int, str]]:
        found: list[tuple[int, str]] = []
        zero = values == 0.0
        self.zeros = np.where(zero, self.zeros + 1, 0)
        if self.zeros.max() >= DROPOUT_SAMPLES:
            for group in (self.angles, self.pressures):
                for i in group:
                    if self.zeros[i] >= DROPOUT_SAMPLES and not all(zero[j] for j in group):
                        found.append((i, "dropout"))
        end = self.pos + self.size + 1  # one past the newest sample
        if self.count >= self.n_dis:
            recent = self.buffer[end - self.n_dis:end]
            for a, r in self.links:
                moved = recent[-1, a] - recent[0, a]
                integral = 0.5 * self.period * (recent[1:, r] + recent[:-1, r]).sum()
                span = recent[:, r].max() - recent[:, r].min()
                if abs(moved - integral) > DISAGREE_LIMIT + DISAGREE_PER_RATE_CHANGE * span:
                    # a one-frame spike is the outlier gate's (rejected, the estimate untouched);
                    # a disagreement that lasts two samples is the sensor's
                    self.disagreeing[a] = self.disagreeing.get(a, 0) + 1
                    if self.disagreeing[a] >= DISAGREE_SAMPLES:
                        found += [(a, "disagree"), (r, "disagree")]
                else:
                    self.disagreeing[a] = 0
        if self.count < self.n_stuck:
            return found
        w = self.buffer[end - self.n_stuck:end]
        still = (w.max(axis=0) - w.min(axis=0)) <= self.quantum
        turning = np.abs(w).max(axis=0) > MOVING_RATE  # rates only
        duration = (len(w) - 1) * self.period
        dropped = {i for i, kind in found if kind == "dropout"}
        for a, r in self.links:
            if still[a] and turning[r] and a not in dropped:
                found.append((a, "stuck"))
            angle_rate = abs(w[-1, a] - w[0, a]) / duration
            if angle_rate > MOVING_RATE:
                if still[r]:
                    found.append((r, "stuck"))
                elif self.zeros[r] >= DROPOUT_SAMPLES:
                    found.append((r, "dropout"))
        for p, r in self.pressure_rate.items():
            if still[p] and turning[r] and p not in dropped:
                found.append((p, "stuck"))
        if any(turning[r] for r in self.arm_rates):
            found += [(i, "stuck") for i in self.lone if still[i]]
        return found


def for_sensor_set(sensor_set) -> HealthMonitor | None:
    """A monitor for ``sensor_set`` (the machine set only; None for the others)."""
    if sensor_set.name != "machine":
        return None
    from excavator_payload.data.schema import RESOLUTION

    resolution = {s: RESOLUTION[sensor_set.units[s]] for s in sensor_set.signals}
    return HealthMonitor(sensor_set.signals, sensor_set.sample_period, resolution)
