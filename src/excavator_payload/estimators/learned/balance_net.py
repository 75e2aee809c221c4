r"""``balance-net``: a payload sensor learned from logs with known loads, shaped by the balance.

Nothing of a machine file is read (``--machine`` is refused): the learned balance of
:mod:`.balance_model` (the basis forces of any planar arm on a slewing house, :mod:`.chain`, a
payload point and per-cylinder pressure maps, every constant fitted to the logs) gives per
window of samples the residual :math:`r_j` at an empty bucket and the payload's regressor
:math:`\varphi_j` of each channel, and the payload is weighed over its whole history,

.. math:: \hat m = \frac{\sum w_j \varphi_j r_j}{\sum w_j \varphi_j^2}, \qquad
          \sigma = \kappa \Big/ \sqrt{\textstyle\sum w_j \varphi_j^2},

:math:`w_j` the inverse of the channel's residual variance in training, :math:`\kappa` the RMS
of the training experiments' final errors in units of their nominal σ (windows overlap, so the
nominal σ is too small by that factor). Streaming computes each sample's four parts of the
balance once (one compiled CasADi call, the same expression the C export compiles) and sums
each window from a ring: batch and stream are one computation.

* A channel's window whose residual at the current estimate lies beyond ``--gate`` σ is not
  used (a regime training never saw: the model says nothing there). When every channel
  disagrees for ``--new-load`` seconds and those windows, weighed on their own, give a load
  more than :data:`NEW_LOAD_SHARE` of the largest trained payload away, that is the new load.
* ``ok`` once the information's part of 2σ, :math:`2\kappa/\sqrt{I}`, is at most
  ``--ready-sigma`` of the largest trained payload, or the weighing holds ``--ready`` of the
  information a median training motion gives, whichever comes first (before: no estimate,
  ``warming_up``): the first windows, all of one phase of a motion, carry that phase's model error.
* The machine set's frames are judged between their neighbours (a one-frame glitch is replaced
  by its neighbours' mean, as in ``calibrated``); the thesis set's samples by the base class's
  gate on the balance's residual.
* Plausibility limits: the joint angles' trained range (widened), ten times the largest
  trained magnitude of the other signals, the sensor set's own for the house's inclination;
  not a machine's.
* ``zero`` re-estimates the sensors' offsets from an empty-bucket motion
  (:meth:`BalanceModel.zero <.balance_model.BalanceModel.zero>`), the windows' information
  divided by κ² (they overlap, as in σ).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult, register
from excavator_payload.estimators.learned.balance_model import BalanceModel, Layout, Samples, experiment_samples
from excavator_payload.estimators.offset_drift import offsets_beyond_drift, offsets_chi2

if TYPE_CHECKING:
    import pandas as pd

#: Angles' plausibility: the training range widened by this share of its span plus ANGLE_MARGIN.
ANGLE_WIDEN, ANGLE_MARGIN = 0.25, math.radians(5.0)
#: Every other signal (but the house's inclination): at most this many times its largest
#: trained magnitude (and within the sensor set's limits).
SIGNAL_SCALE = 10.0
#: A load that differs from the one weighed by more than this share of the largest trained
#: payload is a new one (a dump, a fill); a smaller disagreement is the model's, not the load's.
NEW_LOAD_SHARE = 0.1
#: A zero whose offsets' remaining uncertainty weighs more than this share of the largest
#: trained payload is refused (``zero --force`` keeps it): it would weigh worse than 1 %.
ZERO_REFUSE_SHARE = 0.01
#: A zero whose offsets' χ² against :data:`ZERO_PRIOR` lies beyond this tail of a χ² of as many
#: degrees of freedom as offsets is refused (a load in the bucket taken for offsets; measured on
#: two trainings, 50 empty zero motions of sessions 2-11, swings, slow lever moves, joystick
#: passes, 5° and -8° slopes: χ² 0.5-29.6 against 35.6 at 10⁻⁴ and 46.9 at 10⁻⁶ for 10 offsets).
ZERO_OFFSET_TAIL = 1e-6
#: ... or this many times the largest χ² of the zeros the training made on its own held-out
#: motions, if larger (:meth:`BalanceNet._zero_limit`).
ZERO_CROSS_MARGIN = 3.0
#: Every this-many-th training experiment is held out once to measure σ's model floor.
HELD_OUT_EVERY = 5
#: The lightest held-out experiments serve, one at a time, as the zero motion for the others:
#: the floor then carries what a zero on one motion leaves wrong on another, as in use (a zero
#: is made with an empty bucket; one made with a full one carries the model's error at that
#: load into the offsets).
CROSS_ZEROS = 4
#: s: a gap in the samples up to this long keeps the weighing's sums.
MAX_BRIDGED_GAP = 1.0
#: rad: the house's inclination is novel on this scale besides its trained spread (training is
#: usually level: its spread is the sensor's noise, and gravity's direction enters the balance
#: exactly, so a slope is less new than that spread says; chosen on the tuning draws 1300/1400).
TILT_NOVELTY_SCALE = math.radians(2.0)


def novelty_columns(layout: Layout) -> list[int]:
    """The signals whose distance from the training data is σ's novelty: the joints' angles and
    rates, the slew rate and the house's inclination (in that order).

    Parameters
    ----------
    layout : Layout
        Where each quantity is among the signals.
    """
    return list(layout.q) + list(layout.v) + ([layout.slew] if layout.slew is not None else []) + list(layout.tilt)


def novelty_features(s: Samples) -> np.ndarray:
    """``(N, k)`` the :func:`novelty_columns` of one experiment's samples.

    Parameters
    ----------
    s : Samples
        One experiment's samples.
    """
    parts = [s.q, s.qd] + ([s.slew[:, None]] if s.slew is not None else []) + ([s.tilt] if s.tilt is not None else [])
    return np.column_stack(parts)


def novelty_statistics(features: np.ndarray, tilt: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and precision (inverse covariance) of the training samples' novelty features, the
    last ``tilt`` of them (the inclination) widened by :data:`TILT_NOVELTY_SCALE`.

    Parameters
    ----------
    features : numpy.ndarray
        ``(N, k)`` the training samples' :func:`novelty_features`.
    tilt : int
        How many of the last columns are the house's inclination.
    """
    mean = features.mean(0)
    cov = np.atleast_2d(np.cov(features.T))
    k = len(mean)
    if tilt:
        cov[k - tilt:, k - tilt:] += np.eye(tilt) * TILT_NOVELTY_SCALE**2
    # a signal that never varied in training (a fixed base's slew rate) must not divide by zero
    cov += np.eye(k) * 1e-9 * max(float(np.trace(cov)) / k, 1e-12)
    return mean, np.linalg.inv(cov)


