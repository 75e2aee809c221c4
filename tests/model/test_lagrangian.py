"""The CasADi arm model against an independent sympy derivation done as thesis appendix A.1.

Appendix A.1 (``Model.mat``) builds the frames with homogeneous transforms
T1 = Rz(q1)·Tx(l1/2), T2 = T1·Tx(l1/2)·Rz(q2)·Tx(l2/2), T3 = T2·Tx(l2/2), differentiates the
frame origins in time, forms K, P = −Σ m gᵀp (g = [0, −g, 0]) and the Rayleigh function D, and
applies Euler–Lagrange d/dt ∂K/∂q̇ − ∂K/∂q + ∂P/∂q + ∂D/∂q̇ = T. We repeat that here with sympy,
then compare numerically with ``symbolic().functions`` at random states and parameters.
"""

from functools import lru_cache

import numpy as np
import pytest
import sympy as sp

from excavator_payload.model.dynamics import PARAMETER_NAMES, symbolic


def _rz(angle):
    return sp.Matrix([[sp.cos(angle), -sp.sin(angle), 0, 0], [sp.sin(angle), sp.cos(angle), 0, 0],
                      [0, 0, 1, 0], [0, 0, 0, 1]])


def _tx(length):
    return sp.Matrix([[1, 0, 0, length], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


@lru_cache(maxsize=1)
def appendix_a1_model():
    """Lambdified (torque, mass matrix) from the appendix-A.1 derivation."""
    t = sp.symbols("t", real=True)
    q1f, q2f = sp.Function("q1")(t), sp.Function("q2")(t)
    l1, l2, m1, m2, mb, beta1, beta2, g, mload = sp.symbols(
        "l1 l2 m1 m2 mb beta1 beta2 g mload", real=True)
    J1, J2 = m1 * l1**2 / 12, m2 * l2**2 / 12

    T1 = _rz(q1f) * _tx(l1 / 2)
    T2 = T1 * _tx(l1 / 2) * _rz(q2f) * _tx(l2 / 2)
    T3 = T2 * _tx(l2 / 2)
    poses = [T[:3, 3] for T in (T1, T2, T3)]
    v2 = [sum(c**2 for c in p.diff(t)) for p in poses]  # |v|² of each origin

    dq1f, dq2f = q1f.diff(t), q2f.diff(t)
    m3 = mb + mload  # bucket + payload, point mass at the dipper tip
    K = (sp.Rational(1, 2) * (m1 * v2[0] + J1 * dq1f**2)
         + sp.Rational(1, 2) * (m2 * v2[1] + J2 * (dq1f + dq2f) ** 2)
         + sp.Rational(1, 2) * m3 * v2[2])
    gvec = sp.Matrix([0, -g, 0])
    P = -(m1 * gvec.dot(poses[0]) + m2 * gvec.dot(poses[1]) + m3 * gvec.dot(poses[2]))
    D = sp.Rational(1, 2) * (beta1 * dq1f**2 + beta2 * dq2f**2)

    # Partial derivatives with respect to q and q̇ need plain symbols in their place.
    q1, q2, dq1, dq2, ddq1, ddq2 = sp.symbols("q1 q2 dq1 dq2 ddq1 ddq2", real=True)
    to_sym = {dq1f: dq1, dq2f: dq2}
    to_sym_q = {q1f: q1, q2f: q2}
    back = {dq1: dq1f, dq2: dq2f}
    Ks, Ds = K.subs(to_sym), D.subs(to_sym)
    torques = []
    for qf, dq in ((q1f, dq1), (q2f, dq2)):
        dK_ddq = Ks.diff(dq).subs(back)
        term = (dK_ddq.diff(t) - Ks.subs(to_sym_q).diff({q1f: q1, q2f: q2}[qf]).subs(
            {q1: q1f, q2: q2f}) + P.diff(qf) + Ds.diff(dq).subs(back))
        term = term.subs({q1f.diff(t, 2): ddq1, q2f.diff(t, 2): ddq2})
        term = term.subs({dq1f: dq1, dq2f: dq2}).subs({q1f: q1, q2f: q2})
        torques.append(sp.expand(term))
    mass_matrix = sp.Matrix(2, 2, lambda i, j: sp.diff(torques[i], (ddq1, ddq2)[j]))
    args = (q1, q2, dq1, dq2, ddq1, ddq2, mload, l1, l2, m1, m2, mb, beta1, beta2, g)
    return (sp.lambdify(args, torques, "numpy"), sp.lambdify(args, mass_matrix, "numpy"))


def _random_case(rng):
    q = rng.uniform([-0.8, -2.6], [1.0, -0.3])
    qd = rng.uniform(-1.0, 1.0, 2)
    qdd = rng.uniform(-3.0, 3.0, 2)
    payload = rng.uniform(0.0, 5000.0)
    # Random machines around the CAT 345C: every parameter can matter.
    p = np.array([rng.uniform(3, 8), rng.uniform(1.5, 4), rng.uniform(1e3, 8e3), rng.uniform(5e2, 4e3),
                  rng.uniform(5e2, 4e3), rng.uniform(0, 5e5), rng.uniform(0, 5e5), rng.uniform(9.7, 9.9)])
    assert len(p) == len(PARAMETER_NAMES)
    return q, qd, qdd, payload, p


def test_inverse_dynamics_matches_appendix_a1_derivation():
    torque_fn, _ = appendix_a1_model()
    f = symbolic().functions["inverse_dynamics"]
    rng = np.random.default_rng(0)
    for _ in range(25):
        q, qd, qdd, payload, p = _random_case(rng)
        l1, l2, m1, m2, mb, b1, b2, g = p
        expected = np.array(torque_fn(*q, *qd, *qdd, payload, l1, l2, m1, m2, mb, b1, b2, g), dtype=float)
        got = np.asarray(f(q, qd, qdd, payload, p)).ravel()
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-6 * np.abs(expected).max())


def test_mass_matrix_matches_appendix_a1_derivation():
    _, mass_fn = appendix_a1_model()
    f = symbolic().functions["mass_matrix"]
    rng = np.random.default_rng(1)
    for _ in range(25):
        q, qd, qdd, payload, p = _random_case(rng)
        l1, l2, m1, m2, mb, b1, b2, g = p
        expected = np.array(mass_fn(*q, *qd, *qdd, payload, l1, l2, m1, m2, mb, b1, b2, g), dtype=float)
        got = np.asarray(f(q, payload, p))
        np.testing.assert_allclose(got, expected, rtol=1e-10)
        assert np.all(np.linalg.eigvalsh(got) > 0), "mass matrix must be positive definite"


def test_forward_dynamics_inverts_inverse_dynamics():
    funcs = symbolic().functions
    rng = np.random.default_rng(2)
    for _ in range(10):
        q, qd, qdd, payload, p = _random_case(rng)
        tau = funcs["inverse_dynamics"](q, qd, qdd, payload, p)
        back = np.asarray(funcs["forward_dynamics"](q, qd, tau, payload, p)).ravel()
        np.testing.assert_allclose(back, qdd, rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("joint", [0, 1])
def test_derivation_detects_a_wrong_model(joint):
    """The comparison can fail: a 1 % heavier bucket changes the torques by far more than rtol."""
    torque_fn, _ = appendix_a1_model()
    f = symbolic().functions["inverse_dynamics"]
    q, qd, qdd, payload, p = _random_case(np.random.default_rng(3))
    l1, l2, m1, m2, mb, b1, b2, g = p
    expected = np.array(torque_fn(*q, *qd, *qdd, payload, l1, l2, m1, m2, mb * 1.01, b1, b2, g), dtype=float)
    got = np.asarray(f(q, qd, qdd, payload, p)).ravel()
    assert abs(got[joint] - expected[joint]) > 1e-6 * abs(expected[joint])
