"""trainbr / Adam trainers: known answers on small problems."""

import math

import numpy as np
import pandas as pd
import pytest
import torch

from excavator_payload.estimators.dvs.common import (
    mlp_forward,
    mlp_output_jacobian,
    mlp_sizes,
    n_weights,
    nguyen_widrow_init,
)
from excavator_payload.estimators.dvs.trainbr import (
    LOG_COLUMNS,
    TrainingLog,
    jacobian_forward,
    train_adam,
    train_br,
)

torch.set_num_threads(1)


def _sin_problem(hidden=8, n=41):
    x = torch.linspace(-2.0, 2.0, n, dtype=torch.float64)[:, None]
    t = torch.sin(x[:, 0])
    sizes = mlp_sizes(1, [hidden])

    def residuals(w):
        return t - mlp_forward(w, x, sizes)[:, 0]

    w0 = nguyen_widrow_init(sizes, torch.Generator().manual_seed(3))
    return residuals, w0, x, sizes


def test_trainbr_fits_sine():
    residuals, w0, x, sizes = _sin_problem()
    w, log = train_br(residuals, w0, epochs=100, progress=False)
    x_dense = torch.linspace(-2.0, 2.0, 401, dtype=torch.float64)[:, None]
    err = torch.sin(x_dense[:, 0]) - mlp_forward(w, x_dense, sizes)[:, 0]
    assert float(err.abs().max()) < 1e-3  # between the training points too
    assert log.sse[-1] < 1e-2 * log.sse[0]
    # SSE is not monotone under changing α, β, but the regularised fit ends far below the start
    assert log.trainer == "trainbr" and log.n_errors == 41 and log.n_parameters == n_weights(sizes)


def test_gamma_well_below_parameter_count_for_redundant_network():
    # a straight line through noisy points: 61 weights, a handful of them really needed
    rng = np.random.default_rng(0)
    x = torch.as_tensor(np.linspace(-1, 1, 60)[:, None])
    t = torch.as_tensor(0.6 * np.linspace(-1, 1, 60) + 0.05 * rng.standard_normal(60))
    sizes = mlp_sizes(1, [20])

    def residuals(w):
        return t - mlp_forward(w, x, sizes)[:, 0]

    w, log = train_br(residuals, nguyen_widrow_init(sizes, torch.Generator().manual_seed(1)),
                      epochs=200, progress=False)
    P = n_weights(sizes)
    assert log.gamma[1] == pytest.approx(P)  # first update: α was 0, so γ = P
    assert log.gamma[-1] < P / 6
    assert log.gamma[-1] >= 1.0
    # the residual is about the noise: β ≈ 1/(2σ²) within a factor of two
    assert 0.5 < log.beta[-1] * 2 * 0.05**2 < 2.0


def test_first_step_and_hyperparameter_update_match_hand_computation():
    rng = np.random.default_rng(5)
    A = rng.standard_normal((7, 3))
    t_np = rng.standard_normal(7)
    A_t, t = torch.as_tensor(A), torch.as_tensor(t_np)
    w0_np = np.array([0.3, -0.2, 0.1])

    def residuals(w):
        return t - A_t @ w

    w1, log = train_br(residuals, torch.as_tensor(w0_np), epochs=1, progress=False)
    # epoch 1 with α = 0, β = 1, μ = 0.005: Δw = −(JᵀJ + μI)⁻¹ Jᵀe with J = ∂e/∂w = −A
    J = -A
    e0 = t_np - A @ w0_np
    dw = -np.linalg.solve(J.T @ J + 0.005 * np.eye(3), J.T @ e0)
    np.testing.assert_allclose(w1.numpy(), w0_np + dw, rtol=1e-10, atol=1e-12)
    e1 = t_np - A @ (w0_np + dw)
    E_D, E_W = e1 @ e1, (w0_np + dw) @ (w0_np + dw)
    assert log.sse[1] == pytest.approx(E_D)
    assert log.gamma[1] == pytest.approx(3.0)
    assert log.alpha[1] == pytest.approx(3.0 / (2 * E_W))
    assert log.beta[1] == pytest.approx((7 - 3.0) / (2 * E_D))
    assert log.mu[1] == pytest.approx(0.005)

    # epoch 2 uses the new α, β and μ·0.1, and γ = P − α tr((βJᵀJ + αI)⁻¹)
    w2, log2 = train_br(residuals, torch.as_tensor(w0_np), epochs=2, progress=False)
    a, b, mu = log.alpha[1], log.beta[1], 0.0005
    w1_np = w0_np + dw
    dw2 = -np.linalg.solve(b * J.T @ J + (mu + a) * np.eye(3), b * J.T @ e1 + a * w1_np)
    np.testing.assert_allclose(w2.numpy(), w1_np + dw2, rtol=1e-9, atol=1e-12)
    gamma2 = 3 - a * np.trace(np.linalg.inv(b * J.T @ J + a * np.eye(3)))
    assert log2.gamma[2] == pytest.approx(gamma2)
    assert log2.mu[2] == pytest.approx(mu)


