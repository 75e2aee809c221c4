r"""The Cramér–Rao lower bound on the payload: the physical limit of any unbiased estimator.

The torques are affine in the payload, :math:`\tau_k = \tau_0(q_k,\dot q_k,\ddot q_k) + m\,
\varphi_k`. With the kinematics known and the torque noise white Gaussian with covariance
:math:`\Sigma`, the Fisher information about :math:`m` carried by sample :math:`k` is
:math:`I_k = \varphi_k^\top \Sigma^{-1} \varphi_k`, and for the samples an estimator has used

.. math:: \sigma_m \ge \Big(\sum_{k\in\text{used}} \varphi_k^\top\Sigma^{-1}\varphi_k\Big)^{-1/2}.

``window=None`` uses the whole history of the experiment up to each sample (filters,
recursive least squares, NARX); ``window=N`` the last N samples (a time-delay network with
delays 0…N−1).
"""

from __future__ import annotations

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.machine import Machine, load_machine
from excavator_payload.platforms.thesis import THESIS, NoisePreset, get_noise_preset


def sample_information(dataset: Dataset, machine: Machine | str | None = None,
                       noise: NoisePreset | str | None = None) -> np.ndarray:
    """Fisher information about the payload, kg⁻², of every sample (aligned with the rows).

    Uses the noise-free ``true_*`` kinematics where the dataset has them, else the measured
    ones (their noise is negligible for the bound at the thesis' noise levels).

    Parameters
    ----------
    dataset : Dataset
        Thesis-sensor-set data with boom and dipper angles (rad), rates (rad/s) and
        accelerations (rad/s²).
    machine : Machine or str, optional
        The machine (or preset name or TOML file); default the dataset's.
    noise : NoisePreset or str, optional
        The torque noise (or preset name); default the dataset's preset, else the thesis default.

    Returns
    -------
    numpy.ndarray
        One Fisher information (kg⁻²) per row of ``dataset.frame``; ``inf`` everywhere when the
        torques are noise-free.
    """
    machine = load_machine(machine) if machine is not None else dataset.machine()
    if machine is None:
        raise ValueError("the dataset names no machine; pass one")
    noise = get_noise_preset(noise if noise is not None else dataset.meta.get("noise", THESIS.default_noise))
    prefix = "true_" if dataset.has_truth else ""
    f = dataset.frame
    q = f[[prefix + "boom_angle", prefix + "dipper_angle"]].to_numpy(float)
    qd = f[[prefix + "boom_rate", prefix + "dipper_rate"]].to_numpy(float)
    qdd = f[[prefix + "boom_accel", prefix + "dipper_accel"]].to_numpy(float)
    phi = ArmModel(machine).payload_regressor(q, qd, qdd)
    var = np.diag(noise.torque_covariance)
    if np.any(var <= 0):
        return np.full(len(f), np.inf)  # noise-free torques: the payload is known exactly
    return (phi**2 / var).sum(axis=1)


def cramer_rao_bound(dataset: Dataset, machine: Machine | str | None = None,
                     noise: NoisePreset | str | None = None, window: int | None = None) -> np.ndarray:
    """Lower bound on the payload error's standard deviation (kg) at every sample.

    Parameters
    ----------
    dataset : Dataset
        Thesis-sensor-set data; its noise-free ``true_*`` kinematics are used where present.
    machine : Machine or str, optional
        The machine (or preset name or TOML file); default the dataset's.
    noise : NoisePreset or str, optional
        The torque noise (or preset name); default the dataset's preset, else ``thesis``.
    window : int or None
        ``None``: the information of the experiment's whole history up to the sample;
        ``N``: of the last ``N`` samples only (NaN before N samples exist).
    """
    info = sample_information(dataset, machine, noise)
    exp = dataset.frame["experiment"].to_numpy()
    out = np.empty(len(info))
    starts = np.flatnonzero(np.r_[True, exp[1:] != exp[:-1]])
    bounds = np.r_[starts, len(exp)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        c = np.cumsum(info[a:b])
        if window is None:
            total = c
        else:
            total = np.full(b - a, np.nan)
            total[window - 1:] = c[window - 1:] - np.r_[0.0, c[:-window]]
        with np.errstate(divide="ignore", invalid="ignore"):
            out[a:b] = 1.0 / np.sqrt(total)
    return out
