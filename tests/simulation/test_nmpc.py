"""The NMPC-driven simulator: reaches the target, respects the torque limits, records truth."""

import numpy as np
import pytest

from excavator_payload.data.schema import SAMPLES_PER_EXPERIMENT
from excavator_payload.model.dynamics import ArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.generate import _simulator, simulate_nmpc_experiment
from excavator_payload.simulation.scenario import sample_scenario

MACHINE = load_machine("cat345c")


@pytest.fixture(scope="module")
def runs():
    """Three experiments of seed 5 (the process-wide simulator is built once)."""
    out = []
    for k in range(3):
        sc = sample_scenario(5, k, MACHINE.max_payload)
        out.append((sc, _simulator(MACHINE).run(sc.start_pose, sc.target_pose, sc.payload)))
    return out


def test_reaches_target_at_rest(runs):
    for sc, res in runs:
        assert res.info["reached"], res.info
        assert res.info["settle_time"] is not None and res.info["settle_time"] < 5.0
        np.testing.assert_allclose(res.q[-1], sc.target_pose, atol=np.radians(1))
        assert np.abs(res.qd[-1]).max() < np.radians(1)
        # It starts at rest at the start pose.
        np.testing.assert_allclose(res.q[0], sc.start_pose, atol=1e-12)
        np.testing.assert_allclose(res.qd[0], 0.0, atol=1e-12)


def test_torque_limits_and_zero_order_hold(runs):
    for _, res in runs:
        assert res.tau.shape == (SAMPLES_PER_EXPERIMENT, 2)
        assert np.all(np.abs(res.tau) <= MACHINE.torque_limits * (1 + 1e-6))
        # Control period 0.1 s = two 20 Hz samples: inputs change only at even samples.
        assert np.all(res.tau[1::2] == res.tau[0:-1:2])
        # The motion is a real swing, not a jump: the torque changes gradually.
        assert np.abs(np.diff(res.tau, axis=0)).max() < MACHINE.torque_limits.max()


def test_samples_satisfy_the_inverse_dynamics(runs):
    arm = ArmModel(MACHINE)
    for sc, res in runs:
        tau = arm.inverse_dynamics(res.q, res.qd, res.qdd, sc.payload)
        np.testing.assert_allclose(tau, res.tau, rtol=1e-8, atol=1e-3)


def test_info_fields(runs):
    for _, res in runs:
        info = res.info
        for key in ("final_error_deg", "reached", "solver_status", "n_fallbacks", "wall_time",
                    "solve_time_median_ms", "settle_time"):
            assert key in info
        assert info["n_solves"] == 51


def test_experiment_rows_and_metadata():
    frame, meta = simulate_nmpc_experiment(2, 5, MACHINE, "none", True)
    assert len(frame) == SAMPLES_PER_EXPERIMENT
    np.testing.assert_allclose(frame["time"].to_numpy(), np.arange(101) * 0.05)
    assert (frame["experiment"] == 2).all()
    np.testing.assert_array_equal(frame["boom_angle"], frame["true_boom_angle"])  # noise "none"
    for key in ("seed", "start_pose", "target_pose", "payload", "final_error_deg", "reached",
                "solver_status", "n_fallbacks", "wall_time"):
        assert key in meta
    assert meta["seed"] == 5 and meta["experiment"] == 2


def test_ipopt_fallback_agrees_with_sqp():
    """Forcing the fallback (every SQP plan rejected) gives IPOPT's input: the same optimum."""
    sc = sample_scenario(5, 1, MACHINE.max_payload)
    state = np.array([*sc.start_pose, 0.0, 0.0])
    sqp = _simulator(MACHINE).controller
    sqp.reset(state, np.array(sc.target_pose), sc.payload)
    u_sqp = sqp.control(state)
    assert not sqp.records[-1].fallback
    saved = sqp.settings.max_defect
    sqp.settings.max_defect = -1.0  # no plan is good enough: always fall back
    try:
        sqp.reset(state, np.array(sc.target_pose), sc.payload)
        u_ipopt = sqp.control(state)
    finally:
        sqp.settings.max_defect = saved
    assert sqp.records[-1].fallback and sqp.records[-1].status.startswith("ipopt")
    np.testing.assert_allclose(u_ipopt, u_sqp, rtol=1e-3, atol=1e-3 * MACHINE.torque_limits.max())


def test_interpreted_model_gives_the_same_control_as_the_compiled_one():
    from excavator_payload.simulation.nmpc import NMPCController, NMPCSettings

    sc = sample_scenario(5, 0, MACHINE.max_payload)
    state = np.array([*sc.start_pose, 0.0, 0.0])
    compiled = _simulator(MACHINE).controller
    interpreted = NMPCController(ArmModel(MACHINE), NMPCSettings(jit=False))
    assert not interpreted.compiled
    controls = []
    for ctl in (compiled, interpreted):
        ctl.reset(state, np.array(sc.target_pose), sc.payload)
        controls.append(ctl.control(state))
    np.testing.assert_allclose(controls[0], controls[1], rtol=1e-9, atol=1e-3)


def test_compiled_library_is_cached_on_disk(tmp_path, monkeypatch):
    import casadi as ca

    from excavator_payload.model import codegen

    if codegen.compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("EXCAVATOR_PAYLOAD_CACHE", str(tmp_path))
    x = ca.SX.sym("x", 2)
    f = ca.Function("tiny_model", [x], [ca.sin(x) * x[0]])
    first = codegen.compiled_library([f, f.jacobian()], "tiny_model")
    assert first.parent == tmp_path / "native" and first.exists()
    stamp = first.stat().st_mtime_ns
    again = codegen.compiled_library([f, f.jacobian()], "tiny_model")
    assert again == first and again.stat().st_mtime_ns == stamp  # loaded, not recompiled
    # no temporary left; the library's SHA-256 beside it
    assert sorted(p.name for p in (tmp_path / "native").iterdir()) == [first.name, first.name + ".sha256"]
    ext = ca.external("tiny_model", str(first))
    np.testing.assert_allclose(np.asarray(ext([0.3, 0.7])).ravel(), np.sin([0.3, 0.7]) * 0.3)
