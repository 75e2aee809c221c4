r"""The balance of any planar arm on a slewing house, as features linear in unknown constants.

``balance-net`` knows no machine: no lengths, masses or cylinder pins. What it builds in is what
holds for *every* excavator arm — a serial chain of links turning about parallel axes in one
plane, on a house that slews about the vertical — and nothing else. With :math:`q_i` the joint
angles (each relative to the link before) and :math:`\phi_k = \sum_{i \le k} q_i` the links'
absolute angles, every point of link :math:`k` sits at

.. math:: p = f + \sum_{i<k} l_i\, e(\phi_i) + u\, e(\phi_k) + w\, e^\perp(\phi_k),
   \qquad e(\phi) = (\cos\phi, \sin\phi),\ e^\perp(\phi) = (-\sin\phi, \cos\phi),

a *linear* combination :math:`p = \sum_a c_a b_a(q)` of the basis vectors
:math:`b = (e(\phi_1), e^\perp(\phi_1), \dots)` with constant coefficients (plus the boom
foot's constant offset :math:`f`). The Lagrangian of a point mass,
:math:`L = \tfrac12 m(\|\dot p\|^2 + \dot\psi^2 p_x^2) + m\,g_H\cdot p` (house frame rotating
at the slew rate :math:`\dot\psi`, gravity :math:`g_H` from the house's inclination), and so of
every rigid link (a sum of point masses, its rotational inertia included), is then a linear
combination of the *basis Lagrangians* :math:`\dot b_a\cdot\dot b_b`,
:math:`\dot\psi^2 b_{a,x} b_{b,x}` and :math:`g_H\cdot b_a`. Their Euler–Lagrange forces on
the arm's joints,

.. math::

   K_{ab} = B_a^\top \ddot b_b, \qquad
   S_{ab} = -\dot\psi^2\, b_{a,x} B_{b,x}^\top, \qquad
   G_a = B_a^\top \hat u,
   \qquad B_a = \partial b_a/\partial q,\quad
   \ddot b_a = B_a\ddot q + \dot B_a \dot q,

(:math:`\hat u` the unit "up" of the house frame in the arm's plane) are known functions of the
measured motion: the empty arm's generalised force is :math:`\sum \theta\,(K, S, G)` with
unknown constants :math:`\theta`, and a payload at :math:`p = \sum_a c_a b_a` adds exactly

.. math:: m\,Q(c) = m \Big(\sum_{a,b} c_a c_b K_{ab} + \sum_{a,b} c_a c_b S_{ab}
          + g \sum_a c_a G_a\Big).

(The classical result that rigid-body dynamics are linear in the inertial parameters, Atkeson,
An & Hollerbach 1986; Khalil & Dombre 2002, written here in a basis that needs no lengths.)

Every function here takes ``ops`` — :mod:`numpy` (arrays of samples, training and streaming)
or :mod:`casadi` (symbols, for the C export) — and works on lists of per-joint quantities, so
that one piece of code serves both.
"""

from __future__ import annotations

#: Standard gravity, m/s² (a constant of nature, not of a machine).
GRAVITY = 9.81


def _basis(ops, q, qd, qdd):
    """Basis vectors of the links' absolute angles.

    Returns lists over the ``2·n`` basis vectors (``e(φ_k)``, ``e⊥(φ_k)`` for each link ``k``) of
    ``(b, B, Bdot, bd, bdd)``: ``b = (x, z)``, ``B[i] = (∂x/∂q_i, ∂z/∂q_i)``, ``Bdot[i]`` its time
    derivative, ``bd = (ẋ, ż)`` and ``bdd = (ẍ, z̈)`` (None without accelerations)."""
    n = len(q)
    out = []
    phi, phid, phidd = 0.0, 0.0, 0.0
    for k in range(n):
        phi, phid = phi + q[k], phid + qd[k]
        if qdd is not None:
            phidd = phidd + qdd[k]
        c, s = ops.cos(phi), ops.sin(phi)
        w2 = phid * phid
        zero = 0.0 * c
        # e = (c, s): ∂e/∂φ = e⊥ = (−s, c), d/dt e⊥ = −e φ̇; ë = e⊥ φ̈ − e φ̇²
        rows = [(-s, c) if i <= k else (zero, zero) for i in range(n)]
        rows_d = [(-c * phid, -s * phid) if i <= k else (zero, zero) for i in range(n)]
        bdd = (-s * phidd - c * w2, c * phidd - s * w2) if qdd is not None else None
        out.append(((c, s), rows, rows_d, (-s * phid, c * phid), bdd))
        # e⊥ = (−s, c): ∂e⊥/∂φ = −e, d/dt(−e) = −e⊥ φ̇; ë⊥ = −e φ̈ − e⊥ φ̇²
        rows = [(-c, -s) if i <= k else (zero, zero) for i in range(n)]
        rows_d = [(s * phid, -c * phid) if i <= k else (zero, zero) for i in range(n)]
        bdd = (-c * phidd + s * w2, -s * phidd - c * w2) if qdd is not None else None
        out.append(((-s, c), rows, rows_d, (-c * phid, -s * phid), bdd))
    return out


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1]


