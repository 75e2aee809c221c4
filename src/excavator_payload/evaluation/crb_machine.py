r"""Cramér–Rao bound on the payload for the machine sensor set, nuisances accounted for.

On the machine the payload is weighed through the pressure residual of each arm joint
(:mod:`~excavator_payload.estimators.classical.calibrated_machine`),

.. math:: r_j = \text{count}_j\,\partial l_j/\partial q_j\,\big((\tilde p_h - o_h)A_h
          - (\tilde p_r - o_r)A_r - F_{f,j}(\nu)\big) - \tau_{0,j} - m\,\varphi_j,

whose noise is the pressure transmitters' white noise through the cylinder geometry,
:math:`\operatorname{var} r_j = \text{lever}_j^2 (A_h^2 + A_r^2)\sigma_p^2`. While a cylinder
stands still (rod speed below three Stribeck velocities) its seal holds a friction force the
model cannot know, anywhere within ± the breakaway force :math:`b`, and the *same* force for the
whole standstill: one unknown per episode (variance :math:`b^2/3`), marginalised per episode
(:func:`_episode_information`) — a long standstill tells little more than a short one, so a
motion that starts slowly cannot be weighed early, whatever the estimator. Besides the payload
:math:`m` an estimator must also know the *nuisance* parameters :math:`\nu`: the seal friction
(Coulomb, load coefficient, viscous of each cylinder), the sensor offsets :math:`o` and the IMUs'
dynamics (lag, acceleration leak). It learns them from calibration (and the zero check), with the
posterior covariance :math:`C_\nu` the calibration left; that is prior information
:math:`C_\nu^{-1}`. The Fisher information of :math:`\theta = (m, \nu)` from an experiment's
samples up to :math:`k` is

.. math:: F_k = \sum_{i \le k} \frac{\partial r_i}{\partial\theta}^\top W_i
          \frac{\partial r_i}{\partial\theta} + \begin{bmatrix}0 & 0\\ 0 & C_\nu^{-1}\end{bmatrix},

and the bound on the payload is the Schur complement
:math:`\sigma_m \ge (F_{mm} - F_{m\nu}F_{\nu\nu}^{-1}F_{\nu m})^{-1/2}`: what the nuisances
still unknown cost. The Jacobians are those of the calibration (CasADi, the symbolic model),
evaluated at the model's identified parameters on the true signals where the dataset has them.

Not counted here: the uncertainty of the other calibrated parameters (masses, centres of mass,
geometry). :func:`procedure_bound` counts everything: the whole procedure — calibration motions,
zero check, the experiment — with every calibrated parameter unknown, each term's information
computed as here (not from the calibration's own posterior, which carries its estimated noise
and skipped samples).
"""

from __future__ import annotations

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.platforms import HYDRAULIC


def nuisance_indices() -> np.ndarray:
    """Indices in z of the nuisances: friction parameters, sensor offsets and IMU dynamics."""
    n_delta = len(cm.CALIBRATED_PARAMETERS)
    friction = [cm.CALIBRATED_PARAMETERS.index(p) for p in cm.FRICTION_PARAMETERS]
    n_rest = len(cm.OFFSET_SIGNALS) + len(cm.IMU_PARAMETERS)
    return np.r_[friction, np.arange(n_delta, n_delta + n_rest)].astype(int)


