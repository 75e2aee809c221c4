r"""The machine-set calibration solver: :class:`MachineCalibration`, :func:`calibrate`,
:func:`zero_offsets` and the two-fold cross-check (:func:`cross_validated_model_std`).

Calibration is Bayesian Levenberg–Marquardt on :math:`z = (\delta, o, \iota)`
(:mod:`.settings`): prior :math:`\delta \sim \mathcal N(0, s^2)` (``--prior-std``, 5 % by
default around a file known to be a few % off), :math:`o \sim \mathcal N(0, \sigma_o^2)` and
the IMU terms' prior; in prior-normalised units :math:`u = z/\sigma`,

.. math:: H = J^\top W J + I, \qquad u \leftarrow u - (H + \lambda\,\mathrm{diag}\,H)^{-1}
          (J^\top W r(u) + u),

λ growing until a step lowers the posterior cost (up to eight steps). The weights :math:`W` are
fixed at the start (they depend on z through friction and levers; letting them move rewards
inflating the stiction variance). The rigid-body part is linear in lumped inertial combinations
of the parameters, the geometry is not, hence the iterations; the parameters are the machine
file's physical ones, so that the same vector feeds the compiled model unchanged. What a
handful of motions cannot separate is split by the prior. :math:`H^{-1}` is the posterior
covariance (the Cramér–Rao bound of :mod:`excavator_payload.evaluation.crb_machine` uses its
nuisance block).

In the per-sample form (``--balance differentiated``) the residuals are those of
:func:`~.symbolic.residual_function` with the accelerations of :func:`~.data.accelerations`,
joints near standstill skipped, and the pressure noise from the first pass's residuals,

.. math:: \hat\sigma_p^2 = \operatorname{mean}\big(r_j^2 / (\text{lever}_j^2 (A_h^2 +
          A_r^2))\big)

over moving samples. In the momentum form the residuals are the windows'
(:meth:`MachineCalibration.evaluate_windows`), whose noise model is kept in
per-sample-equivalent variances (pressures' and rates' white noise, a standstill's unknown
friction shared by the window, τ times its window variance); the pressure noise comes from the
data's second differences; the fit runs twice, the second from the prior again with the windows
weighed by what the first left unexplained (:meth:`MachineCalibration.measure_window_inflation`).
:func:`zero_offsets` re-estimates only the offsets :math:`o` from an empty-bucket motion,
prior: the calibrated offsets with the preset's drift as std.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import correlate1d

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical.machine_calibration.data import (
    accel_variance, balance_weights, calibration_arrays, held_direction, imu_sensitivities,
    momentum_windows, pressure_noise_from_data, rate_variance, window_residuals)
from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel
from excavator_payload.estimators.classical.machine_calibration.settings import (
    _OFFSET_COLUMNS, _PARAM_INDEX, BALANCE_HALF_WINDOW, BALANCE_RAMP, CALIBRATED_PARAMETERS,
    CALIBRATION_HALF_WINDOW, DEFAULT_PRESSURE_STD, HELD_IN_MOMENTUM, IMU_LEAK_CHOICES, IMU_PARAMETERS,
    IMU_PRIOR_STD, LOW_SPEED_CHOICES, MIN_CROSS_EXPERIMENTS, NO_LIMIT, OFFSET_PRIOR_STD, OFFSET_SIGNALS,
    SIGMA_COVERAGE, SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.symbolic import compiled, kernel_function
from excavator_payload.estimators.classical.pressure_regression import ANGLES, RATES
from excavator_payload.model.codegen import column_map
from excavator_payload.model.hydraulic import HydraulicArmModel, compiled_function


class MachineCalibration:
    """Identified machine: parameter vector, sensor offsets, pressure noise and covariance.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine file calibration starts from.
    """

    def __init__(self, arm: HydraulicArmModel):
        self.arm = arm
        self.p_file = np.asarray(arm.p, float)
        n = len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS) + len(IMU_PARAMETERS)
        self.z = np.zeros(n)
        self.covariance = np.diag(self.prior_std(0.05) ** 2)
        self.pressure_std = DEFAULT_PRESSURE_STD
        self.accel_var = 0.0  # variance of the differentiated accelerations, (rad/s²)²
        self.rate_var = 0.0  # white-noise variance of the measured rates, (rad/s)²
        self._inertia = 0.0
        self._extra_var = 0.0  # residual variance besides the pressures' (derived signals)
        self.balance = "differentiated"  # or "momentum" (BALANCE_CHOICES)
        # momentum form: actual / modelled variance of each joint's window residual at the
        # identified machine (window_inflation); divides the windows' weights in calibration
        # and zero
        self.window_inflation = np.ones(3)
        # cylinders taken as still below 3 Stribeck velocities (rod speed); calibration's
        # moving samples per cylinder and valid samples (set by calibrate, for fit's warning)
        cyl = arm.machine.cylinders
        self._head = np.array([c.head_area for c in cyl])
        self._rod = np.array([c.rod_area for c in cyl])
        self._stribeck = np.array([c.stribeck_velocity for c in cyl])
        self._still_speed = 3 * self._stribeck
        self.moving = None
        # [low, high] of the boom, dipper and bucket angles (offsets removed) the calibration
        # motions covered (angle_coverage; ±NO_LIMIT: not known)
        self.angle_coverage = np.tile([-NO_LIMIT, NO_LIMIT], (3, 1))
        self.model_std = 0.0  # kg: model error carried in sigma (cross_validated_model_std)
        # kg: the last zero's offsets posterior as it weighs (zero_quality's offset part), in sigma too
        self.zero_std = 0.0

    @staticmethod
    def prior_std(relative: float) -> np.ndarray:
        """Prior standard deviation of each entry of ``z``: ``relative`` (a share) for every
        calibrated parameter, then :data:`OFFSET_PRIOR_STD` and :data:`IMU_PRIOR_STD` (SI units).

        Parameters
        ----------
        relative : float
            Prior std of each calibrated parameter, as a share of its file value.
        """
        return np.r_[np.full(len(CALIBRATED_PARAMETERS), relative), OFFSET_PRIOR_STD, IMU_PRIOR_STD]

    @property
    def p(self) -> np.ndarray:
        p = self.p_file.copy()
        p[_PARAM_INDEX] *= 1 + self.z[:len(CALIBRATED_PARAMETERS)]
        return p

    @property
    def offsets(self) -> np.ndarray:
        n = len(CALIBRATED_PARAMETERS)
        return self.z[n:n + len(OFFSET_SIGNALS)]

    @property
    def imu(self) -> np.ndarray:
        """Identified IMU dynamics (:data:`IMU_PARAMETERS`)."""
        return self.z[len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS):]

    def imu_identification(self) -> dict[str, tuple[float, float, float]]:
        """What the calibration motions told about each IMU parameter.

        Returns
        -------
        dict
            Per :data:`IMU_PARAMETERS` name: (identified value, posterior std, posterior std /
            prior std). A ratio near 1 means the motions did not excite it and the prior
            decided (e.g. the boom IMU's sensitivity on swings: 0.99).
        """
        start = len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS)
        posterior = np.sqrt(np.diag(self.covariance)[start:])
        return {name: (float(v), float(sd), float(sd / prior))
                for name, v, sd, prior in zip(IMU_PARAMETERS, self.imu, posterior, IMU_PRIOR_STD)}

    def offset_vector(self) -> np.ndarray:
        """Offsets as a vector over the sensor set's signals (zeros elsewhere)."""
        v = np.zeros(len(SIGNALS))
        v[_OFFSET_COLUMNS] = self.offsets
        return v

    # -- batch evaluation ------------------------------------------------------------------
    def evaluate(self, values: np.ndarray, qdd: np.ndarray, payload: np.ndarray, z: np.ndarray):
        """Residuals (n, 3), Jacobian (n, 3, nz), lever, speed, stiction (n, 3) of samples.

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        qdd : numpy.ndarray
            Derived accelerations (n, 4), rad/s².
        payload : numpy.ndarray
            Known payload per sample, kg.
        z : numpy.ndarray
            Calibration vector (parameter shares, offsets, IMU sensitivities).
        """
        n = len(values)
        out = column_map(compiled("residual"), n)(values.T, qdd.T, payload[None, :], self.p_file, z)
        r, J, lever, speed, stiction, inertia, dr_dm = out
        self._payload_sensitivity = dr_dm.T  # ∂r/∂m = -φ (n, 3), for the Cramér–Rao bound
        nz = len(z)
        J = J.reshape(3, n, nz).transpose(1, 0, 2)
        self._inertia = inertia.T
        self._extra_var = self._inertia * self.accel_var  # the differentiator's noise
        return r.T, J, lever.T, speed.T, stiction.T

    def evaluate_windows(self, values: np.ndarray, qdd: np.ndarray, payload: np.ndarray, z: np.ndarray,
                         runs: np.ndarray, half: int = BALANCE_HALF_WINDOW, ramp: int = BALANCE_RAMP):
        """As :meth:`evaluate`, on the momentum-balance windows of ``half`` samples each side
        (:func:`window_residuals`): one row per window centre, and the centres' row indices.
        The window's lever is its centre's.

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        qdd : numpy.ndarray
            Derived accelerations (n, 4), rad/s².
        payload : numpy.ndarray
            Known payload per sample, kg.
        z : numpy.ndarray
            Calibration vector.
        runs : numpy.ndarray
            Run id per row (equal ids: contiguous samples).
        half : int
            Samples each side of a window's centre.
        ramp : int
            Ramp of the balance weights, sample intervals.
        """
        n = len(values)
        sign = held_direction(self.rod_speeds(values), runs, self._stribeck)
        out = column_map(compiled("momentum"), n)(values.T, qdd.T, self.p_file, z, sign.T)
        A, dA, lever, speed, stiction, dP0, dPm, integrand_gain = out
        A, lever, speed, stiction, integrand_gain = A.T, lever.T, speed.T, stiction.T, integrand_gain.T
        dA = dA.reshape(12, n, len(z)).transpose(1, 0, 2)
        dP = dP0.reshape(3, n, 4) + payload[None, :, None] * dPm.reshape(3, n, 4)
        gain = np.sum(dP**2, axis=2).T  # Σ_k (∂P_j/∂rate_k)² at the sample's payload
        centres = momentum_windows(runs, half)
        dt = 1.0 / MACHINE_SENSORS.sample_rate
        r, minus_phi = window_residuals(A, payload, centres, half, dt, ramp)
        # ∂r/∂z at the known payload: r = r0(z) - m·φ(z), so the payload's lever (its position
        # in the bucket, the geometry it hangs on) enters through m·∂φ/∂z
        J, _ = window_residuals(dA, payload, centres, half, dt, ramp)
        self._payload_sensitivity = minus_phi
        w, u = balance_weights(half, ramp)
        # The windows' noise model in per-sample-equivalent variances (what weights() adds to
        # the pressures' per-sample variance): a white per-sample error of variance v reaches a
        # window's residual as v/τ (τ = (Σw)²/Σw², the windows sharing it); an error shared by
        # a whole window counts τ times. The rates' noise through the integrand is per-sample
        # (the window's weighted mean of it); through the ends' momentum it is the window's own
        # variance (Σu = 0: it cancels between neighbouring windows, it is not shared by τ).
        tau = float(w.sum() ** 2 / (w**2).sum())
        integrand_var = correlate1d(integrand_gain, w, axis=0, mode="constant")[centres] / w.sum() * self.rate_var
        end_var = correlate1d(gain, u**2, axis=0, mode="constant")[centres] / (w.sum() * dt) ** 2 * self.rate_var
        self._extra_var = integrand_var + end_var
        self._window_var_parts = (end_var, tau)  # for measure_window_inflation
        # the unknown friction of the window's still samples, integrated with the window's
        # weights: the still share of the window times the largest breakaway torque. Returned
        # as a zero "speed" (windows with a standstill) and that stiction, for the downweight
        # rule of :meth:`weights` (skipping every window with a still sample kept too few of the
        # dipper's and bucket's windows; findings: docs/findings/machine-calibration.md)
        stick = np.lib.stride_tricks.sliding_window_view(stiction, 2 * half + 1, axis=0).max(axis=-1)
        # (with the friction's sign held from the last sliding the still windows still carry
        # their variance: without it they outweighed the moving ones)
        still = (np.abs(speed) < self._still_speed).astype(float)
        share = correlate1d(still, w, axis=0, mode="constant")[centres] / w.sum()
        speed_rule = np.where(share > 0, 0.0, np.inf)
        # the still samples' friction is one error shared by the window (and its neighbours):
        # τ times its window variance, as a per-sample-equivalent (the variance weights() adds
        # is stiction²/3). Counted once per window, the still windows (most of the dipper's
        # and bucket's) outweighed the moving ones τ-fold.
        return r, J, lever[centres], speed_rule, math.sqrt(tau) * share * stick[centres - half], centres

    def measure_window_inflation(self, values, qdd, payload, runs) -> np.ndarray:
        r"""Actual over modelled variance of each joint's momentum-window residual at ``z``.

        The windows' noise model (:meth:`evaluate_windows`) holds the pressures' and rates'
        white noise and the standstills' unknown friction; what the identified machine leaves
        unexplained (pump ripple that does not average out, the IMUs' dynamic error, the
        friction law's misfit, parameters that fit the calibration motions only) is not in it.
        Under the model a window's normalised residual has :math:`E[w r^2] = 1/\tau +
        w\,v_e (1 - 1/\tau)`: the per-sample-equivalent parts reach a window as 1/τ of their
        variance (:math:`\tau = (\sum w_b)^2/\sum w_b^2` ≈ 45, :math:`w_b` the balance
        weights), the ends' momentum noise :math:`v_e` as its own. The ratio
        :math:`f_j = \sum w r_j^2 / \sum E[w r_j^2]` (≥ 1) is measured once the machine is
        identified, as a variance component (measured values: docs/findings/machine-calibration.md).

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        qdd : numpy.ndarray
            Derived accelerations (n, 4), rad/s².
        payload : numpy.ndarray
            Known payload per sample, kg.
        runs : numpy.ndarray
            Run id per row.

        Returns
        -------
        numpy.ndarray
            ``f_j`` per joint (3), at least 1.
        """
        r, _, lever, speed, stiction, _ = self.evaluate_windows(values, qdd, payload, self.z, runs)
        w = self.weights(lever, speed, stiction, "downweight", self.pressure_std)
        end_var, tau = self._window_var_parts
        # the model's E[w r²] per window: the per-sample-equivalent parts reach the window as
        # 1/τ of their variance, the ends' momentum noise as its own
        expected = 1.0 / tau + w * end_var * (1.0 - 1.0 / tau)
        ok = np.isfinite(r) & np.isfinite(w) & (w > 0)
        out = np.ones(3)
        for j in range(3):
            if ok[:, j].sum() >= 10:
                use = ok[:, j]
                out[j] = max(1.0, float(np.sum(w[use, j] * r[use, j] ** 2) / np.sum(expected[use, j])))
        return out

    def rod_speeds(self, values: np.ndarray) -> np.ndarray:
        """Rod speeds (n, 3) of the raw measured angles and rates at the file's parameters.

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        """
        q = np.zeros((len(values), 4))
        q[:, :3] = values[:, ANGLES]
        f = column_map(compiled_function("cylinder_speeds"), len(values))
        return f(q.T, values[:, RATES].T, self.p_file)[0].T

    def moving_samples(self, values: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Samples on which each arm cylinder (boom, dipper, bucket) moves: its rod speed at the
        identified machine above the 3 Stribeck velocities below which calibration treats it as
        stuck (what the calibration can learn that cylinder's friction and geometry from).

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        qdd : numpy.ndarray
            Derived accelerations (n, 4), rad/s².

        Returns
        -------
        numpy.ndarray
            Count per cylinder (3).
        """
        n = len(values)
        if n == 0:
            return np.zeros(3, int)
        out = column_map(kernel_function("differentiated"), n)(
            values.T, qdd.T, self.p, self.offset_vector(), np.asarray(self.imu, float))[0]
        return np.sum(np.abs(out[9:12].T) >= self._still_speed, axis=0)

    def weights(self, lever, speed, stiction, low_speed: str, pressure_std: float) -> np.ndarray:
        """Inverse residual variances (n, 3) for the low-speed choice (0: sample skipped).

        Parameters
        ----------
        lever : numpy.ndarray
            Lever of each cylinder force on its joint (n, 3), m.
        speed : numpy.ndarray
            Rod speeds (n, 3), m/s.
        stiction : numpy.ndarray
            Stiction (breakaway) torque of each cylinder on its joint (n, 3), N·m.
        low_speed : str
            One of :data:`LOW_SPEED_CHOICES`.
        pressure_std : float
            White noise of one pressure transmitter, Pa.
        """
        var = lever**2 * (self._head**2 + self._rod**2) * (pressure_std**2 + 1.0) + self._extra_var
        still = np.exp(-(speed / self._still_speed) ** 2)
        if low_speed == "downweight":
            var = var + still * stiction**2 / 3
        w = 1.0 / var
        if low_speed == "skip":
            w = np.where(np.abs(speed) < self._still_speed, 0.0, w)
        return w

    def solve(self, values, qdd, payload, free: np.ndarray, prior_mean: np.ndarray,
              prior_std: np.ndarray, low_speed: str, iterations: int = 8,
              estimate_noise: bool = True, runs: np.ndarray | None = None,
              prior_covariance: np.ndarray | None = None) -> None:
        """Bayesian Levenberg–Marquardt on the entries ``free`` of z (the others stay), in place.

        A plain Gauss–Newton step overshoots where the slow lifts leave directions weakly
        determined and the geometry is non-linear; the damping λ grows until a step lowers the
        posterior cost, and shrinks after each success.

        Parameters
        ----------
        values : numpy.ndarray
            Measured samples (n, signals), SI units.
        qdd : numpy.ndarray
            Derived accelerations (n, 4), rad/s².
        payload : numpy.ndarray
            Known payload per sample, kg.
        free : numpy.ndarray
            Indices of the entries of z to fit.
        prior_mean, prior_std : numpy.ndarray
            Prior mean and std of every entry of z.
        low_speed : str
            One of :data:`LOW_SPEED_CHOICES`.
        iterations : int
            Most Levenberg–Marquardt steps.
        estimate_noise : bool
            Also estimate :attr:`pressure_std` from the residuals.
        runs : numpy.ndarray or None
            Run ids: fit the momentum-balance windows (None: per-sample residuals).
        prior_covariance : numpy.ndarray or None
            A full prior covariance of the entries ``free`` (len(free) × len(free)), in place of
            ``prior_std``'s diagonal one (None).
        """
        z = self.z.copy()
        scale = prior_std[free]  # solve in prior-normalised units u = (z - μ)/σ: well conditioned
        root = None  # a full prior: u = L⁻¹(z - μ), L its Cholesky factor
        if prior_covariance is not None:
            root = np.linalg.cholesky(np.asarray(prior_covariance, float))
            scale = np.ones(len(free))

        def whiten(dz):
            return dz / scale if root is None else np.linalg.solve(root, dz)

        def colour(du):
            return scale * du if root is None else root @ du

        fixed = {}  # weights held during the iterations: they depend on z (friction, levers), and
                    # letting them move would reward inflating the stiction variance

        def linearise(z):
            if runs is None:
                r, J, lever, speed, stiction = self.evaluate(values, qdd, payload, z)
            else:  # the momentum balance over windows (no differentiated accelerations)
                r, J, lever, speed, stiction, _ = self.evaluate_windows(values, qdd, payload, z, runs)
            w = fixed.get("w")
            if w is None:
                w = self.weights(lever, speed, stiction, low_speed, self.pressure_std)
                if runs is not None:
                    w = w / self.window_inflation
            ok = np.isfinite(r) & np.isfinite(w) & np.all(np.isfinite(J), axis=2)
            w = np.where(ok, w, 0.0)
            r = np.where(ok, r, 0.0)
            u = whiten(z[free] - prior_mean[free])
            cost = float(np.sum(w * r**2) + u @ u)
            Jf = J[:, :, free] * scale if root is None else J[:, :, free] @ root
            return cost, r, np.where(ok[..., None], Jf, 0.0), w, (lever, speed)

        cost, r, Js, w, kin = linearise(z)
        if estimate_noise:
            self.pressure_std = self._noise_from_residuals(r, *kin)
            cost, r, Js, w, kin = linearise(z)
        fixed["w"] = w
        damping = 1e-4
        self.cost_trace = [cost]
        for _ in range(iterations):
            u = whiten(z[free] - prior_mean[free])
            H = np.einsum("nja,nj,njb->ab", Js, w, Js) + np.eye(len(free))
            g = np.einsum("nja,nj,nj->a", Js, w, r) + u
            for _ in range(6):
                trial = z.copy()
                trial[free] -= colour(np.linalg.solve(H + damping * np.diag(np.diag(H)), g))
                new = linearise(trial)
                if new[0] < cost:
                    improvement = cost - new[0]
                    z, (cost, r, Js, w, kin) = trial, new
                    damping = max(damping / 10, 1e-8)
                    break
                damping *= 10
            else:
                break
            self.cost_trace.append(cost)
            if improvement < 1e-4 * cost:
                break
        if estimate_noise:  # the residuals of the identified model: the noise the estimator sees
            self.pressure_std = self._noise_from_residuals(r, *kin)
        self.z = z
        H = np.einsum("nja,nj,njb->ab", Js, w, Js) + np.eye(len(free))
        cov = self.covariance.copy()
        cov[free, :] = 0.0
        cov[:, free] = 0.0
        cov[np.ix_(free, free)] = (np.linalg.inv(H) * np.outer(scale, scale) if root is None
                                   else root @ np.linalg.inv(H) @ root.T)
        self.covariance = cov

    def _noise_from_residuals(self, r, lever, speed) -> float:
        moving = np.abs(speed) > self._still_speed
        # what the differentiator's noise explains is not pressure noise
        ratio = (r**2 - self._extra_var) / (lever**2 * (self._head**2 + self._rod**2))
        use = moving & np.isfinite(ratio)
        if use.sum() < 10:
            return self.pressure_std
        return float(np.sqrt(max(np.mean(ratio[use]), 1.0)))

    # -- streaming kernel ------------------------------------------------------------------
    def kernel(self, half_window: int, forgetting: float, low_speed: str,
               outside_calibration: str = "auto", wait_for_boom: str = "auto",
               new_load: str = "auto") -> "CalibratedKernel":
        """A streaming :class:`CalibratedKernel` weighing with this calibration (the arguments are
        its own).

        Parameters
        ----------
        half_window : int
            Samples each side of the differentiator.
        forgetting : float
            Forgetting factor λ in (0, 1].
        low_speed : str
            One of :data:`LOW_SPEED_CHOICES`.
        outside_calibration : str
            One of :data:`OUTSIDE_CALIBRATION_CHOICES`.
        wait_for_boom : str
            One of :data:`WAIT_FOR_BOOM_CHOICES`.
        new_load : str
            One of :data:`NEW_LOAD_CHOICES`.
        """
        return CalibratedKernel(self, half_window, forgetting, low_speed, outside_calibration, wait_for_boom,
                                new_load)


def calibrate(arm: HydraulicArmModel, dataset: Dataset, prior_std: float = 0.05,
              low_speed: str = "downweight",
              pressure_std: float | None = None, balance: str = "differentiated",
              imu_leak: str = "auto") -> MachineCalibration:
    """Identify parameters, offsets and pressure noise from known-payload data (module doc).

    ``pressure_std`` None: estimated from the data; else fixed (Pa). ``balance``: per-sample
    residuals with differentiated accelerations, or the momentum balance over windows.
    ``imu_leak``: :data:`IMU_LEAK_CHOICES`.

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine file's model (the prior).
    dataset : Dataset
        Machine-sensor-set data with the known ``payload``, kg.
    prior_std : float
        Prior std of each parameter as a share of its file value.
    low_speed : str
        One of :data:`LOW_SPEED_CHOICES`.
    pressure_std : float or None
        Pressure noise, Pa (None: from the data).
    balance : str
        One of :data:`BALANCE_CHOICES`.
    imu_leak : str
        One of :data:`IMU_LEAK_CHOICES`.
    """
    if low_speed not in LOW_SPEED_CHOICES:
        raise EstimatorError(f"--low-speed must be one of {', '.join(LOW_SPEED_CHOICES)}")
    if imu_leak not in IMU_LEAK_CHOICES:
        raise EstimatorError(f"--imu-leak must be one of {', '.join(IMU_LEAK_CHOICES)}")
    values, qdd, payload, runs = calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, arm.machine)
    if len(values) < 100:
        raise EstimatorError("calibration needs at least 100 valid samples with known payloads, "
                             f"the data have {len(values)}")
    cal = MachineCalibration(arm)
    cal.accel_var = accel_variance(dataset, CALIBRATION_HALF_WINDOW)
    cal.rate_var = rate_variance(dataset)
    cal.balance = balance
    if pressure_std is not None:
        cal.pressure_std = float(pressure_std)
    std = cal.prior_std(prior_std)
    cal.covariance = np.diag(std**2)
    free = np.arange(len(cal.z))
    prior_mean = np.zeros(len(cal.z))
    # the link IMUs' leak read off their own signals and held (--imu-leak signals): the fit
    # cannot tell it from the geometry and the lag (the momentum form left it out: free, the
    # sensitivities wandered), the IMU's angle minus its integrated rate shows it alone
    links = len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS) + 1 + np.arange(3)
    if imu_leak == "auto":
        imu_leak = "signals" if balance == "momentum" else "fit"
    if imu_leak == "signals":
        k, k_std = imu_sensitivities(dataset, machine=arm.machine)
        prior_mean[links] = k
        cal.z = prior_mean.copy()
        cal.covariance[links, links] = k_std**2
    if imu_leak != "fit":
        free = np.setdiff1d(free, links)
    if balance == "momentum":
        # The pressure noise from the data's second differences (white noise and aliased
        # ripple): a window's residual averages the white noise but not the 3 % file's model
        # error, which the first pass's residuals would blame on the transmitters. Of the IMU
        # dynamics the fit takes the lag (and the links' leak with --imu-leak fit): with the
        # four acceleration sensitivities free the parameters wander; the links' leak is read
        # off their own signals and held by default, the house's is left out (what each cost:
        # docs/findings/machine-calibration.md, "The IMUs' dynamic error"; the house's read off
        # its pitch and roll, data.house_imu_sensitivity, as the prior's mean helped with empty-
        # swing zeros and hurt with slow ones on fresh draws: docs/findings/false-alarms.md). A
        # window with a standstill carries its still share of unknown friction
        # (:meth:`MachineCalibration.evaluate_windows`).
        if pressure_std is None:
            cal.pressure_std = pressure_noise_from_data(dataset)
        free = free[(free < len(CALIBRATED_PARAMETERS) + len(OFFSET_SIGNALS) + 1) | np.isin(free, links)]
        free = np.setdiff1d(free, [CALIBRATED_PARAMETERS.index(n) for n in HELD_IN_MOMENTUM])
        for second in (False, True):
            if second:
                # what the identified machine leaves unexplained, as a variance component
                # (measure_window_inflation); the fit again from the prior with the windows
                # weighted by it: the first fit over-fitted
                cal.window_inflation = cal.measure_window_inflation(values, qdd, payload, runs)
                cal.z = prior_mean.copy()
            cal.solve(values, qdd, payload, free, prior_mean, std, "downweight",
                      estimate_noise=False, runs=runs)
    else:
        # Calibration skips joints near standstill whatever --low-speed says: their friction is
        # anything within ± breakaway, and the parameters would absorb it (over-fitting measured
        # as a cost below that of the true machine).
        cal.solve(values, qdd, payload, free, prior_mean, std, "skip",
                  estimate_noise=pressure_std is None)
    cal.moving = (cal.moving_samples(values, qdd), len(values))
    return cal


def zero_offsets(cal: MachineCalibration, dataset: Dataset, low_speed: str = "downweight",
                 drift_std: np.ndarray = OFFSET_PRIOR_STD, parameters: np.ndarray | None = None,
                 inflation: float = 1.0, correlated: bool = True) -> tuple[int, np.ndarray]:
    """Re-estimate only the sensor offsets from empty-bucket data, in place (module doc; with
    ``parameters``, those too: measured in docs/findings/any-motion.md, not used by ``zero``).
    Returns how many samples it used (the valid ones: finite, angles within range) and, per
    arm cylinder, how many of them it moved on (a still cylinder's offsets are not checked).

    Parameters
    ----------
    cal : MachineCalibration
        The calibration to update (offsets only).
    dataset : Dataset
        Empty-bucket data (payload 0).
    low_speed : str
        One of :data:`LOW_SPEED_CHOICES`.
    drift_std : numpy.ndarray
        Prior std of each offset's change, Pa or rad.
    parameters : numpy.ndarray or None
        Indices of z besides the offsets to re-estimate with them (None: the offsets alone),
        under the calibration's posterior: prior N(z, Σ) over these entries and the offsets,
        Σ = the held covariance with the calibrated parameters' block × ``inflation`` (not the
        IMU entries'), conditioned on the entries not freed (held at their values), plus the
        drift's variance on the offsets.
    inflation : float
        Factor on the parameters' prior covariance (≥ 1: the calibration is over-confident).
    correlated : bool
        Keep the calibration's parameter–offset correlations in the prior (False: independent).

    Returns
    -------
    tuple of (int, numpy.ndarray)
        Samples used, and per arm cylinder the samples it moved on.
    """
    values, qdd, payload, runs = calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, cal.arm.machine)
    cal.accel_var = accel_variance(dataset, CALIBRATION_HALF_WINDOW)
    if len(values) < 50:
        raise EstimatorError(f"the zero check needs at least 50 valid samples, the data have {len(values)}")
    if np.any(payload != 0):
        raise EstimatorError("the zero check needs an empty bucket (the data's payload column is not 0)")
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    free = np.arange(n_delta, n_delta + n_off)
    momentum = cal.balance == "momentum"
    prior_std = np.r_[np.ones(n_delta), drift_std, np.ones(len(IMU_PARAMETERS))]
    if parameters is None:
        cal.solve(values, qdd, payload, free, cal.z.copy(), prior_std,
                  "skip", iterations=4, estimate_noise=False,
                  runs=runs if momentum else None)
    else:
        params = np.setdiff1d(np.asarray(parameters, int), free)
        free = np.r_[params, free]
        k = len(params)
        # the calibration's posterior, its parameters' rows × √inflation, conditioned on the
        # entries held at their values (a block freed alone keeps its compensation with the rest)
        root = np.sqrt(np.where(np.arange(len(cal.z)) < n_delta, inflation, 1.0))
        full = cal.covariance * np.outer(root, root)
        held = np.setdiff1d(np.flatnonzero(np.diag(full) > 0), free)
        sd = np.sqrt(np.diag(full))
        sd[sd == 0] = 1.0
        corr = full / np.outer(sd, sd)  # conditioned as correlations: z mixes Pa, rad and shares
        prior = corr[np.ix_(free, free)] - corr[np.ix_(free, held)] @ np.linalg.solve(
            corr[np.ix_(held, held)], corr[np.ix_(held, free)])
        prior = 0.5 * (prior + prior.T) * np.outer(sd[free], sd[free])
        if not correlated:
            prior[:k, k:] = prior[k:, :k] = 0.0
        prior[k:, k:] += np.diag(np.asarray(drift_std, float) ** 2)
        cal.solve(values, qdd, payload, free, cal.z.copy(), prior_std,
                  "skip", iterations=8, estimate_noise=False,
                  runs=runs if momentum else None, prior_covariance=prior)
    return len(values), cal.moving_samples(values, qdd)


def cross_validated_model_std(dataset: Dataset, calibrate_fold, weigh_with, folds: int = 2) -> float:
    r"""The model error's standard deviation (kg) that σ must carry beside :math:`I^{-1/2}`.

    :math:`I^{-1/2}` is the estimate's spread from the sensor noise alone; the calibrated model
    itself is only as good as a handful of motions made it, and on other motions its error
    does not shrink with information (a bias per pose). Two-fold cross-fit: the calibration
    motions are split in two halves (alternating), each half calibrates a model that weighs the
    other half; :math:`s` is the least value with :math:`|e| \le 2\sqrt{1/I + s^2}` on
    :data:`SIGMA_COVERAGE` of the held-out ``ok`` samples after their first second. Half the
    motions calibrate worse than all of them: the floor errs on the safe side. 0 with fewer
    than :data:`MIN_CROSS_EXPERIMENTS`. With ``folds`` K > 2, motion i is held out in fold
    i mod K and the other motions calibrate it (K ≥ the motions: one motion out); K = 2 is the
    two halves above.

    Parameters
    ----------
    dataset : Dataset
        The calibration motions (known payloads).
    calibrate_fold : callable
        ``calibrate_fold(subset) -> MachineCalibration``: one half's calibration.
    weigh_with : callable
        ``weigh_with(calibration) -> estimator``: a fitted estimator weighing with it (its
        ``estimate`` gives ``payload_estimate``, ``status`` and ``sigma``).
    folds : int
        K, the number of folds (2: the halves that σ's s is fitted by).
    """
    ids = list(dataset.experiment_ids)
    if len(ids) < MIN_CROSS_EXPERIMENTS:
        return 0.0
    k = max(2, min(int(folds), len(ids)))
    errors, variances = [], []
    for i in range(k):
        test = ids[i::k]
        fold = weigh_with(calibrate_fold(dataset.subset([e for e in ids if e not in test])))
        held = dataset.subset(test)
        out = fold.estimate(held)
        f = held.frame
        t = f["time"].to_numpy(float)
        start = f.groupby("experiment", sort=False)["time"].transform("min").to_numpy(float)
        sigma = out["sigma"].to_numpy(float)
        ok = (out["status"].astype(str).to_numpy() == "ok") & (t - start >= 1.0) & np.isfinite(sigma)
        errors.append((out["payload_estimate"].to_numpy(float) - f["payload"].to_numpy(float))[ok])
        variances.append(sigma[ok] ** 2)
    e, v = np.abs(np.concatenate(errors)), np.concatenate(variances)
    if not len(e):
        return 0.0

    def covered(s: float) -> float:
        return float(np.mean(e <= 2.0 * np.sqrt(v + s * s)))

    if covered(0.0) >= SIGMA_COVERAGE:
        return 0.0
    low, high = 0.0, float(e.max())
    for _ in range(40):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if covered(mid) >= SIGMA_COVERAGE else (mid, high)
    return high