def chain_forces(ops, q, qd, qdd=None, slew_rate=None, up=None):
    r"""The basis forces :math:`K_{ab}`, :math:`S_{ab}`, :math:`G_a` of samples (module doc).

    Parameters
    ----------
    ops : module
        :mod:`numpy` or :mod:`casadi`.
    q, qd : list
        Joint angles and rates, one entry (array of samples or symbol) per joint.
    qdd : list or None
        Joint accelerations. None: the *momentum form*, for data whose accelerations are not
        measured: :math:`K_{ab} = \frac{d}{dt}P_{ab} - R_{ab}` with the momentum
        :math:`P_{ab} = B_a^\top \dot b_b` and :math:`R_{ab} = \dot B_a^\top \dot b_b`, functions
        of the angles and rates alone; a window's balance then needs no acceleration
        (:meth:`~.balance_model.BalanceModel.windowed`).
    slew_rate : array or symbol, optional
        The house's slew rate (none on a fixed base).
    up : tuple, optional
        The house frame's unit "up" in the arm's plane ``(x, z)``; default straight up.

    Returns
    -------
    K : dict of (a, b) -> (plain, momentum)
        Per ordered pair of basis vectors, two lists over the joints: the force's plain part
        and the momentum whose time derivative adds to it (``None`` with accelerations given:
        then ``plain`` is ``B_aᵀ b̈_b``).
    S : dict of (a, b) -> list
        ``−ψ̇² b_{a,x} B_{b,x}`` per joint; ``a`` runs over the basis and ``"f"`` (a constant
        offset along x: the boom foot), ``b`` over the basis. Empty without a slew rate.
    G : dict of a -> list
        ``B_aᵀ û`` per joint.
    """
    n = len(q)
    basis = _basis(ops, q, qd, qdd)
    if up is None:
        up = (0.0, 1.0)
    K, S, G = {}, {}, {}
    for a, (_, Ba, Bda, _, _) in enumerate(basis):
        G[a] = [_dot(Ba[i], up) for i in range(n)]
        for b, (_, Bb, _, bdb, bddb) in enumerate(basis):
            if qdd is not None:
                K[(a, b)] = ([_dot(Ba[i], bddb) for i in range(n)], None)
            else:
                K[(a, b)] = ([-_dot(Bda[i], bdb) for i in range(n)], [_dot(Ba[i], bdb) for i in range(n)])
    if slew_rate is not None:
        w2 = slew_rate * slew_rate
        xs = [("f", 1.0)] + [(a, v[0][0]) for a, v in enumerate(basis)]
        for a, xa in xs:
            for b, v in enumerate(basis):
                S[(a, b)] = [-w2 * xa * v[1][i][0] for i in range(n)]
    return K, S, G


def _add(u, v):
    if u is None or v is None:
        return u if v is None else v
    return [x + y for x, y in zip(u, v)]


def empty_arm_features(K, S, G):
    """The rigid links' features as ``(plain, momentum)`` columns (lists over joints; momentum
    None when there is none): symmetric pairs of the basis Lagrangians (a rigid body's
    Lagrangian is symmetric in them).

    Parameters
    ----------
    K, S, G : dict
        The basis forces of :func:`chain_forces`.
    """
    feats = []
    m = len(G)
    for a in range(m):
        for b in range(a, m):
            (pa, ma), (pb, mb) = K[(a, b)], K[(b, a)]
            feats.append((_add(pa, pb), _add(ma, mb)) if a != b else (list(pa), ma))
    if S:
        keys = ["f"] + list(range(m))
        for i, a in enumerate(keys):
            for b in keys[i:]:
                if a == "f" and b == "f":
                    continue  # a constant: no force
                if a == "f":
                    feats.append((list(S[("f", b)]), None))
                elif a == b:
                    feats.append((list(S[(a, a)]), None))
                else:
                    feats.append((_add(S[(a, b)], S[(b, a)]), None))
    feats.extend((list(G[a]), None) for a in range(m))
    return feats


def payload_features(K, S, G):
    """The payload point's features as ``(plain, momentum)`` columns: every ordered pair
    :math:`K_{ab}`, then :math:`S_{fb}` and :math:`S_{ab}`, then :math:`g\\,G_a` (the order of
    :meth:`~.balance_model.BalanceModel.payload_shape`).

    Parameters
    ----------
    K, S, G : dict
        The basis forces of :func:`chain_forces`.
    """
    m = len(G)
    cols = [K[(a, b)] for a in range(m) for b in range(m)]
    if S:
        cols += [(S[(a, b)], None) for a in ["f", *range(m)] for b in range(m)]
    cols += [([GRAVITY * g for g in G[a]], None) for a in range(m)]
    return cols


def up_from_inclination(ops, house_pitch, house_roll):
    """The house frame's unit "up" in the arm's plane from the house IMU's pitch and roll (the
    angles of its x and y axes above the horizontal): ``(sin pitch, √(1 − sin² pitch − sin² roll))``.

    Parameters
    ----------
    ops : module
        :mod:`numpy` or :mod:`casadi`.
    house_pitch, house_roll : array or symbol
        The house IMU's pitch and roll, rad.
    """
    sp, sr = ops.sin(house_pitch), ops.sin(house_roll)
    return sp, ops.sqrt(ops.fmax(1.0 - sp * sp - sr * sr, 0.0))