def test_stops_on_small_gradient():
    t = torch.ones(5, dtype=torch.float64)

    def residuals(w):  # nothing to learn: J = 0 and, with α = 0, ∇F = 0
        return t + 0.0 * w.sum()

    w, log = train_br(residuals, torch.zeros(2, dtype=torch.float64), epochs=50, progress=False)
    assert log.stop_reason.startswith("minimum gradient")
    assert len(log.epoch) == 1


def test_stops_when_mu_exceeds_maximum():
    A = torch.eye(3, dtype=torch.float64)
    t = torch.ones(3, dtype=torch.float64)

    def residuals(w):
        return t - A @ w

    # a Jacobian of the wrong sign: every step goes uphill, μ grows until it exceeds μ_max
    w, log = train_br(residuals, torch.zeros(3, dtype=torch.float64), epochs=50, progress=False,
                      jacobian=lambda w: A.clone(), mu_max=1e3)
    assert log.stop_reason.startswith("maximum mu")
    assert torch.equal(w, torch.zeros(3, dtype=torch.float64))


def test_stops_at_epoch_limit():
    residuals, w0, _, _ = _sin_problem()
    _, log = train_br(residuals, w0, epochs=3, progress=False)
    assert log.epoch == [0, 1, 2, 3]
    assert log.stop_reason.startswith("maximum epochs")


def test_validation_is_logged():
    residuals, w0, _, _ = _sin_problem()
    _, log = train_br(residuals, w0, epochs=5, progress=False,
                      validation=lambda w: float(residuals(w) @ residuals(w)) * 2)
    np.testing.assert_allclose(log.validation_sse, 2 * np.array(log.sse))


def test_forward_jacobian_equals_finite_differences():
    residuals, w0, _, _ = _sin_problem(hidden=3, n=9)
    J = jacobian_forward(residuals, w0, chunk_size=4).numpy()
    h = 1e-6
    fd = np.stack([(residuals(w0 + h * torch.eye(len(w0), dtype=torch.float64)[k])
                    - residuals(w0 - h * torch.eye(len(w0), dtype=torch.float64)[k])).numpy() / (2 * h)
                   for k in range(len(w0))], axis=1)
    np.testing.assert_allclose(J, fd, atol=1e-7)


def test_adam_reduces_error_and_logs_nan_hyperparameters():
    residuals, w0, _, _ = _sin_problem()
    w, log = train_adam(residuals, w0, epochs=300, lr=0.02, progress=False)
    assert log.sse[-1] < 0.1 * log.sse[0]
    assert all(math.isnan(g) for g in log.gamma)
    assert log.trainer == "adam"
    assert float(residuals(w) @ residuals(w)) == pytest.approx(log.sse[-1])


def test_log_frame_roundtrip_and_plot(tmp_path):
    residuals, w0, _, _ = _sin_problem()
    _, log = train_br(residuals, w0, epochs=4, progress=False)
    frame = log.to_frame()
    assert list(frame.columns) == list(LOG_COLUMNS)
    back = TrainingLog.from_frame(frame, log.stop_reason, log.seconds, log.n_errors, log.n_parameters, "trainbr")
    pd.testing.assert_frame_equal(back.to_frame(), frame)
    log.plot(tmp_path / "fig" / "training.png")
    assert (tmp_path / "fig" / "training.png").stat().st_size > 1000


def test_time_limit_stops_training():
    residuals, w0, _, _ = _sin_problem()
    _, log = train_br(residuals, w0, epochs=50, progress=False, max_seconds=0.0)
    assert log.epoch == [0, 1] and log.stop_reason.startswith("time limit")
    _, log = train_adam(residuals, w0, epochs=50, progress=False, max_seconds=0.0)
    assert log.stop_reason.startswith("time limit") and len(log.epoch) == 1


def _line_problem():
    """Rosenbrock's valley as least squares: many small epochs before it converges."""
    def residuals(w):
        return torch.stack([10 * (w[1] - w[0] ** 2), 1 - w[0]])

    return residuals


