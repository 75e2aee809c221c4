r"""Column-wise input and output scaling of a DVS network, as MATLAB's process functions:
``mapminmax`` (the training range onto :math:`[-1, 1]`) or ``mapstd`` (zero mean, unit standard
deviation), fitted on the training experiments.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from excavator_payload.errors import EstimatorError

#: The scaling methods ``--scaling`` accepts.
SCALINGS = ("mapminmax", "mapstd")


class Scaler:
    r"""Column-wise affine scaling :math:`y = (x - c)\,g`, as MATLAB's process functions.

    ``mapminmax``: :math:`c = (x_{max} + x_{min})/2`, :math:`g = 2/(x_{max} - x_{min})`, so the
    training range maps onto :math:`[-1, 1]`. ``mapstd``: :math:`c = \bar x`, :math:`g = 1/s_x`.
    A constant column passes unscaled (:math:`g = 1`), as in MATLAB.

    Parameters
    ----------
    method : str
        ``"mapminmax"`` or ``"mapstd"``.
    """

    def __init__(self, method: str = "mapminmax") -> None:
        if method not in SCALINGS:
            raise EstimatorError(f"unknown scaling {method!r}: choose one of {', '.join(SCALINGS)}")
        self.method = method
        self.center: np.ndarray | None = None
        self.gain: np.ndarray | None = None

    def fit(self, x: np.ndarray) -> "Scaler":
        """Fit centre and gain per column of ``x`` (rows are samples); returns ``self``.

        Parameters
        ----------
        x : numpy.ndarray
            Training values, samples in rows (finite).
        """
        x = np.asarray(x, dtype=float)
        x = x.reshape(len(x), -1)
        if len(x) == 0 or not np.all(np.isfinite(x)):
            raise EstimatorError("cannot fit scaling: no data or non-finite values")
        if self.method == "mapminmax":
            lo, hi = x.min(axis=0), x.max(axis=0)
            center, spread = (hi + lo) / 2.0, (hi - lo) / 2.0
        else:
            center, spread = x.mean(axis=0), x.std(axis=0, ddof=1) if len(x) > 1 else np.zeros(x.shape[1])
        self.center = center
        # A (numerically) constant column keeps gain 1, as MATLAB does for xmax == xmin; a
        # subnormal spread would otherwise overflow the gain to inf and the transform to NaN.
        usable = spread > np.finfo(float).tiny * 1e6
        self.gain = np.where(usable, 1.0 / np.where(usable, spread, 1.0), 1.0)
        return self

    def _check(self) -> None:
        if self.center is None:
            raise EstimatorError("scaler is not fitted")

    def transform(self, x):
        """Scale ``x``: ``(x - center) * gain``.

        Parameters
        ----------
        x : numpy.ndarray or torch.Tensor
            Values in their own units, columns as fitted.
        """
        self._check()
        return (x - self.center) * self.gain

    def inverse(self, y):
        """Undo :meth:`transform`: ``y / gain + center``.

        Parameters
        ----------
        y : numpy.ndarray or torch.Tensor
            Scaled values.
        """
        self._check()
        return y / self.gain + self.center

    def to_arrays(self, prefix: str = "scaler") -> dict[str, np.ndarray]:
        """``{prefix}_center``, ``{prefix}_gain``, ``{prefix}_method`` (for an ``.npz``).

        Parameters
        ----------
        prefix : str
            Prefix of the array names.
        """
        self._check()
        return {f"{prefix}_center": self.center, f"{prefix}_gain": self.gain,
                f"{prefix}_method": np.array(self.method)}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], prefix: str = "scaler",
                    method: str | None = None) -> "Scaler":
        """Inverse of :meth:`to_arrays` (``method`` defaults to the stored one).

        Parameters
        ----------
        arrays : Mapping[str, numpy.ndarray]
            Saved arrays (e.g. an ``.npz``).
        prefix : str
            Prefix of the array names.
        method : str or None
            Scaling method (None: the stored one, else ``mapminmax``).
        """
        if method is None:
            method = str(arrays[f"{prefix}_method"]) if f"{prefix}_method" in arrays else "mapminmax"
        s = cls(method)
        s.center = np.asarray(arrays[f"{prefix}_center"], dtype=float)
        s.gain = np.asarray(arrays[f"{prefix}_gain"], dtype=float)
        return s


__all__ = ["SCALINGS", "Scaler"]