def machine_bound(dataset: Dataset, calibration: "cm.MachineCalibration",
                  pressure_std: float | None = None, half_window: int = 5,
                  nuisances: bool = True, stiction_episodes: bool = True) -> np.ndarray:
    """Lower bound on the payload error's std (kg) at every row of ``dataset``.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data with the true ``payload`` column.
    calibration : MachineCalibration
        The identified machine (parameters, offsets and their covariance).
    pressure_std : float, optional
        White pressure noise, Pa; default the dataset's noise preset where it names one, else
        the calibration's estimate.
    half_window : int
        Samples each side of the centred differentiator that gives the accelerations when the
        dataset has no true ones.
    nuisances : bool
        False: the payload alone (friction and offsets known exactly).
    stiction_episodes : bool
        True (default): a cylinder standing still holds one unknown stiction force for the
        whole standstill (:func:`_episode_information`); False: as independent noise of
        variance (breakaway)²/3 on every slow sample, which counts a long standstill as many
        independent measurements and so overstates what standing still tells.
    """
    if not HYDRAULIC.carries(dataset):
        raise EstimatorError("the machine bound needs machine-sensor-set data")
    terms = _sample_terms(dataset, calibration, pressure_std, half_window, stiction_episodes)
    out = np.full(len(dataset.frame), np.nan)
    if terms is None:
        return out
    idx, G_all, w, still, stiction, exp = terms
    cols = nuisance_indices() if nuisances else np.zeros(0, int)
    C = calibration.covariance[np.ix_(cols, cols)]
    # nuisances in units of their calibration std: F stays well conditioned (Pa beside 1e-2)
    scale = np.sqrt(np.maximum(np.diag(C), 1e-300)) if len(cols) else np.zeros(0)
    G = np.concatenate([G_all[:, :, :1], G_all[:, :, 1 + cols] * scale], axis=2)  # (n, 3, 1 + nν)
    prior = np.zeros((1 + len(cols), 1 + len(cols)))
    if len(cols):
        prior[1:, 1:] = np.linalg.pinv(C / np.outer(scale, scale), hermitian=True)
    for rows, info in _experiment_information(G, w, still, stiction, exp, stiction_episodes):
        out[idx[rows]] = _payload_std(np.cumsum(info, axis=0) + prior)
    return out


def procedure_bound(dataset: Dataset, calibration: "cm.MachineCalibration", calibration_data: Dataset,
                    zero_data: Dataset | None = None, pressure_std: float | None = None,
                    prior_std: float = 0.05, half_window: int = 5) -> np.ndarray:
    r"""Bound on the payload error of the whole procedure: calibrate, zero, then weigh.

    :func:`machine_bound` takes the calibrated masses, centres of mass and geometry as known;
    an estimator that learnt them from a few calibration motions carries their error into every
    later weighing. This bound counts it: every calibrated parameter is unknown, and the
    information about them is what the calibration motions, the zero check and the weighed
    experiment itself carry, plus the estimator's priors. With
    :math:`\psi = (m, \theta, o_A, o_B)` — the payload, the machine parameters and IMU dynamics
    :math:`\theta`, the sensor offsets of the calibration session :math:`o_A` and of the working
    session :math:`o_B` (independent sessions) —

    .. math:: F_k = P + F_\text{cal}(\theta, o_A) + F_\text{zero}(\theta, o_B)
              + \sum_{i \le k} F_i(m, \theta, o_B),

    each term as in :func:`machine_bound` (white pressure noise through the cylinder geometry,
    one unknown stiction force per standstill, true accelerations), :math:`P` the priors'
    information (``prior_std`` of each relative parameter, the offsets' and IMU priors of
    :mod:`~excavator_payload.estimators.classical.calibrated_machine`). The bound is
    :math:`\sigma_m \ge ([F_k^{-1}]_{mm})^{1/2}`: the best any estimator given the same
    calibration motions, zero check and samples so far can do, over the ensemble of
    calibrations. One calibration's parameter error is a single draw shared by all later
    experiments, so efficiency against this bound is judged over several calibrations
    (``benchmarks/bench_procedure_bound.py``).

    Parameters
    ----------
    dataset : Dataset
        Test data (machine sensor set, true ``payload``), working session B.
    calibration : MachineCalibration
        The identified machine: the point the Jacobians are evaluated at.
    calibration_data, zero_data : Dataset
        The calibration motions (known payloads, session A) and the zero check (empty, session B).
    pressure_std : float, optional
        White pressure noise, Pa (default: the test data's preset, else the calibration's estimate).
    prior_std : float
        Relative prior std of the calibrated parameters (``calibrated``'s ``prior_std`` on the
        machine sensor set).
    half_window : int
        Samples each side of the centred differentiator that gives the accelerations of data
        without true ones.
    """
    for name, d in (("test", dataset), ("calibration", calibration_data), ("zero", zero_data)):
        if d is not None and not HYDRAULIC.carries(d):
            raise EstimatorError(f"the procedure bound needs machine-sensor-set {name} data")
    n_delta, n_off, n_imu = len(cm.CALIBRATED_PARAMETERS), len(cm.OFFSET_SIGNALS), len(cm.IMU_PARAMETERS)
    n_theta = n_delta + n_imu
    dim = 1 + n_theta + 2 * n_off
    prior_z = calibration.prior_std(prior_std)  # (delta, offsets, imu) in z's order
    theta_cols = np.r_[np.arange(n_delta), n_delta + n_off + np.arange(n_imu)]
    offset_cols = n_delta + np.arange(n_off)
    # psi = (m, theta, o_A, o_B) in units of the priors' std: F stays well conditioned
    scale = np.r_[1.0, prior_z[theta_cols], prior_z[offset_cols], prior_z[offset_cols]]

    def to_psi(G, session: str) -> np.ndarray:
        out = np.zeros(G.shape[:2] + (dim,))
        out[..., 0] = G[..., 0]
        out[..., 1:1 + n_theta] = G[..., 1 + theta_cols]
        start = 1 + n_theta + (0 if session == "A" else n_off)
        out[..., start:start + n_off] = G[..., 1 + offset_cols]
        return out * scale

    def information(d: Dataset, session: str, with_payload: bool):
        terms = _sample_terms(d, calibration, pressure_std, half_window)
        if terms is None:
            return None
        idx, G, w, still, stiction, exp = terms
        G = to_psi(G, session)
        if not with_payload:  # known payloads: m is not a parameter of these samples
            G[..., 0] = 0.0
        return [(idx[rows], info) for rows, info in _experiment_information(G, w, still, stiction, exp)]

    base = np.diag(np.r_[0.0, np.ones(dim - 1)])  # the priors, in their own units
    for d, session in ((calibration_data, "A"), (zero_data, "B")):
        if d is None:
            continue
        pieces = information(d, session, with_payload=False)
        for _, info in pieces or ():
            base += info.sum(axis=0)
    out = np.full(len(dataset.frame), np.nan)
    pieces = information(dataset, "B", with_payload=True)
    for rows, info in pieces or ():
        out[rows] = _payload_std(np.cumsum(info, axis=0) + base)
    return out


