r"""``calibrated`` on the machine sensor set: identify the machine from a few known-payload motions.

A service technician's set-up: a roughly right machine file (``cat345c-hydraulic-3pct``: every
number 3 % off), a handful of calibration lifts with known payloads (empty bucket and known
weights), then weighing. The residual of one sample, per arm joint :math:`j` (boom, dipper,
bucket), is the one of
:class:`~excavator_payload.estimators.classical.pressure_regression.PressureRegression`,

.. math:: r_j(z) = \text{count}_j\,\partial l_j/\partial q_j\,\big((\tilde p_h - o_h)A_h
          - (\tilde p_r - o_r)A_r - F_{f,j}\big) - \tau_{0,j}(\tilde q - o_q, \dot q, \ddot q,
          \text{tilt}(\tilde\iota - o_\iota)) - m\,\varphi_j(\dots),

all from the symbolic model (``HydraulicSymbolic.functions["pressure_regression"]`` called on
CasADi symbols), with the unknowns :math:`z = (\delta, o)`:

* :math:`\delta`: relative deviations of the machine file's physical parameters,
  :math:`p = p_\text{file}\odot(1 + \delta)` — the link masses, centres of mass and inertias
  (the *inertial* parameters, on which the rigid-body torque is linear in the lumped
  combinations :math:`m, m c, I + m c c`), the payload position, link lengths and boom foot,
  the cylinder pins, the four-bar linkage, piston and annulus areas, and the seal friction
  (Coulomb, load coefficient, viscous) of each cylinder;
* :math:`o`: the sensor offsets of the six pressures, the three joint angles and the house
  pitch and roll.

The regressor is :math:`\partial r/\partial z` (a CasADi Jacobian, evaluated on all samples in
one mapped call); calibration is Bayesian Levenberg–Marquardt: prior :math:`\delta \sim
\mathcal N(0, s^2)` (``--prior-std``, 5 % by default around a file known to be a few % off) and
:math:`o \sim \mathcal N(0, \sigma_o^2)` with :math:`\sigma_o` the field preset's session-offset
magnitudes; in prior-normalised units :math:`u = z/\sigma`,

.. math:: H = J^\top W J + I, \qquad u \leftarrow u - (H + \lambda\,\mathrm{diag}\,H)^{-1}
          (J^\top W r(u) + u),

λ growing until a step lowers the posterior cost (up to eight steps). The weights :math:`W` are
fixed at the start (they depend on z through friction and levers; letting them move rewards
inflating the stiction variance). The rigid-body part is linear in lumped inertial combinations
of these parameters, the geometry is not, hence the iterations; the parameters are the machine
file's physical ones rather than a symbolic set of lumped ones, so that the same vector feeds the
compiled model unchanged. What a handful of motions cannot separate (a mass against its centre
of mass, a pin against a length…) is split by the prior; what weighing needs — the torque the
empty arm and the payload produce at each pose — is what the motions pin down. The calibration
motions must move every joint (swings with slewing: :mod:`excavator_payload.evaluation.
demo_machine`); the ``lifts`` motion moves the boom only and identifies little else.
:math:`H^{-1}` is the posterior covariance (kept: the Cramér–Rao bound of
:mod:`excavator_payload.evaluation.crb_machine` uses its nuisance block).

Accelerations are derived as in ``inverse-dynamics``: the centred least-squares slope of the
measured rates (in calibration over ±15 samples, Savitzky–Golay of order 1: the rate noise
through a ±5 window is ≈ 8 kN·m on the boom, five times the pressure noise; while weighing the
option ``--half-window``, 3 by default, through a ring buffer; on 60 validation experiments
per family, within 1 % for ±2 / 3 / 4 / 5 samples: NMPC swings 98 / 97 / 93 / 90 %, work cycles
80 / 75 / 73 / 73 %, slowly starting swings 25 / 37 / 48 / 52 %).

The momentum balance (``--balance momentum``)
--------------------------------------------
The differentiator is the floor of the per-sample form: with perfect sensors and the true
machine file, the regression with the simulator's accelerations is within 3.8 kg (mean MAX on
20 NMPC swings), with the ±3 slope 26.6 kg (``benchmarks/bench_machine_floor.py``): valve steps
make the accelerations jump, and a slope over a jump is wrong on both sides. Lagrange's
equation read as a momentum balance needs no acceleration,

.. math:: \frac{d}{dt}\frac{\partial K}{\partial\dot q} = \tau_p + \frac{\partial K}{\partial q}
          - \frac{\partial V}{\partial q} - \frac{\partial R}{\partial\dot q},

integrated over a window (``HydraulicSymbolic``'s ``momentum_regression``, affine in the
payload; :func:`window_residuals`): the momentum's change against the integral of the torques
and forces. Weighted by a trapezoid (:func:`balance_weights`) and summed by parts, each end's
momentum is averaged over ``BALANCE_RAMP`` samples — the rates' noise enters the momentum only
there. With the
true machine, offsets and IMU dynamics this form weighs field-noise work cycles within 13.4 kg
mean MAX and NMPC swings within 24.5 kg, whose MAX is at their start from rest (after 3 s:
1.5-14.5 kg; the per-sample form at the true machine: 66 kg on the held-force simulator's
swings — the calibrated parameters of that form partly compensate its differentiator).
Calibration in this form identifies the parameters, offsets and the IMU lag; the link IMUs'
acceleration sensitivities, which wander when fitted, are read off the IMUs' own signals
(:func:`imu_sensitivities`, ``--imu-leak``) and held. The windows overlap, so their noise model is kept in
per-sample-equivalent variances (:meth:`MachineCalibration.evaluate_windows`): the pressures' and
the rates' white noise per sample (the rates' through the seal friction and the centrifugal and
Coriolis forces, and at the window's ends through the momentum), and a standstill's unknown
friction, which the whole window shares, τ times its window variance. The friction itself is
modelled with its presliding state held (:func:`held_direction`): a stopped seal keeps the
friction of its last sliding direction, one-signed, where a smooth sign of the (noisy, near
zero) rod speed says nothing (three calibration draws: NMPC swings 26.9 → 22.5 kg mean MAX, work
cycles 50.7 → 42.8 kg, the slope 33.6 → 25.7 kg). With the true machine that
model explains the calibration windows (actual / modelled variance 1.1-1.7 per joint with field
sensors, 1.0-2.6 with perfect ones; counting the standstill once per window and leaving out the
rates' noise through the integrand, it was 19-39 and 15-102: the still windows, 88 % of the
dipper's and bucket's on ten calibration swings, outweighed the moving ones τ-fold). It fits twice:
what the first fit leaves unexplained is measured per joint as a variance component
(:meth:`MachineCalibration.measure_window_inflation`, 1.0-2.1 on five calibration draws) and the
second fit, from the prior again, weighs the windows by it (so does the zero check). Over five
calibration draws, 40 experiments per test set (``benchmarks/bench_machine_draws.py``), the
consistent noise model against the earlier one (whose variance component was 12-56): hand-made
trajectories 100 % within 1 % (84 %), NMPC swings on a 5° slope 96 % (71.5 %), planned swings 84 %
(77.5 %), NMPC swings 87.5 % (94 %), work cycles 63 % (68.5 %). The streaming
kernel keeps two rings (the differentiator's, for the IMU correction, and the balance's); the estimate refers to the sample 0.28 s back. The C export
carries both rings (``runtime/export_c.py``).

Sensor noise from the data
--------------------------
After the first pass the residuals of the calibration data (known payloads) give the pressure
noise: :math:`\hat\sigma_p^2 = \operatorname{mean}\big(r_j^2 / (\text{lever}_j^2 (A_h^2 +
A_r^2))\big)` over moving samples (it absorbs pump ripple and the IMU's dynamic error, as the
estimator sees them); the second pass and the estimator's weights use it. No noise preset is
needed (``--noise auto`` falls back to this when the data name none).

Low-speed samples
-----------------
Near standstill the seal friction is anywhere within ± its breakaway force (stiction). Option
``--low-speed``: ``model`` (use the smooth-sign friction model as if moving), ``downweight``
(the joint's residual variance grows by (breakaway torque)²/3, fading with speed, as
``inverse-dynamics``), or ``skip`` (the default: drop joints whose rod speed is below 3
Stribeck velocities). Measured on 30 session-B experiments each (mean MAX / RMS, kg): swings
182/102 (model), 97/27 (downweight), 85/14 (skip); work cycles 207/141, 112/39, 63/16;
hand-made trajectories 189/106, 134/43, 130/39 — skipping is best everywhere. Calibration
always skips (the parameters would otherwise absorb the stiction).

Outside the calibrated range
----------------------------
Calibration identifies the machine where its motions went. Work cycles begin with the bucket
open at the end of the cut (−20…+10°); calibration swings keep it at −115…−30°, so there the
model extrapolates the bucket's four-bar linkage (on the study's calibration: 40 work cycles at
70.5 kg mean MAX, the MAX in the first 1–3 s, while the bucket curls and the boom stands). fit
records the range of each arm angle the calibration motions covered (:func:`angle_coverage`:
0.5–99.5 percentiles ± 5°, offsets removed; saved with the model); while weighing, option
``--outside-calibration`` ``skip`` gives the bucket joint no weight where its angle lies outside
its range (the momentum form: anywhere in the window), ``use`` weighs it anyway, ``auto`` (the
default) skips in the momentum form and uses in the per-sample form, whose boom and dipper alone
are worse than its extrapolated bucket (40 work cycles, study's calibration: 36.0 → 86.4 kg). Over
five calibration draws see the README.

Waiting for the boom
--------------------
While the boom stands its seals hold an unknown stiction force (≈ 470 kg of payload at the
boom), so nothing weighs it: the estimate would rest on the dipper and bucket, whose
calibration at the poses of a cut is the least sure (work cycles start by curling the bucket
with the boom still; planned swings start slowly). Option ``--wait-for-boom`` (``auto``, the
default: ``yes`` in the momentum form, ``no`` in the per-sample form) reports no estimate (NaN,
``warming_up``) until a window has weighed the boom (0.5 s of boom motion); the information
gathered meanwhile is kept. A motion that never moves the boom is never weighed; ``no`` reports
from the first information, as before. Over five draws see the README.

Zero
----
:func:`zero_offsets` re-estimates only the offsets :math:`o` from a short empty-bucket motion
(the commercial "check zero"), prior: the calibrated offsets with the preset's drift as std.
"""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np
from scipy.ndimage import correlate1d
from scipy.signal import savgol_filter

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical.pressure_regression import (
    ANGLES, PITCH, PRESSURES, RATES, ROLL, PressureRegression)
