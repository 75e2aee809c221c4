"""The SQP solvers generated as C: CasADi's numbers and return status, and CasADi's solver without
a compiler.

Tolerance: the generated solver runs the C runtime templates CasADi's own solver is built from,
on the same compiled model, so on this machine every output is equal to the bit. The tests allow
1e-12 (relative to the largest value) so that a C compiler that orders the same operations
differently still passes; any difference in logic (another iterate, another active set, another
exit) is many orders of magnitude larger.
"""

import casadi as ca
import numpy as np
import pytest

from excavator_payload.model import codegen
from excavator_payload.model.compiled_sqp import compiled_sqp
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.scenario import sample_scenario

needs_compiler = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler")
MACHINE = load_machine("cat345c")


def _close(a, b, what=""):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(1.0, float(np.max(np.abs(a))) if a.size else 1.0)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * scale, err_msg=what)


def _toy_solver(name, max_iter=20, tol=1e-6, start_nan=False):
    """A small NLP whose model is an external (compiled) function, as the NMPCs' are."""
    z, u = ca.SX.sym("z", 2), ca.SX.sym("u")
    model = ca.Function(f"{name}_model", [z, u], [ca.vertcat(ca.sqrt(z[0]) + u, ca.sin(z[1]) * u)],
                        ["z", "u"], ["y"])
    compiled = codegen.native(model, model.jacobian())
    x, p = ca.MX.sym("x", 3), ca.MX.sym("p")
    y = compiled(x[:2], x[2])
    # quadratic objective (the constant Hessian below is exact), nonlinear constraints
    nlp = {"x": x, "p": p, "f": ca.sumsqr(x - ca.vertcat(p, 0.1, 0.6)), "g": ca.vertcat(y, x[0] + x[1])}
    # a constant Gauss–Newton-like Hessian, as the NMPCs give (an external has no second derivatives)
    xs, ps, lam_f, lam_g = ca.SX.sym("x", 3), ca.SX.sym("p"), ca.SX.sym("lam_f"), ca.SX.sym("lam_g", 3)
    hess_lag = ca.Function(f"{name}_hess", [xs, ps, lam_f, lam_g], [lam_f * ca.SX(ca.DM.eye(3) * 2.0)],
                           ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    opts = {"qpsol": "qrqp", "max_iter": max_iter, "tol_pr": tol, "tol_du": tol, "hess_lag": hess_lag,
            "hessian_approximation": "exact",
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False,
                              "error_on_fail": False},
            "print_header": False, "print_iteration": False, "print_status": False, "print_time": False,
            "error_on_fail": False, "show_eval_warnings": False}
    return ca.nlpsol(name, "sqpmethod", nlp, opts), [model, model.jacobian()]


@needs_compiler
@pytest.mark.parametrize("case, expected", [
    ({}, "Solve_Succeeded"),
    ({"max_iter": 1}, "Maximum_Iterations_Exceeded"),
    ({"tol": 1e-300}, "Search_Direction_Becomes_Too_Small"),
    ({"start_nan": True}, "Non_Regular_Sensitivities"),
])
def test_generated_solver_gives_casadis_numbers_and_status(case, expected):
    solver, model = _toy_solver("toy_" + "_".join(case) if case else "toy", **case)
    generated = compiled_sqp([solver], model, solver.name())
    assert generated is not None
    args = dict(x0=[-0.5 if case.get("start_nan") else 0.4, 0.2, 0.3], p=1.2, lbx=[0.0, -1, -1],
                ubx=[2.0, 1, 1], lbg=[-np.inf, -1.0, -np.inf], ubg=[1.3, 1.0, 2.0], lam_x0=0.0, lam_g0=0.0)
    reference = solver(**args)
    status = solver.stats()["return_status"]
    assert status == expected
    call = generated[solver.name()]
    out = call(**{k: np.broadcast_to(np.asarray(v, float), (solver.nnz_in(k),)) for k, v in args.items()})
    assert call.stats()["return_status"] == status
    assert call.stats()["success"] == solver.stats()["success"]
    if expected != "Non_Regular_Sensitivities":  # after a failed evaluation only the status counts
        for key in ("x", "f", "g", "lam_x", "lam_g"):
            _close(out[key], np.asarray(reference[key]).ravel(), key)


def test_an_edit_that_does_not_apply_leaves_casadis_solver(monkeypatch):
    from excavator_payload.model import compiled_sqp as module

    solver, model = _toy_solver("toy_unedited")
    monkeypatch.setattr(module, "_MAX_ITER", module.re.compile("no such line"))
    assert compiled_sqp([solver], model, solver.name()) is None


def test_no_compiler_means_casadis_solver(monkeypatch):
    monkeypatch.setenv(codegen.NATIVE_ENV, "0")
    solver, model = _toy_solver("toy_no_compiler")
    assert compiled_sqp([solver], model, solver.name()) is None


def _run(settings, duration=1.5, experiment=1):
    from excavator_payload.simulation.nmpc import NMPCSimulator

    sim = NMPCSimulator(ArmModel(MACHINE), settings, duration=duration)
    sc = sample_scenario(5, experiment, MACHINE.max_payload)
    return sim, sim.run(sc.start_pose, sc.target_pose, sc.payload)