def _sample_terms(dataset: Dataset, calibration: "cm.MachineCalibration", pressure_std: float | None,
                  half_window: int, stiction_episodes: bool = True):
    """Per-sample sensitivities and weights of the pressure residuals of ``dataset``.

    Returns ``None`` when no sample is usable, else ``(idx, G, w, still, stiction, experiment)``:
    the rows used, ``G`` (n, 3, 1 + nz) = [∂r/∂m, ∂r/∂z] at the calibration's z, the inverse
    residual variances ``w`` (white pressure noise; a standstill's stiction left to
    :func:`_episode_information` when ``stiction_episodes``), the standstill mask, the breakaway
    torques and the experiment numbers of the rows.
    """
    if pressure_std is None:
        name = dataset.meta.get("noise")
        pressure_std = HYDRAULIC.noise(name).pressure_noise if name else calibration.pressure_std
    f = dataset.frame
    signals = list(cm.SIGNALS)
    if dataset.has_truth and all("true_" + s in f for s in signals):
        # true signals plus the model's offsets: the residual function subtracts them again
        values = f[["true_" + s for s in signals]].to_numpy(float) + calibration.offset_vector()
        qdd = f[["true_boom_accel", "true_dipper_accel", "true_bucket_accel", "true_slew_accel"]].to_numpy(float)
    else:
        values = f[signals].to_numpy(float)
        qdd = cm.accelerations(dataset, half_window)
    payload = f["payload"].to_numpy(float)
    ok = np.all(np.isfinite(values), axis=1) & np.all(np.isfinite(qdd), axis=1) & np.isfinite(payload)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return None
    accel_var, calibration.accel_var = calibration.accel_var, 0.0
    try:  # true accelerations: no differentiator noise in the bound
        r, J, lever, speed, stiction = calibration.evaluate(values[idx], qdd[idx], payload[idx], calibration.z)
        w = calibration.weights(lever, speed, stiction, "downweight", float(pressure_std))
        w_white = calibration.weights(lever, speed, stiction, "model", float(pressure_std))
    finally:
        calibration.accel_var = accel_var
    v_s = np.array([c.stribeck_velocity for c in calibration.arm.machine.cylinders])
    still = np.abs(speed) < 3 * v_s
    if stiction_episodes:  # white weights; the shared stiction enters per episode
        w = np.where(still, w_white, w)
    phi = calibration._payload_sensitivity  # ∂r/∂m = -φ, set by evaluate
    G = np.nan_to_num(np.concatenate([phi[..., None], J], axis=2))
    w = np.where(np.isfinite(w), w, 0.0)
    return idx, G, w, still, stiction, f["experiment"].to_numpy()[idx]


