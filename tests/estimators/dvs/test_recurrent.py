"""Tests of the recurrent virtual sensors ``net2`` (closed-loop NARX) and ``lrn``."""

import math

import numpy as np
import pandas as pd
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.estimators.dvs.recurrent import (
    LayerRecurrentNetwork,
    Net2,
    RecurrentStepper,
    RecurrentStructure,
    bptt_jacobian,
    experiment_jacobian,
    init_weights,
    narx_jacobian,
    open_loop_gradients,
    parse_delay_option,
    rollout,
    unpack_weights,
)
from excavator_payload.estimators.dvs.trainbr import jacobian_forward, train_br

torch.set_num_threads(1)


def _tiny_narx_weights():
    # One signal, input delays 0 and 1, output fed back at t−1, one tanh neuron:
    #   a_k = tanh(0.5 u_k − 0.25 u_{k−1} + 0.8 ŷ_{k−1} + 0.1),   ŷ_k = 2 a_k − 0.3
    structure = RecurrentStructure(n_signals=1, hidden=(1,), input_delays=(0, 1), feedback_delays=(1,))
    w = torch.tensor([0.5, -0.25, 0.8, 0.1, 2.0, -0.3], dtype=torch.float64)
    return structure, w


def test_closed_loop_rollout_matches_hand_computation():
    structure, w = _tiny_narx_weights()
    u = np.array([1.0, -2.0, 0.5, 3.0])
    y0 = 0.7
    # by hand: the first estimate is at k = 1 (input delay line of 2 samples), fed y0
    a1 = math.tanh(0.5 * -2.0 - 0.25 * 1.0 + 0.8 * y0 + 0.1)
    y1 = 2 * a1 - 0.3
    a2 = math.tanh(0.5 * 0.5 - 0.25 * -2.0 + 0.8 * y1 + 0.1)
    y2 = 2 * a2 - 0.3
    a3 = math.tanh(0.5 * 3.0 - 0.25 * 0.5 + 0.8 * y2 + 0.1)
    y3 = 2 * a3 - 0.3
    expected = [y1, y2, y3]
    got = rollout(w, torch.tensor(u)[None, :, None], structure, y0)[0].numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-14)
    stepper = RecurrentStepper(w.numpy(), structure, y0)
    stream = [stepper.step(np.array([v])) for v in u]
    assert math.isnan(stream[0])
    np.testing.assert_allclose(stream[1:], expected, rtol=1e-14)
    # the feedback is the network's own estimate, not a target: changing y0 changes everything
    other = rollout(w, torch.tensor(u)[None, :, None], structure, -0.7)[0].numpy()
    assert np.all(np.abs(other - got) > 1e-6)


def test_experiments_do_not_cross_in_batch_rollout():
    structure = RecurrentStructure(n_signals=2, hidden=(3, 2), input_delays=(0, 2), feedback_delays=(1, 2))
    w = init_weights(structure, torch.Generator().manual_seed(3))
    u = torch.randn(3, 9, 2, dtype=torch.float64)
    together = rollout(w, u, structure, 0.2)
    for e in range(3):
        alone = rollout(w, u[e:e + 1], structure, 0.2)[0]
        torch.testing.assert_close(together[e], alone, rtol=0, atol=0)
    assert together.shape == (3, 9 - 2)


