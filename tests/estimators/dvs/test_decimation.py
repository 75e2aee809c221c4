"""--decimation (networks at a lower rate than the data), --smoothing, and the in-place negated
Jacobian."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.estimators.dvs.common import (
    block_means,
    experiment_arrays,
    mlp_forward,
    mlp_layers,
    mlp_output_jacobian,
    nguyen_widrow_init,
)
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

TINY = dict(hidden="4", delays="0,2", epochs=3, train_experiments=2, validation_experiments=1,
            progress=False)


@pytest.fixture(scope="module")
def swings():
    return simulate_machine_dataset(3, seed=22, noise="field", motion="swing", session=3)


def _reference_jacobian(w, x, sizes):
    """The Jacobian as it was built before (blocks, concatenation, then negated)."""
    layers = mlp_layers(w, sizes)
    acts = [x]
    for W, b in layers[:-1]:
        acts.append(torch.tanh(acts[-1] @ W.T + b))
    blocks = []
    delta = torch.ones(x.shape[0], 1, dtype=x.dtype)
    for l in range(len(layers) - 1, -1, -1):
        blocks.append(delta)
        blocks.append((delta[:, :, None] * acts[l][:, None, :]).reshape(x.shape[0], -1))
        if l > 0:
            delta = (delta @ layers[l][0]) * (1.0 - acts[l] ** 2)
    return torch.cat(blocks[::-1], dim=1)


@pytest.mark.parametrize("sizes", [[36, 10, 10, 10, 1], [5, 3, 1], [4, 1]])
def test_negated_jacobian_is_bit_identical(sizes):
    g = torch.Generator().manual_seed(5)
    w = 1.3 * nguyen_widrow_init(sizes, g)
    x = 2 * torch.rand(257, sizes[0], generator=g, dtype=torch.float64) - 1
    reference = _reference_jacobian(w, x, sizes)
    # bit for bit: the thesis networks' training must not change in the last digit
    assert torch.equal(mlp_output_jacobian(w, x, sizes), reference)
    assert torch.equal(mlp_output_jacobian(w, x, sizes, negate=True), -reference)
    # and it is the derivative of the forward pass
    auto = torch.func.jacrev(lambda v: mlp_forward(v, x, sizes)[:, 0])(w)
    torch.testing.assert_close(reference, auto, rtol=1e-10, atol=1e-12)


def test_block_means():
    x = np.arange(14.0).reshape(7, 2)
    np.testing.assert_array_equal(block_means(x, 3), [[2.0, 3.0], [8.0, 9.0]])  # last row dropped
    np.testing.assert_array_equal(block_means(x, 1), x)
    assert block_means(x[:2], 3).shape == (0, 2)


@pytest.mark.parametrize("value", [0, -1, 1001])
def test_decimation_is_validated(value):
    with pytest.raises(EstimatorError, match="--decimation"):
        create_estimator("net1", decimation=value)


@pytest.mark.parametrize("name", ["net1", "net2"])
def test_decimated_network_runs_on_block_means_and_holds(name, swings, tmp_path):
    K = 4
    est = create_estimator(name, decimation=K, **TINY).fit(swings)
    full = create_estimator(name, **TINY).fit(swings)
    # K times fewer training targets (the same preparets warm-up, in network samples)
    n_rows = [len(rows) for _, rows in swings.subset(swings.experiment_ids[:2]).experiments()]
    warm = 2 if name == "net1" else est.structure.warmup
    assert est.training_log.n_errors == sum(n // K - warm for n in n_rows)
    assert full.training_log.n_errors == sum(n - warm for n in n_rows)

    frame = est.estimate(swings)
    first = swings.subset(swings.experiment_ids[:1])
    y = frame["payload_estimate"].to_numpy()[:n_rows[0]]
    status = frame["status"].to_numpy()[:n_rows[0]]
    # the first network sample is the mean of samples 0…K−1; the warm-up lasts `warm` of them
    first_ok = (warm + 1) * K - 1
    assert np.all(status[:first_ok] == Status.WARMING_UP.value)
    assert status[first_ok] == Status.OK.value
    # held between network samples, changes only at the end of a block
    ok = np.arange(first_ok, n_rows[0])
    changes = ok[1:][np.diff(y[ok]) != 0]
    assert len(changes) > 0 and np.all((changes + 1) % K == 0)

    # the estimate equals an undecimated twin fed the block means at 1/K the rate
    xs, _ = experiment_arrays(first, est.input_names)
    means = block_means(xs[0], K)
    twin = create_estimator(name, **TINY)
    twin.fit(swings)  # same seed, then swap in the decimated net's weights and scalers
    twin.input_scaler, twin.output_scaler = est.input_scaler, est.output_scaler
    if name == "net2":
        twin.initial_payload = est.initial_payload
    twin.weights = est.weights
    twin._use_weights(est.weights)
    reference = (twin.predict_windows if name == "net1" else twin.predict_experiments)([means])[0]
    np.testing.assert_allclose(y[K - 1::K][:len(reference)], reference, rtol=1e-9, atol=1e-6)

    with pytest.raises(EstimatorError, match="decimation"):
        (est.predict_windows if name == "net1" else est.predict_experiments)(xs)
    est.save(tmp_path / name)
    again = load_estimator(tmp_path / name)
    assert again.decimation == K
    np.testing.assert_array_equal(again.estimate(swings)["payload_estimate"].to_numpy(),
                                  frame["payload_estimate"].to_numpy())


def test_decimated_network_is_not_exported(mj_dataset, tmp_path):
    from excavator_payload.runtime.export_c import export_c
    from excavator_payload.runtime.export_onnx import export_onnx

    est = create_estimator("net1", decimation=2, hidden="4", epochs=2, train_experiments=14,
                           validation_experiments=6, progress=False).fit(mj_dataset)
    with pytest.raises(EstimatorError, match="decimation"):
        export_c(est, tmp_path / "c")
    with pytest.raises(EstimatorError, match="decimation"):
        export_onnx(est, tmp_path / "onnx")
    assert not math.isnan(est.residual_std)


def test_smoothing_is_a_first_order_low_pass_of_the_estimate(swings):
    K, tau = 2, 0.3
    plain = create_estimator("net1", decimation=K, **TINY).fit(swings)
    smooth = create_estimator("net1", decimation=K, smoothing=tau, **TINY).fit(swings)
    np.testing.assert_array_equal(plain.weights, smooth.weights)  # training is not affected
    first = swings.subset(swings.experiment_ids[:1])
    y = plain.estimate(first)["payload_estimate"].to_numpy()
    z = smooth.estimate(first)["payload_estimate"].to_numpy()
    ok = np.flatnonzero(np.isfinite(y))
    np.testing.assert_array_equal(np.isfinite(z), np.isfinite(y))
    samples = ok[(ok + 1) % K == 0]  # the network's samples (held in between)
    a = 1 - math.exp(-K * swings.sensor_set.sample_period / tau)
    expected = [y[samples[0]]]
    for v in y[samples[1:]]:
        expected.append(expected[-1] + a * (v - expected[-1]))
    np.testing.assert_allclose(z[samples], expected, rtol=1e-12)
    assert np.std(np.diff(z[samples])) < np.std(np.diff(y[samples]))


@pytest.mark.parametrize("value", [-1.0, float("nan"), 1e9])
def test_smoothing_is_validated(value):
    with pytest.raises(EstimatorError, match="--smoothing"):
        create_estimator("net1", smoothing=value)