def novelty_distance(features: np.ndarray, mean: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """Mahalanobis distance of each row of ``features`` from the training samples.

    Parameters
    ----------
    features : numpy.ndarray
        ``(N, k)`` or ``(k,)`` novelty features.
    mean, precision : numpy.ndarray
        :func:`novelty_statistics` of the training samples.
    """
    f = np.atleast_2d(features) - mean
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", f, precision, f), 0.0))


def fit_floor(errors: np.ndarray, nominal: np.ndarray, measure: np.ndarray) -> tuple[float, float]:
    """σ's model floor as a variance that grows with a measure of how new a motion is,
    ``s² = max(a + b·d, 0)``: least squares of the held-out weighings' squared errors beyond their
    nominal variance on their mean measure ``d`` (``b ≥ 0``; with ``b = 0`` the constant RMS
    floor).

    Parameters
    ----------
    errors, nominal, measure : numpy.ndarray
        Per held-out weighing: its error (kg), its nominal σ (kg) and its measure's mean.
    """
    excess = np.square(errors) - np.square(nominal)
    if len(excess) >= 3 and np.ptp(measure) > 0:
        a, b = np.linalg.lstsq(np.c_[np.ones_like(measure), measure], excess, rcond=None)[0]
        if b > 0:
            return float(a), float(b)
    return float(max(np.mean(excess), 0.0)), 0.0


def fit_floors(errors: np.ndarray, nominal: np.ndarray, novelty: np.ndarray,
               misfit: np.ndarray) -> tuple[float, float, float]:
    """``(a, b, c)`` of σ's model floor ``s² = max(a + b·novelty + c·misfit, 0)``: each measure's
    :func:`fit_floor` alone, the two summed. (Fitted together, the misfit took all of it on the
    tuning draws and the novelty none, and slopes, which the misfit does not see, were covered
    60–73 %; each alone attributes all the excess to itself, so the sum is the wider.)

    Parameters
    ----------
    errors, nominal, novelty, misfit : numpy.ndarray
        Per held-out weighing: its error (kg), its nominal σ (kg), its mean novelty and misfit.
    """
    a1, b = fit_floor(errors, nominal, novelty)
    a2, c = fit_floor(errors, nominal, misfit)
    if b == 0.0 and c == 0.0:
        return a1, 0.0, 0.0  # neither grows: the constant floor, once
    return a1 + a2, b, c


_NO_SUMS = (0.0, 0.0, 0.0, 0.0)


def _add_window(sums: tuple, w: np.ndarray, phi: np.ndarray, r: np.ndarray, novelty: float) -> tuple:
    """The weighing's sums ``(num, info, novelty, misfit)`` with one window added: its channels'
    ``Σ w φ r`` and information ``Σ w φ²``, the novelty and the channels' χ² at the estimate after
    it, each weighted by the window's information."""
    num, info, novelty_sum, misfit = sums
    added = float(np.sum(w * phi * phi))
    num += float(np.sum(w * phi * r))
    info += added
    novelty_sum += added * novelty
    if info > 0:
        misfit += added * float(np.sum(w * (r - num / info * phi) ** 2))
    return num, info, novelty_sum, misfit


class _Columns:
    """``x[..., i]`` of a list of CasADi symbols (the model indexes samples' columns so)."""

    def __init__(self, items) -> None:
        self.items = list(items)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, key):
        return self.items[key[-1] if isinstance(key, tuple) else key]


