r"""The pressure offsets the unloaded chambers show (``--unloaded-chamber back-pressure``).

A cylinder's balance sees its two pressures only through the force
:math:`F = (p_h - o_h) A_h - (p_r - o_r) A_r`: the head and rod offsets :math:`o_h, o_r` enter
every joint's balance with the same lever, so the windows fix one combination of them per
cylinder and the priors split it (a zero check left the rod offsets at their prior,
docs/findings/any-motion.md, "What the calibration gets wrong"). The hydraulic model says
more: the side that does not carry the load holds the return line's back pressure
(:mod:`excavator_payload.model.hydraulic`, the make-up valves), so wherever a cylinder clearly
pushes its rod chamber reads :math:`p_\text{back} + o_r`, and wherever it clearly pulls its
head chamber reads :math:`p_\text{back} + o_h`. Each such chamber gives one observation of its
offset, the median of (reading − the file's back pressure), whose error is the file's back
pressure error (systematic: it does not average out over samples), taken as the parameters'
relative prior std of the back pressure. It is fused with the offset's prior as a second
Gaussian observation (:func:`fuse_offset_prior`).
"""

from __future__ import annotations

import numpy as np

from excavator_payload.estimators.classical.machine_calibration.settings import (
    _OFFSET_COLUMNS, OFFSET_PRIOR_STD)

#: Choices of ``--unloaded-chamber``: ``ignore`` (the offsets from the balance and their priors
#: alone) or ``back-pressure`` (also from the chambers that hold the back pressure).
UNLOADED_CHAMBER_CHOICES = ("ignore", "back-pressure")
#: A chamber counts as unloaded where the cylinder's force is beyond the two-sides-at-back-
#: pressure force by this many times the force its two offsets' prior std could make (the
#: offsets are not known yet when the side is judged) ...
UNLOADED_MARGIN = 5.0
#: ... on at least this many samples (1 s at 100 Hz).
MIN_UNLOADED_SAMPLES = 100


def unloaded_offsets(values: np.ndarray, head: np.ndarray, rod: np.ndarray, back_pressure: float,
                     relative_std: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pressure offset as the unloaded chambers show it.

    Parameters
    ----------
    values : numpy.ndarray
        Measured samples (n, signals) of the machine sensor set, SI units, offsets not removed.
    head, rod : numpy.ndarray
        Piston and annulus area of each cylinder (boom, dipper, bucket), m².
    back_pressure : float
        The machine file's return-line back pressure, Pa.
    relative_std : float
        Relative std of the file's back pressure (the observation's std is this share of it).

    Returns
    -------
    tuple of numpy.ndarray
        Per pressure offset (the six pressures of :data:`~.settings.OFFSET_SIGNALS`, in order):
        the observed offset (Pa; NaN where fewer than :data:`MIN_UNLOADED_SAMPLES` samples show
        the chamber unloaded), its std (Pa) and the samples it rests on.
    """
    if not back_pressure > 0 or not relative_std > 0:
        raise ValueError(f"back pressure and its relative std must be positive, got {back_pressure} and "
                         f"{relative_std}")
    head, rod = np.asarray(head, float), np.asarray(rod, float)
    p = np.asarray(values, float)[:, _OFFSET_COLUMNS[:6]]
    observed, std, count = np.full(6, np.nan), np.full(6, np.nan), np.zeros(6, int)
    for c in range(3):
        p_head, p_rod = p[:, 2 * c], p[:, 2 * c + 1]
        force = p_head * head[c] - p_rod * rod[c]
        both_back = back_pressure * (head[c] - rod[c])
        margin = UNLOADED_MARGIN * OFFSET_PRIOR_STD[2 * c] * (head[c] + rod[c])
        finite = np.isfinite(force)
        for side, unloaded, reading in ((1, force > both_back + margin, p_rod),  # pushing: rod holds p_back
                                        (0, force < both_back - margin, p_head)):  # pulling: head holds it
            use = finite & unloaded
            k = 2 * c + side
            count[k] = int(use.sum())
            if count[k] >= MIN_UNLOADED_SAMPLES:
                r = reading[use] - back_pressure
                noise = 1.4826 * np.median(np.abs(r - np.median(r))) / np.sqrt(count[k])
                observed[k] = float(np.median(r))
                std[k] = float(np.hypot(relative_std * back_pressure, noise))
    return observed, std, count


def fuse_offset_prior(mean: np.ndarray, std: np.ndarray, observed: np.ndarray,
                      observed_std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pressure offsets' prior with the unloaded chambers' observations fused in.

    Parameters
    ----------
    mean, std : numpy.ndarray
        Prior mean and std of the six pressure offsets, Pa.
    observed, observed_std : numpy.ndarray
        :func:`unloaded_offsets`' observation and std (NaN: none, the prior kept).

    Returns
    -------
    tuple of numpy.ndarray
        Mean and std of the product of the two Gaussians.
    """
    mean, std = np.asarray(mean, float).copy(), np.asarray(std, float).copy()
    have = np.isfinite(observed) & np.isfinite(observed_std) & (observed_std > 0)
    info = 1.0 / std[have] ** 2 + 1.0 / observed_std[have] ** 2
    mean[have] = (mean[have] / std[have] ** 2 + observed[have] / observed_std[have] ** 2) / info
    std[have] = 1.0 / np.sqrt(info)
    return mean, std