from excavator_payload.model.codegen import column_map, native
from excavator_payload.model.hydraulic import (
    CYLINDERS, HYDRAULIC_PARAMETER_NAMES, HydraulicArmModel, compiled_function, hydraulic_symbolic)

SIGNALS = MACHINE_SENSORS.signals
DEG = math.pi / 180.0

#: Physical parameters calibration adjusts (relative deviation from the machine file).
CALIBRATED_PARAMETERS: tuple[str, ...] = (
    "boom_length", "dipper_length", "boom_foot_x", "boom_foot_z",
    *(f"{link}_{k}" for link in ("boom", "dipper", "bucket")
      for k in ("mass", "com_u", "com_w", "inertia_u", "inertia_y", "inertia_w")),
    "payload_u", "payload_w",
    "boom_cylinder_parent_x", "boom_cylinder_parent_z", "boom_cylinder_child_u", "boom_cylinder_child_w",
    "dipper_cylinder_parent_u", "dipper_cylinder_parent_w", "dipper_cylinder_child_u",
    "dipper_cylinder_child_w", "bucket_cylinder_parent_u", "bucket_cylinder_parent_w",
    "rocker_pivot_u", "rocker_pivot_w", "rocker_length", "link_length", "bucket_point_u", "bucket_point_w",
    *(f"{c}_{k}" for c in CYLINDERS for k in ("head_area", "rod_area", "coulomb", "load_coefficient",
                                               "viscous")),
)
#: Friction parameters among them (nuisances of the Cramér–Rao bound).
FRICTION_PARAMETERS = tuple(p for p in CALIBRATED_PARAMETERS
                            if p.endswith(("coulomb", "load_coefficient", "viscous")))
#: Parameters the momentum form's calibration holds at the machine file: where the arm stands
#: relative to the slew axis. Moving the boom foot together with the boom cylinder's base is
#: invisible in the arm's own balance (vertically not at all, horizontally only through the
#: slewing's centrifugal terms), so the fit used that direction to absorb what it cannot
#: model: once its Jacobian was right it moved both 0.14 m outwards (foot x +22 %, 9σ of its
#: posterior; study's calibration) and the hand-made trajectories' first estimates came out
#: +41 kg (47.5 kg mean MAX, 68 % within 1 % on 40). Held at the file (a drawing dimension)
#: the translation is fixed and the cylinder base, whose position relative to the foot sets
#: the boom's moment arm, stays free: 15.3 kg, 100 %; NMPC swings 9.5 → 9.5 kg, work cycles
#: 12.4 → 11.6 kg (README, docs/machine-findings.md for five draws).
HELD_IN_MOMENTUM = ("boom_foot_x", "boom_foot_z")
#: Signals with an estimated offset (zero), in this order.
OFFSET_SIGNALS: tuple[str, ...] = (
    *(s for s in SIGNALS if s.endswith("_pressure")), "boom_angle", "dipper_angle", "bucket_angle",
    "house_pitch", "house_roll")
#: Prior std of each offset (the field preset's session offsets), SI units.
OFFSET_PRIOR_STD = np.array([1.5e5] * 6 + [0.1 * DEG] * 3 + [0.1 * DEG] * 2)
#: The IMUs' dynamic error, identified in calibration: output lag τ (s) and each inclination
#: IMU's sensitivity to its link's tangential acceleration (s²: tilt error per rad/s² of the
#: link's absolute angular acceleration; the house IMU's per (rad/s)² centripetal and rad/s²
#: tangential slew acceleration).
IMU_PARAMETERS: tuple[str, ...] = ("imu_lag", "boom_imu_acceleration_sensitivity",
                                   "dipper_imu_acceleration_sensitivity",
                                   "bucket_imu_acceleration_sensitivity",
                                   "house_imu_acceleration_sensitivity")
#: Their prior: mean 0, std 20 ms (MEMS IMU output filters: a few to tens of ms) and, for the
#: sensitivities, a 5 % fusion leak at the IMU's distance d from its axis, 0.05 · d / g: a link
#: IMU up to 4 m from its joint, 0.02 s²; the house IMU (pitch and roll) within 1 m of the slew
#: axis, where inclination sensors go, 0.005 s². The house IMU used to share the links' 0.02 s²:
#: ten calibration swings then put it at 0.022-0.040 s² (three calibration draws; the sensors
#: have 0.005), and at 0.027 s² even with a perfect house IMU — it absorbed what the rates' noise
#: does to the fit, not the IMU's leak — and that centripetal correction biased smooth motions
#: (+8 kg; NMPC motions replayed on a 5° slope or on level ground alike: mean MAX 41 kg).
IMU_PRIOR_STD = np.array([0.02, 0.02, 0.02, 0.02, 0.005])
#: Moving samples per cylinder below which fit warns that calibration learned little of it
#: (2 s at 100 Hz; ten calibration swings give 2000-9000 per cylinder).
MIN_MOVING_SAMPLES = 200
#: The same for one cylinder in the zero check (1 s at 100 Hz).
MIN_ZERO_MOVING_SAMPLES = 100
#: ``zero`` warns of an offset beyond this many prior standard deviations (:data:`OFFSET_PRIOR_STD`):
#: 2.5° of angle, 37.5 bar. Clean zero checks reached 4.8 (16 swings of sessions 2-9) and 9.4
#: (3 empty slopes motions); a stuck or mis-scaled signal in the zero check goes far beyond (a
#: constant boom head pressure: house pitch -8°, 80; a boom angle stuck at 0: 18°, 179).
ZERO_OFFSET_WARNING = 25.0
#: Choices of ``--low-speed``.
LOW_SPEED_CHOICES = ("model", "downweight", "skip")
#: Choices of ``--outside-calibration``: what becomes of a joint's window where the joint's angle
#: lies outside the range the calibration motions covered. ``auto``: ``skip`` in the momentum
#: form, ``use`` in the per-sample form (on the study's calibration, 40 work cycles: momentum
#: 70.5 → 36.1 kg mean MAX with skip, per-sample 36.0 → 86.4 kg — its boom and dipper alone,
#: through the differentiator, are worse than its extrapolated bucket).
OUTSIDE_CALIBRATION_CHOICES = ("auto", "skip", "use")
#: Choices of ``--wait-for-boom``: report no estimate until the boom joint has been weighed
#: (a 0.5 s window of boom motion). ``auto``: ``yes`` in the momentum form, ``no`` in the
#: per-sample form.
WAIT_FOR_BOOM_CHOICES = ("auto", "yes", "no")
#: Choices of ``--new-load``: restart the weighing when the load changes (a dump, a new bucket
#: load on a machine that weighs one load after another). ``auto``: ``detect`` in the momentum
#: form, ``off`` in the per-sample form.
NEW_LOAD_CHOICES = ("auto", "detect", "off")
#: Choices of ``--imu-leak``: where the three link IMUs' acceleration sensitivities come from.
#: ``signals``: read off each IMU's own angle and rate (:func:`imu_sensitivities`) and held in
#: calibration, zero and weighing; ``fit``: identified in the calibration fit with the other
#: parameters; ``none``: not modelled (0); ``auto`` (the default): ``signals`` in the momentum
#: form, ``fit`` in the per-sample form. The house IMU's is fitted in the per-sample form and
#: left out of the momentum form whatever the choice (read off its signals and held it cost the
#: hand-made trajectories: two draws, 21.0 / 20.6 -> 33.9 / 54.3 kg mean MAX).
IMU_LEAK_CHOICES = ("auto", "signals", "fit", "none")
#: The new-load test compares the estimate of a short memory (exponential, this time constant,
#: s) with the whole weighing's ...
NEW_LOAD_MEMORY = 1.0
#: ... and takes a difference of more than this share of the rated payload, and more than
#: :data:`NEW_LOAD_SIGMAS` standard deviations of the difference, for a new load.
NEW_LOAD_MIN_SHARE = 0.1
NEW_LOAD_SIGMAS = 5.0
#: Before a new load is certain, a short memory leaving the whole one by both
#: :data:`CHANGING_SIGMAS` and :data:`CHANGING_MIN_SHARE` of the rated payload says the load is
#: changing (status ``load_changing``): while the bucket dumps, the whole memory still holds the
#: load before, and calling it ``ok`` reported the old load for the 1-3 s the restart test needs.
CHANGING_MIN_SHARE = 0.05
CHANGING_SIGMAS = 5.0
#: The covered range of each arm angle: these percentiles of the calibration samples (robust to
#: a glitch), widened by :data:`COVERAGE_MARGIN` each side (rad).
COVERAGE_PERCENTILES = (0.5, 99.5)
COVERAGE_MARGIN = 5.0 * DEG
#: The joints the range limits while weighing: the bucket, whose four-bar linkage is the model's
#: most nonlinear geometry. Boom and dipper levers extrapolate smoothly; limiting them too cost
#: NMPC swings and the slope on one of five calibration draws (slope 37.8 → 40.3 kg mean MAX, 78 →
#: 72 % within 1 %) and gained nothing on work cycles over limiting the bucket alone.
COVERAGE_JOINTS = (False, False, True)
#: Stands for "no limit" in the coverage (a model saved before it existed, or ``use``); finite,
#: so that the C export writes it as a number.
NO_LIMIT = 1.0e30
#: Default pressure noise before it is estimated (the field preset's), Pa.
DEFAULT_PRESSURE_STD = 3.0e4
_PARAM_INDEX = np.array([HYDRAULIC_PARAMETER_NAMES.index(n) for n in CALIBRATED_PARAMETERS])
_OFFSET_COLUMNS = np.array([SIGNALS.index(s) for s in OFFSET_SIGNALS])