def sample_function(model: BalanceModel):
    """The CasADi function ``(signals, offsets) -> [r_plain, r_momentum, φ_plain, φ_momentum]``
    (one value per channel each) of one sample: the fitted constants are numbers in it.

    Parameters
    ----------
    model : BalanceModel
        The fitted model.
    """
    import casadi as ca

    L = model.layout
    x = ca.SX.sym("x", len(L.signals))
    off = ca.SX.sym("offsets", model.offset_count())
    cols = lambda idx: _Columns([x[i] for i in idx])  # noqa: E731
    s = Samples(q=cols(L.q), qd=cols(L.v), qdd=cols(L.a) if not L.differentiate else None,
                slew=x[L.slew] if L.slew is not None else None, tilt=cols(L.tilt) if L.tilt else None,
                head=cols(L.head if L.pressure else L.torque), rod=cols(L.rod) if L.pressure else None)
    saved = model.offsets
    model.offsets = _Columns([off[i] for i in range(model.offset_count())])
    try:
        blocks = model.design(s, ops=ca)
    finally:
        model.offsets = saved
    from excavator_payload.estimators.learned.balance_model import BLOCKS, MASS_SCALE

    n = L.n
    parts = [[ca.SX(0.0)] * n for _ in range(4)]
    i = 0
    c = model.coef
    for name, sign in BLOCKS:
        payload = name == "payload"
        for plain, mom in blocks[name]:
            k = 2 if payload else 0
            scale = -sign * MASS_SCALE if payload else sign
            if c[i] != 0.0:
                for j in range(n):
                    parts[k][j] = parts[k][j] + scale * c[i] * plain[j]
                    if mom is not None:
                        parts[k + 1][j] = parts[k + 1][j] + scale * c[i] * mom[j]
            i += 1
    out = ca.vertcat(*[ca.vertcat(*p) for p in parts])
    return ca.Function("balance_net_sample", [x, off], [out], ["x", "offsets"], ["terms"])


