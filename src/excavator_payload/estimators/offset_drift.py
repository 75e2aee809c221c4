"""A zero check's offsets against a working session's drift: the one test and message both
zeroing estimators (``calibrated``, ``balance-net``) refuse a zero with.

A zero assumes an empty bucket (or the load its data say): a load it is not told of is taken for
sensor offsets and every later weight comes out light by about that load. Offsets whose
:math:`\\chi^2 = \\sum_k (o_k/\\sigma_k)^2` against their prior lies past a limit are refused
(measured: docs/findings/machine-calibration.md, "Zero offset check").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def offsets_chi2(offsets, prior_std) -> float:
    """:math:`\\sum_k (o_k/\\sigma_k)^2` of ``offsets`` against ``prior_std`` (both SI units).

    Parameters
    ----------
    offsets : array_like
        The zero's offsets.
    prior_std : array_like
        Their prior standard deviations.
    """
    return float(np.sum((np.asarray(offsets, float) / np.asarray(prior_std, float)) ** 2))


def offsets_beyond_drift(names: Sequence[str], offsets, prior_std, limit: float) -> str:
    """Why the offsets are beyond a session's drift (their χ² past ``limit``, the four largest
    named in bar, N·m or degrees), or ``""`` when they are not.

    Parameters
    ----------
    names : sequence of str
        The offsets' signals.
    offsets : array_like
        The zero's offsets (SI units).
    prior_std : array_like
        Their prior standard deviations (SI units).
    limit : float
        The χ² past which the zero is refused.
    """
    offsets = np.asarray(offsets, float)
    ratio = offsets / np.asarray(prior_std, float)
    chi2 = offsets_chi2(offsets, prior_std)
    if not chi2 > limit:  # NaN offsets were refused before (no valid samples)
        return ""

    def shown(k: int) -> str:
        if names[k].endswith("_pressure"):
            return f"{names[k]} {offsets[k] / 1e5:+.3g} bar"
        if names[k].endswith("_torque"):
            return f"{names[k]} {offsets[k]:+.3g} N·m"
        return f"{names[k]} {math.degrees(offsets[k]):+.3g}°"

    named = ", ".join(shown(k) for k in np.argsort(-np.abs(ratio))[:4] if abs(ratio[k]) >= 3.0)
    return (f"its sensor offsets are far beyond a working session's drift (χ² {chi2:.0f} over "
            f"{len(ratio)} offsets, limit {limit:.1f}{'; ' + named if named else ''}): was the bucket "
            "empty? A load the data do not carry is taken for offsets and every later weight comes "
            "out light by about that load. Repeat the zero check with an empty bucket; if it was "
            "empty, a sensor is stuck, mis-scaled or changed since the calibration: check those signals")


def never_zeroed_note(name: str, measured: str | None = None) -> str:
    """The note for a zeroing estimator that weighs with its calibration session's offsets.

    Parameters
    ----------
    name : str
        The estimator's name, to start the line with.
    measured : str, optional
        What such a model was measured to do on another session's data (default: the
        calibrated model's, below).
    """
    # Measured: a simulated shift of another working session, weighed with an unzeroed
    # calibration, put every truck's first pass 350-510 kg off, as `ok`.
    measured = measured or "an unzeroed calibration weighed passes 350-510 kg off as 'ok'"
    return (f"{name}: this model was never zeroed: it weighs with the sensor offsets of the working "
            f"session(s) it was fitted in. Offsets drift between sessions (a day, a service); on another "
            f"session's data {measured}. Zero it on "
            "an empty-bucket motion of this session: excavator-payload zero --model MODEL --data EMPTY "
            "--out ZEROED")