def _corrected_signals(x, qdd, offsets, imu):
    """Symbolic sensor correction of one raw sample: offsets, then the IMUs' dynamic error.

    Returns the joint angles ``q`` (4, slew 0), rates ``qd`` (4), ground tilt (2) and pressures
    (6) the arm model takes. ``offsets`` has one entry per signal (zeros where none is
    estimated); ``imu`` = (lag τ, the boom, dipper and bucket IMUs' and the house IMU's
    acceleration sensitivity k, s²) — see the module doc.
    """
    corr = [x[i] - offsets[i] for i in range(len(SIGNALS))]
    lag, k_links, k_house = imu[0], [imu[1], imu[2], imu[3]], imu[4]
    rates = [corr[i] for i in RATES]
    # a first-order lag τ delays a signal by τ at the frequencies of arm motion: the true value
    # is the measured one plus τ times its derivative (the rate for an angle, the derived
    # acceleration for a rate)
    angles = [corr[i] + lag * rates[j] for j, i in enumerate(ANGLES)]
    qd = ca.vertcat(*[rates[j] + lag * qdd[j] for j in range(4)])
    # an inclination IMU's fusion reads part of its link's tangential acceleration as tilt:
    # k_j times the link's absolute angular acceleration; a relative angle is the difference
    # of two IMUs (the boom's reference, the house, does not pitch with the arm)
    absolute = [qdd[0], qdd[0] + qdd[1], qdd[0] + qdd[1] + qdd[2]]
    for j in range(3):
        angles[j] = angles[j] - k_links[j] * absolute[j] + (k_links[j - 1] * absolute[j - 1] if j else 0)
    q = ca.vertcat(*angles, 0)
    # the house IMU ahead of the slew axis: centripetal acceleration into pitch, tangential
    # into roll
    slew_rate = rates[3] + lag * qdd[3]
    pitch = corr[PITCH] - k_house * slew_rate**2
    roll = corr[ROLL] + k_house * qdd[3]
    # ground tilt from the house IMU at slew angle 0 (inverse of house_inclination at ψ = 0,
    # as pressure_regression.ground_tilt)
    tilt = ca.vertcat(ca.asin(ca.sin(pitch) / ca.cos(roll)), roll)
    pressures = ca.vertcat(*[corr[i] for i in PRESSURES])
    return q, qd, tilt, pressures


def _unpack(p_file, z):
    """Symbolic z = (δ, o, imu) as the model's parameter vector p = p_file ⊙ (1 + δ), the
    offsets over all signals (zeros where none is estimated) and the IMU dynamics."""
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    scale = ca.SX.ones(len(HYDRAULIC_PARAMETER_NAMES))
    for k, i in enumerate(_PARAM_INDEX):
        scale[int(i)] = 1 + z[k]
    offsets = ca.SX.zeros(len(SIGNALS))
    for k, i in enumerate(_OFFSET_COLUMNS):
        offsets[int(i)] = z[n_delta + k]
    return p_file * scale, offsets, z[n_delta + n_off:]


@lru_cache(maxsize=1)
def residual_function() -> ca.Function:
    """CasADi function of one sample: residual (3), its Jacobian by z (3×nz) and the kernel's
    lever, rod speed and stiction torque (3 each).

    Inputs: signals (15, raw measured), qdd (4), payload, p (file), z = (δ, o, imu).
    """
    sym = hydraulic_symbolic()
    f = sym.functions["pressure_regression"]
    n_delta, n_off, n_imu = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS), len(IMU_PARAMETERS)
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    payload = ca.SX.sym("payload")
    p_file = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    z = ca.SX.sym("z", n_delta + n_off + n_imu)
    p, offsets, imu = _unpack(p_file, z)
    q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
    residual, phi, lever, speed, stiction = f(q, qd, qdd, tilt, pressures, p)
    r = residual - payload * phi
    # ∂r/∂q̈ carries the differentiator's noise into the residual (weights)
    inertia = ca.sum2(ca.jacobian(r, qdd) ** 2)
    return ca.Function("cal_machine_residual", [x, qdd, payload, p_file, z],
                       [r, ca.jacobian(r, z), lever, speed, stiction, inertia, ca.jacobian(r, payload)])


def _momentum_terms(x, qdd, p, offsets, imu, sign=None):
    """Symbolic momentum-balance terms of one raw sample (``HydraulicSymbolic``'s
    ``momentum_regression`` behind the sensor correction): (P0, Pm, I0, Fm) (12), lever,
    rod speed, stiction and the rates' gain into the momentum (3 each). With ``sign`` the seal
    friction's presliding state is given (``momentum_regression_held``), else a smooth sign of
    the rod speed."""
    q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
    functions = hydraulic_symbolic().functions
    if sign is None:
        terms = functions["momentum_regression"](q, qd, tilt, pressures, p)
    else:
        terms = functions["momentum_regression_held"](q, qd, tilt, pressures, sign, p)
    P0, Pm, I0, Fm, lever, speed, stiction, gain = terms
    return ca.vertcat(P0, Pm, I0, Fm), lever, speed, stiction, gain


@lru_cache(maxsize=4)
def compiled(name: str) -> ca.Function:
    """``residual`` or ``momentum``: the batch functions of calibration and zero, compiled to C
    (:func:`~excavator_payload.model.codegen.native`; CasADi's virtual machine where no compiler
    is). Calibration evaluates them on every sample once per iteration: on three swings the
    virtual machine took 10 of the 15 s. (The streaming kernels, :func:`kernel_function`, are
    compiled already.)"""
    return native({"residual": residual_function, "momentum": momentum_function}[name]())


@lru_cache(maxsize=1)
def momentum_function() -> ca.Function:
    """CasADi function of one sample for calibration and zero: the momentum-balance terms A
    (12), ∂A/∂z (12×nz), lever, rod speed and stiction (3 each). Inputs as
    :func:`residual_function` but no payload (A is split by it) and with the seals' presliding
    state last (3, :func:`held_direction`): a stopped seal holds the friction of its last
    sliding direction, which the smooth sign of the streaming kernel cannot know. On noise-free
    calibration swings at the true machine this took the residual of windows centred on a
    standstill from 17070 / 7102 / 1833 to 1233 / 163 / 77 N·m RMS (boom / dipper / bucket);
    the windows keep their standstill variance (the state is not known to the millimetre of
    presliding, nor before a cylinder's first sliding)."""
    n_delta, n_off, n_imu = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS), len(IMU_PARAMETERS)
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p_file = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    z = ca.SX.sym("z", n_delta + n_off + n_imu)
    sign = ca.SX.sym("sign", 3)
    A, lever, speed, stiction, _ = _momentum_terms(x, qdd, *_unpack(p_file, z), sign=sign)
    # how the rates' white noise enters (the windows' noise model): through the momentum at the
    # window's ends, at the sample's payload (∂(P0 + m Pm)/∂rates, 3×4 each), and through each
    # sample's integrand, by the seal friction and the centrifugal and Coriolis forces (for the
    # dipper and bucket more than the pressures' noise near standstill)
    dA = ca.jacobian(A, x)[:, RATES]
    return ca.Function("cal_machine_momentum", [x, qdd, p_file, z, sign],
                       [A, ca.jacobian(A, z), lever, speed, stiction, dA[0:3, :], dA[3:6, :],
                        ca.sum2(dA[6:9, :] ** 2)])


#: Slow samples after the last sliding one that keep its friction direction (0.1 s): a reversal
#: or a slow pass turns the friction over through the presliding state, but once a valve has
#: closed the seal holds whatever balanced the trapped pressures, anywhere within ± breakaway.
HELD_SAMPLES = 10


def held_direction(speed: np.ndarray, runs: np.ndarray, threshold: np.ndarray,
                   held: int = HELD_SAMPLES) -> np.ndarray:
    """Each cylinder's presliding state as calibration can know it: the sign of its rod speed
    where it slides faster than ``threshold`` (per cylinder), held through up to ``held``
    slower samples, then 0 — a standstill's friction is unknown within ± breakaway, mean 0, its
    spread in the windows' standstill variance — and 0 from the start of each run until the
    first sliding. ``speed`` (n, 3), ``runs`` a run id per row."""
    marks = np.where(np.abs(speed) > threshold, np.sign(speed), np.nan)
    start = np.r_[True, runs[1:] != runs[:-1]]
    marks[start] = np.where(np.isnan(marks[start]), 0.0, marks[start])
    # forward fill: each row takes the last mark at or before it (every run starts with one)
    rows = np.arange(len(marks))[:, None]
    index = np.maximum.accumulate(np.where(np.isnan(marks), 0, rows), axis=0)
    filled = marks[index, np.arange(marks.shape[1])]
    return np.where(rows - index > held, 0.0, filled)


def momentum_windows(runs: np.ndarray, half: int) -> np.ndarray:
    """Centres ``c`` (row indices) whose window ``c - half … c + half`` lies in one run of
    contiguous samples (``runs``: a run id per row, equal ids = contiguous)."""
    n = len(runs)
    if n <= 2 * half:
        return np.zeros(0, int)
    c = np.arange(half, n - half)
    return c[runs[c - half] == runs[c + half]]