@pytest.mark.parametrize("trainer", ["trainbr", "adam"])
def test_best_validation_returns_the_weights_of_the_lowest_validation_error(trainer):
    """The validation error is scripted as a V (lowest at the 3rd call): those weights come back,
    and patience 4 stops training four epochs after the minimum."""
    from excavator_payload.estimators.dvs.trainbr import train_adam, train_br

    scripted = [5.0, 4.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]
    seen = []

    def validation(w):
        seen.append(w.detach().clone())
        return scripted[len(seen) - 1]

    train = train_br if trainer == "trainbr" else train_adam
    kwargs = {"min_grad": 0.0} if trainer == "trainbr" else {"lr": 0.05}
    w, log = train(_line_problem(), torch.tensor([-1.2, 1.0], dtype=torch.float64), epochs=10,
                   validation=validation, progress=False, best_validation=True,
                   validation_patience=4, **kwargs)
    assert log.best_epoch == log.epoch[2]
    assert torch.equal(w, seen[2])
    assert "not improved for 4 epochs" in log.stop_reason
    assert len(log.epoch) == 7  # epochs 0..6: the minimum at index 2, then four worse ones
    assert log.returned_validation_sse == 1.0


def test_without_best_validation_the_last_weights_come_back():
    from excavator_payload.estimators.dvs.trainbr import train_br

    calls = []

    def validation(w):
        calls.append(w.detach().clone())
        return float(len(calls))  # only ever gets worse

    w, log = train_br(_line_problem(), torch.tensor([-1.2, 1.0], dtype=torch.float64), epochs=5,
                      validation=validation, progress=False)
    assert log.best_epoch == -1
    assert torch.equal(w, calls[-1])


# -- the Cholesky epoch against the eigen-decomposition it replaced ---------------------------------
def _eigh_step(H, g, alpha, beta, mu):
    """The step as the previous release took it: one eigen-decomposition of H."""
    s, V = np.linalg.eigh(H)
    s = s.clip(min=0.0)
    return -(V @ ((V.T @ g) / (beta * s + mu + alpha)))


def _eigh_gamma(H, alpha, beta):
    s = np.linalg.eigvalsh(H).clip(min=0.0)
    return len(s) - alpha * np.sum(1.0 / (beta * s + alpha)) if alpha > 0 else float(len(s))


def _net_problem(n=300, hidden=(6, 5), seed=0):
    """A small MLP fit (rank-deficient-ish Gauss–Newton Hessian, like the real nets')."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 4, generator=gen, dtype=torch.float64) * 2 - 1
    t = torch.sin(2 * x[:, 0]) * x[:, 1] + 0.3 * x[:, 2] ** 2 + 0.01 * torch.randn(n, generator=gen, dtype=torch.float64)
    sizes = mlp_sizes(4, list(hidden))

    def residuals(w):
        return t - mlp_forward(w, x, sizes)[:, 0]

    return residuals, x, sizes, nguyen_widrow_init(sizes, torch.Generator().manual_seed(seed + 1))


@pytest.mark.parametrize("alpha, beta, mu", [(0.0, 1.0, 0.005), (0.37, 120.0, 1e-3), (2.5, 3e4, 1e-9),
                                             (1e-3, 50.0, 10.0), (0.8, 7e3, 0.0)])
def test_cholesky_step_and_gamma_equal_the_eigendecomposition(alpha, beta, mu):
    from excavator_payload.estimators.dvs.trainbr import effective_parameters, lm_step

    residuals, x, sizes, w = _net_problem()
    J = -mlp_output_jacobian(w, x, sizes).numpy()
    e = residuals(w).numpy()
    H = J.T @ J
    g = beta * (J.T @ e) + alpha * w.numpy()
    step = lm_step(np.asfortranarray(np.triu(H)), g, alpha, beta, mu)  # reads the upper triangle only
    ref = _eigh_step(H, g, alpha, beta, mu)
    np.testing.assert_allclose(step, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    assert effective_parameters(H, alpha, beta) == pytest.approx(_eigh_gamma(H, alpha, beta), rel=1e-9, abs=1e-9)


def test_a_matrix_that_is_not_positive_definite_is_a_failed_trial():
    from excavator_payload.estimators.dvs.trainbr import effective_parameters, lm_step

    H = np.diag([4.0, 1.0, 0.0])  # singular: μ + α = 0 leaves it singular, any shift > 0 does not
    assert lm_step(H, np.ones(3), 0.0, 1.0, 0.0) is None
    np.testing.assert_allclose(lm_step(H, np.ones(3), 0.0, 1.0, 1.0), -1 / np.array([5.0, 2.0, 1.0]))
    assert effective_parameters(H, 0.5, 2.0) == pytest.approx(3 - 0.5 * (1 / 8.5 + 1 / 2.5 + 1 / 0.5))


def _train_br_eigh(residuals, jacobian, w0, epochs, mu=0.005):
    """The previous release's trainbr epoch (eigh of JᵀJ), as a reference."""
    w = w0.clone()
    e = residuals(w)
    alpha, beta, P, N = 0.0, 1.0, w.numel(), e.numel()
    e_d, e_w, sse, gammas = float(e @ e), float(w @ w), [], []
    for _ in range(epochs):
        J = jacobian(w).numpy()
        H, g = J.T @ J, beta * (J.T @ e.numpy()) + alpha * w.numpy()
        cost = beta * e_d + alpha * e_w
        while True:
            w_new = w + torch.from_numpy(_eigh_step(H, g, alpha, beta, mu))
            e_new = residuals(w_new)
            if beta * float(e_new @ e_new) + alpha * float(w_new @ w_new) < cost:
                break
            mu *= 10.0
        w, e, mu = w_new, e_new, mu * 0.1
        e_d, e_w = float(e @ e), float(w @ w)
        gamma = _eigh_gamma(H, alpha, beta)
        alpha, beta = gamma / (2 * e_w), (N - gamma) / (2 * e_d)
        sse.append(e_d)
        gammas.append(gamma)
    return w, sse, gammas


