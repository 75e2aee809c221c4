r"""Data preparation for the machine-set calibration and zero check.

From a :class:`~excavator_payload.data.dataset.Dataset` of the machine sensor set:

* **accelerations** (:func:`accelerations`): the centred least-squares slope of the measured
  rates over ``2·half_window + 1`` samples (Savitzky–Golay of order 1), per experiment;
* **noise from the data** (:func:`rate_variance`, :func:`pressure_noise_from_data`,
  :func:`accel_variance`): white-noise variances from second differences,
  :math:`\operatorname{var}(\Delta^2 x) = 6\sigma^2` on a smooth signal, robustly through the
  median of :math:`\chi^2_1` (0.4549);
* **valid samples and runs** (:func:`calibration_arrays`): finite samples inside the machine's
  angle ranges, a run id per contiguous stretch;
* **momentum windows** (:func:`momentum_windows`, :func:`balance_weights`,
  :func:`window_residuals`): the balance over ``c ± half`` samples, trapezoid rule, its ends
  averaged over ``ramp`` samples by summation by parts,

  .. math:: r = \frac{1}{W}\Big[\sum_j w_j I_{0,j}\,\Delta t + \sum_j u_j P_{0,j}\Big]
            - \frac{m}{W}\Big[-\sum_j u_j P_{m,j} - \sum_j w_j F_{m,j}\,\Delta t\Big];

* **the seals' presliding state** (:func:`held_direction`);
* **glitches and the IMUs' acceleration leak** (:func:`_glitches`, :func:`imu_sensitivities`,
  :func:`house_imu_sensitivity`);
* **the angles the calibration covered** (:func:`angle_coverage`).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d
from scipy.signal import savgol_filter

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATION_HALF_WINDOW, COVERAGE_MARGIN, COVERAGE_PERCENTILES, GLITCH_SIGMAS,
    HELD_SAMPLES, IMU_PRIOR_STD, NO_LIMIT, SIGNALS)
from excavator_payload.estimators.classical.pressure_regression import (  # noqa: F401 (pressure noise re-exported)
    ANGLES, PRESSURES, RATES, pressure_noise_from_data, white_noise_variance)


def held_direction(speed: np.ndarray, runs: np.ndarray, threshold: np.ndarray,
                   held: int = HELD_SAMPLES) -> np.ndarray:
    """Each cylinder's presliding state as calibration can know it: the sign of its rod speed
    where it slides faster than ``threshold`` (per cylinder), held through up to ``held``
    slower samples, then 0 — a standstill's friction is unknown within ± breakaway, mean 0, its
    spread in the windows' standstill variance — and 0 from the start of each run until the
    first sliding. ``speed`` (n, 3), ``runs`` a run id per row.

    Parameters
    ----------
    speed : numpy.ndarray
        Rod speeds of the three arm cylinders, (n, 3), m/s.
    runs : numpy.ndarray
        Run id per row (equal ids: contiguous samples).
    threshold : numpy.ndarray
        Sliding speed per cylinder (3), m/s.
    held : int
        Slower samples through which the last sign is held.

    Returns
    -------
    numpy.ndarray
        -1, 0 or +1 per row and cylinder, (n, 3).
    """
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
    contiguous samples (``runs``: a run id per row, equal ids = contiguous).

    Parameters
    ----------
    runs : numpy.ndarray
        Run id per row.
    half : int
        Samples each side of a window's centre.

    Returns
    -------
    numpy.ndarray
        The centres' row indices.
    """
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
    (I_j + I_{j+1})/2 Δt, so the integrand's weight is w_j = (v_j + v_{j-1})/2 (Σw = Σv).

    Parameters
    ----------
    half : int
        Samples each side of the window's centre.
    ramp : int
        Sample intervals over which the balance's weight rises and falls.
    """
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

    Parameters
    ----------
    A : numpy.ndarray
        Per-sample momentum terms (or their derivatives), (n, 12[, nz]).
    payload : numpy.ndarray
        Known payload per row, kg.
    centres : numpy.ndarray
        Row indices of the window centres (:func:`momentum_windows`).
    half : int
        Samples each side of a centre.
    dt : float
        Sample period, s.
    ramp : int
        Ramp of the balance weights (:func:`balance_weights`).

    Returns
    -------
    tuple of numpy.ndarray
        ``(r, -phi)``, one row per window, one column per joint.
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


def rate_variance(dataset: Dataset) -> float:
    """White-noise variance of the measured joint rates, from their second differences
    (var(Δ²x) = 6σ² for white noise on a smooth signal; the median makes it robust to jumps).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.

    Returns
    -------
    float
        Variance, (rad/s)² (0 with fewer than 10 usable rows).
    """
    variance = white_noise_variance(dataset.frame[[SIGNALS[i] for i in RATES[:3]]].to_numpy(float))
    return 0.0 if variance is None else variance


def accel_variance(dataset: Dataset, half_window: int) -> float:
    """Variance of the differentiated accelerations from the rates' own white noise.

    The rate noise is estimated from the data (second differences of the measured rates:
    var(Δ²x) = 6σ² for white noise on a smooth signal), then passed through the least-squares
    slope: σ² / Σ t_k².

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.
    half_window : int
        Samples each side of the differentiator's slope.

    Returns
    -------
    float
        Variance, (rad/s²)².
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
    """Centred least-squares slope of the measured rates (n, 4), per experiment, rad/s².

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.
    half_window : int
        Samples each side of the slope (NaN where the window does not fit an experiment).
    """
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