def balance_weights(half: int, ramp: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights of the momentum balance over ``2·half + 1`` samples: ``w`` of the integrand and
    ``u`` of the momentum. The balance's weight ``v`` rises and falls over ``ramp`` sample
    intervals (a trapezoid in time, 0 after the last interval); ``u_j = v_{j-1} - v_j`` are its
    differences, so Σ v_j (P_{j+1} - P_j) = Σ u_j P_j (summation by parts) and each end's
    momentum is averaged over ``ramp`` samples. Each interval's integral is the trapezoid rule,
    (I_j + I_{j+1})/2 Δt, so the integrand's weight is w_j = (v_j + v_{j-1})/2 (Σw = Σv)."""
    L = 2 * half + 1
    j = np.arange(L)
    v = np.minimum(1.0, np.minimum((j + 1) / ramp, (L - 1 - j) / ramp))
    before = np.r_[0.0, v[:-1]]
    return 0.5 * (v + before), before - v


def _window_sums(X: np.ndarray, weights: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``correlate1d(X, weights, axis=0)[centres]``, skipping the columns that are zero
    throughout: of a Jacobian of the momentum terms 614 of 852 entries are structurally zero,
    and their window sums are zero (each column is correlated on its own, so the others'
    numbers are the same to the bit)."""
    if X.ndim == 2:
        return correlate1d(X, weights, axis=0, mode="constant")[centres]
    flat = X.reshape(len(X), -1)
    used = np.flatnonzero(np.any(flat != 0, axis=0))
    out = np.zeros((len(centres), flat.shape[1]))
    out[:, used] = correlate1d(flat[:, used], weights, axis=0, mode="constant")[centres]
    return out.reshape((len(centres),) + X.shape[1:])


def window_residuals(A: np.ndarray, payload: np.ndarray, centres: np.ndarray, half: int, dt: float,
                     ramp: int = 1):
    r"""The momentum balance over each window ``c ± half`` (module doc), trapezoid rule,
    weighted by :func:`balance_weights`.

    ``A`` (n, 12[, nz]) holds per sample (P0, Pm, I0, Fm) or their derivatives; returns the
    window residual at ``payload`` and its payload sensitivity :math:`-\varphi`, per joint,

    .. math:: r = \frac{1}{W}\Big[\sum_j w_j I_{0,j}\,\Delta t + \sum_j u_j P_{0,j}\Big]
              - \frac{m}{W}\Big[-\sum_j u_j P_{m,j} - \sum_j w_j F_{m,j}\,\Delta t\Big],
              \qquad W = \sum_j w_j \Delta t.

    Each sample interval's integral is the trapezoid rule: pressures, forces and accelerations
    of a hydraulic machine are continuous (valve and pressure dynamics; the NMPC simulator's
    force lag). A left rectangle rule is exact only for inputs held over each sample period,
    as the NMPC simulator's were before it had the lag (README, "Not done yet").
    """
    w, u = balance_weights(half, ramp)
    W = float(w.sum()) * dt
    integ = _window_sums(A[:, 6:12], w * dt, centres)
    mom = _window_sums(A[:, 0:6], u, centres)
    # the balance Σ w_j I_j dt = Σ w_j (P_{j+1} - P_j) = Σ u_j P_j (summation by parts)
    r0 = (integ[:, 0:3] - mom[:, 0:3]) / W
    sens = (mom[:, 3:6] - integ[:, 3:6]) / W  # φ of the window
    m = payload[centres].reshape((-1,) + (1,) * (A.ndim - 1))
    return r0 - m * sens, -sens


#: Samples each side of the centred differentiator in calibration (0.3 s: the lifts are slow,
#: and the rate noise through a shorter window dominates the boom's residual). Measured on 20
#: swings after calibration and zero (mean MAX, kg): ±5 samples 150, ±8 83, ±15 62, ±25 66.
CALIBRATION_HALF_WINDOW = 15
#: ``--balance``: how the estimator does without measured accelerations.
BALANCE_CHOICES = ("differentiated", "momentum")
#: The momentum balance's window: ±25 samples (0.5 s), its ends averaged over 10 samples
#: (:func:`balance_weights`). The rates' noise through the momentum falls as the window grows
#: and nothing else grows with it (no differentiator bias); measured on 30 NMPC swings after
#: calibration: ±3 / ±10 / ±25 / ±40 samples MAX 201 / 139 / 24 / 26 kg (ends not averaged
#: for the first three), ramp 1 / 10 at ±25: 24.3 / 23.6 kg.
BALANCE_HALF_WINDOW = 25
BALANCE_RAMP = 10


def rate_variance(dataset: Dataset) -> float:
    """White-noise variance of the measured joint rates, from their second differences
    (var(Δ²x) = 6σ² for white noise on a smooth signal; the median makes it robust to jumps)."""
    rates = dataset.frame[[SIGNALS[i] for i in RATES[:3]]].to_numpy(float)
    d2 = np.diff(rates, 2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if len(d2) < 10:
        return 0.0
    return float(np.median(d2**2) / 0.4549 / 6)  # median of χ²₁ = 0.4549


def pressure_noise_from_data(dataset: Dataset) -> float:
    """White noise of the pressure transmitters (Pa) from second differences of the measured
    pressures (as :func:`rate_variance`): needs no known payload, so any data will do; it sees
    the white noise and the aliased pump ripple, as the estimator does."""
    cols = [SIGNALS[i] for i in PRESSURES]
    x = dataset.frame[cols].to_numpy(float)
    d2 = np.diff(x, 2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if len(d2) < 10:
        return DEFAULT_PRESSURE_STD
    return float(np.sqrt(np.median(d2**2) / 0.4549 / 6))


def accel_variance(dataset: Dataset, half_window: int) -> float:
    """Variance of the differentiated accelerations from the rates' own white noise.

    The rate noise is estimated from the data (second differences of the measured rates:
    var(Δ²x) = 6σ² for white noise on a smooth signal), then passed through the least-squares
    slope: σ² / Σ t_k².
    """
    rates = dataset.frame[[SIGNALS[i] for i in RATES[:3]]].to_numpy(float)
    d2 = np.diff(rates, 2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if len(d2) < 10:
        return 0.0
    sigma2 = float(np.median(d2**2) / 0.4549 / 6)  # median of χ²₁ = 0.4549: robust to jumps
    dt = 1.0 / MACHINE_SENSORS.sample_rate
    k = np.arange(-half_window, half_window + 1) * dt
    return sigma2 / float(k @ k)


def accelerations(dataset: Dataset, half_window: int) -> np.ndarray:
    """Centred least-squares slope of the measured rates (n, 4), per experiment, rad/s²."""
    f = dataset.frame
    rates = f[[SIGNALS[i] for i in RATES]].to_numpy(float)
    out = np.full_like(rates, np.nan)
    exp = f["experiment"].to_numpy()
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    window = 2 * half_window + 1
    dt = 1.0 / MACHINE_SENSORS.sample_rate
    for a, b in zip(starts, np.r_[starts[1:], len(exp)]):
        if b - a < window:
            continue
        segment = rates[a:b]
        bad = ~np.isfinite(segment)
        if not bad.any():
            out[a:b] = savgol_filter(segment, window, 1, deriv=1, delta=dt, axis=0, mode="interp")
            continue
        # The edges' polynomial fit refuses a non-finite value (one NaN rate among the first or
        # last samples crashed train and zero): slope the filled rates, then mark every slope
        # whose window (at the edges, the first or last whole window) held a bad sample.
        slope = savgol_filter(np.where(bad, 0.0, segment), window, 1, deriv=1, delta=dt, axis=0,
                              mode="interp")
        touched = np.stack([np.convolve(bad[:, j], np.ones(window), mode="same") > 0
                            for j in range(bad.shape[1])], axis=1)
        touched[:half_window] |= bad[:window].any(axis=0)
        touched[-half_window:] |= bad[-window:].any(axis=0)
        out[a:b] = np.where(touched, np.nan, slope)
    return out


#: A sample whose angle or rate jumps more than this many robust noise stds (of the second
#: difference) is a glitch to :func:`imu_sensitivities`: arm motion's own second differences stay
#: below 1 % of it (a jerk of 340 rad/s³ would reach it).
GLITCH_SIGMAS = 8.0


def _glitches(x: np.ndarray, experiment: np.ndarray, half_window: int) -> np.ndarray:
    """Rows of ``x`` (angles and rates) near a one-frame glitch: a second difference beyond
    :data:`GLITCH_SIGMAS` robust stds, widened by ``half_window`` (the derived accelerations see
    it that far). A rate glitch would otherwise step the integrated rate for the rest of its run."""
    d2 = np.full_like(x, 0.0)
    d2[1:-1] = x[2:] - 2 * x[1:-1] + x[:-2]
    same = np.r_[False, experiment[2:] == experiment[:-2], False] & np.r_[False, experiment[1:-1] == experiment[:-2], False]
    d2[~same] = 0.0
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(d2) & same[:, None]
        scale = np.array([np.median(np.abs(d2[finite[:, c], c])) / 0.6745 if finite[:, c].any() else np.inf
                          for c in range(x.shape[1])])
        bad = np.any(np.abs(d2) > GLITCH_SIGMAS * np.maximum(scale, 1e-12), axis=1)
    # a glitch's neighbours carry its second difference too; the accelerations ±half_window
    return correlate1d(bad.astype(float), np.ones(2 * half_window + 3), mode="constant") > 0


def imu_sensitivities(dataset: Dataset, half_window: int = CALIBRATION_HALF_WINDOW,
                      machine=None) -> tuple[np.ndarray, np.ndarray]:
    r"""The link IMUs' acceleration sensitivities, read off their own signals.

    An inclination IMU's angle and its gyro's rate pass the same output filter, so the angle
    minus the integrated rate holds neither the lag nor the motion, only what the fusion's
    accelerometer leaks, an offset and the gyro bias's ramp. Per arm joint :math:`j` (a
    relative angle: the difference of two link IMUs, the boom's against the house),

    .. math:: \tilde q_j(t) - \int_0^t \tilde{\dot q}_j\,dt = k_j a_j - k_{j-1} a_{j-1}
              + c + b\,t + \varepsilon,

    with :math:`a_j` the link's absolute angular acceleration (the sum of the relative ones,
    derived from the rates as in calibration), :math:`c, b` per run of contiguous samples (a
    run ends at a non-finite sample, an angle outside ``machine``'s range or a one-frame glitch,
    :func:`_glitches`: a rate glitch would step the integral for the rest of the run). Least
    squares over the three joints at once, the nuisances projected out per run. Needs no
    known payload and no machine file; on ten calibration swings of the field preset it finds
    0.0076-0.0088 / 0.0075-0.0077 / 0.0077-0.0078 s² where the simulator has 0.0076 (three
    draws).

    With the sensitivities' prior (:data:`IMU_PRIOR_STD`, mean 0): a joint the data hardly
    accelerate keeps about 0 and the prior's std.

    Returns
    -------
    k, std : ndarray
        Sensitivities of the boom, dipper and bucket IMUs (s²) and their posterior std.
    """
    f = dataset.frame
    values = f[list(SIGNALS)].to_numpy(float)
    qdd = accelerations(dataset, half_window)
    dt = 1.0 / MACHINE_SENSORS.sample_rate
    exp = f["experiment"].to_numpy()
    ok = np.all(np.isfinite(values), axis=1) & np.all(np.isfinite(qdd), axis=1)
    if machine is not None:
        ranges = machine.angle_ranges
        ok &= np.all((ranges[:, 0] <= values[:, ANGLES]) & (values[:, ANGLES] <= ranges[:, 1]), axis=1)
    ok &= ~_glitches(values[:, [*ANGLES, *RATES[:3]]], exp, half_window)
    runs = np.cumsum(np.r_[True, (exp[1:] != exp[:-1]) | ~ok[:-1]])
    absolute = np.cumsum(qdd[:, :3], axis=1)
    ys, xs = [], []
    for run in np.unique(runs[ok]):
        idx = np.flatnonzero((runs == run) & ok)
        if len(idx) < 4 * half_window:
            continue
        v, a = values[idx], absolute[idx]
        t = np.arange(len(idx)) * dt
        rates = v[:, list(RATES[:3])]
        integral = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (rates[1:] + rates[:-1]) * dt, axis=0)])
        Q, _ = np.linalg.qr(np.column_stack([np.ones_like(t), t - t.mean()]))
        for j in range(3):
            x = np.zeros((len(idx), 3))
            x[:, j] = a[:, j]
            if j:
                x[:, j - 1] = -a[:, j - 1]
            y = v[:, ANGLES[j]] - integral[:, j]
            ys.append(y - Q @ (Q.T @ y))
            xs.append(x - Q @ (Q.T @ x))
    prior = IMU_PRIOR_STD[1:4]
    if not ys:
        return np.zeros(3), prior.copy()
    y, X = np.concatenate(ys), np.vstack(xs)
    # with the sensitivities' prior (mean 0): a joint the motions hardly accelerate keeps about
    # 0 instead of a ratio of noises; where they do move it the prior weighs ~1e-6 of the data
    residual = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    sigma2 = max(float(residual @ residual) / max(len(y) - 3, 1), 1e-30)
    posterior = np.linalg.inv(X.T @ X / sigma2 + np.diag(1.0 / prior**2))
    return posterior @ (X.T @ y) / sigma2, np.sqrt(np.diag(posterior))


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

    @staticmethod
    def prior_std(relative: float) -> np.ndarray:
        """Prior standard deviation of each entry of ``z``: ``relative`` (a share) for every
        calibrated parameter, then :data:`OFFSET_PRIOR_STD` and :data:`IMU_PRIOR_STD` (SI units)."""
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
        """Residuals (n, 3), Jacobian (n, 3, nz), lever, speed, stiction (n, 3) of samples."""
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
        The window's lever is its centre's."""
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
        # rule of :meth:`weights` (skipping every window with a still sample kept 11 % of the
        # dipper's and bucket's windows: NMPC swings MAX 23.6 kg, this 16.9 kg on 30 swings)
        stick = np.lib.stride_tricks.sliding_window_view(stiction, 2 * half + 1, axis=0).max(axis=-1)
        # (with the friction's sign held from the last sliding the still windows still carry
        # their variance: without it they outweighed the moving ones, two calibration draws:
        # hand-made trajectories 21.0 / 20.6 → 76.3 / 53.3 kg mean MAX, work cycles 70.5 / 30.5
        # → 97.4 / 50.4 kg)
        still = (np.abs(speed) < self._still_speed).astype(float)
        share = correlate1d(still, w, axis=0, mode="constant")[centres] / w.sum()
        speed_rule = np.where(share > 0, 0.0, np.inf)
        # the still samples' friction is one error shared by the window (and its neighbours):
        # τ times its window variance, as a per-sample-equivalent (the variance weights() adds
        # is stiction²/3). Counted once per window, the still windows — 88 % of the dipper's
        # and bucket's on ten calibration swings — outweighed the moving ones τ-fold.
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
        identified, as a variance component: 1.0-2.1 on five draws of ten calibration swings,
        1.1-1.7 at the true machine.
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
        """Rod speeds (n, 3) of the raw measured angles and rates at the file's parameters."""
        q = np.zeros((len(values), 4))
        q[:, :3] = values[:, ANGLES]
        f = column_map(compiled_function("cylinder_speeds"), len(values))
        return f(q.T, values[:, RATES].T, self.p_file)[0].T

    def moving_samples(self, values: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Samples on which each arm cylinder (boom, dipper, bucket) moves: its rod speed at the
        identified machine above the 3 Stribeck velocities below which calibration treats it as
        stuck (what the calibration can learn that cylinder's friction and geometry from)."""
        n = len(values)
        if n == 0:
            return np.zeros(3, int)
        out = column_map(kernel_function("differentiated"), n)(
            values.T, qdd.T, self.p, self.offset_vector(), np.asarray(self.imu, float))[0]
        return np.sum(np.abs(out[9:12].T) >= self._still_speed, axis=0)

    def weights(self, lever, speed, stiction, low_speed: str, pressure_std: float) -> np.ndarray:
        """Inverse residual variances (n, 3) for the low-speed choice (0: sample skipped)."""
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
              estimate_noise: bool = True, runs: np.ndarray | None = None) -> None:
        """Bayesian Levenberg–Marquardt on the entries ``free`` of z (the others stay), in place.

        A plain Gauss–Newton step overshoots where the slow lifts leave directions weakly
        determined and the geometry is non-linear; the damping λ grows until a step lowers the
        posterior cost, and shrinks after each success.
        """
        z = self.z.copy()
        scale = prior_std[free]  # solve in prior-normalised units u = (z - μ)/σ: well conditioned

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
            u = (z[free] - prior_mean[free]) / scale
            cost = float(np.sum(w * r**2) + u @ u)
            return cost, r, np.where(ok[..., None], J[:, :, free] * scale, 0.0), w, (lever, speed)

        cost, r, Js, w, kin = linearise(z)
        if estimate_noise:
            self.pressure_std = self._noise_from_residuals(r, *kin)
            cost, r, Js, w, kin = linearise(z)
        fixed["w"] = w
        damping = 1e-4
        self.cost_trace = [cost]
        for _ in range(iterations):
            u = (z[free] - prior_mean[free]) / scale
            H = np.einsum("nja,nj,njb->ab", Js, w, Js) + np.eye(len(free))
            g = np.einsum("nja,nj,nj->a", Js, w, r) + u
            for _ in range(6):
                trial = z.copy()
                trial[free] -= scale * np.linalg.solve(H + damping * np.diag(np.diag(H)), g)
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
        cov[np.ix_(free, free)] = np.linalg.inv(H) * np.outer(scale, scale)
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
        its own)."""
        return CalibratedKernel(self, half_window, forgetting, low_speed, outside_calibration, wait_for_boom,
                                new_load)


def calibration_arrays(dataset: Dataset, half_window: int, machine=None):
    """Measured signals, derived accelerations, payloads and run ids of the valid samples
    (equal run ids: contiguous samples of one experiment)."""
    values = dataset.frame[list(SIGNALS)].to_numpy(float)
    qdd = accelerations(dataset, half_window)
    payload = dataset.frame["payload"].to_numpy(float) if "payload" in dataset.frame else np.zeros(len(values))
    ok = np.all(np.isfinite(values), axis=1) & np.all(np.isfinite(qdd), axis=1) & np.isfinite(payload)
    if machine is not None:
        ranges = machine.angle_ranges
        a = values[:, ANGLES]
        ok &= np.all((ranges[:, 0] <= a) & (a <= ranges[:, 1]), axis=1)
    exp = dataset.frame["experiment"].to_numpy()
    # a new run wherever a sample is dropped or an experiment starts
    breaks = np.r_[True, (exp[1:] != exp[:-1]) | ~ok[:-1]]
    runs = np.cumsum(breaks)
    return values[ok], qdd[ok], payload[ok], runs[ok]


def calibrate(arm: HydraulicArmModel, dataset: Dataset, prior_std: float = 0.05,
              low_speed: str = "downweight", half_window: int = 5,
              pressure_std: float | None = None, balance: str = "differentiated",
              imu_leak: str = "auto") -> MachineCalibration:
    """Identify parameters, offsets and pressure noise from known-payload data (module doc).

    ``pressure_std`` None: estimated from the data; else fixed (Pa). ``balance``: per-sample
    residuals with differentiated accelerations, or the momentum balance over windows.
    ``imu_leak``: :data:`IMU_LEAK_CHOICES`.
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
        # four acceleration sensitivities free the parameters wander (house sensitivity
        # 0.096 s² against the simulator's 0.005; NMPC swings MAX 218 kg against 24 kg with the
        # lag alone, 30 swings); the links' leak read off their own signals and held (the
        # default) took five draws × 40 from efficiency 2.44 to 2.23 on NMPC swings and 2.96 to
        # 2.28 on work cycles (README). The house's read off the IMU's
        # own signals (pitch against slew rate², 0.0051 s² where the simulator has 0.0051) and
        # held was tried: five draws, hand-made trajectories 18.2 -> 24.7 kg mean MAX (100 ->
        # 93.5 % within 1 %; the first estimate at the slew's start), planned swings 41.8 ->
        # 39.0 kg; not kept. A window with a standstill
        # carries its still share of unknown friction (:meth:`MachineCalibration.evaluate_windows`).
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
                 half_window: int = 5, drift_std: np.ndarray = OFFSET_PRIOR_STD) -> tuple[int, np.ndarray]:
    """Re-estimate only the sensor offsets from empty-bucket data, in place (module doc).
    Returns how many samples it used (the valid ones: finite, angles within range) and, per
    arm cylinder, how many of them it moved on (a still cylinder's offsets are not checked)."""
    values, qdd, payload, runs = calibration_arrays(dataset, CALIBRATION_HALF_WINDOW, cal.arm.machine)
    cal.accel_var = accel_variance(dataset, CALIBRATION_HALF_WINDOW)
    if len(values) < 50:
        raise EstimatorError(f"the zero check needs at least 50 valid samples, the data have {len(values)}")
    if np.any(payload != 0):
        raise EstimatorError("the zero check needs an empty bucket (the data's payload column is not 0)")
    n_delta, n_off = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)
    free = np.arange(n_delta, n_delta + n_off)
    momentum = cal.balance == "momentum"
    cal.solve(values, qdd, payload, free, cal.z.copy(),
              np.r_[np.ones(n_delta), drift_std, np.ones(len(IMU_PARAMETERS))],
              "skip", iterations=4, estimate_noise=False,
              runs=runs if momentum else None)
    return len(values), cal.moving_samples(values, qdd)