def _block_jacobian(x, sizes, size):
    from excavator_payload.estimators.dvs.trainbr import BlockJacobian, row_blocks

    rows = row_blocks(len(x), size)
    return BlockJacobian([lambda w, out=None, r=r: mlp_output_jacobian(w, x[r], sizes, negate=True, out=out)
                          for r in rows], rows)


@pytest.mark.parametrize("blocks", [False, True])
def test_training_follows_the_eigendecomposition_epochs(blocks):
    residuals, x, sizes, w0 = _net_problem()
    jacobian = _block_jacobian(x, sizes, 70) if blocks else (lambda w: -mlp_output_jacobian(w, x, sizes))
    w_ref, sse_ref, gamma_ref = _train_br_eigh(residuals, lambda w: -mlp_output_jacobian(w, x, sizes), w0, 25)
    w, log = train_br(residuals, w0, epochs=25, progress=False, jacobian=jacobian, min_grad=0.0, threads=2)
    assert log.epoch[-1] == 25
    np.testing.assert_allclose(log.sse[1:], sse_ref, rtol=1e-9)
    np.testing.assert_allclose(log.gamma[1:], gamma_ref, rtol=1e-9)
    np.testing.assert_allclose(w.numpy(), w_ref.numpy(), rtol=1e-7, atol=1e-9)
    assert log.gamma[-1] < 0.9 * log.n_parameters  # the regularisation took hold: a real test of γ


def test_same_bits_for_any_thread_count():
    residuals, x, sizes, w0 = _net_problem(n=400)
    jacobian = _block_jacobian(x, sizes, 50)
    runs = [train_br(residuals, w0, epochs=12, progress=False, jacobian=jacobian, threads=n) for n in (1, 2, 3)]
    for w, log in runs[1:]:
        assert torch.equal(w, runs[0][0])
        pd.testing.assert_frame_equal(log.to_frame(), runs[0][1].to_frame(), check_exact=True)


def test_threads_inside_training_are_the_jobs_not_the_libraries():
    """The blocks run on at most `threads` threads of trainbr's own pool; torch and BLAS are
    single-threaded inside (their pools would fight ours), and come back afterwards."""
    import threading

    from threadpoolctl import threadpool_info

    from excavator_payload.estimators.dvs.trainbr import BlockJacobian, row_blocks

    residuals, x, sizes, w0 = _net_problem(n=600)
    rows = row_blocks(len(x), 40)
    seen = []

    def block(r):
        def run(w, out=None):
            seen.append((threading.current_thread().name, torch.get_num_threads(),
                         {i["num_threads"] for i in threadpool_info()}))
            return mlp_output_jacobian(w, x[r], sizes, negate=True, out=out)
        return run

    torch.set_num_threads(2)
    try:
        train_br(residuals, w0, epochs=3, progress=False, jacobian=BlockJacobian([block(r) for r in rows], rows),
                 threads=2)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)
    names = {name for name, _, _ in seen}
    assert names and all(name.startswith("trainbr") for name in names) and len(names) <= 2
    assert {n for _, n, _ in seen} == {1} and set().union(*(s for _, _, s in seen)) == {1}
    seen.clear()
    train_br(residuals, w0, epochs=1, progress=False, jacobian=BlockJacobian([block(r) for r in rows], rows),
             threads=1)
    assert {name for name, _, _ in seen} == {threading.main_thread().name}