@register
class BalanceNet(Estimator):
    """The learned balance of the arm, weighed over the load's history (module doc).

    Parameters
    ----------
    machine : None
        Refused: it learns from recorded data alone.
    **options
        See ``OPTIONS`` (``excavator-payload estimators balance-net``).
    """

    name = "balance-net"
    NEEDS_MACHINE = False
    OPTIONS = {
        "order": Option(int, 6, "Chebyshev polynomials per pressure map of a joint's angle"),
        "still_rate": Option(float, 0.05, "rad/s below which a cylinder's channel says nothing "
                             "(its seals' force at rest is unknown)"),
        "half_window": Option(int, 25, "samples each side of a balance window's centre (machine set)"),
        "ramp": Option(int, 10, "sample intervals over which a window's weight rises and falls"),
        "margin": Option(float, 0.1, "share of a joint's trained span it may go beyond and still "
                         "be weighed at"),
        "every": Option(int, 5, "train on every K-th window (neighbours share most samples)"),
        "gate": Option(float, 4.0, "a channel's window further than this many sigma from the "
                       "estimate is not used"),
        "new_load": Option(float, 1.0, "seconds of every channel disagreeing with the weighed load "
                           "after which a load weighed 10 % of the largest trained payload away "
                           "replaces it"),
        "ready_sigma": Option(float, 0.003, "ok once the information's part of 2 sigma (2 kappa/sqrt(I)) "
                              "is at most this share of the largest trained payload (0.003: 15 kg of "
                              "5 t), or at --ready, whichever comes first; the first windows, all of "
                              "one phase, carry that phase's model error"),
        "ready": Option(float, 0.3, "or ok once the weighing holds this share of the information a "
                        "median training motion gives (0: --ready-sigma alone; the only rule before "
                        "session 22)"),
    }

    def __init__(self, machine=None, **options: Any) -> None:
        if machine is not None:
            raise EstimatorError("balance-net learns from recorded data with known loads alone: it "
                                 "takes no --machine (drop the option)")
        super().__init__(None, **options)
        o = self.options
        if not 1 <= int(o["order"]) <= 12:
            raise EstimatorError(f"{self.name}: --order must be 1 … 12")
        if not 1 <= int(o["half_window"]) <= 500 or not 1 <= int(o["ramp"]) <= int(o["half_window"]):
            raise EstimatorError(f"{self.name}: --half-window must be 1 … 500 and --ramp 1 … --half-window")
        if not 1 <= int(o["every"]) <= 1000:
            raise EstimatorError(f"{self.name}: --every must be 1 … 1000")
        if not 0.0 <= float(o["margin"]) <= 1.0:
            raise EstimatorError(f"{self.name}: --margin must be 0 … 1")
        for key in ("still_rate", "gate", "new_load", "ready_sigma"):
            if not float(o[key]) > 0:
                raise EstimatorError(f"{self.name}: --{key.replace('_', '-')} must be > 0")
        if not float(o["ready"]) >= 0:
            raise EstimatorError(f"{self.name}: --ready must be ≥ 0")
        self.model: BalanceModel | None = None
        self.kappa = 1.0
        self.model_std = 0.0
        # σ's model floor² = max(a + b·novelty + c·misfit, 0), kg² (:func:`fit_floor`)
        self.floor_a, self.floor_b, self.floor_c = 0.0, 0.0, 0.0
        self.novelty_mean = np.zeros(0)
        self.novelty_precision = np.zeros((0, 0))
        self.typical_info = 0.0
        self.payload_scale = 1.0
        self.cross_zero_chi2: list[float] = []
        self.zero_chi2_limit = math.inf
        self.spike_threshold: np.ndarray | None = None
        self.training: dict = {}
        self._fn = None
        self._reset()

    # -- fitting --------------------------------------------------------------------------
    def _new_model(self, signals) -> BalanceModel:
        o = self.options
        return BalanceModel(tuple(signals), order=int(o["order"]), still_rate=float(o["still_rate"]),
                            half_window=int(o["half_window"]), ramp=int(o["ramp"]), margin=float(o["margin"]),
                            period=float(self.sensor_set.sample_period))

    def experiments(self, dataset: Dataset, payload: bool = True) -> list[Samples]:
        """The dataset's experiments as :class:`Samples`.

        Parameters
        ----------
        dataset : Dataset
            Data of the sensor set it was fitted on.
        payload : bool
            Carry the known payloads (where the data have them).
        """
        layout = self.model.layout if self.model is not None else Layout(self.sensor_set.signals)
        values = dataset.signals(self.sensor_set.signals)
        exp = dataset.frame["experiment"].to_numpy()
        pay = dataset.frame["payload"].to_numpy(float) if payload and dataset.has_payload else None
        cuts = np.flatnonzero(exp[1:] != exp[:-1]) + 1
        out = []
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(exp)]):
            out.append(experiment_samples(layout, values[a:b], None if pay is None else pay[a:b]))
        return out

    def _final_errors(self, experiments: list[Samples]) -> list[tuple[float, float, float, float]]:
        """(error, nominal σ with κ = :attr:`kappa`, mean novelty, mean misfit) of each
        experiment's whole-history weighing (one payload each), kg; the novelty of each window is
        that of its newest sample (as streamed), its misfit its channels' χ² at the weighing,
        both averaged with the windows' information as weights."""
        out = []
        for e in experiments:
            _, r, phi, w = self.model.terms(e)
            window_info = np.sum(w * phi * phi, axis=1)
            info = float(np.sum(window_info))
            if info > 0 and e.m is not None and np.ptp(e.m) == 0:
                d = 0.0
                if len(self.novelty_mean):
                    dist = novelty_distance(novelty_features(e), self.novelty_mean, self.novelty_precision)
                    d = float(np.sum(window_info * dist[self.model.width - 1:][:len(window_info)]) / info)
                estimate = float(np.sum(w * phi * r) / info)
                misfit = float(np.sum(window_info * np.sum(w * (r - estimate * phi) ** 2, axis=1)) / info)
                out.append((estimate - e.m[0], self.kappa / math.sqrt(info), d, misfit))
        return out

    def _cross_zero_errors(self, held: list[Samples]) -> list[tuple[float, float, float, float]]:
        """(error, nominal σ, mean novelty, mean misfit) of the held-out experiments' weighings, each after a zero on another
        held-out experiment (with its known payload; the :data:`CROSS_ZEROS` lightest); without
        enough held-out experiments, the weighings without a zero."""
        plain = self._final_errors(held)
        if len(held) < 2:
            return plain
        offsets, zero_std = self.model.offsets.copy(), self.model.zero_std
        out = []
        lightest = np.argsort([abs(float(e.m[0])) if e.m is not None else 0.0 for e in held], kind="stable")
        for i in lightest[:CROSS_ZEROS]:
            try:
                self.model.zero([held[i]], temper=self.kappa**2)
                self.cross_zero_chi2.append(self._offset_chi2())
                out += self._final_errors([e for k, e in enumerate(held) if k != i])
            except EstimatorError:  # this one never moved inside the trained range
                pass
            finally:
                self.model.offsets, self.model.zero_std = offsets.copy(), zero_std
        return out or plain

    def _kappa(self, experiments: list[Samples]) -> float:
        """σ's scale: the experiments' final errors in units of their nominal σ (the windows
        overlap: their noise is not independent), at least 1."""
        self.kappa = 1.0
        z = [err / sigma for err, sigma, *_ in self._final_errors(experiments)]
        return float(max(np.sqrt(np.mean(np.square(z))), 1.0)) if z else 1.0

    def _fit(self, dataset: Dataset) -> None:
        import time as _time

        if not dataset.has_payload:
            raise EstimatorError(f"{self.name}: training needs the known payload of every experiment "
                                 "(a 'payload' column)")
        values = dataset.signals(self.sensor_set.signals)
        payload = dataset.frame["payload"].to_numpy(float)
        if not (np.all(np.isfinite(values)) and np.all(np.isfinite(payload))):
            raise EstimatorError(f"{self.name}: training data contain NaN or infinite values; clean them first")
        if np.ptp(dataset.payloads) <= 0:
            raise EstimatorError(f"{self.name}: the payload's balance is learned from how it changes with "
                                 "the load: give experiments with at least two different known payloads")
        started = _time.perf_counter()
        experiments = self.experiments(dataset)
        every = int(self.options["every"])
        # σ's model floor from experiments the fit did not see: every fifth held out, the rest
        # fitted, then everything fitted again
        self.model_std = 0.0
        self.floor_a, self.floor_b, self.floor_c = 0.0, 0.0, 0.0
        self.cross_zero_chi2 = []
        tilt = len(Layout(self.sensor_set.signals).tilt)
        if len(experiments) >= HELD_OUT_EVERY * 2:
            held = experiments[HELD_OUT_EVERY - 1::HELD_OUT_EVERY]
            rest = [e for i, e in enumerate(experiments) if (i + 1) % HELD_OUT_EVERY]
            self.model = self._new_model(self.sensor_set.signals)
            try:
                self.model.fit(rest, every=every)
            except EstimatorError as exc:  # enough data for the whole fit, not for four fifths
                self.fit_warnings.append(f"{self.name}: no model floor in sigma ({exc})")
            else:
                self.kappa = self._kappa(rest)
                # novelty from the fitted experiments' samples: the held-out ones are new to it
                self.novelty_mean, self.novelty_precision = novelty_statistics(
                    np.vstack([novelty_features(e) for e in rest]), tilt)
                pairs = self._cross_zero_errors(held)
                if pairs:
                    errors, nominal, novelty, misfit = np.array(pairs).T
                    self.model_std = float(np.sqrt(max(np.mean(np.square(errors)) - np.mean(np.square(nominal)), 0.0)))
                    self.floor_a, self.floor_b, self.floor_c = fit_floors(errors, nominal, novelty, misfit)
        self.model = self._new_model(self.sensor_set.signals)
        summary = self.model.fit(experiments, every=every)
        self.zero_chi2_limit = self._zero_limit(self.cross_zero_chi2)
        self.payload_scale = float(max(np.max(np.abs(payload)), 1.0))
        self._fn = None
        self.kappa = self._kappa(experiments)
        self.novelty_mean, self.novelty_precision = novelty_statistics(
            np.vstack([novelty_features(e) for e in experiments]), tilt)
        infos = [float(np.sum(w * phi * phi)) for _, _, phi, w in (self.model.terms(e) for e in experiments)]
        self.typical_info = float(np.median(infos)) if infos else 0.0
        if self.model.layout.differentiate:
            from excavator_payload.estimators.classical.pressure_regression import difference_scale, spike_threshold

            self.spike_threshold = spike_threshold(difference_scale(dataset))
        lo, hi = values.min(0), values.max(0)
        span = hi - lo
        # the joint angles' maps are polynomials fitted over the trained poses: beyond them
        # they run away; pressures, torques and rates enter the balance by physics (linearly or
        # as products), so they are only held to SIGNAL_SCALE times their trained size, and
        # gravity's direction enters exactly: a slope never trained is no extrapolation
        limit = np.array([float(self.sensor_set.plausible_abs[s]) for s in self.sensor_set.signals])
        limit = np.minimum(limit, SIGNAL_SCALE * np.maximum(np.abs(lo), np.abs(hi)) + 1e-9)
        widen = np.full(len(lo), np.inf)
        angles = [i for i, s in enumerate(self.sensor_set.signals) if s.endswith("_angle")]
        widen[angles] = ANGLE_WIDEN * span[angles] + ANGLE_MARGIN
        tilt = [i for i, s in enumerate(self.sensor_set.signals) if s.startswith("house_")]
        limit[tilt] = [float(self.sensor_set.plausible_abs[self.sensor_set.signals[i]]) for i in tilt]
        self._limits = (np.maximum(lo - widen, -limit), np.minimum(hi + widen, limit))
        self.training = {**summary, "experiments": len(experiments), "kappa": self.kappa,
                         "model_std": self.model_std, "floor_a": self.floor_a, "floor_b": self.floor_b, "floor_c": self.floor_c,
                         "seconds": round(_time.perf_counter() - started, 2)}
        self.fit_report = [f"{self.name}: learned from {len(experiments)} experiments in "
                           f"{self.training['seconds']:.1f} s; payload point {np.round(self.model.point, 3).tolist()}; "
                           f"sigma scale {self.kappa:.2f}, model floor {self.model_std:.1f} kg RMS, "
                           f"floor^2 = max({self.floor_a:.1f} + {self.floor_b:.1f} d + {self.floor_c:.1f} c, 0) kg^2 with d the "
                           "motion's distance from the training data and c its misfit (experiments held out)"]

    def fit(self, dataset: Dataset) -> "BalanceNet":
        """Learn from ``dataset`` (experiments with known payloads; no machine file is read).

        Parameters
        ----------
        dataset : Dataset
            Logged experiments with their known payloads.
        """
        super().fit(dataset)
        # no machine: the limits are the training data's envelope, and no rated payload
        self.plausible_low, self.plausible_high = self._limits
        self.rated_payload = None
        self.reset()
        return self

    # -- zero -----------------------------------------------------------------------------
    def zero(self, dataset: Dataset) -> list[str]:
        """The zero check: re-estimate the sensors' offsets from a motion of known payload (an
        empty bucket when the data carry none); returns warnings.

        Parameters
        ----------
        dataset : Dataset
            The zero motion, of the sensor set it was fitted on.
        """
        if not self.fitted or self.model is None:
            raise EstimatorError(f"{self.name}: zero needs a trained model")
        sensors = self._check_sensor_set(dataset)
        if sensors.name != self.sensor_set.name:
            raise EstimatorError(f"{self.name} was trained on the {self.sensor_set.name} sensor set, "
                                 f"not {sensors.name}")
        experiments = self.experiments(dataset.until_dump(), payload=dataset.has_payload)
        if sum(len(e) for e in experiments) < self.model.width:
            raise EstimatorError(f"{self.name}: the zero motion is shorter than one balance window")
        self.model.zero(experiments, temper=self.kappa**2)
        self._fn = None
        self.reset()
        self.zero_refusals, self.zero_report = [], []
        share = self.model.zero_std / self.payload_scale
        self.zero_report.append(f"zero: the offsets' remaining uncertainty weighs {self.model.zero_std:.1f} kg "
                                f"({100 * share:.2f} % of the largest trained payload) on motions like this one")
        if share > ZERO_REFUSE_SHARE:
            self.zero_refusals.append(f"zero: the offsets it leaves uncertain weigh {self.model.zero_std:.0f} kg, "
                                      f"more than {100 * ZERO_REFUSE_SHARE:.0f} % of the largest trained payload: "
                                      "make the zero motion move every joint, within the trained poses")
        far = self._far_offsets()
        if far:
            self.zero_refusals.append(far)
        used = sum(int(np.sum(self.model.terms(e)[3] > 0)) for e in experiments)
        if used < 100:
            return [f"{self.name}: the zero motion gave {used} usable windows (joints moving inside "
                    "the trained range); its offsets rest mostly on their prior"]
        return []

    @property
    def never_zeroed(self) -> bool:
        """A trained model that still weighs with its training logs' sensor offsets (no zero yet)."""
        return bool(self.fitted and self.model is not None and self.model.zero_std == 0.0)

    #: What an unzeroed model did on another session (docs/balance-net.md: before the day's zero
    #: every family 0 % within 1 % of the largest trained payload, 200-270 kg mean MAX).
    never_zeroed_measured = "an unzeroed balance-net weighed every motion family 200-270 kg off (mean MAX)"

    def estimate_notes(self, dataset: Dataset, estimates: pd.DataFrame | None = None) -> list[str]:
        from excavator_payload.estimators.offset_drift import never_zeroed_note

        return [never_zeroed_note(self.name, self.never_zeroed_measured)] if self.never_zeroed else []

    def _offset_chi2(self) -> float:
        """The offsets' χ² against their prior (:data:`ZERO_PRIOR`)."""
        return offsets_chi2(self.model.offsets, self.model.offset_prior_std())

    def _zero_limit(self, cross: list[float]) -> float:
        """The χ² past which a zero is refused: the :data:`ZERO_OFFSET_TAIL` quantile of a χ² of
        as many degrees of freedom as offsets, or :data:`ZERO_CROSS_MARGIN` times the largest χ²
        of the zeros the training made on its own held-out motions (``cross``), if larger: a
        model trained on little data needs larger offsets on a clean zero."""
        from scipy.stats import chi2 as chi2_distribution

        tail = float(chi2_distribution.isf(ZERO_OFFSET_TAIL, self.model.offset_count()))
        return max([tail, *(ZERO_CROSS_MARGIN * c for c in cross if np.isfinite(c))])

    def _far_offsets(self) -> str:
        """Why the offsets are beyond a session's drift (χ² past :attr:`zero_chi2_limit`), or
        ``""`` (clean zeros 0.5–29.6; 300 kg the data did not say: 40–2956)."""
        far = offsets_beyond_drift(self.offset_names(), self.model.offsets, self.model.offset_prior_std(),
                                   self.zero_chi2_limit)
        return f"zero: {far}" if far else ""

    def offset_table(self) -> list[tuple[str, float]]:
        """``(signal, offset)`` of every offset ``zero`` estimates (SI units)."""
        return list(zip(self.offset_names(), np.asarray(self.model.offsets, float).tolist()))

    def offset_names(self) -> list[str]:
        """The signals whose offsets ``zero`` estimates, in the model's order."""
        L, s = self.model.layout, self.sensor_set.signals
        names = [s[i] for i in L.q] + ([s[L.tilt[0]]] if L.tilt else [])
        return names + [s[i] for i in (L.head + L.rod if L.pressure else L.torque)]

    # -- streaming ------------------------------------------------------------------------
    def _terms_of(self, values: np.ndarray) -> np.ndarray:
        if self._fn is None:
            self._fn = sample_function(self.model)
            self._offsets = np.asarray(self.model.offsets, float)
        return np.asarray(self._fn(values, self._offsets), float).reshape(-1)

    def _reset(self) -> None:
        self.num = 0.0
        self.info = 0.0
        self.novelty = 0.0  # sum of each window's information times its novelty
        self.misfit = 0.0  # ... times its channels' χ² at the estimate after it
        self._ring: list = []  # (terms, used) of the window's samples
        self._frames: list = []  # machine set: the newest frames, not yet judged
        self._disagree = 0
        self._new = _NO_SUMS  # (num, info, novelty, misfit) of the windows no channel of the weighed load explains

    def _on_gap(self, time: float, values: np.ndarray) -> None:
        """A gap of up to :data:`MAX_BRIDGED_GAP` keeps the sums (the load is the same; each
        window is its own equation) and starts the window again; a longer one, or time going
        back, starts the weighing again."""
        if self._last_time is None or not 0.0 < time - self._last_time <= MAX_BRIDGED_GAP:
            self._reset()
        else:
            self._ring, self._frames = [], []

    def _on_skip(self, time: float, values: np.ndarray) -> None:
        """After samples the gate rejected: a window must not span the hole, the sums stay."""
        self._ring, self._frames = [], []

    def _state_finite(self) -> bool:
        return (math.isfinite(self.num) and math.isfinite(self.info) and math.isfinite(self.novelty)
                and math.isfinite(self.misfit))

    def _estimate_sigma(self) -> float:
        """κ/√I, the model's floor at the weighed windows' mean novelty (measured on held-out
        training experiments, :func:`fit_floor`) and the zero's (its offsets' uncertainty,
        :meth:`BalanceModel.zero <.balance_model.BalanceModel.zero>`)."""
        if self.info <= 0:
            return math.nan
        floor = max(self.floor_a + self.floor_b * (self.novelty / self.info) + self.floor_c * (self.misfit / self.info),
                    0.0)
        return math.sqrt(self.kappa**2 / self.info + floor + self.model.zero_std**2)

    def _novelty_of(self, values: np.ndarray) -> float:
        """The sample's distance from the training data (:func:`novelty_distance`; 0 without
        statistics)."""
        if not len(self.novelty_mean):
            return 0.0
        f = values[novelty_columns(self.model.layout)] - self.novelty_mean
        return math.sqrt(max(float(f @ self.novelty_precision @ f), 0.0))

    def _result(self) -> StepResult:
        """The weight once :attr:`ready`; before, none (``warming_up``): an early estimate rests
        on one phase of the motion and is no weight to show."""
        if not self.ready:
            return StepResult(math.nan, Status.WARMING_UP)
        return StepResult(self.num / self.info, Status.OK)

    @property
    def ready(self) -> bool:
        """The weighing holds :meth:`ready_info`."""
        return self.info > 0 and self.info >= self.ready_info()

    def ready_info(self) -> float:
        """The information from which a weight is shown: where 2κ/√I falls to ``--ready-sigma`` of
        the largest trained payload, or ``--ready`` of a median training motion's, whichever is
        less (``--ready`` 0: the first alone).

        A share of a training motion's information is a proxy that moves with the training's
        motions and left motions unlike them (slow grading, bang-bang levers) unweighed; the
        information's part of σ is stated in kg whatever they were. The share stays for a
        model whose κ is large although it weighs its own family (the thesis setting trained on
        NMPC swings alone: no test swing reached the default ``--ready-sigma``, 20 of 20).

        Returns
        -------
        float
            Information (the sum of the windows' weighted squared regressors), 1/kg².
        """
        o = self.options
        by_sigma = (2.0 * self.kappa / (float(o["ready_sigma"]) * self.payload_scale)) ** 2
        share = float(o["ready"])
        return min(by_sigma, share * self.typical_info) if share > 0 else by_sigma

    def _used(self, values: np.ndarray) -> np.ndarray:
        m = self.model
        q = values[m.layout.q]
        low, high = m.limits()
        inside = np.all((q >= low) & (q <= high))
        moving = np.abs(values[m.layout.v]) >= (m.still_rate if m.layout.pressure else 0.0)
        return moving & inside

    def _innovation(self, time: float, values: np.ndarray):
        """Thesis set (one sample per window): the sample's balance residual at the estimate."""
        m = self.model
        if m is None or m.layout.differentiate or self.info <= 0:
            return None
        t = self._terms_of(values)
        n = m.layout.n
        r, phi = t[:n], t[2 * n:3 * n]
        used = self._used(values)
        est = self.num / self.info
        var = m.channel_var + phi * phi * self.kappa**2 / self.info
        return float(np.sum(np.where(used, (r - est * phi) ** 2 / var, 0.0))), max(int(used.sum()), 1)

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        m = self.model
        if m.layout.differentiate:
            from excavator_payload.estimators.classical.pressure_regression import one_frame_glitch

            # judge the frame before this one between its neighbours; a glitch takes their mean
            self._frames.append(values)
            if len(self._frames) < 3:
                if len(self._frames) == 1:
                    return self._result()
                values = self._frames[0]
            else:
                before, mid, after = self._frames[-3:]
                self._frames = self._frames[-2:]
                if self.gating and one_frame_glitch(before, mid, after, self.spike_threshold):
                    mid = 0.5 * (before + after)
                    self._frames[0] = mid
                values = mid
        self._ring.append((self._terms_of(values), self._used(values)))
        if len(self._ring) > m.width:
            self._ring.pop(0)
        if len(self._ring) < m.width:
            return self._result()
        n = m.layout.n
        terms = np.array([t for t, _ in self._ring])
        used = np.all([u for _, u in self._ring], axis=0)
        r = (m._w @ terms[:, :n] + m._u @ terms[:, n:2 * n] / m.period) / m._span
        phi = (m._w @ terms[:, 2 * n:3 * n] + m._u @ terms[:, 3 * n:] / m.period) / m._span
        w = used / m.channel_var
        novelty = self._novelty_of(values)
        if self.gating and self.info > 0 and self.kappa / math.sqrt(self.info) <= 0.05 * self.payload_scale:
            est = self.num / self.info
            spread = np.sqrt(1.0 / np.maximum(w, 1e-300) + phi * phi * self.kappa**2 / self.info)
            agree = np.abs(r - est * phi) <= float(self.options["gate"]) * self.kappa * spread
            if np.any(w > 0) and not np.any(agree & (w > 0)):
                # the load weighed so far explains no channel: a new load, or a regime the
                # model never saw; the windows are weighed on their own meanwhile
                self._new = _add_window(self._new, w, phi, r, novelty)
                self._disagree += 1
                if self._disagree * m.period >= float(self.options["new_load"]):
                    num_new, info_new = self._new[:2]
                    if info_new > 0 and abs(num_new / info_new - est) > NEW_LOAD_SHARE * self.payload_scale:
                        self.num, self.info, self.novelty, self.misfit = self._new  # a new load
                    self._new = _NO_SUMS
                    self._disagree = 0
                return self._result()
            self._disagree = 0
            self._new = _NO_SUMS
            w = np.where(agree, w, 0.0)
        self.num, self.info, self.novelty, self.misfit = _add_window(
            (self.num, self.info, self.novelty, self.misfit), w, phi, r, novelty)
        return self._result()

    # -- persistence ------------------------------------------------------------------------
    def _config(self) -> dict:
        return {"kappa": self.kappa, "model_std": self.model_std, "floor_a": self.floor_a,
                "floor_b": self.floor_b, "floor_c": self.floor_c, "typical_info": self.typical_info, "zero_std": self.model.zero_std, "payload_scale": self.payload_scale, "training": self.training,
                "zero_chi2_limit": self.zero_chi2_limit, "tied_maps": bool(self.model.tied_maps),
                "period": self.model.period if self.model is not None else None}

    def _arrays(self) -> dict[str, np.ndarray]:
        m = self.model
        out = {"coef": m.coef, "lo": m.lo, "hi": m.hi, "channel_var": m.channel_var,
               "offsets": np.asarray(m.offsets, float), "point": m.point,
               "plausible_low": self.plausible_low, "plausible_high": self.plausible_high,
               "novelty_mean": self.novelty_mean, "novelty_precision": self.novelty_precision}
        if self.spike_threshold is not None:
            out["spike_threshold"] = self.spike_threshold
        return out

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        try:
            self.model = self._new_model(self.sensor_set.signals)
            self.model.period = float(config["period"])
            # absent in models saved before it: one map of each chamber
            self.model.tied_maps = bool(config.get("tied_maps", False))
            for key in ("coef", "lo", "hi", "channel_var", "offsets", "point"):
                setattr(self.model, key, np.asarray(arrays[key], float))
            self.kappa = float(config["kappa"])
            self.model_std = float(config.get("model_std", 0.0))
            # absent in models saved before it: the constant floor, no novelty
            self.floor_a = float(config.get("floor_a", self.model_std**2))
            self.floor_b = float(config.get("floor_b", 0.0))
            self.floor_c = float(config.get("floor_c", 0.0))
            self.novelty_mean = np.asarray(arrays["novelty_mean"], float) if "novelty_mean" in arrays else np.zeros(0)
            self.novelty_precision = (np.asarray(arrays["novelty_precision"], float).reshape(len(self.novelty_mean), -1)
                                      if "novelty_precision" in arrays else np.zeros((0, 0)))
            self.typical_info = float(config["typical_info"])
            self.model.zero_std = float(config.get("zero_std", 0.0))
            self.payload_scale = float(config["payload_scale"])
            # absent in models saved before it: the χ² quantile alone
            self.zero_chi2_limit = float(config.get("zero_chi2_limit", self._zero_limit([])))
            self.training = dict(config.get("training") or {})
            self._limits = (np.asarray(arrays["plausible_low"], float), np.asarray(arrays["plausible_high"], float))
            self.spike_threshold = (np.asarray(arrays["spike_threshold"], float)
                                    if "spike_threshold" in arrays else None)
        except (KeyError, TypeError, ValueError) as exc:
            raise EstimatorError(f"{self.name}: saved model incomplete ({exc})") from None
        n_cols = sum(self.model.block_sizes().values())
        m = self.model
        if (m.coef.shape != (n_cols,) or m.lo.shape != (m.layout.n,) or m.channel_var.shape != (m.layout.n,)
                or m.offsets.shape != (m.offset_count(),) or not np.all(m.channel_var > 0)
                or not np.all(np.isfinite(m.coef)) or not self.kappa > 0
                or (len(self.novelty_mean) and self.novelty_precision.shape
                    != (len(novelty_columns(m.layout)),) * 2)):
            raise EstimatorError(f"{self.name}: saved arrays do not match the options (corrupt model folder)")
        self.plausible_low, self.plausible_high = self._limits
        self.rated_payload = None
        self._fn = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_fn"] = None  # a CasADi function is rebuilt, not pickled
        return state


__all__ = ["BalanceNet", "sample_function"]