@lru_cache(maxsize=2)
def kernel_function(balance: str = "differentiated") -> ca.Function:
    """One streaming sample, compiled, from raw signals (15), q̈ (4), p, the offsets (one per
    signal) and the IMU dynamics (:data:`IMU_PARAMETERS`), corrected as in calibration.

    ``differentiated``: residual τ_p − τ0 (3), φ (3), lever, rod speed and stiction torque (3
    each). ``momentum``: the momentum-balance terms (P0, Pm, I0, Fm) (12), lever, rod speed,
    stiction and the rates' gain into the momentum (3 each); q̈ serves the IMU correction only.
    """
    x = ca.SX.sym("x", len(SIGNALS))
    qdd = ca.SX.sym("qdd", 4)
    p = ca.SX.sym("p", len(HYDRAULIC_PARAMETER_NAMES))
    offsets = ca.SX.sym("offsets", len(SIGNALS))
    imu = ca.SX.sym("imu", len(IMU_PARAMETERS))
    if balance == "momentum":
        A, lever, speed, stiction, gain = _momentum_terms(x, qdd, p, offsets, imu)
        out = ca.vertcat(A, lever, speed, stiction, gain)
        name = "cal_machine_momentum_kernel"
    else:
        q, qd, tilt, pressures = _corrected_signals(x, qdd, offsets, imu)
        residual, phi, lever, speed, stiction = hydraulic_symbolic().functions["pressure_regression"](
            q, qd, qdd, tilt, pressures, p)
        out = ca.vertcat(residual, phi, lever, speed, stiction)
        name = "cal_machine_kernel"
    function = ca.Function(name, [x, qdd, p, offsets, imu], [out])
    from excavator_payload.model.codegen import native

    return native(function)