def _experiment_information(G, w, still, stiction, exp, episodes: bool = True):
    """Per experiment (contiguous rows of ``exp``): its rows (a slice) and the per-sample
    information increments (n, d, d) of its residuals, a standstill's shared stiction
    marginalised per episode (:func:`_episode_information`) when ``episodes``."""
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(exp)]):
        info = np.einsum("nja,nj,njb->nab", G[a:b], w[a:b], G[a:b])
        if episodes:
            info -= _episode_information(G[a:b], w[a:b], still[a:b], stiction[a:b])
        yield slice(a, b), info


def _payload_std(F: np.ndarray) -> np.ndarray:
    """The payload's bound from Fisher matrices (n, d, d) with the payload first: the Schur
    complement of the other parameters, (F_mm − F_mν F_νν⁻¹ F_νm)^(-1/2)."""
    schur = F[:, 0, 0]
    if F.shape[1] > 1:
        Fmn, Fnn = F[:, 0, 1:], F[:, 1:, 1:]
        schur = schur - np.einsum("na,na->n", Fmn, np.linalg.solve(Fnn, Fmn[..., None])[..., 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        return 1.0 / np.sqrt(np.maximum(schur, 0.0))


def _episode_information(G, w, still, stiction) -> np.ndarray:
    r"""Per-sample increments of the information a standstill episode's shared stiction removes.

    While joint :math:`j`'s cylinder stands still its friction :math:`s_E` is one unknown
    within ± the breakaway torque :math:`b` (uniform: variance :math:`b^2/3`) for the whole
    episode :math:`E`, not fresh noise on every sample. Marginalising it from the episode's
    samples so far (Schur complement) removes

    .. math:: \frac{S_E S_E^\top}{W_E + 3/b^2}, \qquad S_E = \sum_{k \in E} w_k g_k,\;
              W_E = \sum_{k \in E} w_k,

    from the information: a long standstill tells little more than a short one. Returned as
    increments (n, d, d), so that their cumulative sum is the removal up to each sample.
    """
    n, _, d = G.shape
    out = np.zeros((n, d, d))
    for j in range(G.shape[1]):
        s = still[:, j]
        edges = np.flatnonzero(np.diff(np.r_[0, s.astype(int), 0]))
        for start, stop in zip(edges[0::2], edges[1::2]):
            a = w[start:stop, j, None] * G[start:stop, j, :]
            S = np.cumsum(a, axis=0)
            W = np.cumsum(w[start:stop, j])
            b = float(np.nanmax(np.abs(stiction[start:stop, j])))
            c = 3.0 / max(b * b, 1e-300)
            removed = np.einsum("na,nb->nab", S, S) / (W + c)[:, None, None]
            out[start:stop] += np.diff(removed, axis=0, prepend=np.zeros((1, d, d)))
    return out


def dataset_machine_bound(dataset: Dataset, estimator) -> np.ndarray | None:
    """The bound for ``dataset`` given a fitted model; ``None`` when the model has no machine
    calibration (only ``calibrated`` fitted on the machine sensor set carries one).

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set test data with the true ``payload`` column (kg).
    estimator : Estimator
        A fitted estimator; its ``calibration`` attribute, if any, is the identified machine.

    Returns
    -------
    numpy.ndarray or None
        :func:`machine_bound` (kg, one per row), or ``None`` as said above.
    """
    cal = getattr(estimator, "calibration", None)
    if cal is None or not HYDRAULIC.carries(dataset) or "payload" not in dataset.frame:
        return None
    return machine_bound(dataset, cal, half_window=estimator.options.get("half_window", 5))