@needs_compiler
def test_thesis_nmpc_generated_solver_equals_casadis():
    from excavator_payload.simulation.nmpc import NMPCSettings

    generated_sim, generated = _run(NMPCSettings())
    casadi_sim, reference = _run(NMPCSettings(generate_solver=False))
    assert generated_sim.controller.generated_solver and not casadi_sim.controller.generated_solver
    for key in ("q", "qd", "qdd", "tau"):
        _close(getattr(generated, key), getattr(reference, key), key)
    for key in ("solver_status", "n_fallbacks", "n_solves", "reached"):
        assert generated.info[key] == reference.info[key]


def test_thesis_nmpc_without_compiler_runs_casadis_solver(monkeypatch):
    from excavator_payload.simulation.nmpc import NMPCSettings

    monkeypatch.setenv(codegen.NATIVE_ENV, "0")
    sim, result = _run(NMPCSettings(), duration=1.0, experiment=2)
    assert not sim.controller.compiled and not sim.controller.generated_solver
    monkeypatch.delenv(codegen.NATIVE_ENV)
    other, reference = _run(NMPCSettings(), duration=1.0, experiment=2)
    for key in ("q", "qd", "tau"):  # the interpreted model rounds like the compiled one (1e-9 elsewhere)
        np.testing.assert_allclose(getattr(result, key), getattr(reference, key), rtol=1e-9, atol=1e-9)
    assert result.info["solver_status"] == reference.info["solver_status"]


@needs_compiler
def test_hydraulic_nmpc_generated_solver_equals_casadis():
    from excavator_payload.simulation.hydraulic_nmpc import HydraulicNMPCSettings, HydraulicNMPCSimulator
    from excavator_payload.simulation.machine_sim import arm_model

    arm = arm_model(load_machine("cat345c-hydraulic-3pct"))
    start, target = np.array([0.3, -1.8, -1.0, 0.0]), np.array([0.6, -1.4, -0.8, 0.8])
    runs = []
    for generate in (True, False):
        sim = HydraulicNMPCSimulator(arm, HydraulicNMPCSettings(generate_solver=generate))
        assert sim.controller.generated_solver == generate
        runs.append(sim.run(start, target, np.zeros(2), 1500.0, 2.0))
    for a, b in zip(runs[0][:5], runs[1][:5]):
        _close(a, b)
    for key in ("n_solves", "n_retries", "n_plan_followed", "reached"):
        assert runs[0][5][key] == runs[1][5][key]


def test_thesis_interval_jacobians_equal_casadis():
    """The NMPC's state/input Jacobian is CasADi's own to the bit; the chain-rule one (an option)
    equals it to rounding (1e-12 relative: the operations differ, the derivative does not)."""
    from excavator_payload.simulation.nmpc import _chain_rule_jacobian, _state_input_jacobian
    from excavator_payload.simulation.plant import rk4_interval

    arm = ArmModel(MACHINE)
    model = rk4_interval(arm, 0.1, 2, "nmpc_model")
    full, blocks, chain = model.jacobian(), _state_input_jacobian(model), _chain_rule_jacobian(arm, 0.1, 2, "nmpc_model")
    assert chain.n_instructions() < 0.6 * blocks.n_instructions() < 0.6 * full.n_instructions()
    rng = np.random.default_rng(3)
    for _ in range(20):
        args = [np.r_[rng.uniform(-0.3, 0.8), rng.uniform(-2.2, -1.0), rng.normal(size=2)],
                rng.uniform(-1, 1, 2) * MACHINE.torque_limits, rng.uniform(0, MACHINE.max_payload), np.zeros((4, 0))]
        expected = [np.asarray(v) for v in full(*args)]
        for i in range(2):
            np.testing.assert_array_equal(np.asarray(blocks(*args)[i]), expected[i])
            np.testing.assert_allclose(np.asarray(chain(*args)[i]), expected[i], rtol=1e-12,
                                       atol=1e-12 * np.abs(expected[i]).max())
    assert blocks.sparsity_out(2).nnz() == chain.sparsity_out(2).nnz() == 0  # payload: never differentiated


@needs_compiler
def test_two_live_controllers_in_one_process_each_get_their_own_solver_memory():
    """CasADi's generated code keeps one static memory per live caller, one unless told: a second
    live NMPC controller in a process crashed it (segmentation fault). Five live ones now run and
    give the same numbers; past the slots a controller takes CasADi's solver."""
    from excavator_payload.model import compiled_sqp as module
    from excavator_payload.simulation.nmpc import NMPCSettings

    live = [_run(NMPCSettings(), duration=0.3) for _ in range(5)]
    assert all(sim.controller.generated_solver for sim, _ in live)
    for _, result in live[1:]:
        np.testing.assert_array_equal(result.q, live[0][1].q)
    library = next(k for k in module._LIVE if "nmpc_sqp" in k and "hyd" not in k)
    assert module._LIVE[library] >= 5
    taken = dict(module._LIVE)
    try:
        module._LIVE[library] = module.SOLVER_SLOTS
        sim, _ = _run(NMPCSettings(), duration=0.3)
        assert not sim.controller.generated_solver
    finally:
        module._LIVE.update(taken)