class CalibratedKernel(PressureRegression):
    """:class:`PressureRegression` with the identified parameters, offsets and noise.

    Streaming in tens of microseconds: the window of samples is a doubled ring buffer (the
    window is always one contiguous slice), the centred slope a fixed weight vector (uniform
    sampling: the base class resets on gaps), and one compiled CasADi call per sample.

    The weights are those of ``inverse-dynamics`` (pressure noise through the geometry, plus
    stiction near standstill). Adding the differentiator's noise through ∂r/∂q̈ (for the boom
    larger than the pressure noise) was measured *worse* (mean MAX 116 against 97 kg on 15
    swings): it hands the weight to the bucket joint, whose linkage the calibration knows least.
    Adding the slope error at a kink of the rates (half the difference of the two half-windows'
    slopes, through ∂r/∂q̈) was mixed on 20 experiments each: NMPC swings mean MAX 31.7 → 28.2
    kg but RMS 11.2 → 15.4 kg, work cycles 52.2 → 54.4 kg; not used.
    """

    def __init__(self, cal: MachineCalibration, half_window: int, forgetting: float, low_speed: str,
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
        if outside_calibration == "skip":
            limited = np.array(COVERAGE_JOINTS)
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
        self._new_load_min = NEW_LOAD_MIN_SHARE * float(cal.arm.machine.rated_payload)
        self._changing_min = CHANGING_MIN_SHARE * float(cal.arm.machine.rated_payload)
        self.model_std = float(getattr(cal, "model_std", 0.0))  # kg, in σ beside I^-1/2
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
        length = getattr(self, "_width", 1) + 1
        self._ring = np.zeros((2 * length, len(SIGNALS)))
        self._ring_used = np.zeros(2 * length, bool)
        self._count = 0
        b = getattr(self, "_balance_len", 1)  # reset() runs in the base __init__ before it is set
        self._terms = np.zeros((2 * b, getattr(self, "_n_out", 24)))  # per-sample balance terms, doubled as the ring
        self._terms_used = np.zeros(2 * b, bool)
        self._terms_inside = np.zeros((2 * b, 3), bool)  # each sample's joints inside the coverage
        self._terms_count = 0
        self.boom_weighed = False  # a window with weight on the boom joint seen (--wait-for-boom)
        self.num_short = 0.0  # the short memory of the new-load test (--new-load)
        self.info_short = 0.0
        self.new_loads = 0  # new loads detected since the last reset
        self.changing = False  # the short memory has left the whole one (status load_changing)

    @property
    def ready(self) -> bool:
        """Whether an estimate may be reported (``--wait-for-boom``): while the boom has stood
        still its seals hold an unknown stiction force (≈ 470 kg of payload), so the weighing
        rests on the dipper and bucket, whose calibration at the poses of a cut is least sure."""
        return self.boom_weighed or not self.wait_for_boom

    def restart_window(self) -> None:
        self._count = 0
        self._terms_count = 0

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
        """Each joint's angle inside the range calibration covered (``--outside-calibration``)."""
        angles = sample[ANGLES]
        return (angles >= self._raw_low) & (angles <= self._raw_high)

    def update(self, time: float, values: np.ndarray) -> bool:
        # ring of the window (2·half_window + 1 samples) and the newest, not yet judged sample,
        # stored twice so that the window is always one contiguous slice
        w = self._width
        length = w + 1
        pos = self._count % length
        self._ring[pos] = self._ring[pos + length] = values
        self._ring_used[pos] = self._ring_used[pos + length] = True
        self._count += 1
        self.rejected = False
        if self.judge and self._count >= 3:  # the sample before this one, between its neighbours
            mid, before = (pos - 1) % length, (pos - 2) % length
            if self._spike(self._ring[before], self._ring[mid], values):
                self._ring[mid] = self._ring[mid + length] = 0.5 * (self._ring[before] + values)
                self._ring_used[mid] = self._ring_used[mid + length] = False
                self.rejected = True
        if self._count < length:
            return False
        # the window ends on the sample before this one: every sample in it has been judged
        centre_used = self._ring_used[pos + 1 + self.half_window]
        if not centre_used and self.balance != "momentum":
            return False  # a rejected sample's slot: part of the window, never regressed
        window = self._ring[pos + 1:pos + 1 + w]
        centre = window[self.half_window]
        out = self._call(centre, self._slope @ window[:, RATES])
        if self.balance != "momentum":
            residual, phi, lever, speed, stiction = out[0:3], out[3:6], out[6:9], out[9:12], out[12:15]
            wt = np.where(self._used(speed) & self._inside(centre), 1.0 / self._variance(lever, speed, stiction), 0.0)
            self.boom_weighed = self.boom_weighed or bool(wt[0] > 0.0)
            self._accumulate(float(wt @ (phi * residual)), float(wt @ (phi * phi)))
            return True
        # momentum: the terms of the differentiator window's centre (its q̈ serves the IMU
        # correction only) go into a second ring, the balance's window
        b = self._balance_len
        slot = self._terms_count % b
        self._terms[slot] = self._terms[slot + b] = out
        # a rejected sample's repaired slot stays in the balance (its interval is part of the
        # integral) but is never a window's centre
        self._terms_used[slot] = self._terms_used[slot + b] = centre_used
        self._terms_inside[slot] = self._terms_inside[slot + b] = self._inside(centre)
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
        # weighting by the still share, as calibration does, was worse: NMPC swings MAX 33 against
        # 17 kg, work cycles 201 against 66 kg on 30 each)
        # a joint outside its calibrated range anywhere in the window is not weighed
        inside = self._terms_inside[start:start + b].all(axis=0)
        wt = np.where(self._used(slowest) & inside,
                      1.0 / (self._variance(lever, slowest, stiction) + rate_var), 0.0)
        self.boom_weighed = self.boom_weighed or bool(wt[0] > 0.0)
        self._accumulate(float(wt @ (phi * residual)), float(wt @ (phi * phi)))
        return True

    def _accumulate(self, d_num: float, d_info: float) -> None:
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
        """
        self.num = self.forgetting * self.num + d_num
        self.info = self.forgetting * self.info + d_info
        if not self.new_load:
            return
        self.num_short = self._short_forgetting * self.num_short + d_num
        self.info_short = self._short_forgetting * self.info_short + d_info
        self.changing = False
        if self.ready and 0.0 < self.info_short < self.info:
            change = self.num_short / self.info_short - self.num / self.info
            spread = max(1.0 / self.info_short - 1.0 / self.info, 0.0)
            if abs(change) > max(self._new_load_min, NEW_LOAD_SIGMAS * math.sqrt(spread)):
                self.num = self.info = self.num_short = self.info_short = 0.0
                self.boom_weighed = False
                self.new_loads += 1
            else:
                self.changing = abs(change) > max(self._changing_min, CHANGING_SIGMAS * math.sqrt(spread))


# -- the estimator's machine-sensor-set side (CalibratedEstimator dispatches here) ------------

def angle_coverage(dataset: Dataset, offsets: np.ndarray) -> np.ndarray:
    """[low, high] (3, 2) of the boom, dipper and bucket angles the data cover, offsets
    (:meth:`MachineCalibration.offset_vector`) removed: :data:`COVERAGE_PERCENTILES` of the finite
    samples, widened by :data:`COVERAGE_MARGIN`.

    Where a joint's angle leaves this range the calibrated model extrapolates (the bucket's
    four-bar linkage above all: work cycles begin with the bucket open at −20…+10°, calibration
    swings keep it at −115…−30°), and ``--outside-calibration skip`` does not weigh that joint.
    """
    angles = dataset.frame[[SIGNALS[i] for i in ANGLES]].to_numpy(float) - offsets[ANGLES]
    out = np.tile([-NO_LIMIT, NO_LIMIT], (3, 1))
    for j in range(3):
        a = angles[np.isfinite(angles[:, j]), j]
        if len(a):
            lo, hi = np.percentile(a, COVERAGE_PERCENTILES)
            out[j] = (lo - COVERAGE_MARGIN, hi + COVERAGE_MARGIN)
    return out


def coverage_notes(estimator, dataset: Dataset) -> list[str]:
    """A note per limited joint (:data:`COVERAGE_JOINTS`) whose angle leaves the range the
    calibration covered on some of ``dataset``'s samples, while ``--outside-calibration`` skips it:
    the weighing then rests on the other joints there."""
    kernel = estimator._pressure
    if getattr(kernel, "outside_calibration", "use") != "skip":
        return []
    notes = []
    for j, joint in enumerate(("boom", "dipper", "bucket")):
        if not COVERAGE_JOINTS[j]:
            continue
        a = dataset.frame[SIGNALS[ANGLES[j]]].to_numpy(float)
        a = a[np.isfinite(a)]
        if not len(a):
            continue
        outside = float(np.mean((a < kernel._raw_low[j]) | (a > kernel._raw_high[j])))
        if outside > 0:
            low, high = estimator.calibration.angle_coverage[j] / DEG
            notes.append(f"{estimator.name}: the {joint} angle lay outside the range the calibration "
                         f"motions covered ({low:.0f}…{high:.0f}°) on {100 * outside:.1f} % of the samples; "
                         f"the {joint} is not weighed there. Calibrate with motions that cover the "
                         f"{joint} angles you work at (or train with --outside-calibration use)")
    return notes


def waiting_notes(estimator, estimates) -> list[str]:
    """A note when ``--wait-for-boom`` kept whole experiments of ``estimates`` (the frame
    ``estimate`` returns) without an estimate: their boom never moved through a 0.5 s window
    without a stop, so the weighing never started. Without the note such a motion's NaN column
    looks like a broken sensor."""
    kernel = estimator._pressure
    if not getattr(kernel, "wait_for_boom", False) or estimates is None or not len(estimates):
        return []
    estimate = estimates["payload_estimate"].to_numpy(float)
    status = estimates["status"].astype(str).to_numpy()
    experiments = estimates["experiment"].to_numpy()
    silent = []
    names = list(dict.fromkeys(experiments.tolist()))
    for name in names:
        rows = experiments == name
        # warming_up on most samples: not an experiment lost to invalid input or one too short
        if not np.isfinite(estimate[rows]).any() and np.mean(status[rows] == "warming_up") > 0.5:
            silent.append(name)
    if not silent:
        return []
    shown = ", ".join(str(e) for e in silent[:5]) + (", …" if len(silent) > 5 else "")
    return [f"{estimator.name}: no estimate in {len(silent)} of {len(names)} experiments ({shown}): the "
            f"boom never moved for {2 * BALANCE_HALF_WINDOW / MACHINE_SENSORS.sample_rate:.1f} s "
            "without a stop, and the weighing waits until it has weighed the boom (a standing "
            "boom's seals hold an unknown force). Move the boom while weighing, or train with "
            "--wait-for-boom no to weigh from the dipper and bucket"]


def hardly_moved(moving: np.ndarray, minimum: int) -> list[tuple[str, int]]:
    """(joint, moving samples) of the arm cylinders that moved on fewer than ``minimum`` samples
    (:meth:`MachineCalibration.moving_samples`): what fit and zero warn about."""
    return [(joint, int(k)) for joint, k in zip(("boom", "dipper", "bucket"), moving) if k < minimum]


def _machine_arm(estimator) -> HydraulicArmModel:
    if getattr(estimator.machine, "kind", None) != "hydraulic":
        raise EstimatorError(f"{estimator.name}: data of the machine sensor set need a hydraulic "
                             f"machine file, not '{estimator.machine.name}' (e.g. --machine "
                             "cat345c-hydraulic-3pct)")
    return HydraulicArmModel(estimator.machine, compiled=False)


#: Share of held-out calibration samples whose error the reported σ must cover twice
#: (:func:`cross_validated_model_std`): σ = √(1/I + s_model²) with 2σ ⊇ 95 % of them.
SIGMA_COVERAGE = 0.95
#: Fewest calibration experiments for the cross-check (two folds of at least two motions).
MIN_CROSS_EXPERIMENTS = 4


def cross_validated_model_std(estimator, dataset: Dataset, calibrate_fold) -> float:
    r"""The model error's standard deviation (kg) that σ must carry beside :math:`I^{-1/2}`.

    :math:`I^{-1/2}` is the estimate's spread from the sensor noise alone; the calibrated model
    itself is only as good as a handful of motions made it, and on other motions its error
    does not shrink with information (a bias per pose). Two-fold cross-fit: the calibration
    motions are split in two halves (alternating), each half calibrates a model
    (``calibrate_fold(subset) -> MachineCalibration``) that weighs the other half; :math:`s` is
    the least value with :math:`|e| \le 2\sqrt{1/I + s^2}` on :data:`SIGMA_COVERAGE` of the
    held-out ``ok`` samples after their first second. Half the motions calibrate worse than all
    of them: the floor errs on the safe side. 0 with fewer than :data:`MIN_CROSS_EXPERIMENTS`.
    """
    import copy

    ids = list(dataset.experiment_ids)
    if len(ids) < MIN_CROSS_EXPERIMENTS:
        return 0.0
    errors, variances = [], []
    for train, test in ((ids[0::2], ids[1::2]), (ids[1::2], ids[0::2])):
        fold = copy.copy(estimator)  # fit is still running: make the copy estimate-ready
        fold.fitted, fold.sensor_set, fold.plausible_low = True, dataset.sensor_set, None
        fold._sentinel = None
        _install(fold, calibrate_fold(dataset.subset(train)))
        fold.reset()
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


def _install(estimator, cal: MachineCalibration) -> None:
    from excavator_payload.estimators.classical.pressure_regression import spike_threshold

    estimator.calibration = cal
    estimator._pressure = cal.kernel(estimator.options["half_window"], estimator.options["forgetting"],
                                     estimator.options["low_speed"], estimator.options["outside_calibration"],
                                     estimator.options["wait_for_boom"], estimator.options["new_load"])
    estimator._pressure.spike_threshold = spike_threshold(estimator.difference_scale)
    estimator._warm_info = 1.0 / float(estimator.options["warmup_std"]) ** 2


def fit_estimator(estimator, dataset: Dataset) -> None:
    """``CalibratedEstimator.fit`` on machine-sensor-set data: :func:`calibrate` and install."""
    from excavator_payload.simulation.machine_sensors import get_machine_noise

    from excavator_payload.estimators.classical.calibrated import calibration_subset

    arm = _machine_arm(estimator)
    dataset, ids = calibration_subset(estimator, dataset)
    if "payload" not in dataset.frame or not np.all(np.isfinite(dataset.frame["payload"].to_numpy(float))):
        raise EstimatorError(f"{estimator.name}: calibration experiments need known payloads")
    name = estimator.options["noise"]
    pressure_std = None
    if name != "auto":  # a preset named explicitly overrides the noise estimated from the data
        pressure_std = get_machine_noise(name).pressure_noise
    prior = estimator.options["prior_std"]
    prior = 0.05 if prior == 0.1 else prior  # 0.1 is the thesis set's default

    def calibrate_on(subset: Dataset) -> MachineCalibration:
        """The calibration of ``subset`` with the estimator's options, and the angles it covers
        (all the motions, and each half of them for the cross-check)."""
        fitted = calibrate(arm, subset, prior, estimator.options["low_speed"], estimator.options["half_window"],
                           pressure_std, estimator.options["balance"], estimator.options["imu_leak"])
        fitted.angle_coverage = angle_coverage(subset, fitted.offset_vector())
        return fitted

    cal = calibrate_on(dataset)
    from excavator_payload.estimators.classical.pressure_regression import difference_scale

    # a cylinder the calibration motions hardly moved keeps the file's numbers (e.g. lifts that
    # move the boom only): say so rather than weigh with them silently
    moving, n_valid = cal.moving
    if n_valid < len(dataset.frame):  # dropped rows: not finite, or outside the angle ranges
        estimator.fit_warnings.append(
            f"{estimator.name}: {len(dataset.frame) - n_valid} of {len(dataset.frame)} calibration "
            "samples not used (a signal not finite, or an angle outside the machine's range)")
    still = [f"{joint} {k}" for joint, k in hardly_moved(moving, MIN_MOVING_SAMPLES)]
    if still:
        estimator.fit_refusals.append(
            f"{estimator.name}: cylinders that hardly moved in the calibration data (moving samples: "
            f"{', '.join(still)} of {n_valid}; {MIN_MOVING_SAMPLES} or more wanted): what it "
            "learned of them is mostly the machine file's. Calibrate with motions that move the "
            "boom, dipper and bucket (and slew)")

    estimator.noise_name = "estimated" if pressure_std is None else name
    estimator.calibration_experiments = [int(i) for i in ids]
    estimator.difference_scale = difference_scale(dataset)
    if estimator.options["model_std"] == "cross":
        cal.model_std = cross_validated_model_std(estimator, dataset, calibrate_on)
        rated = float(arm.machine.rated_payload)
        if len(ids) >= MIN_CROSS_EXPERIMENTS:
            estimator.fit_report.append(
                f"calibration: each half of the calibration motions weighs the other within "
                f"±{2 * cal.model_std:.0f} kg (95 %) beyond the sensor noise; that model error is "
                "carried in every estimate's sigma")
        if 2 * cal.model_std > 0.01 * rated:
            estimator.fit_refusals.append(
                f"{estimator.name}: each half of the calibration motions weighs the other only within "
                f"±{2 * cal.model_std:.0f} kg (95 %), more than 1 % of the rated payload "
                f"({0.01 * rated:.0f} kg): add calibration motions with known loads that move the boom, "
                "dipper and bucket through the poses you work at, while slewing")
        if len(ids) < MIN_CROSS_EXPERIMENTS:
            estimator.fit_warnings.append(
                f"{estimator.name}: {len(ids)} calibration motions cannot check themselves (the σ "
                f"of each estimate then carries the sensor noise only; {MIN_CROSS_EXPERIMENTS} or "
                "more calibrate a model error into it)")
    low, high = cal.angle_coverage[:, 0] / DEG, cal.angle_coverage[:, 1] / DEG
    estimator.fit_report.append(
        "calibration covers boom {:.0f}…{:.0f}°, dipper {:.0f}…{:.0f}°, bucket {:.0f}…{:.0f}° "
        "(beyond, the bucket is not weighed)".format(low[0], high[0], low[1], high[1], low[2], high[2]))
    _install(estimator, cal)


def zero(estimator, dataset: Dataset) -> list[str]:
    """Re-estimate a fitted machine-set ``calibrated`` estimator's sensor offsets, in place.
    Returns warnings (samples it could not use), as fit's ``fit_warnings``; sets the estimator's
    ``zero_report`` (the predicted weighing error, one line) and ``zero_refusals`` (why not to
    weigh with it: ``excavator-payload zero`` refuses unless ``--force``), from
    :func:`~excavator_payload.estimators.classical.zero_quality.zero_quality`."""
    from excavator_payload.estimators.classical.zero_quality import zero_quality

    if getattr(estimator, "calibration", None) is None:
        raise EstimatorError(f"zero needs a 'calibrated' model fitted on machine-sensor-set data, "
                             f"not a '{estimator.name}' model")
    if dataset.sensor_set.name != "machine":
        raise EstimatorError(f"zero needs machine-sensor-set data, these are of the "
                             f"{dataset.sensor_set.name} sensor set")
    used, moving = zero_offsets(estimator.calibration, dataset, estimator.options["low_speed"],
                                estimator.options["half_window"])
    _install(estimator, estimator.calibration)
    estimator.reset()
    quality = zero_quality(estimator.calibration, dataset, moving)
    estimator.zero_quality = quality
    estimator.zero_report = [quality.report()]
    estimator.zero_refusals = [f"zero: {reason}" for reason in quality.refusals]
    n = len(dataset.frame)
    warnings = []
    if used < n:
        warnings.append(f"zero: {n - used} of {n} samples not used (a signal not finite, or an angle "
                        "outside the machine's range)")
    # a cylinder that stood still tells nothing of its pressure offsets: they keep the values of
    # the calibration's session (one zero swing whose dipper moved 1.8° left the dipper's
    # offsets 2.9 bar off and the weighing 40 kg off, with the true machine file)
    rate = MACHINE_SENSORS.sample_rate
    still = [f"{joint} ({k / rate:.1f} s of motion)" for joint, k in hardly_moved(moving, MIN_ZERO_MOVING_SAMPLES)]
    if still:
        warnings.append(f"zero: cylinders that hardly moved: {', '.join(still)}; "
                        f"{MIN_ZERO_MOVING_SAMPLES / rate:.0f} s or more wanted. Their pressure offsets "
                        "were not checked and keep the calibration's values: repeat the zero check "
                        "moving the boom, dipper and bucket")
    offsets = estimator.calibration.offsets
    far = [f"{name} {value / 1e5:+.3g} bar" if name.endswith("_pressure") else f"{name} {value / DEG:+.3g}°"
           for name, value, std in zip(OFFSET_SIGNALS, offsets, OFFSET_PRIOR_STD)
           if not abs(value) <= ZERO_OFFSET_WARNING * std]
    if far:
        warnings.append(f"zero: sensor offsets far beyond a working session's (more than "
                        f"{ZERO_OFFSET_WARNING:g}× their usual spread): {', '.join(far)}. A stuck, "
                        "mis-scaled or disconnected sensor in the zero check? Check those signals and "
                        "repeat it before weighing with this model")
    return warnings


def config(estimator) -> dict:
    """The JSON-able part of a ``calibrated`` estimator of the machine sensor set to save (the
    estimator's ``_config``): kernel, noise, calibration experiments, parameter names, balance
    form and pressure noise (Pa)."""
    return {"kernel": "calibrated_machine", "noise": estimator.noise_name,
            "calibration_experiments": estimator.calibration_experiments,
            "calibrated_parameters": list(CALIBRATED_PARAMETERS),
            "offset_signals": list(OFFSET_SIGNALS),
            "imu_parameters": list(IMU_PARAMETERS), "balance": estimator.options["balance"],
            "pressure_std": estimator.calibration.pressure_std}


def arrays(estimator) -> dict[str, np.ndarray]:
    """The arrays of a ``calibrated`` estimator of the machine sensor set to save (the estimator's
    ``_arrays``): the identified ``z`` and its covariance, the noise, the window inflation, the
    covered angle range and the difference scale."""
    cal = estimator.calibration
    return {"z": cal.z, "z_covariance": cal.covariance, "pressure_std": np.array([cal.pressure_std]),
            "rate_var": np.array([cal.rate_var]), "window_inflation": cal.window_inflation,
            "angle_coverage": cal.angle_coverage, "model_std": np.array([getattr(cal, "model_std", 0.0)]),
            "difference_scale": np.asarray(estimator.difference_scale, float)}


#: The largest magnitude :func:`restore` accepts in a saved calibration ``z`` (a pressure offset
#: of 10,000 bar; the preset's calibrations stay below 3e5).
MAX_CALIBRATION_VALUE = 1e9


def restore(estimator, cfg: dict, saved) -> None:
    """Rebuild ``estimator``'s calibration and kernel from what :func:`config` (``cfg``) and
    :func:`arrays` (``saved``) wrote; :class:`EstimatorError` when they are corrupt or of
    another version."""
    arm = _machine_arm(estimator)
    cal = MachineCalibration(arm)
    z = np.asarray(saved["z"], float)
    cov = np.asarray(saved["z_covariance"], float)
    std = np.asarray(saved["pressure_std"], float)
    if (z.shape != cal.z.shape or cov.shape != (len(z), len(z)) or std.shape != (1,)
            or not np.all(np.isfinite(z)) or not np.isfinite(std[0]) or std[0] < 0
            # parameter moves, offsets (Pa, rad) and IMU terms: a real calibration's are < 1e6;
            # 1e300 passed, left every state non-finite and broke the C export with casadi_inf
            or not np.all(np.abs(z) < MAX_CALIBRATION_VALUE)
            or list(cfg.get("calibrated_parameters", [])) != list(CALIBRATED_PARAMETERS)
            or list(cfg.get("offset_signals", OFFSET_SIGNALS)) != list(OFFSET_SIGNALS)
            or list(cfg.get("imu_parameters", IMU_PARAMETERS)) != list(IMU_PARAMETERS)):
        raise EstimatorError("saved machine calibration is corrupt or of another version")
    # The calibration belongs to the balance form it was fitted in: a momentum calibration
    # read as the per-sample form weighed a 2.5 t mean as 3.4 t, 'ok' (an edited option).
    if cfg.get("balance", estimator.options["balance"]) != estimator.options["balance"]:
        raise EstimatorError(f"saved machine calibration was fitted with --balance {cfg.get('balance')!r}, "
                             f"the options say {estimator.options['balance']!r}")
    cal.z, cal.covariance, cal.pressure_std = z, cov, float(std[0])
    cal.balance = estimator.options["balance"]
    if "rate_var" in saved:
        rate_var = np.asarray(saved["rate_var"], float).ravel()
        # a negative variance left every estimate warming_up, blamed on a boom that never moved
        if rate_var.shape != (1,) or not np.isfinite(rate_var[0]) or rate_var[0] < 0:
            raise EstimatorError("saved machine calibration is corrupt or of another version")
        cal.rate_var = float(rate_var[0])
    if "window_inflation" in saved:
        inflation = np.asarray(saved["window_inflation"], float).ravel()
        if inflation.shape != (3,) or not np.all(np.isfinite(inflation)) or np.any(inflation < 1):
            raise EstimatorError("saved machine calibration is corrupt or of another version")
        cal.window_inflation = inflation
    if "model_std" in saved:  # absent in models saved before it: σ from the sensor noise only
        model_std = np.asarray(saved["model_std"], float).ravel()
        if model_std.shape != (1,) or not np.isfinite(model_std[0]) or model_std[0] < 0:
            raise EstimatorError("saved machine calibration is corrupt or of another version")
        cal.model_std = float(model_std[0])
    if "angle_coverage" in saved:  # absent in models saved before it: no limit
        coverage = np.asarray(saved["angle_coverage"], float)
        if (coverage.shape != (3, 2) or not np.all(np.isfinite(coverage))
                or np.any(coverage[:, 0] >= coverage[:, 1])):
            raise EstimatorError("saved machine calibration is corrupt or of another version")
        cal.angle_coverage = coverage
    from excavator_payload.estimators.classical.inverse_dynamics import restore_difference_scale

    estimator.noise_name = str(cfg.get("noise", "estimated"))
    estimator.calibration_experiments = [int(i) for i in cfg.get("calibration_experiments", [])]
    estimator.difference_scale = restore_difference_scale(saved)
    _install(estimator, cal)