@pytest.mark.parametrize("structure", [
    RecurrentStructure(6, (10, 10, 10), tuple(range(6)), (1,)),
    RecurrentStructure(3, (4, 5), (0, 2), (1, 3)),
    RecurrentStructure(2, (3, 4, 2), (0,), (), (1, 2), (0, 1, 2)),
    RecurrentStructure(2, (3, 4), (0, 1), (1,), (1,), (1,)),
])
def test_stepper_equals_rollout(structure):
    w = init_weights(structure, torch.Generator().manual_seed(0))
    u = torch.randn(3, 15, structure.n_signals, dtype=torch.float64)
    batch = rollout(w, u, structure, 0.3).numpy()
    stepper = RecurrentStepper(w.numpy(), structure, 0.3)
    for e in range(3):
        stepper.reset()
        out = np.array([stepper.step(u[e, k].numpy()) for k in range(15)])
        assert np.all(np.isnan(out[:structure.warmup]))
        np.testing.assert_allclose(out[structure.warmup:], batch[e], rtol=1e-12, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(n_signals=st.integers(1, 3), hidden=st.lists(st.integers(1, 4), min_size=1, max_size=3),
       input_delays=st.sets(st.integers(0, 3), min_size=1), feedback=st.sets(st.integers(1, 3), max_size=2),
       layer_delays=st.sets(st.integers(1, 3), max_size=2), recurrent=st.sets(st.integers(0, 2), max_size=3),
       length=st.integers(1, 12), seed=st.integers(0, 1000), y0=st.floats(-2, 2))
def test_stepper_equals_rollout_for_any_structure(n_signals, hidden, input_delays, feedback, layer_delays,
                                                   recurrent, length, seed, y0):
    structure = RecurrentStructure(n_signals, tuple(hidden), tuple(sorted(input_delays)),
                                   tuple(sorted(feedback)), tuple(sorted(layer_delays)),
                                   tuple(sorted(r for r in recurrent if r < len(hidden))))
    w = init_weights(structure, torch.Generator().manual_seed(seed))
    T = structure.warmup + length
    u = torch.randn(2, T, n_signals, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    batch = rollout(w, u, structure, y0).numpy()
    stepper = RecurrentStepper(w.numpy(), structure, y0)
    for e in range(2):
        stepper.reset()
        out = np.array([stepper.step(u[e, k].numpy()) for k in range(T)])
        assert np.all(np.isnan(out[:structure.warmup]))
        np.testing.assert_allclose(out[structure.warmup:], batch[e], rtol=1e-12, atol=1e-12)


def test_open_loop_gradients_equal_torch_func():
    structure = RecurrentStructure(3, (4, 5), (0, 1), (1,))
    w = init_weights(structure, torch.Generator().manual_seed(1))
    x = torch.randn(7, structure.layer_shapes()[0][1], dtype=torch.float64)

    def one(w_, x_):
        a = x_
        layers = unpack_weights(w_, structure)
        for W, b in layers[:-1]:
            a = torch.tanh(W @ a + b)
        return (layers[-1][0] @ a + layers[-1][1])[0]

    dw, dx = torch.func.vmap(torch.func.grad(one, argnums=(0, 1)), in_dims=(None, 0))(w, x)
    got_dw, got_dx = open_loop_gradients(w, x, structure)
    torch.testing.assert_close(got_dw, dw)
    torch.testing.assert_close(got_dx, dx)


@pytest.mark.parametrize("structure", [
    RecurrentStructure(2, (4, 3), (0, 1, 2), (1,)),
    RecurrentStructure(2, (3, 3), (0, 1), (1, 2)),
])
def test_narx_jacobian_is_the_closed_loop_jacobian(structure):
    """The fast RTRL Jacobian equals forward-mode AD through the whole closed-loop rollout."""
    w = init_weights(structure, torch.Generator().manual_seed(2))
    u = torch.randn(4, 12, 2, dtype=torch.float64)
    reference = jacobian_forward(lambda v: rollout(v, u, structure, -0.4).reshape(-1), w)
    y, S = narx_jacobian(w, u, structure, -0.4)
    torch.testing.assert_close(S.reshape(-1, structure.n_weights), reference)
    torch.testing.assert_close(y, rollout(w, u, structure, -0.4))
    # and it really flows through the feedback: the open-loop (teacher-forced) Jacobian differs
    open_loop, _ = open_loop_gradients(w, _open_inputs(u, y, structure, -0.4), structure)
    assert float((open_loop.reshape(S.shape) - S).abs().max()) > 1e-3


def _open_inputs(u, y, structure, y0):
    from excavator_payload.estimators.dvs.recurrent import tapped_delay_inputs

    K = structure.warmup
    x = tapped_delay_inputs(u, structure.input_delays, K)
    pad = max(structure.feedback_delays)
    padded = torch.cat([y.new_full((y.shape[0], pad), y0), y], dim=1)
    fb = torch.stack([padded[:, pad - f:pad - f + y.shape[1]] for f in structure.feedback_delays], -1)
    return torch.cat([x, fb], -1).reshape(-1, structure.layer_shapes()[0][1])


@pytest.mark.parametrize("structure", [
    RecurrentStructure(2, (3, 2), (0,), (), (1, 2), (0, 1)),          # layrecnet
    RecurrentStructure(2, (3, 4, 2), (0, 1), (1, 2), (1, 3), (0, 2)),  # feedback and layer loops
    RecurrentStructure(2, (3,), (0, 2), (1,)),                         # NARX
])
def test_bptt_jacobians_equal_forward_mode(structure):
    w = init_weights(structure, torch.Generator().manual_seed(4))
    u = torch.randn(5, 9, 2, dtype=torch.float64)
    reference = jacobian_forward(lambda v: rollout(v, u, structure, 0.1).reshape(-1), w)
    for got in (experiment_jacobian(w, u, structure, 0.1), bptt_jacobian(w, u, structure, 0.1, chunk=2)):
        torch.testing.assert_close(got.reshape(-1, structure.n_weights), reference)


def test_training_learns_a_recursive_system():
    """A NARX net trained in closed loop learns y_k = 0.8 y_{k−1} + 0.2 u_k (an exponential
    running mean of its input, which needs the feedback: 6 input delays cannot see far enough)."""
    gen = torch.Generator().manual_seed(5)
    u = (2 * torch.rand(30, 40, 1, generator=gen, dtype=torch.float64) - 1)
    target = torch.zeros(30, 40, dtype=torch.float64)
    y = torch.zeros(30, dtype=torch.float64)
    for k in range(40):
        y = 0.8 * y + 0.2 * u[:, k, 0]
        target[:, k] = y
    def train(structure):
        K = structure.warmup

        def residuals(w):
            return (target[:, K:] - rollout(w, u, structure, 0.0)).reshape(-1)

        def jacobian(w):
            return -narx_jacobian(w, u, structure, 0.0)[1].reshape(-1, structure.n_weights)

        w0 = init_weights(structure, torch.Generator().manual_seed(6))
        w, log = train_br(residuals, w0, epochs=60, progress=False, jacobian=jacobian)
        # compare on the same samples (k >= 5) whatever the delay line
        rms = lambda v: float(residuals(v).reshape(30, -1)[:, 5 - K:].pow(2).mean().sqrt())  # noqa: E731
        return rms(w0), rms(w), log

    rms0, rms, log = train(RecurrentStructure(1, (4,), (0,), (1,)))
    assert rms0 > 0.1
    assert rms < 0.1 * rms0
    assert log.sse[-1] < log.sse[0] / 100
    # a same-size net without feedback but a 6-sample input window does clearly worse
    _, rms_window, _ = train(RecurrentStructure(1, (4,), tuple(range(6)), ()))
    assert rms < 0.7 * rms_window


# -- the estimators --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def trained_net2(mj_dataset):
    est = create_estimator("net2", hidden="6,6", epochs=12, train_experiments=15,
                           validation_experiments=5, progress=False, seed=1)
    return est.fit(mj_dataset)


@pytest.fixture(scope="module")
def trained_lrn(mj_dataset):
    est = create_estimator("lrn", hidden="4,4", epochs=4, train_experiments=10,
                           validation_experiments=0, progress=False)
    return est.fit(mj_dataset)


def test_net2_training_reduces_error(trained_net2, mj_dataset):
    log = trained_net2.training_log
    assert log.sse[-1] < 0.1 * log.sse[0]
    assert log.validation_sse[-1] < log.validation_sse[0]
    assert trained_net2.initial_payload == pytest.approx(np.mean(mj_dataset.payloads[:15]))
    est = trained_net2.estimate(mj_dataset)
    truth = mj_dataset.frame["payload"].to_numpy()
    ok = est["status"] == "ok"
    # far better than guessing the mean payload (the spread of the payloads)
    assert np.sqrt(np.mean((est["payload_estimate"][ok] - truth[ok]) ** 2)) < 0.5 * np.std(truth)


@pytest.mark.parametrize("which", ["trained_net2", "trained_lrn"])
def test_streaming_equals_batch(which, request, mj_dataset):
    est = request.getfixturevalue(which)
    part = mj_dataset.subset(mj_dataset.experiment_ids[:4])
    streamed = est.estimate(part)  # reset per experiment + step loop (numpy)
    inputs = [rows[list(est.input_names)].to_numpy(float) for _, rows in part.experiments()]
    batch = np.concatenate(est.predict_experiments(inputs))  # torch closed-loop rollout
    np.testing.assert_allclose(streamed["payload_estimate"].to_numpy(), batch, rtol=1e-10, equal_nan=True)
    K = est.structure.warmup
    status = streamed["status"].to_numpy().reshape(4, -1)
    assert np.all(status[:, :K] == Status.WARMING_UP.value)
    assert np.all(status[:, K:] == Status.OK.value)
    assert np.all(np.isnan(streamed["payload_estimate"].to_numpy().reshape(4, -1)[:, :K]))


def test_streaming_step_api_and_gap(trained_net2, mj_dataset):
    rows = next(mj_dataset.experiments())[1]
    est = trained_net2
    est.reset()
    results = [est.step(r) for r in rows.to_dict("records")[:8]]
    assert [r.status for r in results[:5]] == [Status.WARMING_UP] * 5
    assert results[5].status == Status.OK
    bad = dict(rows.iloc[8])
    bad["boom_torque"] = float("nan")
    assert est.step(bad).status == Status.INVALID
    later = dict(rows.iloc[9])
    later["time"] += 10.0
    r = est.step(later)  # time gap: restart, the delay lines fill again
    assert r.status == Status.GAP and math.isnan(r.estimate)


def test_save_load_roundtrip(trained_net2, trained_lrn, mj_dataset, tmp_path):
    part = mj_dataset.subset(mj_dataset.experiment_ids[:3])
    for est in (trained_net2, trained_lrn):
        folder = est.save(tmp_path / est.name)
        assert (folder / "training_log.csv").is_file()
        loaded = load_estimator(folder)
        assert type(loaded) is type(est)
        assert loaded.initial_payload == est.initial_payload
        assert loaded.structure == est.structure
        pd.testing.assert_frame_equal(loaded.estimate(part), est.estimate(part))


def test_lrn_structure_follows_layrecnet():
    est = LayerRecurrentNetwork()
    s = est.structure
    assert s.input_delays == (0,) and s.layer_delays == (1, 2) and s.recurrent_layers == (0, 1, 2)
    assert s.warmup == 2
    assert s.layer_shapes() == [(10, 6 + 20), (10, 10 + 20), (10, 10 + 20), (1, 10)]
    first = LayerRecurrentNetwork(recurrent_layers="first").structure
    assert first.recurrent_layers == (0,)
    net2 = Net2().structure
    assert net2.input_delays == tuple(range(6)) and net2.feedback_delays == (1,) and net2.warmup == 5
    assert net2.layer_shapes()[0] == (10, 6 * 6 + 1)


@pytest.mark.parametrize("options", [
    {"feedback_delays": "0"},
    {"feedback_delays": "x"},
    {"initial_payload": "heavy"},
    {"initial_payload": "nan"},
    {"hidden": "0"},
])
def test_bad_options_raise_clear_errors(options):
    with pytest.raises(EstimatorError):
        Net2(**options)
    assert parse_delay_option("none", "layer_delays") == ()
    with pytest.raises(EstimatorError):
        LayerRecurrentNetwork(layer_delays="0:2")


def test_too_short_experiments_give_clear_error(mj_dataset):
    short = Dataset(mj_dataset.frame.groupby("experiment").head(4).reset_index(drop=True), mj_dataset.meta)
    with pytest.raises(EstimatorError, match="shorter"):
        Net2(epochs=1, train_experiments=5, progress=False).fit(short)


def test_fixed_initial_payload_and_cli(mj_dataset, tmp_path):
    from excavator_payload.cli import main
    from excavator_payload.data.io import read_estimates, write_dataset

    data = tmp_path / "data.parquet"
    write_dataset(mj_dataset.subset(mj_dataset.experiment_ids[:8]), data)
    model = tmp_path / "model"
    code = main(["train", "net2", "--data", str(data), "--out", str(model), "--epochs", "2",
                 "--hidden", "3", "--train-experiments", "6", "--initial-payload", "1234.5",
                 "--progress", "false"])
    assert code == 0
    loaded = load_estimator(model)
    assert loaded.initial_payload == 1234.5
    out = tmp_path / "est.parquet"
    assert main(["estimate", "--model", str(model), "--data", str(data), "--out", str(out)]) == 0
    assert len(read_estimates(out)) == 8 * 101
