r"""The learned balance of ``balance-net``: design, fit and zero (no machine file).

Per sample and measured channel :math:`j` (a joint torque, or a cylinder's two pressures) the
model says

.. math:: \underbrace{h_j(y, q_j)}_{\text{measured force}}
          - \underbrace{\sum_k d_{jk}\, T_k(q_j)\,(s_j, \dot q_j)}_{\text{friction}}
          - \underbrace{\theta^\top F_j(q,\dot q,\ddot q,\dot\psi,\hat u)}_{\text{empty arm}}
          = m\, \underbrace{\beta^\top U_j(q,\dot q,\ddot q,\dot\psi,\hat u)}_{\varphi_j}

with :math:`F` and :math:`U` the basis forces of :mod:`.chain` (symmetric pairs for the links,
every pair for the payload point), :math:`T_k` Chebyshev polynomials of the joint's angle over
its trained range and :math:`s_j` the direction of the joint's motion. A torque is measured in
N·m; a cylinder's force reaches its joint through a moment arm nobody told us, so
:math:`h_j = \sum_k a^{s}_{jk} (p_{h,j} - \rho\, p_{r,j})\,T_k(q_j)`: one map of the
piston's pressure difference per direction of motion and sign of the load, which also takes the
seals' load-proportional friction (it changes sign with the motion). Both chambers push on the
same piston, so they reach the joint through the same moment arm (:data:`AREA_RATIO` ρ). A map of
each chamber on its own (``tied_maps=False``, the structure before 2026-11-29) let the rod map
times the steady back pressure be any function of the joint's angle, which on level ground is
indistinguishable from the boom's gravity: the fit split the boom's weight between them at
random, and on a tilted house only the gravity part turns with the tilt (docs/balance-net.md,
session 19). Everything is linear in the
unknown constants: one weighted least-squares fit, with the first head-pressure map's constant
set to 1 (the balance is homogeneous: only ratios matter, and the payload comes out in kg
because :math:`m` multiplies :math:`\varphi`).

The payload is one point mass (:meth:`BalanceModel.payload_shape`): its columns' coefficients
are :math:`\kappa\,(c_a c_b, c_a)`, with the point :math:`c` found by variable projection (for
a given point everything else is linear). Free coefficients would fit any motion seen and
extrapolate badly to the ones not seen.

Near standstill (:math:`|\dot q_j|` below ``still_rate``) a cylinder's seals hold an unknown
force within their breakaway band: that channel says nothing then, in training and weighing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical.machine_calibration.data import balance_weights
from excavator_payload.estimators.learned.chain import (
    chain_forces,
    empty_arm_features,
    payload_features,
    up_from_inclination,
)

#: The arm's joints, base first, as the sensor sets name them.
JOINTS = ("boom", "dipper", "bucket")
#: Scale of pressures in the design (Pa → MPa): keeps the normal equations well conditioned.
PRESSURE_SCALE = 1e-6
#: Scale of torques in the design (N·m → kN·m).
TORQUE_SCALE = 1e-3
#: Scale of the payload's columns (kg → t).
MASS_SCALE = 1e-3
#: Rod-to-head area ratio ρ that tells a pushing cylinder from a pulling one (seal friction grows
#: with the load's size, whatever its sign: the maps differ by the load's sign as well as the
#: motion's), and with which the rod pressure enters the piston's map, ``p_h − ρ p_r``.
#: Cylinders of excavators have 0.45-0.6; a wrong guess misjudges the sign of small loads, where
#: the friction they carry is small too, and scales a map whose load side is the rod (each sign
#: of the load has its own map); ρ 0.45 / 0.5 / 0.6 against the simulated machine's 0.50-0.53
#: gave 5.1 / 4.5 / 4.1 kg RMS on noise-free 5° slopes (10.0 with untied maps; session 19).
AREA_RATIO = 0.5
#: Relative ridge on the normal equations: the basis forces are redundant on purpose (a base
#: parameter set would need the arm's structure); the ridge picks the smallest fit.
RIDGE = 1e-9
#: Zero: prior standard deviation of a pressure transmitter's offset (Pa), of an angle's and the
#: house pitch's (rad), of a torque sensor's (N·m): a datasheet's turn-on offsets, loose, so that
#: an empty motion that says little about one of them does not push it anywhere.
ZERO_PRIOR = {"pressure": 5e5, "angle": math.radians(0.5), "torque": 2e3}


class Layout:
    """Which signals of a sensor set are the joints' angles, rates, accelerations, the house's
    slew rate and inclination, and the measured forces (found by the signals' names).

    Parameters
    ----------
    signals : sequence of str
        The sensor set's signals, in their order.
    """

    def __init__(self, signals) -> None:
        signals = tuple(signals)
        idx = {s: i for i, s in enumerate(signals)}
        self.joints = [j for j in JOINTS if f"{j}_angle" in idx]
        if len(self.joints) < 2:
            raise EstimatorError("balance-net needs the angles of at least two joints")
        self.q = [idx[f"{j}_angle"] for j in self.joints]
        self.v = [idx[f"{j}_rate"] for j in self.joints]
        self.a = [idx[f"{j}_accel"] for j in self.joints if f"{j}_accel" in idx]
        self.slew = idx.get("slew_rate")
        self.tilt = [idx["house_pitch"], idx["house_roll"]] if "house_pitch" in idx else []
        self.torque = [idx[f"{j}_torque"] for j in self.joints if f"{j}_torque" in idx]
        self.head = [idx[f"{j}_head_pressure"] for j in self.joints if f"{j}_head_pressure" in idx]
        self.rod = [idx[f"{j}_rod_pressure"] for j in self.joints if f"{j}_rod_pressure" in idx]
        n = len(self.joints)
        if len(self.torque) != n and (len(self.head) != n or len(self.rod) != n):
            raise EstimatorError("balance-net needs each joint's torque or its cylinder's two pressures")
        self.pressure = len(self.torque) != n
        self.n = n
        #: accelerations differentiated from the rates (no measured accelerations)
        self.differentiate = len(self.a) != n
        self.signals = signals


#: Columns of the design, in order: (block name, sign in the balance "measured − rest = 0").
BLOCKS = (("measured", 1.0), ("friction", -1.0), ("empty", -1.0), ("payload", -1.0))


@dataclass
class Samples:
    """The signals of one experiment's consecutive samples, SI units.

    Parameters
    ----------
    q, qd : numpy.ndarray
        ``(N, n)`` joint angles and rates.
    qdd : numpy.ndarray or None
        ``(N, n)`` measured joint accelerations; None where they are not measured.
    slew : numpy.ndarray or None
        ``(N,)`` slew rate (None on a fixed base).
    tilt : numpy.ndarray or None
        ``(N, 2)`` house pitch and roll.
    head : numpy.ndarray
        ``(N, n)`` joint torques, or the cylinders' head pressures.
    rod : numpy.ndarray or None
        ``(N, n)`` rod pressures (None with torques).
    m : numpy.ndarray or None
        ``(N,)`` known payload, kg (NaN where unknown).
    """

    q: np.ndarray            # (N, n) joint angles
    qd: np.ndarray           # (N, n) joint rates
    qdd: np.ndarray | None   # (N, n) measured joint accelerations
    slew: np.ndarray | None  # (N,) slew rate
    tilt: np.ndarray | None  # (N, 2) house pitch, roll
    head: np.ndarray         # (N, n) torques or head pressures
    rod: np.ndarray | None   # (N, n) rod pressures
    m: np.ndarray | None = None  # (N,) known payload

    def __len__(self) -> int:
        return len(self.q)


def experiment_samples(layout: Layout, values: np.ndarray, payload: np.ndarray | None = None) -> Samples:
    """:class:`Samples` of one experiment from its signal rows.

    Parameters
    ----------
    layout : Layout
        Where each quantity is among the signals.
    values : numpy.ndarray
        ``(N, signals)`` rows in ``layout.signals`` order, SI units.
    payload : numpy.ndarray, optional
        ``(N,)`` known payload, kg.
    """
    L = layout
    return Samples(q=values[:, L.q], qd=values[:, L.v], qdd=None if L.differentiate else values[:, L.a],
                   slew=values[:, L.slew] if L.slew is not None else None,
                   tilt=values[:, L.tilt] if L.tilt else None,
                   head=values[:, L.head] if L.pressure else values[:, L.torque],
                   rod=values[:, L.rod] if L.pressure else None,
                   m=None if payload is None else np.asarray(payload, float))


def _chebyshev(ops, x, order: int) -> list:
    """:math:`T_0 … T_{order-1}` at ``x`` (numpy arrays or CasADi symbols)."""
    out = [1.0 + 0.0 * x, x]
    while len(out) < order:
        out.append(2.0 * x * out[-1] - out[-2])
    return out[:order]


def _correlate(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``out[i] = Σ_k weights[k]·x[i + k]`` along the first axis (the windows' sums, indexed by
    their first sample)."""
    n = len(x) - len(weights) + 1
    out = np.zeros((max(n, 0),) + x.shape[1:])
    for k, w in enumerate(weights):
        if w != 0.0 and n > 0:
            out += w * x[k:k + n]
    return out


@dataclass
class BalanceModel:
    """The fitted constants of the learned balance (module doc) and how to use them.

    Parameters
    ----------
    signals : tuple of str
        The sensor set's signals (the layout is found from their names).
    order : int
        Chebyshev polynomials per map of a joint's angle.
    still_rate : float
        rad/s: below it a cylinder's channel is not used (its seals' force is unknown).
    margin : float
        Share of a joint's trained span it may go beyond and still be weighed at.
    half_window, ramp : int
        Momentum form (accelerations not measured): samples each side of a window's centre,
        and the sample intervals over which its weight rises and falls.
    period : float
        Sample period, s.
    lo, hi : numpy.ndarray
        Fitted: each joint's trained angle range, rad.
    coef : numpy.ndarray
        Fitted: the design's coefficients (:meth:`block_sizes` order).
    channel_var : numpy.ndarray
        Fitted: each channel's residual variance in training.
    offsets : numpy.ndarray
        The sensors' offsets the zero estimated (:meth:`offset_count` of them).
    point : numpy.ndarray
        Fitted: the payload point on the basis (and the boom foot's x offset).
    zero_std : float
        kg: what the zero's remaining offset uncertainty weighs (:meth:`zero`).
    tied_maps : bool
        Pressures: one map of ``p_h − ρ p_r`` per direction of motion and sign of the load (True),
        or one of each chamber (False: models saved before 2026-11-29).
    """

    signals: tuple
    order: int = 6
    still_rate: float = 0.05
    half_window: int = 25
    ramp: int = 10
    period: float = 0.01
    margin: float = 0.1
    lo: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(0))
    coef: np.ndarray = field(default_factory=lambda: np.zeros(0))
    channel_var: np.ndarray = field(default_factory=lambda: np.ones(0))
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))
    point: np.ndarray = field(default_factory=lambda: np.zeros(0))
    zero_std: float = 0.0
    tied_maps: bool = True

    def __post_init__(self) -> None:
        self.layout = Layout(self.signals)
        if not self.layout.differentiate:
            self.half_window = 0
        w, u = balance_weights(self.half_window, max(self.ramp, 1)) if self.half_window else (np.ones(1), np.zeros(1))
        self._w, self._u = w, u
        self._span = float(w.sum())

    @property
    def width(self) -> int:
        """Samples of one window (1 with measured accelerations)."""
        return 2 * self.half_window + 1

    def _map_order(self) -> int:
        return self.order if self.layout.pressure else 1

    def offset_count(self) -> int:
        """Offsets the zero estimates: each angle, the house pitch, each measured signal."""
        L = self.layout
        return L.n + (1 if L.tilt else 0) + (2 if L.pressure else 1) * L.n

    def _corrected(self, s: Samples, ops=np) -> tuple:
        """The signals with the zero's offsets removed: ``(q, qd, qdd, slew, up, head, rod)``."""
        L = self.layout
        off = self.offsets if len(self.offsets) else np.zeros(self.offset_count())
        n = L.n
        q = [s.q[..., i] - off[i] for i in range(n)]
        qd = [s.qd[..., i] for i in range(n)]
        qdd = None if s.qdd is None else [s.qdd[..., i] for i in range(n)]
        up = up_from_inclination(ops, s.tilt[..., 0] - off[n], s.tilt[..., 1]) if L.tilt else (0.0, 1.0)
        k = n + (1 if L.tilt else 0)
        head = [s.head[..., i] - off[k + i] for i in range(n)]
        rod = [s.rod[..., i] - off[k + n + i] for i in range(n)] if L.pressure else None
        return q, qd, qdd, s.slew, up, head, rod

    # -- the design -------------------------------------------------------------------------
    def design(self, s: Samples, ops=np) -> dict[str, list]:
        """The design's blocks per sample: per block a list of columns ``(plain, momentum)``,
        each a list over channels (momentum None: none); the balance of a window is
        ``Σ w·plain + Σ u·momentum / Δt`` (module doc), and the model says
        ``measured − friction − empty − m·payload = 0`` there.

        Parameters
        ----------
        s : Samples
            The samples (arrays), or one sample's CasADi symbols.
        ops : module
            :mod:`numpy` or :mod:`casadi`.
        """
        L, K = self.layout, self._map_order()
        q, qd, qdd, slew, up, head, rod = self._corrected(s, ops)
        n = L.n
        x = [2.0 * (q[j] - self.lo[j]) / (self.hi[j] - self.lo[j]) - 1.0 for j in range(n)]
        T = [_chebyshev(ops, x[j], K) for j in range(n)]

        def only(j, value):
            col = [0.0] * n
            col[j] = value
            return (col, None)

        measured, friction = [], []
        for j in range(n):
            sgn = ops.sign(qd[j])
            if L.pressure:
                up_move, down_move = 0.5 * (1.0 + sgn), 0.5 * (1.0 - sgn)
                piston = head[j] - AREA_RATIO * rod[j]  # the piston's force over its head area
                pushes = 0.5 * (1.0 + ops.sign(piston))
                for ind in (up_move * pushes, up_move * (1.0 - pushes), down_move * pushes,
                            down_move * (1.0 - pushes)):
                    for k in range(K):
                        if self.tied_maps:
                            measured.append(only(j, ind * piston * T[j][k] * PRESSURE_SCALE))
                        else:
                            measured.append(only(j, ind * head[j] * T[j][k] * PRESSURE_SCALE))
                            measured.append(only(j, -ind * rod[j] * T[j][k] * PRESSURE_SCALE))
            else:
                measured.append(only(j, head[j] * TORQUE_SCALE))
            for feat in (0.5 * (1.0 + sgn), 0.5 * (1.0 - sgn), qd[j]):
                for k in range(K):
                    friction.append(only(j, feat * T[j][k] * TORQUE_SCALE * 100.0))
        Kf, S, G = chain_forces(ops, q, qd, qdd, slew, up)
        return {"measured": measured, "friction": friction, "empty": empty_arm_features(Kf, S, G),
                "payload": payload_features(Kf, S, G)}

    def block_sizes(self) -> dict[str, int]:
        """Columns of each block of the design."""
        L, K = self.layout, self._map_order()
        nb = 2 * L.n
        maps = 4 * K if self.tied_maps else 8 * K
        sizes = {"measured": (maps if L.pressure else 1) * L.n, "friction": 3 * K * L.n,
                 "empty": nb * (nb + 1) // 2 + nb, "payload": nb * nb + nb}
        if L.slew is not None:
            sizes["empty"] += (nb + 1) * (nb + 2) // 2 - 1
            sizes["payload"] += (nb + 1) * nb
        return sizes

    def _sample_arrays(self, s: Samples) -> tuple[np.ndarray, np.ndarray]:
        """The design per sample as two arrays ``(N, channels, columns)``: the plain parts and
        the momenta, with each block's sign of the balance (the payload's per unit mass)."""
        N, n = len(s), self.layout.n
        blocks = self.design(s)
        n_cols = sum(len(blocks[name]) for name, _ in BLOCKS)
        P = np.zeros((N, n, n_cols))
        M = np.zeros((N, n, n_cols))
        c = 0
        for name, sign in BLOCKS:
            for plain, mom in blocks[name]:
                for target, parts in ((P, plain), (M, mom)):
                    if parts is None:
                        continue
                    for j, v in enumerate(parts):
                        if not (isinstance(v, float) and v == 0.0):  # structural zeros stay
                            target[:, j, c] = sign * v
                c += 1
        return P, M

    def _sample_used(self, s: Samples) -> np.ndarray:
        """``(N, channels)``: the sample can serve the channel (its cylinder moves; every joint
        inside its trained range)."""
        low, high = self.limits()
        inside = np.all((s.q >= low) & (s.q <= high), axis=1)
        moving = np.abs(s.qd) >= (self.still_rate if self.layout.pressure else 0.0)  # seals: cylinders only
        return moving & inside[:, None]

    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        """The joint angles the model weighs at: the trained range widened by ``margin`` of its
        span each side (its polynomials turn gently there; far out they run away)."""
        span = self.hi - self.lo
        return self.lo - self.margin * span, self.hi + self.margin * span

    def _window(self, plain: np.ndarray, momentum: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """The balance of the windows starting at ``rows`` (default all), averaged over their
        span: a sparse band of the samples' weights, so that only the windows asked for cost."""
        from scipy.sparse import csr_matrix

        n = len(plain) - self.width + 1
        rows = np.arange(max(n, 0)) if rows is None else rows
        if len(rows) == 0:
            return np.zeros((0,) + plain.shape[1:])
        k = np.arange(self.width)
        index = (rows[:, None] + k[None, :]).ravel()
        indptr = np.arange(len(rows) + 1) * self.width

        def band(weights):
            return csr_matrix((np.tile(weights, len(rows)), index, indptr), shape=(len(rows), len(plain)))

        flat = lambda a: a.reshape(len(a), -1)  # noqa: E731
        out = band(self._w) @ flat(plain)
        moving = np.flatnonzero(np.any(flat(momentum) != 0.0, axis=0))  # columns with a momentum
        if len(moving):
            out[:, moving] += band(self._u / self.period) @ flat(momentum)[:, moving]
        return (out / self._span).reshape((len(rows),) + plain.shape[1:])

    def _window_used(self, used: np.ndarray) -> np.ndarray:
        """A window serves a channel if every one of its samples does."""
        return _correlate(1.0 - used.astype(float), np.ones(self.width)) == 0.0

    def _windowed(self, s: Samples, every: int = 1):
        """``(first rows, X, used, m)`` of the windows of one experiment (every ``every``-th):
        X ``(W, channels, columns)`` with the payload's columns per unit mass; ``m`` the payload
        if the same all through the window, else NaN."""
        P, M = self._sample_arrays(s)
        rows = np.arange(0, max(len(s) - self.width + 1, 0), every)
        X = self._window(P, M, rows)
        used = self._window_used(self._sample_used(s))[rows]
        m = np.full(len(rows), np.nan)
        if s.m is not None and len(rows):
            from numpy.lib.stride_tricks import sliding_window_view

            mw = sliding_window_view(s.m, self.width)[rows]
            m = np.where(mw.max(1) == mw.min(1), mw[:, 0], np.nan)
        return rows, X, used, m

    def _split(self) -> int:
        """Index of the first payload column."""
        sizes = self.block_sizes()
        return sizes["measured"] + sizes["friction"] + sizes["empty"]

    def _sample_terms(self, s: Samples) -> tuple:
        """Per sample and channel the balance's parts with the fitted constants: ``(r_plain,
        r_momentum, φ_plain, φ_momentum, used)``; a window's residual and regressor are their
        window sums (:meth:`_window`), as the streaming sensor sums them sample by sample."""
        P, M = self._sample_arrays(s)
        k = self._split()
        c = self.coef
        # the payload's columns carry the balance's minus sign: φ is the force per kg
        return (P[..., :k] @ c[:k], M[..., :k] @ c[:k], -(P[..., k:] @ c[k:]) * MASS_SCALE,
                -(M[..., k:] @ c[k:]) * MASS_SCALE, self._sample_used(s))

    def terms(self, s: Samples) -> tuple:
        """``(first rows, r, φ, weight)`` of every window of one experiment: the balance's
        residual at an empty bucket, the payload's regressor (``m = r/φ`` in kg) and the
        weight (0: not used).

        Parameters
        ----------
        s : Samples
            One experiment's samples.
        """
        rp, rm, fp, fm, used = self._sample_terms(s)
        r, phi = self._window(rp, rm), self._window(fp, fm)
        w = self._window_used(used) / self.channel_var
        return np.arange(len(r)), r, phi, w

    # -- fitting ------------------------------------------------------------------------------
    def _fixed_free(self, n_cols: int) -> tuple[list, np.ndarray]:
        """Columns whose coefficient is fixed at 1 (every torque; the first head-pressure map's
        constant) and the free ones."""
        fixed = [0] if self.layout.pressure else list(range(self.layout.n))
        return fixed, np.setdiff1d(np.arange(n_cols), fixed)

    def _normal_equations(self, X: np.ndarray, use: np.ndarray, weights: np.ndarray):
        """Weighted normal equations of the free columns: ``(G, b, yWy)``."""
        fixed, free = self._fixed_free(X.shape[2])
        G = np.zeros((len(free), len(free)))
        b = np.zeros(len(free))
        yy = 0.0
        for j in range(self.layout.n):
            rows = use[:, j]
            Xj = X[rows, j]
            yj = -Xj[:, fixed].sum(1)
            Xj = Xj[:, free]
            G += weights[j] * (Xj.T @ Xj)
            b += weights[j] * (Xj.T @ yj)
            yy += weights[j] * float(yj @ yj)
        return G, b, yy

    @staticmethod
    def _ridge_solve(G: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = np.diag(G).copy()
        d[d <= 0] = 1.0
        G = G + np.diag(RIDGE * d + RIDGE * d.mean())
        try:
            return np.linalg.solve(G, b)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(G, b, rcond=None)[0]

    def _with_fixed(self, n_cols: int, free_values: np.ndarray) -> np.ndarray:
        fixed, free = self._fixed_free(n_cols)
        coef = np.ones(n_cols)
        coef[free] = free_values
        return coef

    def payload_shape(self, point: np.ndarray) -> np.ndarray:
        r"""The payload columns' coefficients of a point mass at ``point`` = (its coefficients
        :math:`c_a` on the basis, then the boom foot's x offset): :math:`c_a c_b` for the
        :math:`K_{ab}` and :math:`S_{ab}`, foot·:math:`c_b` for :math:`S_{fb}`, :math:`c_a`
        for the :math:`G_a` (the order of :meth:`design`).

        Parameters
        ----------
        point : numpy.ndarray
            The point's coefficients on the basis, then the boom foot's x offset (slewing only).
        """
        m = 2 * self.layout.n
        c, foot = point[:m], point[m] if len(point) > m else 0.0
        parts = [np.outer(c, c).ravel()]
        if self.layout.slew is not None:
            parts += [foot * c, np.outer(c, c).ravel()]
        parts.append(c)
        return np.concatenate(parts)

    def _point_from(self, beta: np.ndarray) -> np.ndarray:
        """A first guess of the payload point from the free payload coefficients ``beta``
        (:meth:`payload_shape` times an unknown scale κ): the gravity part is κc, the
        kinetic part κccᵀ."""
        m = 2 * self.layout.n
        kin, grav = beta[:m * m].reshape(m, m), beta[-m:]
        outer = np.outer(grav, grav)
        inv_kappa = float(np.sum(0.5 * (kin + kin.T) * outer) / max(np.sum(outer * outer), 1e-300))
        if not inv_kappa > 0:
            inv_kappa = 1.0 / max(np.linalg.norm(grav), 1e-12)
        c = grav * inv_kappa
        point = [c]
        if self.layout.slew is not None:
            foot_row = beta[m * m:m * m + m]
            point.append([float(foot_row @ grav / max(grav @ grav, 1e-300))])
        return np.concatenate(point)

    def _fit_point(self, G: np.ndarray, b: np.ndarray, yy: float, n_cols: int) -> tuple[np.ndarray, np.ndarray]:
        r"""The payload as one point mass (variable projection: for a point :math:`c` the
        rest is linear; :math:`c` minimises what is left). Returns ``(point, free coefficients)``."""
        from scipy.optimize import minimize

        fixed, free = self._fixed_free(n_cols)
        n_payload = self.block_sizes()["payload"]
        n_rest = len(free) - n_payload
        G_rr, G_rp, G_pp = G[:n_rest, :n_rest], G[:n_rest, n_rest:], G[n_rest:, n_rest:]
        b_r, b_p = b[:n_rest], b[n_rest:]
        beta0 = self._ridge_solve(G, b)[n_rest:]
        scale = 1.0

        def reduced(point):
            h = self.payload_shape(point)
            Gr = np.empty((n_rest + 1, n_rest + 1))
            Gr[:n_rest, :n_rest] = G_rr
            Gr[:n_rest, n_rest] = Gr[n_rest, :n_rest] = G_rp @ h
            Gr[n_rest, n_rest] = h @ G_pp @ h
            br = np.append(b_r, h @ b_p)
            return Gr, br, h

        def cost(point):
            Gr, br, _ = reduced(point)
            x = self._ridge_solve(Gr, br)
            return (yy - 2 * x @ br + x @ Gr @ x) / scale

        start = self._point_from(beta0)
        scale = max(abs(cost(start)), 1e-300)
        best = minimize(cost, start, method="BFGS", options={"gtol": 1e-10, "maxiter": 500})
        point = best.x if best.fun <= cost(start) else start
        Gr, br, h = reduced(point)
        x = self._ridge_solve(Gr, br)
        return point, np.concatenate([x[:n_rest], x[n_rest] * h])

    def fit(self, experiments: list[Samples], every: int = 5) -> dict:
        """Fit every constant to ``experiments`` (their known payloads); returns a summary.

        The windows' per-channel Gram matrices are summed experiment by experiment (every
        ``every``-th window: neighbours share most samples), so memory stays small.

        Parameters
        ----------
        experiments : list of Samples
            The training experiments, each with its known payload ``m``.
        every : int
            Train on every ``every``-th window.
        """
        L = self.layout
        if not experiments or any(e.m is None for e in experiments):
            raise EstimatorError("balance-net: training needs the known payload of every sample")
        q = np.concatenate([e.q for e in experiments])
        self.lo, self.hi = q.min(0), q.max(0)
        self.hi = self.lo + np.maximum(self.hi - self.lo, 1e-3)
        self.offsets = np.zeros(self.offset_count())
        k = self._split()
        every = max(1, min(every, self.width))  # windows of one sample share nothing
        grams, counts = None, np.zeros(L.n)
        for e in experiments:
            _, X, used, m = self._windowed(e, every)
            ok = np.isfinite(m)
            X, used, m = X[ok], used[ok], m[ok]
            X[..., k:] *= (m * MASS_SCALE)[:, None, None]
            if grams is None:
                grams = np.zeros((L.n, X.shape[2], X.shape[2]))
            for j in range(L.n):
                Xj = X[used[:, j], j]
                grams[j] += Xj.T @ Xj
                counts[j] += len(Xj)
        if grams is None or np.any(counts < 2 * grams.shape[1] / L.n):
            raise EstimatorError("balance-net: too few moving samples with a known payload to learn from "
                                 f"({int(counts.min())} windows of the least moving joint)")
        n_cols = grams.shape[1]
        fixed, free = self._fixed_free(n_cols)

        def variance(coef):
            return np.array([coef @ grams[j] @ coef / counts[j] for j in range(L.n)])

        def normal(weights):
            Gw = np.tensordot(weights, grams, 1)
            one = np.ones(len(fixed))
            return (Gw[np.ix_(free, free)], -Gw[np.ix_(free, fixed)] @ one,
                    float(one @ Gw[np.ix_(fixed, fixed)] @ one))

        weights = np.ones(L.n)
        for _ in range(2):  # free payload columns; the weights from their residuals
            G, b, yy = normal(weights)
            var = variance(self._with_fixed(n_cols, self._ridge_solve(G, b)))
            weights = 1.0 / np.maximum(var, 1e-30)
        G, b, yy = normal(weights)
        self.point, free_values = self._fit_point(G, b, yy, n_cols)
        self.coef = self._with_fixed(n_cols, free_values)
        self.channel_var = np.maximum(variance(self.coef), 1e-30)
        return {"windows": int(counts.max()), "channel_std": np.sqrt(self.channel_var).tolist(),
                "payload_point": self.point.tolist()}

    # -- zero -----------------------------------------------------------------------------
    def offset_prior_std(self) -> np.ndarray:
        """Prior std of each offset :meth:`zero` estimates (:data:`ZERO_PRIOR`, SI units): the
        angles' (and the house pitch's), then the pressures' or torques'."""
        L = self.layout
        angles = L.n + (1 if L.tilt else 0)
        other = ZERO_PRIOR["pressure" if L.pressure else "torque"]
        return np.array([ZERO_PRIOR["angle"] if i < angles else other for i in range(self.offset_count())])

    def zero(self, experiments: list[Samples], temper: float = 1.0) -> np.ndarray:
        """Re-estimate the sensors' offsets from motions of known payload (``m``; an empty
        bucket when None): the maximum a-posteriori offsets under :data:`ZERO_PRIOR`, from the
        balance linearised in them, the windows' information divided by ``temper``. Returns the
        change of the offsets.

        Parameters
        ----------
        experiments : list of Samples
            The zero motion(s); their payload ``m`` (None: an empty bucket).
        temper : float
            How many times the windows' nominal information overstates what the motion tells
            (``balance-net`` passes κ²: the windows overlap and the model's error runs along a
            motion). With 1 a long zero motion overrides the prior and its offsets take up the
            model's error on that motion.
        """
        if not temper >= 1.0:
            raise EstimatorError(f"balance-net: the zero's temper must be >= 1 (got {temper})")
        L = self.layout
        n_off = self.offset_count()
        base = self.offsets.copy()
        prior = self.offset_prior_std()
        angles = L.n + (1 if L.tilt else 0)
        steps = [1e-4 if i < angles else (1e3 if L.pressure else 10.0) for i in range(n_off)]

        def residual(off):
            self.offsets = off
            out, regressors, weights = [], [], []
            for e in experiments:
                _, r, phi, w = self.terms(e)
                m = np.zeros(len(r)) if e.m is None else e.m[:len(r)]
                out.append(r - np.nan_to_num(m)[:, None] * phi)
                regressors.append(phi)
                weights.append(w)
            return np.concatenate(out), np.concatenate(regressors), np.concatenate(weights)

        try:
            r0, phi, w = residual(base)
            J = []
            for i in range(n_off):
                off = base.copy()
                off[i] += steps[i]
                J.append((residual(off)[0] - r0) / steps[i])
        finally:
            self.offsets = base
        if not np.any(w > 0):
            raise EstimatorError("balance-net: the zero motion never moves a joint inside the trained range")
        J = np.stack(J, 2)
        A = np.diag(1.0 / np.square(prior))
        g = np.zeros(n_off)
        for j in range(L.n):
            A += (J[:, j] * w[:, j:j + 1]).T @ J[:, j] / temper
            g += (J[:, j] * w[:, j:j + 1]).T @ r0[:, j] / temper
        delta = np.linalg.solve(A, -g)
        self.offsets = base + delta
        # how the offsets' remaining uncertainty (the posterior's covariance A⁻¹) weighs on a
        # weighing of motions like this one: σ² = sᵀA⁻¹s, s = ∂m̂/∂offsets
        info = float(np.sum(w * phi * phi))
        sens = np.einsum("nj,nj,njk->k", w, phi, J) / info if info > 0 else np.zeros(n_off)
        self.zero_std = float(np.sqrt(max(sens @ np.linalg.solve(A, sens), 0.0)))
        return delta

