r"""The streaming kernel of the calibrated machine: :class:`CalibratedKernel`.

:class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression` with
the identified parameters, offsets, IMU dynamics and noise. Per sample it calls the compiled
:func:`~.symbolic.kernel_function` on the centre of the differentiator's ring and accumulates

.. math:: N \leftarrow \lambda N + \sum_j w_j\varphi_j r_j, \qquad
          I \leftarrow \lambda I + \sum_j w_j\varphi_j^2, \qquad \hat m = N / I,

with :math:`w_j` the inverse residual variance (pressure noise through the lever, stiction near
standstill per ``--low-speed``, the rates' noise through the momentum). In the momentum form
the per-sample terms go into a second ring, and the residual and :math:`\varphi` are the
balance's over its window (:func:`~.data.window_residuals`, the same weights). The kernel
also owns ``--outside-calibration`` (a joint outside its covered angles gets no weight),
``--wait-for-boom`` (:attr:`CalibratedKernel.ready`, then :attr:`CalibratedKernel.steady`),
``--new-load`` (a short memory against the whole one, :meth:`CalibratedKernel._accumulate`;
and a dump's end, :attr:`CalibratedKernel.dump_pending`)
and ``--joint-check`` (each joint's share of the sums against the others',
:meth:`CalibratedKernel._check_joints`).
"""

from __future__ import annotations

import math

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.classical.machine_calibration.data import balance_weights
from excavator_payload.estimators.classical.machine_calibration.settings import (
    BALANCE_HALF_WINDOW, BALANCE_RAMP, BOOM_READY_WINDOWS, CHANGING_MIN_SHARE, CHANGING_SIGMAS, COVERAGE_JOINTS,
    DUMP_HOLD, DUMP_LOAD_SHARE, DUMP_OPENING_RATE, DUMP_RESTARTS, DUMP_TURN, NEW_LOAD_MEMORY, NEW_LOAD_MIN_SHARE,
    NEW_LOAD_SIGMAS, NO_LIMIT, SETTLE_WINDOWS, SIGNALS, STEADY_SHARE, STEADY_WINDOWS)
from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
from excavator_payload.estimators.classical.machine_calibration.symbolic import kernel_function
from excavator_payload.estimators.classical.pressure_regression import ANGLES, LOOK_AHEAD, RATES, PressureRegression


