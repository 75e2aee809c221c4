r"""EKF and UKF on the machine sensor set: IMU angles and rates, slew rate, tilt, pressures.

The kernel behind ``ekf`` and ``ukf`` when the data hold the machine sensor set (issue 12). The
thesis filters (:mod:`._kalman`) integrate the arm's forward dynamics with the *measured*
torques as input and use the *measured* accelerations; a machine measures neither. Here the
arm's motion is a kinematic state, the pressures are measurements of it, and the
accelerations the inertial torques need are *filter states*:

State, process
--------------
.. math::

    x = [q_1, q_2, q_3,\ \dot q_1, \dot q_2, \dot q_3, \dot\psi,\
         \ddot q_1, \ddot q_2, \ddot q_3, \ddot\psi,\ m]^\top

(boom, dipper, bucket angles; their rates and the slew rate; the four accelerations; the
payload). Each coordinate is a white-jerk (nearly-constant-acceleration) chain, linear and exact
over one sample :math:`T`,

.. math::

    q_{k+1} = q_k + T\dot q_k + \tfrac{T^2}{2}\ddot q_k, \quad \dot q_{k+1} = \dot q_k + T\ddot q_k,
    \quad \ddot q_{k+1} = \ddot q_k + w_k, \qquad
    Q_j = s_j \begin{bmatrix} T^5/20 & T^4/8 & T^3/6 \\ T^4/8 & T^3/3 & T^2/2 \\
                              T^3/6 & T^2/2 & T \end{bmatrix}

with jerk density :math:`s_j` sized from the training data (:func:`jerk_density`), and the
payload a slow random walk (``--payload-walk`` kg/√s). The slew angle does not enter the
dynamics (only its rate and acceleration do), so it is not a state. The slew rate is a known
input in the sense that it is measured, not modelled: it is a state only so that the filter
also gives its derivative, the slew acceleration, which the arm's inertial torques need.
Accelerations are never measured on a machine: the white-jerk chains estimate them from the
IMU rates *and* the pressures jointly (the force update corrects them too), without the lag of
a causal differentiator and without the half-window delay of the centred one
(:mod:`.pressure_regression`).

Known inputs
------------
Ground tilt from the house IMU (:func:`~.pressure_regression.ground_tilt`: at slew angle 0 the
house's pitch and roll are the ground's, which gives gravity in the house frame exactly), and,
for the seals' load-dependent friction only, the measured piston forces.

Measurements
------------
Angles and rates (:math:`h = Cx`, linear, IMU noise of the preset), then the piston force of
each cylinder :math:`F_j = p_{h,j}A_{h,j} - p_{r,j}A_{r,j}` (a linear function of the two
measured pressures, so its noise is known: :math:`A_h^2\sigma_{p_h}^2 + A_r^2\sigma_{p_r}^2`,
the pump ripple's RMS included as in :mod:`.pressure_regression`), predicted by the one symbolic
model (``HydraulicSymbolic``, compiled with :mod:`excavator_payload.model.codegen`):

.. math::

    h_{F,j}(x) = \frac{\tau_j(q, \dot q, \ddot q, \text{tilt}, m)}{\text{count}_j\,\partial l_j/
                 \partial q_j} + F_{f,j}(\dot l_j)

with :math:`\tau` the rigid-body inverse dynamics of boom, dipper and bucket on the slewing,
tilted house and :math:`F_f` the seal friction with a smooth sign of the rod speed. Near
standstill the friction can be anything within ± the breakaway force (stiction), so the force
noise grows by :math:`\text{breakaway}^2/3`, fading with speed (down-weighted, as in
:mod:`.pressure_regression`). That force persists for the whole standstill, so many such samples
still add up to a biased estimate: with ``--low-speed skip`` (default) a cylinder slower than
one Stribeck velocity gives no force measurement once the payload's standard deviation is below
``--converged-std`` (measured on noise-free swings with seal friction, 8 experiments: mean RMS
57 → 15 kg, mean MAX 126 → 89 kg; field noise without offsets, 10 swings: RMS 56 → 17 kg). The two groups are processed one after the other (sequential
update): the forces are linearised (EKF) or sigma-pointed (UKF) at the state already corrected
by the angles and rates.

Sensor offsets are not estimated (that is the calibration and zero of issue 12).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError, ExcavatorPayloadError
from excavator_payload.estimators.classical.pressure_regression import ground_tilt
from excavator_payload.model.codegen import native
from excavator_payload.model.hydraulic import (CYLINDERS, HYDRAULIC_PARAMETER_NAMES, hydraulic_symbolic,
                                               parameter_vector)
from excavator_payload.platforms import HYDRAULIC

SIGNALS = MACHINE_SENSORS.signals
T = MACHINE_SENSORS.sample_period
N_STATE = 12
PAYLOAD = 11
ANGLE_STATES = [0, 1, 2]
RATE_STATES = [3, 4, 5, 6]     # boom, dipper, bucket, slew rates
ACCEL_STATES = [7, 8, 9, 10]
#: Sample positions of the kinematic measurements, in state order (angles, then rates).
KINEMATIC = MACHINE_SENSORS.indices(("boom_angle", "dipper_angle", "bucket_angle", "boom_rate",
                                     "dipper_rate", "bucket_rate", "slew_rate"))
PRESSURES = [i for i, s in enumerate(SIGNALS) if s.endswith("_pressure")]
PITCH, ROLL = MACHINE_SENSORS.index("house_pitch"), MACHINE_SENSORS.index("house_roll")
N_KIN = len(KINEMATIC)
#: ``--low-speed skip``: rod speeds below this many Stribeck velocities give no force measurement.
SKIP_SPEED = 1.0
#: Smallest standard deviations used where a noise preset says 0 (keeps R invertible).
STD_FLOOR = {"angle": 1e-6, "rate": 1e-6, "pressure": 1e3}
#: Force variance (N²) that removes a measurement (``--low-speed skip``): no information.
SKIPPED_VARIANCE = 1e30


@lru_cache(maxsize=1)
def force_measurement_function() -> ca.Function:
    """:func:`force_measurement_symbolic` compiled to C where a compiler exists."""
    return native(force_measurement_symbolic())


@lru_cache(maxsize=1)
def force_measurement_symbolic() -> ca.Function:
    r"""``(x (12), tilt (2), force (3), p) -> [h (3), vec H (3×12), breakaway (3), speed (3)]``.

    ``h`` is the piston force each cylinder needs for the state (module doc), ``H = ∂h/∂x``,
    ``breakaway`` the stiction force bound (static ratio × load-dependent Coulomb force at the
    measured ``force``) and ``speed`` the rod speeds.
    """
    sym = hydraulic_symbolic()
    fn = sym.functions
    x = ca.SX.sym("x", N_STATE)
    tilt = ca.SX.sym("tilt", 2)
    force = ca.SX.sym("force", 3)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    q = ca.vertcat(x[0:3], 0)
    qd = x[3:7]
    qdd = x[7:11]
    torque = fn["inverse_dynamics"](q, qd, qdd, tilt, x[PAYLOAD], p)[0:3]
    arms = fn["moment_arms"](q, p)

    def get(key):
        return ca.vertcat(*[p[HYDRAULIC_PARAMETER_NAMES.index(f"{c}_{key}")] for c in CYLINDERS])

    lever = get("count") * arms
    speed = arms * qd[0:3]
    # the friction law is of the load force, which the state gives (torque / lever)
    friction = fn["moving_friction"](speed, torque / lever, p)
    h = torque / lever + friction
    H = ca.jacobian(h, x)
    breakaway = (get("coulomb") + get("load_coefficient") * ca.fabs(force)) * get("static_ratio")
    packed = ca.cse(ca.densify(ca.vertcat(h, ca.vec(H), breakaway, speed)))
    return ca.Function("hyd_kalman_force", [x, tilt, force, p], [packed],
                       ["x", "tilt", "force", "p"], ["packed"])


@lru_cache(maxsize=4)
def force_sigma_function(n_points: int) -> ca.Function:
    """``(X (12×N), tilt, force, p) -> vec h(X) (3N)``: the force model at all sigma points
    (compiled)."""
    inner = force_measurement_symbolic()
    X = ca.SX.sym("X", N_STATE, n_points)
    tilt = ca.SX.sym("tilt", 2)
    force = ca.SX.sym("force", 3)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    h = ca.horzcat(*[inner(X[:, i], tilt, force, p)[0:3] for i in range(n_points)])
    return native(ca.Function(f"hyd_kalman_force_sigma_{n_points}", [X, tilt, force, p],
                              [ca.cse(ca.vec(h))]))


def transition_matrix() -> np.ndarray:
    """F of the white-jerk chains (module doc), 12×12."""
    F = np.eye(N_STATE)
    for j in range(3):
        F[j, 3 + j] = T
        F[j, 7 + j] = T * T / 2
    for j in range(4):
        F[3 + j, 7 + j] = T
    return F


def process_noise(jerk: np.ndarray, payload_walk: float) -> np.ndarray:
    """Q of the white-jerk chains with densities ``jerk`` (4: boom, dipper, bucket, slew), 12×12.

    Parameters
    ----------
    jerk : numpy.ndarray
        Jerk densities (4), rad²/s⁵.
    payload_walk : float
        Payload random walk, kg/√s.
    """
    Q = np.zeros((N_STATE, N_STATE))
    block = np.array([[T**5 / 20, T**4 / 8, T**3 / 6], [T**4 / 8, T**3 / 3, T**2 / 2],
                      [T**3 / 6, T**2 / 2, T]])
    for j in range(3):
        idx = [j, 3 + j, 7 + j]
        Q[np.ix_(idx, idx)] = jerk[j] * block
    idx = [6, 10]
    Q[np.ix_(idx, idx)] = jerk[3] * block[1:, 1:]
    Q[PAYLOAD, PAYLOAD] = payload_walk**2 * T
    return Q


def jerk_density(dataset: Dataset, half_window: int = 10, quantile: float = 0.99) -> np.ndarray:
    r"""Jerk densities :math:`s_j` (rad²/s⁵) of boom, dipper, bucket and slew from measured rates.

    Accelerations and jerks by a centred least-squares slope over ``2·half_window + 1`` samples
    (applied twice to the measured rates, within each experiment). A white-jerk model moves the
    acceleration by :math:`\sqrt{s T}` per sample; the motions' jerk is smooth, not white, so
    the density is set to let the acceleration follow the ``quantile`` (99 %) jerk within one
    sample: :math:`s = j_{99}^2 T`.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set training data (the four rates, rad/s).
    half_window : int
        Samples each side of the least-squares slope.
    quantile : float
        Quantile of the absolute jerk used, in (0, 1).
    """
    rates = dataset.signals(["boom_rate", "dipper_rate", "bucket_rate", "slew_rate"])
    exp = dataset.frame["experiment"].to_numpy()
    k = np.arange(-half_window, half_window + 1) * T
    kernel = k[::-1] / (k @ k)   # correlation with k/Σk² = convolution with the reversed kernel
    jerks = []
    for e in np.unique(exp):
        r = rates[exp == e]
        if len(r) < 4 * half_window + 3:
            continue
        acc = np.stack([np.convolve(r[:, i], kernel, mode="valid") for i in range(4)], axis=1)
        jerks.append(np.stack([np.convolve(acc[:, i], kernel, mode="valid") for i in range(4)], axis=1))
    if not jerks:
        raise EstimatorError(f"the training data have no experiment of {4 * half_window + 3} samples or "
                             "more to size the filter's jerk from")
    jerk = np.concatenate(jerks)
    j99 = np.nanquantile(np.abs(jerk), quantile, axis=0)
    return np.maximum(j99, 1e-3) ** 2 * T


@dataclass
class MachineTuning:
    """Covariances of the machine-set filters (everything that is saved).

    Parameters
    ----------
    R_kinematic : numpy.ndarray
        Variances of the 7 angle and rate measurements, rad² and (rad/s)².
    pressure_std : float
        White noise of one pressure transmitter, Pa.
    ripple_fraction : float
        Pump ripple as a share of the pressure.
    jerk : numpy.ndarray
        Jerk densities (4), rad²/s⁵.
    payload_walk : float
        Payload random walk, kg/√s.
    noise : str
        Name of the noise preset.
    spike_threshold : numpy.ndarray or None
        Per-signal glitch thresholds (None: no test).

    Attributes
    ----------
    R_kinematic : (7,) variances of the angle and rate measurements.
    pressure_std : float, Pa; ripple_fraction : float (share of the pressure).
    jerk : (4,) jerk densities; payload_walk : kg/√s.
    noise : name of the noise preset.
    spike_threshold : (16,) per-signal threshold of the one-frame glitch test
        (:func:`~.pressure_regression.spike_threshold` of the training data's sample-to-sample
        changes; ``inf``: no test, as models saved before it).
    """

    R_kinematic: np.ndarray
    pressure_std: float
    ripple_fraction: float
    jerk: np.ndarray
    payload_walk: float
    noise: str
    spike_threshold: np.ndarray = None

    def __post_init__(self):
        if self.spike_threshold is None:
            self.spike_threshold = np.full(len(SIGNALS), np.inf)

    def config(self) -> dict:
        """The JSON-able part to save: the scalar covariances and the noise preset, marked as the
        machine sensor set's."""
        return {"tuning": "consistent", "sensor_set": HYDRAULIC.sensors.name, "noise": self.noise,
                "pressure_std": self.pressure_std, "ripple_fraction": self.ripple_fraction,
                "payload_walk": self.payload_walk}

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save: ``R_kinematic``, ``jerk`` and ``spike_threshold``."""
        return {"R_kinematic": self.R_kinematic, "jerk": self.jerk, "spike_threshold": self.spike_threshold}

    @classmethod
    def restore(cls, config: dict, arrays) -> "MachineTuning":
        """The tuning saved by :meth:`config` and :meth:`arrays`; :class:`EstimatorError` when a
        value is missing or a covariance is not positive and finite.

        Parameters
        ----------
        config : dict
            What :meth:`config` returned.
        arrays : Mapping[str, numpy.ndarray]
            What :meth:`arrays` returned.
        """
        try:
            R = np.asarray(arrays["R_kinematic"], float)
            jerk = np.asarray(arrays["jerk"], float)
            values = [float(config[k]) for k in ("pressure_std", "ripple_fraction", "payload_walk")]
        except KeyError as exc:
            raise EstimatorError(f"saved machine-set filter lacks {exc}") from None
        if R.shape != (N_KIN,) or jerk.shape != (4,) or not (np.all(R > 0) and np.all(jerk > 0)
                                                             and np.all(np.isfinite(values))):
            raise EstimatorError("saved machine-set filter covariances are corrupt")
        # models saved before the glitch test have no thresholds: no test, as then
        spikes = np.asarray(arrays["spike_threshold"], float) if "spike_threshold" in arrays else \
            np.full(len(SIGNALS), np.inf)
        if spikes.shape != (len(SIGNALS),) or np.any(np.isnan(spikes)) or np.any(spikes <= 0):
            raise EstimatorError("saved machine-set filter: its glitch thresholds are corrupt")
        return cls(R, values[0], values[1], jerk, values[2], str(config.get("noise", "")), spikes)


def machine_tuning(dataset: Dataset, noise_name: str, payload_walk: float) -> MachineTuning:
    """Covariances from the machine noise preset and the training data's jerk (module doc).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set training data.
    noise_name : str
        Machine noise preset (empty: the dataset's).
    payload_walk : float
        Payload random walk, kg/√s.
    """
    if not noise_name:
        noise_name = dataset.meta.get("noise") or ""
        if not noise_name:
            raise EstimatorError("the machine-set filter needs the sensor noise level: the dataset "
                                 "names no noise preset, pass --noise field|none")
    try:
        preset = HYDRAULIC.noise(noise_name)
    except ExcavatorPayloadError as exc:
        raise EstimatorError(str(exc)) from None
    angle = max(preset.angle_noise, STD_FLOOR["angle"])
    rate = max(preset.rate_noise, STD_FLOOR["rate"])
    R = np.array([angle**2] * 3 + [rate**2] * 4)
    return MachineTuning(R, max(preset.pressure_noise, STD_FLOOR["pressure"]), preset.ripple_fraction,
                         jerk_density(dataset), float(payload_walk), preset.name)


class MachineKalman:
    """One streaming EKF (``unscented=False``) or UKF on machine-sensor-set samples.

    Parameters
    ----------
    machine : HydraulicMachine
        The model the filter believes in.
    tuning : MachineTuning
    unscented : bool
        Sigma-point (UKF) force update instead of the linearised one.
    alpha, beta, kappa : float
        UKF sigma-point parameters.
    low_speed : {'skip', 'downweight'}
        Low-speed handling (module doc).
    skip_std : float
        kg; ``skip`` drops low-speed force measurements once the payload's standard deviation
        is below this (before, they are down-weighted: better than no information at all).
    """

    def __init__(self, machine, tuning: MachineTuning, unscented: bool = False,
                 alpha: float = 0.5, beta: float = 2.0, kappa: float = 0.0, low_speed: str = "skip",
                 skip_std: float = 50.0):
        self.machine = machine
        self.skip_low_speed = low_speed == "skip"
        self.skip_std = float(skip_std)
        self.tuning = tuning
        self.unscented = unscented
        self.F = transition_matrix()
        self.Q = process_noise(tuning.jerk, tuning.payload_walk)
        self.R_kin = np.diag(tuning.R_kinematic)
        cyl = machine.cylinders
        self._head2 = np.array([c.head_area for c in cyl]) ** 2
        self._rod2 = np.array([c.rod_area for c in cyl]) ** 2
        self._head = np.sqrt(self._head2)
        self._rod = np.sqrt(self._rod2)
        self._v_still = 3.0 * np.array([c.stribeck_velocity for c in cyl])
        self._v_skip = SKIP_SPEED * np.array([c.stribeck_velocity for c in cyl])
        self._pvar = tuning.pressure_std**2
        self._ripple = tuning.ripple_fraction**2 / 2
        self._p = parameter_vector(machine)
        self._max_payload = float(machine.max_payload)
        self._bounds = (-0.5 * float(machine.bucket.mass), 20.0 * max(machine.max_payload,
                                                                      machine.rated_payload))
        self._build_runtime()
        if unscented:
            n = N_STATE
            lam = alpha**2 * (n + kappa) - n
            if n + lam <= 0:
                raise EstimatorError("ukf: α²(n + κ) must be positive; increase --alpha or --kappa")
            self.Wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
            self.Wc = self.Wm.copy()
            self.Wm[0] = lam / (n + lam)
            self.Wc[0] = lam / (n + lam) + 1 - alpha**2 + beta
            self.spread = n + lam
        self.reset()

    def _build_runtime(self) -> None:
        from excavator_payload.estimators.classical._kalman import BufferedFunction

        self._force = BufferedFunction(force_measurement_function())
        self._force.set_input(3, self._p)
        if self.unscented:
            self._sigma = BufferedFunction(force_sigma_function(2 * N_STATE + 1))
            self._sigma.set_input(3, self._p)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("_force", "_sigma")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._build_runtime()

    def reset(self) -> None:
        """Forget the state: the next :meth:`step` starts again from :meth:`initial_state`."""
        self.x: np.ndarray | None = None
        self.P: np.ndarray | None = None

    def initial_state(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angles and rates from the sample (broad prior), accelerations 0 ± 1 rad/s², payload
        m_max/2 ± m_max/2.

        Parameters
        ----------
        values : numpy.ndarray
            The sample, machine-set :data:`SIGNALS` order (SI units).

        Returns
        -------
        tuple of numpy.ndarray
            ``(x, P)``.
        """
        x = np.zeros(N_STATE)
        x[:N_KIN] = values[KINEMATIC]
        x[PAYLOAD] = self._max_payload / 2
        P = np.diag(np.r_[100.0 * self.tuning.R_kinematic, np.ones(4), (self._max_payload / 2) ** 2])
        return x, P

    def restart_kinematics(self, values: np.ndarray, elapsed: float) -> None:
        """After a gap: kinematic states from the new sample, the payload kept (its variance
        grown by the random walk over ``elapsed`` seconds).

        Parameters
        ----------
        values : numpy.ndarray
            The sample after the gap, machine-set :data:`SIGNALS` order (SI units).
        elapsed : float
            Length of the gap, s.
        """
        payload, var = self.x[PAYLOAD], self.P[PAYLOAD, PAYLOAD]
        self.x, self.P = self.initial_state(values)
        self.x[PAYLOAD] = payload
        self.P[PAYLOAD, PAYLOAD] = var + self.tuning.payload_walk**2 * elapsed

    def force_noise(self, pressures: np.ndarray) -> np.ndarray:
        """Variance of each measured piston force from its two pressures (noise + ripple), N².

        Parameters
        ----------
        pressures : numpy.ndarray
            Head and rod pressures of the three cylinders, interleaved (6), Pa.

        Returns
        -------
        numpy.ndarray
            Three force variances, N².
        """
        p_head, p_rod = pressures[0::2], pressures[1::2]
        return (self._head2 * (self._pvar + self._ripple * p_head**2)
                + self._rod2 * (self._pvar + self._ripple * p_rod**2))

    def _kinematic_update(self, x: np.ndarray, P: np.ndarray, values: np.ndarray):
        """Update 1 (angles and rates, :math:`h = x_{0:7}`): the corrected state and covariance,
        the innovation and its covariance."""
        S = P[:N_KIN, :N_KIN] + self.R_kin
        nu = values[KINEMATIC] - x[:N_KIN]
        K = np.linalg.solve(S, P[:N_KIN]).T
        x = x + K @ nu
        P = P - K @ P[:N_KIN]
        return x, 0.5 * (P + P.T), nu, S

    def _force_terms(self, x: np.ndarray, P: np.ndarray, values: np.ndarray):
        """What update 2 needs at state ``x``: the tilt, the measured piston forces, their
        model (value ``h`` and Jacobian ``H``) and their noise ``R`` (stiction and
        ``--low-speed skip`` included)."""
        pressures = values[PRESSURES]
        force = pressures[0::2] * self._head - pressures[1::2] * self._rod
        tilt = np.array(ground_tilt(float(values[PITCH]), float(values[ROLL])))
        packed = self._force(x, tilt, force)
        h, H = packed[0:3], packed[3:39].reshape(3, N_STATE, order="F")
        breakaway, speed = packed[39:42], packed[42:45]
        still = np.exp(-(speed / self._v_still) ** 2)
        R = np.diag(self.force_noise(pressures) + still * breakaway**2 / 3)
        if self.skip_low_speed and P[PAYLOAD, PAYLOAD] < self.skip_std**2:
            # Stiction holds a force that stays for the whole standstill (not white noise, so
            # down-weighting still over-counts it): once the payload is known to skip_std, a
            # cylinder slower than the skip speed gives no force measurement at all.
            R[np.diag_indices(3)] += np.where(np.abs(speed) < self._v_skip, SKIPPED_VARIANCE, 0.0)
        return tilt, force, h, H, R

    def predict(self) -> None:
        """One prediction without a measurement: bridges the slot of a sample judged a glitch
        (the white-jerk chains carry the motion over the hole; restarting the kinematics
        mid-motion biases the payload)."""
        if self.x is None:
            return
        self.x = self.F @ self.x
        P = self.F @ self.P @ self.F.T + self.Q
        self.P = 0.5 * (P + P.T)

    def step(self, values: np.ndarray) -> bool:
        """Update with one sample and predict to the next; False (state kept) if not finite.

        Parameters
        ----------
        values : numpy.ndarray
            The sample, machine-set :data:`SIGNALS` order (SI units).

        Returns
        -------
        bool
            Whether the state was updated.
        """
        if self.x is None:
            self.x, self.P = self.initial_state(values)
        x, P, _, _ = self._kinematic_update(self.x, self.P, values)
        # Update 2: piston forces through the symbolic model, at the state after update 1.
        tilt, force, h, H, R = self._force_terms(x, P, values)
        if self.unscented:
            x, P = self._unscented_update(x, P, tilt, force, R)
        else:
            PHt = P @ H.T
            S = H @ PHt + R
            K = np.linalg.solve(S, PHt.T).T
            x = x + K @ (force - h)
            I_KH = np.eye(N_STATE) - K @ H
            P = I_KH @ P @ I_KH.T + K @ R @ K.T
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.diag(P) >= 0)):
            return False
        x[PAYLOAD] = min(max(x[PAYLOAD], self._bounds[0]), self._bounds[1])
        self.posterior = (x, P)
        # Prediction (linear).
        self.x = self.F @ x
        P = self.F @ P @ self.F.T + self.Q
        self.P = 0.5 * (P + P.T)
        return True

    def _unscented_update(self, x, P, tilt, force, R):
        from excavator_payload.estimators.classical._kalman import covariance_sqrt, statistical_linearisation

        L = covariance_sqrt(self.spread * P)
        chi = np.hstack([x[:, None], x[:, None] + L, x[:, None] - L])
        Y = self._sigma(chi, tilt, force).reshape(3, -1, order="F")
        y_hat = Y @ self.Wm
        dY = Y - y_hat[:, None]
        dX = chi - x[:, None]
        P_yy = (dY * self.Wc) @ dY.T + R
        P_xy = (dX * self.Wc) @ dY.T
        K = np.linalg.solve(P_yy, P_xy.T).T
        H_s = statistical_linearisation(P, P_xy)
        residual = dY - H_s @ dX
        E = (residual * self.Wc) @ residual.T
        I_KH = np.eye(N_STATE) - K @ H_s
        x = x + K @ (force - y_hat)
        P = I_KH @ P @ I_KH.T + K @ (R + E) @ K.T
        return x, 0.5 * (P + P.T)

    @property
    def estimate(self) -> float:
        return float(self.posterior[0][PAYLOAD])

    @property
    def payload_std(self) -> float:
        return math.sqrt(max(float(self.posterior[1][PAYLOAD, PAYLOAD]), 0.0))