def test_default_threads_are_the_cores_the_job_is_given(tmp_path):
    """In a process allowed one core (its CPU affinity), or told one thread, trainbr runs its
    blocks in the calling thread; given two cores it uses a pool of its own, never more
    threads than cores."""
    import os
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import os, sys, threading, torch
        from excavator_payload.estimators.dvs.common import mlp_forward, mlp_output_jacobian, mlp_sizes, nguyen_widrow_init
        from excavator_payload.estimators.dvs.trainbr import BlockJacobian, row_blocks, train_br
        from excavator_payload.execution import job_threads
        x = torch.linspace(-1, 1, 400, dtype=torch.float64)[:, None]
        sizes = mlp_sizes(1, [5])
        rows = row_blocks(400, 20)
        cores = sorted(os.sched_getaffinity(0))

        def probe(n_cores, threads_env=None):
            os.sched_setaffinity(0, set(cores[:n_cores]))
            os.environ.pop("EXCAVATOR_PAYLOAD_THREADS", None)
            if threads_env:
                os.environ["EXCAVATOR_PAYLOAD_THREADS"] = threads_env
            names = set()
            def block(r):
                def run(w, out=None):
                    names.add(threading.current_thread().name)
                    return mlp_output_jacobian(w, x[r], sizes, negate=True, out=out)
                return run
            train_br(lambda w: torch.sin(3 * x[:, 0]) - mlp_forward(w, x, sizes)[:, 0],
                     nguyen_widrow_init(sizes, torch.Generator().manual_seed(0)), epochs=2, progress=False,
                     jacobian=BlockJacobian([block(r) for r in rows], rows))
            return f"{job_threads()}:{'pool' if any(n.startswith('trainbr') for n in names) else 'here'}"

        print(probe(1), probe(len(cores), "1"), probe(2), probe(2, "64"))
    """)
    path = tmp_path / "probe.py"
    path.write_text(script)
    environ = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "EXCAVATOR_PAYLOAD_THREADS")}

    def run(**env):
        done = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=120,
                              env={**environ, **env})
        assert done.returncode == 0, done.stderr
        return done.stdout.split()

    one_core, told_one, two_cores, told_too_many = run()
    assert one_core == "1:here" and told_one == "1:here"
    if len(os.sched_getaffinity(0)) >= 2:
        assert two_cores == "2:pool" and told_too_many == "2:pool"  # never more than the cores
    assert run(OMP_NUM_THREADS="1")[2] == "1:here"  # OMP_NUM_THREADS as the job started is a request too


def _trials(log, mu_dec):
    """Levenberg–Marquardt trials of each epoch, read from the damping the log records:
    an epoch starts at μ_prev·μ_dec and multiplies by μ_inc = 10 per failed trial."""
    mu = np.asarray(log.mu)
    start = np.r_[mu[0], mu[1:-1] * mu_dec]
    return 1 + np.round(np.log10(mu[1:] / start)).astype(int)


@pytest.mark.parametrize("threads", [2, 3])
def test_trials_side_by_side_take_the_damping_one_after_the_other_would(threads):
    """On a pool the next `threads` dampings are tried at once; the first that lowers F must
    win, exactly as in one thread, also when an epoch needs more trials than there are threads
    (a large μ_dec makes the first trials of every epoch fail)."""
    residuals, x, sizes, w0 = _net_problem(n=250, seed=3)
    jacobian = _block_jacobian(x, sizes, 60)
    kwargs = dict(epochs=15, progress=False, jacobian=jacobian, mu=10.0, mu_dec=1e-4)
    w1, log1 = train_br(residuals, w0, threads=1, **kwargs)
    trials = _trials(log1, 1e-4)
    assert trials.max() > threads  # some epoch needed more than one batch of trials
    assert (trials % threads != 0).any()  # and some accepted a trial inside a batch
    w, log = train_br(residuals, w0, threads=threads, **kwargs)
    assert torch.equal(w, w1)
    pd.testing.assert_frame_equal(log.to_frame(), log1.to_frame(), check_exact=True)