def _clean_runs(dataset: Dataset, half_window: int, judged: list, machine=None):
    """The signals, their accelerations, which samples are clean (finite, inside ``machine``'s
    angle ranges, no glitch in the ``judged`` columns) and the runs of consecutive clean samples
    of one experiment that a read-off fits on: (values, qdd, ok, runs).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.
    half_window : int
        Samples each side of the differentiator.
    judged : list of int
        Columns of :data:`SIGNALS` a glitch is looked for in.
    machine : HydraulicMachine or None
        Machine whose angle ranges end a run (None: no range check).
    """
    values = dataset.frame[list(SIGNALS)].to_numpy(float)
    qdd = accelerations(dataset, half_window)
    exp = dataset.frame["experiment"].to_numpy()
    ok = np.all(np.isfinite(values), axis=1) & np.all(np.isfinite(qdd), axis=1)
    if machine is not None:
        ranges = machine.angle_ranges
        ok &= np.all((ranges[:, 0] <= values[:, ANGLES]) & (values[:, ANGLES] <= ranges[:, 1]), axis=1)
    ok &= ~_glitches(values[:, judged], exp, half_window)
    runs = np.cumsum(np.r_[True, (exp[1:] != exp[:-1]) | ~ok[:-1]])
    return values, qdd, ok, runs


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
    known payload and no machine file (what it finds on simulated swings:
    docs/findings/machine-calibration.md).

    With the sensitivities' prior (:data:`IMU_PRIOR_STD`, mean 0): a joint the data hardly
    accelerate keeps about 0 and the prior's std.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data (no payload needed).
    half_window : int
        Samples each side of the differentiator for the accelerations.
    machine : HydraulicMachine or None
        Machine whose angle ranges end a run (None: no range check).

    Returns
    -------
    k, std : ndarray
        Sensitivities of the boom, dipper and bucket IMUs (s²) and their posterior std.
    """
    values, qdd, ok, runs = _clean_runs(dataset, half_window, [*ANGLES, *RATES[:3]], machine)
    dt = 1.0 / MACHINE_SENSORS.sample_rate
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


def house_imu_sensitivity(dataset: Dataset, half_window: int = CALIBRATION_HALF_WINDOW,
                          tilt: bool = True) -> tuple[float, float]:
    r"""The house IMU's acceleration sensitivity, read off its own pitch and roll.

    On ground that does not move, the house's true pitch and roll within a run depend only on
    the slew angle (constant on level ground), so what the slew's accelerations add is the
    fusion's leak (:func:`~.symbolic.house_imu_leak`, the kernel's definition),

    .. math:: \tilde\theta = k\,\dot\psi^2 + c_\theta + J_\theta(\psi)\,g + \varepsilon,
              \qquad \tilde\phi = -k\,\ddot\psi + c_\phi + J_\phi(\psi)\,g + \varepsilon,

    with :math:`c` per run and channel (offset and tilt at the run's start) and, with ``tilt``,
    a ground tilt :math:`g` (2) per run through the model's ``house_inclination`` linearised at
    level ground, :math:`\psi` the slew rate integrated over the run. Least squares with
    :data:`IMU_PRIOR_STD`'s house entry as prior (mean 0); runs as in :func:`imu_sensitivities`.
    A measurement (``benchmarks/house_imu_readoff.py``): the calibration does not use it (as the
    momentum form's prior mean it helped with empty-swing zeros and hurt with slow ones on fresh
    calibration draws, docs/findings/false-alarms.md).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data (no payload needed).
    half_window : int
        Samples each side of the differentiator for the slew acceleration.
    tilt : bool
        Model a ground tilt per run (the house's pitch and roll varying with the slew angle).

    Returns
    -------
    k, std : float
        Sensitivity (s²) and its posterior std.
    """
    from excavator_payload.estimators.classical.machine_calibration.symbolic import house_imu_leak
    from excavator_payload.estimators.classical.pressure_regression import PITCH, ROLL

    values, qdd, ok, runs = _clean_runs(dataset, half_window, [PITCH, ROLL, RATES[3]])
    dt = 1.0 / MACHINE_SENSORS.sample_rate
    exp = dataset.frame["experiment"].to_numpy()
    ys, xs, groups = [], [], []
    for run in np.unique(runs[ok]):
        idx = np.flatnonzero((runs == run) & ok)
        if len(idx) < 4 * half_window:
            continue
        rate = values[idx, RATES[3]]
        centripetal, tangential = house_imu_leak(rate, qdd[idx, 3])
        y = np.r_[values[idx, PITCH], values[idx, ROLL]]
        x = np.r_[centripetal, -tangential]
        n = len(idx)
        nuisance = [np.r_[np.ones(n), np.zeros(n)], np.r_[np.zeros(n), np.ones(n)]]
        if tilt:
            slew = np.r_[0.0, np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)]
            nuisance += list(_tilt_columns(slew).T)
        Q, _ = np.linalg.qr(np.column_stack(nuisance))
        ys.append(y - Q @ (Q.T @ y))
        xs.append(x - Q @ (Q.T @ x))
        groups.append(np.full(2 * n, exp[idx[0]]))
    prior = float(IMU_PRIOR_STD[4])
    if not ys:
        return 0.0, prior
    y, x, group = np.concatenate(ys), np.concatenate(xs), np.concatenate(groups)
    xx = float(x @ x)
    residual = y - x * (float(x @ y) / xx if xx > 0 else 0.0)
    sigma2 = max(float(residual @ residual) / max(len(y) - 1, 1), 1e-30)
    # the residuals are not white (the IMUs' filter, the differentiator): the data's variance
    # at least that of the experiments' own estimates about the whole (their scatter measured
    # ~10x the white-noise posterior std on the recommended motions)
    per = [(float(x[group == e] @ y[group == e]), float(x[group == e] @ x[group == e])) for e in np.unique(group)]
    k_all = float(x @ y) / xx if xx > 0 else 0.0
    if len(per) > 1 and xx > 0:
        # the sandwich (cluster-robust) variance of the pooled slope, experiments as clusters
        scatter = sum((xy_e - k_all * xx_e) ** 2 for xy_e, xx_e in per) / xx**2
        data_var = max(sigma2 / xx, scatter * len(per) / (len(per) - 1))
    else:
        data_var = sigma2 / xx if xx > 0 else np.inf
    variance = 1.0 / (1.0 / data_var + 1.0 / prior**2)
    return variance * k_all / data_var, float(np.sqrt(variance))


def _tilt_columns(slew: np.ndarray, step: float = 1e-4) -> np.ndarray:
    """(2n, 2): the house's (pitch; roll) per rad of ground pitch and roll at slew angles
    ``slew`` (the model's ``house_inclination`` at level ground, differenced)."""
    from excavator_payload.model.hydraulic import hydraulic_symbolic

    f = hydraulic_symbolic().functions["house_inclination"].map(len(slew))
    q = np.zeros((4, len(slew)))
    q[3] = slew
    level = np.asarray(f(q, np.zeros((2, len(slew)))))
    cols = [(np.asarray(f(q, np.outer(np.eye(2)[i] * step, np.ones(len(slew))))) - level) / step for i in range(2)]
    return np.column_stack([c.reshape(-1) for c in cols])


def calibration_arrays(dataset: Dataset, half_window: int, machine=None):
    """Measured signals, derived accelerations, payloads and run ids of the valid samples
    (equal run ids: contiguous samples of one experiment).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data (``payload`` column, kg, if any; else 0).
    half_window : int
        Samples each side of the differentiator for the accelerations.
    machine : HydraulicMachine or None
        Machine whose angle ranges drop samples (None: no range check).

    Returns
    -------
    tuple of numpy.ndarray
        ``(values, qdd, payload, runs)`` of the valid rows.
    """
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


def angle_coverage(dataset: Dataset, offsets: np.ndarray) -> np.ndarray:
    """[low, high] (3, 2) of the boom, dipper and bucket angles the data cover, offsets
    (``MachineCalibration.offset_vector``) removed: :data:`COVERAGE_PERCENTILES` of the finite
    samples, widened by :data:`COVERAGE_MARGIN`.

    Where a joint's angle leaves this range the calibrated model extrapolates (the bucket's
    four-bar linkage above all: work cycles begin with the bucket open at −20…+10°, calibration
    swings keep it at −115…−30°), and ``--outside-calibration skip`` does not weigh that joint.

    Parameters
    ----------
    dataset : Dataset
        The calibration data.
    offsets : numpy.ndarray
        Sensor offsets per signal (``MachineCalibration.offset_vector``), SI units.
    """
    angles = dataset.frame[[SIGNALS[i] for i in ANGLES]].to_numpy(float) - offsets[ANGLES]
    out = np.tile([-NO_LIMIT, NO_LIMIT], (3, 1))
    for j in range(3):
        a = angles[np.isfinite(angles[:, j]), j]
        if len(a):
            lo, hi = np.percentile(a, COVERAGE_PERCENTILES)
            out[j] = (lo - COVERAGE_MARGIN, hi + COVERAGE_MARGIN)
    return out