class CalibratedKernel(PressureRegression):
    """:class:`PressureRegression` with the identified parameters, offsets and noise.

    Streaming in tens of microseconds: the window of samples is a doubled ring buffer (the
    window is always one contiguous slice), the centred slope a fixed weight vector (uniform
    sampling: the base class resets on gaps), and one compiled CasADi call per sample.

    The weights are those of ``inverse-dynamics`` (pressure noise through the geometry, plus
    stiction near standstill); adding the differentiator's noise or the slope error at a kink
    through ∂r/∂q̈ was measured and not kept (findings: "The kernel's weights").

    Parameters
    ----------
    cal : MachineCalibration
        The calibration it weighs with (parameters, offsets, IMU dynamics, noise, covered angles).
    half_window : int
        Samples each side of the centred differentiator.
    forgetting : float
        Forgetting factor λ of the recursive sums.
    low_speed : str
        ``--low-speed``: ``model``, ``downweight`` or ``skip``.
    outside_calibration : str
        ``--outside-calibration``: ``auto``, ``skip`` or ``use``.
    wait_for_boom : str
        ``--wait-for-boom``: ``auto``, ``yes`` or ``no``.
    new_load : str
        ``--new-load``: ``auto``, ``detect`` or ``off``.
    """

    _imu_nuisance = None  # ``--imu-nuisance on``: an ImuNuisanceFilter (use_imu_nuisance)
    _offset_share = None  # after a zero, momentum form: the zero's share of σ (use_offset_share)
    #: Per joint (boom, dipper, bucket): the next sample's cylinder pressures are not to be
    #: weighed (a degraded estimator sets it while the health monitor names one; the
    #: estimator's ``_drop_joints``). A balance window holding such a sample gives that joint no
    #: weight, so it is weighed again only once its windows are clean; the sums it gave before
    #: are kept.
    drop = (False, False, False)
    #: The sample weighs the health monitor's substitutes (set before each by the estimator's
    #: ``_substituting``): a pause of the joint check that ends then restarts nothing (a weighing
    #: begun on a substitute alone: a stuck boom rate's slope left one 62 kg off after the fault).
    substituting = False
    #: The weighed motions keep their load whatever the bucket does (the calibration's
    #: cross-check weighs motions of known loads that stay in the bucket): a dump neither says
    #: ``load_changing`` nor restarts the weighing. Python only: the exported C weighs work.
    loads_stay = False

    def __init__(self, cal, half_window: int, forgetting: float, low_speed: str,
                 outside_calibration: str = "auto", wait_for_boom: str = "auto", new_load: str = "auto"):
        super().__init__(cal.arm, pressure_std=cal.pressure_std, ripple_fraction=0.0,
                         half_window=half_window, forgetting=forgetting)
        self.balance = cal.balance
        self._kernel = kernel_function(self.balance)
        self._n_out = 24 if self.balance == "momentum" else 15
        self._trigger = None
        self._p = cal.p
        self._offset = cal.offset_vector()
        self._imu = np.array(cal.imu, float)
        self.low_speed = low_speed
        # the covered angle range in raw (measured) units, raw = corrected + offset: the C
        # export compares the same numbers
        if outside_calibration == "auto":
            outside_calibration = "skip" if self.balance == "momentum" else "use"
        self.outside_calibration = outside_calibration
        coverage = np.tile([-NO_LIMIT, NO_LIMIT], (3, 1))
        if outside_calibration in ("skip", "arm"):
            limited = np.ones(3, bool) if self.whole_arm else np.array(COVERAGE_JOINTS)
            coverage[limited] = np.asarray(cal.angle_coverage, float)[limited]
        self._raw_low = np.clip(coverage[:, 0] + self._offset[ANGLES], -NO_LIMIT, NO_LIMIT)
        self._raw_high = np.clip(coverage[:, 1] + self._offset[ANGLES], -NO_LIMIT, NO_LIMIT)
        if wait_for_boom == "auto":
            wait_for_boom = "yes" if self.balance == "momentum" else "no"
        self.wait_for_boom = wait_for_boom == "yes"
        if new_load == "auto":
            new_load = "detect" if self.balance == "momentum" else "off"
        self.new_load = new_load == "detect"
        width = 2 * self.half_window + 1
        dt = 1.0 / MACHINE_SENSORS.sample_rate
        self._short_forgetting = math.exp(-dt / NEW_LOAD_MEMORY)
        self._dump_hold = int(round(DUMP_HOLD / dt))  # samples a dump lasts after the bucket's last fast opening
        self._new_load_min = NEW_LOAD_MIN_SHARE * float(cal.arm.machine.rated_payload)
        self._changing_min = CHANGING_MIN_SHARE * float(cal.arm.machine.rated_payload)
        self._dump_load_min = DUMP_LOAD_SHARE * float(cal.arm.machine.rated_payload)
        self._steady_limit = STEADY_SHARE * float(cal.arm.machine.rated_payload)
        # kg, in σ beside I^-1/2: the calibration's cross-checked model error and the zero's offsets
        # (their RMS over the calibrated poses; the momentum form carries each estimate's own
        # share instead, use_offset_share)
        self.model_std = math.hypot(float(cal.model_std), float(getattr(cal, "zero_std", 0.0)))
        # --joint-check: its thresholds were set on the calibration's s alone (a zero's offset error
        # is shared by the joints' weighings it compares)
        self._joints = JointCheck(float(cal.arm.machine.rated_payload), float(cal.model_std))
        k = np.arange(-self.half_window, self.half_window + 1) * dt
        self._slope = k / float(k @ k)
        self._lever_var = (self._head**2 + self._rod**2) * self.pressure_var
        self._width = width
        self._balance_len = 2 * BALANCE_HALF_WINDOW + 1  # samples of the momentum-balance window
        w, u = balance_weights(BALANCE_HALF_WINDOW, BALANCE_RAMP)
        self._balance_w, self._balance_u = w * dt, u
        self._balance_span = float(w.sum()) * dt
        self._rate_var_span = cal.rate_var / self._balance_span**2
        self.reset()

    def _bind(self) -> None:
        """CasADi's buffer interface: the compiled call on preallocated arrays (≈ 7 µs, against
        ≈ 250 µs through the Python call with its conversions)."""
        self._x, self._qdd, self._pvec = np.zeros(len(SIGNALS)), np.zeros(4), np.array(self._p, float)
        self._ovec, self._ivec = np.array(self._offset, float), np.array(self._imu, float)
        self._out = np.zeros(self._n_out)
        self._buffer_call, self._trigger = self._kernel.buffer()
        for i, a in enumerate((self._x, self._qdd, self._pvec, self._ovec, self._ivec)):
            self._buffer_call.set_arg(i, memoryview(a))
        self._buffer_call.set_res(0, memoryview(self._out))

    def __getstate__(self):  # copies and pickles rebind the buffers on first use
        state = dict(self.__dict__)
        for key in ("_buffer_call", "_trigger", "_kernel", "_f"):
            state.pop(key, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._kernel = kernel_function(self.balance)
        self._f = self._kernel
        self._trigger = None

    def reset(self) -> None:
        """Start again: the base class's reset, plus empty sample and balance-term rings and
        cleared ``--wait-for-boom`` / ``--new-load`` state."""
        super().reset()
        length = getattr(self, "_width", 1) + LOOK_AHEAD
        self._ring = np.zeros((2 * length, len(SIGNALS)))
        self._ring_used = np.zeros(2 * length, bool)
        self._ring_drop = np.zeros((2 * length, 3), bool)  # each sample's joints dropped (drop)
        self._count = 0
        self._dump_left = 0  # samples the dump still lasts (dumping)
        self._dump_ended = False  # a dump has ended since the last window (_accumulate restarts)
        self._dump_load = False  # the current dump began with a load in the bucket (or none known)
        self._dump_from = 0.0  # the bucket's angle as it began to open fast, rad
        self._dump_turned = False  # ... and it has opened by DUMP_TURN since: the load slides out
        # with --imu-nuisance: the filter's payload as the last window left it (the joint check's
        # moving rule reads it, as the C export's check runs before the filter's window)
        self.payload_before = math.nan
        b = getattr(self, "_balance_len", 1)  # reset() runs in the base __init__ before it is set
        self._terms = np.zeros((2 * b, getattr(self, "_n_out", 24)))  # per-sample balance terms, doubled as the ring
        self._terms_used = np.zeros(2 * b, bool)
        self._terms_inside = np.zeros((2 * b, 3), bool)  # each sample's joints inside the coverage
        self._terms_count = 0
        self.boom_windows = 0  # windows with weight on the boom joint seen (--wait-for-boom)
        self.num_joint = [0.0, 0.0, 0.0]  # each joint's share of num and info (boom, dipper, bucket)
        self.info_joint = [0.0, 0.0, 0.0]
        self.num_short = 0.0  # the short memory of the new-load test (--new-load)
        self.info_short = 0.0
        self.num_joint_short = [0.0, 0.0, 0.0]  # its joints' shares (the joint check's, after a settle)
        self.info_joint_short = [0.0, 0.0, 0.0]
        self.changing_windows = 0  # windows of the current load_changing episode
        self.settles = 0  # changing episodes that ended with the whole memory set to the short one
        self.new_loads = 0  # new loads detected since the last reset
        self.dump_restarts = 0  # ... of which restarts at a dump's end
        self.changing = False  # the short memory has left the whole one (status load_changing)
        self._restart_steady()
        if hasattr(self, "_joints"):
            self._joints.reset()
        if self._imu_nuisance is not None:
            self._imu_nuisance.reset()
        if self._offset_share is not None:
            self._offset_share.reset()

    @property
    def ready(self) -> bool:
        """Whether an estimate may be reported (``--wait-for-boom``): while the boom has stood
        still its seals hold an unknown stiction force (≈ 470 kg of payload), so the weighing
        rests on the dipper and bucket, whose calibration at the poses of a cut is least sure;
        and the first boom windows, all of one phase of the motion (its start), carry that
        phase's model error (:data:`BOOM_READY_WINDOWS`)."""
        return self.boom_windows >= BOOM_READY_WINDOWS or not self.wait_for_boom

    def _restart_steady(self) -> None:
        self.steady = not getattr(self, "wait_for_boom", False)  # reported once it holds still
        self._steady_history = [0.0] * (STEADY_WINDOWS + 1)  # the last estimates, a ring
        self._steady_count = 0

    def _track_steady(self) -> None:
        """:attr:`steady`: once :attr:`ready`, the estimate has moved by at most
        :data:`STEADY_SHARE` of the rated payload over the last :data:`STEADY_WINDOWS` windows;
        it stays so until the weighing restarts (a reset, a new load)."""
        if self.steady or not self.ready or self.info <= 0.0:
            return
        k, n = self._steady_count, STEADY_WINDOWS + 1
        estimate = self.num / self.info
        history = self._steady_history
        if k >= STEADY_WINDOWS and abs(estimate - history[(k - STEADY_WINDOWS) % n]) <= self._steady_limit:
            self.steady = True
        history[k % n] = estimate
        self._steady_count = k + 1

    def restart_window(self) -> None:
        self._count = 0
        self._terms_count = 0

    def forget(self, joints: tuple[bool, ...]) -> None:
        """Give these joints (boom, dipper, bucket) no weight in any window that holds a sample
        now in the rings: the samples before the health monitor named a signal carry its fault
        too (a rate at 0 for the 0.3 s it takes to name it). Windows already weighed are kept.

        Parameters
        ----------
        joints : tuple of bool
            Per joint, whether its windows over the samples held now are dropped.
        """
        mask = np.asarray(joints, bool)
        self._ring_drop[:, mask] = True
        self._terms_inside[:, mask] = False

    def _call(self, sample: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        if self._trigger is None:
            self._bind()
        self._x[:] = sample
        self._qdd[:] = qdd
        self._trigger()
        return self._out

    def _variance(self, lever, speed, stiction) -> np.ndarray:
        var = lever**2 * self._lever_var
        if self.low_speed == "downweight":
            var = var + np.exp(-(speed / (3 * self._v_stribeck)) ** 2) * stiction**2 / 3
        return var

    def _used(self, speed) -> np.ndarray:
        if self.low_speed == "skip":
            return np.abs(speed) >= 3 * self._v_stribeck
        return np.ones(3, bool)

    def _inside(self, sample: np.ndarray) -> np.ndarray:
        """Each joint's angle inside the range calibration covered (``--outside-calibration``;
        ``arm``: every joint inside, or none)."""
        angles = sample[ANGLES]
        inside = (angles >= self._raw_low) & (angles <= self._raw_high)
        if self.whole_arm:
            return np.full(3, bool(inside.all()))
        return inside

    @property
    def whole_arm(self) -> bool:
        """``--outside-calibration arm``: a sample with any arm joint outside its covered range
        weighs no joint."""
        return self.outside_calibration == "arm"

    def update(self, time: float, values: np.ndarray) -> bool:
        # ring of the window (2·half_window + 1 samples) and the newest, not yet judged samples,
        # stored twice so that the window is always one contiguous slice
        w = self._width
        length = w + LOOK_AHEAD
        pos = self._count % length
        self._ring[pos] = self._ring[pos + length] = values
        self._ring_used[pos] = self._ring_used[pos + length] = True
        self._ring_drop[pos] = self._ring_drop[pos + length] = self.drop
        self._count += 1
        self.rejected = False
        if values[RATES[2]] > DUMP_OPENING_RATE:  # the bucket opens fast: a dump (dumping)
            if not self._dump_left:  # it starts: can it leave a load (dump_pending)?
                self._dump_load = not self.ready or not self.info > 0.0 or \
                    self.num / self.info > self._dump_load_min
                self._dump_from = float(values[ANGLES[2]])
                self._dump_turned = False
            self._dump_left = self._dump_hold
        elif self._dump_left:
            self._dump_left -= 1
            # the dump is over: what the bucket holds now is a new load (_accumulate restarts)
            if self._dump_left == 0 and self._dump_load and self._dump_turned:
                self._dump_ended = True
        if self._dump_left and values[ANGLES[2]] - self._dump_from > DUMP_TURN:  # turned over: a dump
            self._dump_turned = True
        if self.judge and self._count >= 4:  # the sample two before this one, between its neighbours
            slots = [(pos - back) % length for back in (4, 3, 2, 1)]
            context = [self._ring[i] for i in slots] + [values]
            if self._count < 5:
                context[0] = None  # the first sample has no neighbour before it
            stands_out, self.rejected = self._spike(context)
            if stands_out:  # never regressed; reported only as a glitch
                mid = slots[2]
                self._ring[mid] = self._ring[mid + length] = 0.5 * (context[1] + context[3])
                self._ring_used[mid] = self._ring_used[mid + length] = False

        if self._count < length:
            return False
        # the window ends two samples before this one: every sample in it has been judged
        centre_used = self._ring_used[pos + 1 + self.half_window]
        if not centre_used and self.balance != "momentum":
            return False  # a rejected sample's slot: part of the window, never regressed
        window = self._ring[pos + 1:pos + 1 + w]
        centre = window[self.half_window]
        out = self._call(centre, self._slope @ window[:, RATES])
        if self.balance != "momentum":
            residual, phi, lever, speed, stiction = out[0:3], out[3:6], out[6:9], out[9:12], out[12:15]
            wt = np.where(self._used(speed) & self._inside(centre), 1.0 / self._variance(lever, speed, stiction), 0.0)
            self.boom_windows += bool(wt[0] > 0.0)
            d_num, d_info = (wt * phi * residual).tolist(), (wt * phi * phi).tolist()
            self._accumulate(d_num, d_info)
            self._track_steady()
            if self.joint_check:
                self._check_joints(d_num, d_info, (wt > 0.0) & (phi < 0.0))
            return True
        # momentum: the terms of the differentiator window's centre (its q̈ serves the IMU
        # correction only) go into a second ring, the balance's window
        b = self._balance_len
        slot = self._terms_count % b
        self._terms[slot] = self._terms[slot + b] = out
        # a rejected sample's repaired slot stays in the balance (its interval is part of the
        # integral) but is never a window's centre
        self._terms_used[slot] = self._terms_used[slot + b] = centre_used
        self._terms_inside[slot] = self._terms_inside[slot + b] = \
            self._inside(centre) & ~self._ring_drop[pos + 1 + self.half_window]
        if self._imu_nuisance is not None:
            self._imu_nuisance.sample(self, slot)
        if self._offset_share is not None:
            self._offset_share.sample(self, slot)
        self._terms_count += 1
        if self._terms_count < b:
            return False
        # stage 2: the momentum balance over the last b samples (window_residuals)
        start = (slot + 1) % b
        t = self._terms[start:start + b]
        if not self._terms_used[start + BALANCE_HALF_WINDOW]:
            return False  # a rejected sample's slot at the window's centre: never regressed
        integral = self._balance_w @ t[:, 6:12]
        momentum = self._balance_u @ t[:, 0:6]
        residual = (integral[0:3] - momentum[0:3]) / self._balance_span
        phi = (momentum[3:6] - integral[3:6]) / self._balance_span
        lever = t[BALANCE_HALF_WINDOW, 12:15]
        slowest = np.abs(t[:, 15:18]).min(axis=0)
        stiction = t[:, 18:21].max(axis=0)
        rate_var = (self._balance_u**2 @ t[:, 21:24]) * self._rate_var_span
        # while weighing, a window with a standstill is judged by its slowest sample (--low-speed;
        # weighting by the still share, as calibration does, was measured worse)
        # a joint outside its calibrated range anywhere in the window is not weighed
        inside = self._terms_inside[start:start + b].all(axis=0)
        wt = np.where(self._used(slowest) & inside,
                      1.0 / (self._variance(lever, slowest, stiction) + rate_var), 0.0)
        self.boom_windows += bool(wt[0] > 0.0)
        d_num, d_info = (wt * phi * residual).tolist(), (wt * phi * phi).tolist()
        self._accumulate(d_num, d_info)
        if self._imu_nuisance is not None:
            self._imu_nuisance.window(self, start, wt, phi, residual)
        if self._offset_share is not None:
            a = self._imu_nuisance.last_a if self._imu_nuisance is not None else phi[:, None]
            self._offset_share.window(self, start, wt, a, residual)
        self._track_steady()
        if self.joint_check:
            self._check_joints(d_num, d_info, (wt > 0.0) & (phi < 0.0))
        if self._imu_nuisance is not None:
            self.payload_before = self._imu_nuisance.payload
        return True

    def use_imu_nuisance(self, cal) -> None:
        """``--imu-nuisance on``: weigh with the IMU dynamics re-estimated per load
        (:class:`~.imu_nuisance.ImuNuisanceFilter`; momentum form only).

        Parameters
        ----------
        cal : MachineCalibration
            The calibration weighed with (the prior of the IMU dynamics).
        """
        from excavator_payload.estimators.classical.machine_calibration.imu_nuisance import ImuNuisanceFilter

        self._imu_nuisance = ImuNuisanceFilter(cal, self._balance_len)

    def use_offset_share(self, cal) -> None:
        """After a zero (momentum form): carry the zero's offsets posterior into each estimate's
        σ through the estimate's own sensitivity (:class:`~.offset_share.OffsetShare`), in place
        of its RMS over the calibrated poses. Call after :meth:`use_imu_nuisance`.

        Parameters
        ----------
        cal : MachineCalibration
            The zeroed calibration weighed with (its offsets' posterior).
        """
        from excavator_payload.estimators.classical.machine_calibration.offset_share import OffsetShare

        regressors = 1 + 2 * self._imu_nuisance.n if self._imu_nuisance is not None else 1
        self._offset_share = OffsetShare(cal, self._balance_len, regressors)
        self.model_std = float(cal.model_std)

    @property
    def extra_std(self) -> float:
        """The current estimate's own share of σ beside 1/I and :attr:`model_std`, kg: the zero's
        offsets through its sensitivity (0 without :meth:`use_offset_share`)."""
        return self._offset_share.std if self._offset_share is not None else 0.0

    @property
    def estimate(self) -> float:
        """The payload: N / I, or with ``--imu-nuisance on`` the filter's."""
        if self._imu_nuisance is not None:
            return self._imu_nuisance.payload if self.info > 0 else math.nan
        return self.num / self.info if self.info > 0 else math.nan

    @property
    def weighed_info(self) -> float:
        """The information on the payload σ reads: I, or the filter's marginal one (a
        non-finite I as it is: the estimator then restarts the state)."""
        if self._imu_nuisance is not None and math.isfinite(self.info):
            return self._imu_nuisance.info if self.info > 0 else 0.0
        return self.info

    @property
    def dumping(self) -> bool:
        """Whether the bucket dumps: it opened faster than :data:`~.settings.DUMP_OPENING_RATE`
        within the last :data:`~.settings.DUMP_HOLD` s (the joint check names nothing new and
        does not sum the window)."""
        return self._dump_left > 0

    @property
    def dump_pending(self) -> bool:
        """Whether a dump is under way whose end will restart the weighing (``--new-load detect``,
        :data:`~.settings.DUMP_RESTARTS`): the load leaves, so the estimate before it is not
        reported ``ok`` (``load_changing``)."""
        return self.new_load and DUMP_RESTARTS and not self.loads_stay and self._dump_left > 0 and \
            self._dump_load and self._dump_turned

    @property
    def checks_joints(self) -> bool:
        """Whether the joint check can run: in the momentum form (the one it was set on)."""
        return self.balance == "momentum"

    def _check_joints(self, d_num: list, d_info: list, d_negative=None) -> None:
        """The joint consistency check of this window (:class:`~.joint_check.JointCheck`); when a
        joint it named has cleared, the weighing starts again (its sums hold the fault's windows),
        and so it does when a joint weighs less after a dump than before it (a load too small for
        the new-load test left, ``JointCheck._dumped_load``)."""
        self._joints.update(self, d_num, d_info, None if d_negative is None else d_negative.tolist())
        if self._joints.restart:
            self._joints.restart = False
            self._restart_load()
            self.changing = False
            if self._imu_nuisance is not None:
                self._imu_nuisance.restart(self)
            if self._offset_share is not None:
                self._offset_share.restart(self)

    # the check's state, read by PressureKernel.step (and the C export's parity tests)
    joint_fault = property(lambda self: self._joints.fault, doc="``signal:balance,...`` while the check fails.")
    joint_degraded = property(lambda self: self._joints.degraded,
                              doc="(estimate, information) of the weighing without the joint named.")
    joint_chi2 = property(lambda self: self._joints.chi2, doc="χ² of the joints' estimates about their mean.")
    joint_checked = property(lambda self: self._joints.checked,
                             doc="Two joints weighed well enough to check one another.")
    joint_pausing = property(lambda self: self._joints.pausing,
                             doc="The check pauses: a joint sees the load change (``load_changing``).")
    joint_suspect = property(lambda self: self._joints.suspect,
                             doc="The weighing moves before a fault is named (``load_changing``).")
    joint_moved_settled = property(lambda self: self._joints.moved_settled,
                               doc="... while it was settled (LONE_YOUNG_SHARE): a joint alone waits.")

    def _without(self, j: int) -> tuple[float, float]:
        """(estimate, information) of the weighing without joint ``j``'s share."""
        info = self.info - self.info_joint[j]
        if info <= 1e-12 * self.info or info <= 0.0:
            return math.nan, 0.0
        return (self.num - self.num_joint[j]) / info, info

    def _accumulate(self, d_num_joint: list, d_info_joint: list) -> None:
        r"""Add a window's information, and restart the weighing when the load has changed.

        The weighing sums :math:`N \leftarrow \lambda N + w\varphi r`,
        :math:`I \leftarrow \lambda I + w\varphi^2` (estimate :math:`N/I`). With
        ``--new-load detect`` a short memory (:math:`\lambda_s = e^{-\Delta t/T}`,
        :data:`NEW_LOAD_MEMORY`) sums the same terms; its estimate is nested in the whole one, so
        under one load their difference has variance :math:`1/I_s - 1/I`. A difference beyond
        both :data:`NEW_LOAD_SIGMAS` of it and :data:`NEW_LOAD_MIN_SHARE` of the rated payload is
        a new load (the bucket dumped, or filled again): both memories restart and the weighing
        waits for the boom again. Without it a sensor that runs through one work cycle after
        another averages every load it has seen (a dump left work cycles 100-1900 kg off).

        Each joint's share (``d_num_joint``, ``d_info_joint``: boom, dipper, bucket) is summed
        too (:attr:`num_joint`, :attr:`info_joint`, the same λ and restarts) for the joint
        consistency check (:meth:`_check_joints`).
        """
        lam = self.forgetting
        d_num = d_num_joint[0] + d_num_joint[1] + d_num_joint[2]
        d_info = d_info_joint[0] + d_info_joint[1] + d_info_joint[2]
        self.num = lam * self.num + d_num
        self.info = lam * self.info + d_info
        nj, ij = self.num_joint, self.info_joint
        for j in range(3):
            nj[j] = lam * nj[j] + d_num_joint[j]
            ij[j] = lam * ij[j] + d_info_joint[j]
        if not self.new_load:
            return
        mu = self._short_forgetting
        self.num_short = mu * self.num_short + d_num
        self.info_short = mu * self.info_short + d_info
        if self.joint_check:
            ns, is_ = self.num_joint_short, self.info_joint_short
            for j in range(3):
                ns[j] = mu * ns[j] + d_num_joint[j]
                is_[j] = mu * is_[j] + d_info_joint[j]
        was_changing, self.changing = self.changing, False
        if self._dump_ended and DUMP_RESTARTS and not self.loads_stay:
            self._dump_ended = False
            self.dump_restarts += 1
            self._restart_load()
            return
        if self.ready and 0.0 < self.info_short < self.info:
            change = self.num_short / self.info_short - self.num / self.info
            spread = max(1.0 / self.info_short - 1.0 / self.info, 0.0)
            if abs(change) > max(self._new_load_min, NEW_LOAD_SIGMAS * math.sqrt(spread)):
                self._restart_load()
                return
            self.changing = abs(change) > max(self._changing_min, CHANGING_SIGMAS * math.sqrt(spread))
        if self.changing:
            self.changing_windows += 1
        elif was_changing:
            if self.changing_windows >= SETTLE_WINDOWS:
                self._settle()
            self.changing_windows = 0

    def _restart_load(self) -> None:
        """Start the weighing again (a new load; or a joint the check named has cleared, whose
        biased windows the sums still hold): both memories, the joints' shares, the wait for the
        boom and for a steady estimate; the IMU dynamics follow (``new_loads``)."""
        self.num = self.info = self.num_short = self.info_short = 0.0
        self.num_joint, self.info_joint = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.num_joint_short, self.info_joint_short = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.boom_windows = 0
        self._restart_steady()
        self.new_loads += 1
        self.changing_windows = 0

    def _settle(self) -> None:
        """A load change smaller than a new load's (or one that began before a restart's wait
        ended: the bucket still filling) has settled: the whole memory still holds the windows
        of the change and would take seconds to forget them (a pass locked 144 kg under its
        load), so it takes the short memory's sums, whose windows of the change have faded
        (:data:`SETTLE_WINDOWS`)."""
        self.num, self.info = self.num_short, self.info_short
        if self.joint_check:
            self.num_joint, self.info_joint = list(self.num_joint_short), list(self.info_joint_short)
        self.settles += 1
