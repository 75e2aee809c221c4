"""Shared DVS pieces: scaling, option parsing, MLP algebra, delay lines."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.dvs.common import (
    THESIS_INPUTS,
    DelayLine,
    Scaler,
    delay_windows,
    mlp_forward,
    mlp_forward_numpy,
    mlp_layers,
    mlp_output_jacobian,
    mlp_sizes,
    n_weights,
    nguyen_widrow_init,
    parse_delays,
    parse_hidden,
    parse_inputs,
)

torch.set_num_threads(1)


# -- scaling --------------------------------------------------------------------------------
def test_mapminmax_maps_training_range_to_unit_interval():
    x = np.array([[0.0, -5.0, 3.0], [10.0, 5.0, 3.0], [2.5, 0.0, 3.0]])
    s = Scaler("mapminmax").fit(x)
    y = s.transform(x)
    np.testing.assert_allclose(y[:, :2].min(axis=0), -1.0)
    np.testing.assert_allclose(y[:, :2].max(axis=0), 1.0)
    np.testing.assert_allclose(y[2, 0], -0.5)
    np.testing.assert_allclose(y[:, 2], 0.0)  # constant column: centred, gain 1
    np.testing.assert_allclose(s.inverse(y), x)


def test_mapstd_standardises():
    x = np.random.default_rng(0).normal(3.0, 2.0, size=(500, 2))
    y = Scaler("mapstd").fit(x).transform(x)
    np.testing.assert_allclose(y.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(y.std(axis=0, ddof=1), 1.0)


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, (6, 3), elements=st.floats(-1e4, 1e4)), st.sampled_from(["mapminmax", "mapstd"]))
def test_scaler_roundtrip_and_persistence(x, method):
    s = Scaler(method).fit(x)
    back = Scaler.from_arrays(s.to_arrays("input"), "input", method)
    np.testing.assert_allclose(back.inverse(back.transform(x)), x, rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(back.transform(x), s.transform(x))
    default = Scaler.from_arrays(s.to_arrays())  # default prefix; the method travels along
    assert default.method == method
    np.testing.assert_array_equal(default.transform(x), s.transform(x))


def test_scaler_errors():
    with pytest.raises(EstimatorError):
        Scaler("minmax")
    with pytest.raises(EstimatorError):
        Scaler().fit(np.array([[1.0], [np.nan]]))
    with pytest.raises(EstimatorError):
        Scaler().transform(np.zeros(2))


# -- option parsing -------------------------------------------------------------------------
def test_parsers():
    assert parse_hidden("10,10,10") == [10, 10, 10]
    assert parse_hidden("[10 10 10]") == [10, 10, 10]
    assert parse_hidden([5, 7]) == [5, 7]
    assert parse_delays("0:5") == [0, 1, 2, 3, 4, 5]
    assert parse_delays("0:2:6") == [0, 2, 4, 6]
    assert parse_delays("3,1") == [1, 3]
    assert parse_delays(0) == [0]
    assert parse_inputs("1,2,4,5,7,8") == list(THESIS_INPUTS)  # appendix A.3 Input='[1 2 4 5 7 8]'
    assert parse_inputs("all") == list(SIGNALS)
    assert parse_inputs("boom_torque, dipper_torque") == ["boom_torque", "dipper_torque"]
    for bad in ("a,b", "0,-1"):
        with pytest.raises(EstimatorError):
            parse_hidden(bad)
    for bad in ("", "1,1", "-1:2"):
        with pytest.raises(EstimatorError):
            parse_delays(bad)
    for bad in ("boom_speed", "9", "boom_angle,boom_angle"):
        with pytest.raises(EstimatorError):
            parse_inputs(bad)


# -- MLP ------------------------------------------------------------------------------------
def test_mlp_forward_matches_hand_computation():
    sizes = mlp_sizes(2, [3])
    w = torch.arange(n_weights(sizes), dtype=torch.float64) / 10.0
    (W1, b1), (W2, b2) = mlp_layers(w.numpy(), sizes)
    np.testing.assert_array_equal(W1, np.arange(6).reshape(3, 2) / 10.0)  # row-major W, then b
    np.testing.assert_array_equal(b1, np.arange(6, 9) / 10.0)
    x = np.array([[0.5, -1.0], [2.0, 0.1]])
    expected = np.tanh(x @ W1.T + b1) @ W2.T + b2
    np.testing.assert_allclose(mlp_forward(w, torch.as_tensor(x), sizes).numpy(), expected)
    np.testing.assert_allclose(mlp_forward_numpy(mlp_layers(w.numpy(), sizes), x), expected)
    np.testing.assert_allclose(mlp_forward_numpy(mlp_layers(w.numpy(), sizes), x[1]), expected[1])
    with pytest.raises(EstimatorError):
        mlp_layers(w[:-1], sizes)


def test_backprop_jacobian_equals_torch_func():
    sizes = mlp_sizes(4, [5, 3])
    w = nguyen_widrow_init(sizes, torch.Generator().manual_seed(0))
    x = torch.randn(17, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    reference = torch.func.vmap(torch.func.grad(lambda w, xi: mlp_forward(w, xi, sizes)[0]),
                                in_dims=(None, 0))(w, x)
    np.testing.assert_allclose(mlp_output_jacobian(w, x, sizes).numpy(), reference.numpy(), atol=1e-13)


def test_nguyen_widrow():
    sizes = mlp_sizes(36, [10, 10], 1)
    w1 = nguyen_widrow_init(sizes, torch.Generator().manual_seed(4))
    w2 = nguyen_widrow_init(sizes, torch.Generator().manual_seed(4))
    assert w1.dtype == torch.float64 and w1.shape == (n_weights(sizes),)
    assert torch.equal(w1, w2)
    layers = mlp_layers(w1, sizes)
    for (W, b), (n_prev, n_next) in zip(layers, zip(sizes[:-1], sizes[1:])):
        beta = 0.7 * n_next ** (1.0 / n_prev)
        np.testing.assert_allclose(torch.linalg.vector_norm(W, dim=1).numpy(), beta)
        if n_next > 1:  # biases spread evenly over [-β, β]
            np.testing.assert_allclose(np.sort(np.abs(b.numpy())),
                                       np.sort(np.abs(beta * np.linspace(-1, 1, n_next))))
        else:
            assert float(b[0]) == 0.0


# -- delay lines ----------------------------------------------------------------------------
def test_delay_windows_hand_computed():
    x = np.array([[0.0, 10.0], [1.0, 11.0], [2.0, 12.0], [3.0, 13.0]])
    win = delay_windows(x, [0, 2])
    assert np.isnan(win[:2]).all()  # preparets: the first max(delays) samples get no window
    np.testing.assert_array_equal(win[2], [2.0, 12.0, 0.0, 10.0])
    np.testing.assert_array_equal(win[3], [3.0, 13.0, 1.0, 11.0])
    np.testing.assert_array_equal(delay_windows(x, [0]), x)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=4, unique=True).map(sorted),
       st.integers(1, 15), st.integers(1, 3))
def test_delay_line_streams_the_batch_windows(delays, n_samples, n_channels):
    x = np.random.default_rng(n_samples).standard_normal((n_samples, n_channels))
    batch = delay_windows(x, delays)
    line = DelayLine(n_channels, delays)
    for _ in range(2):  # twice: reset must forget everything
        line.reset()
        for t in range(n_samples):
            got = line.push(x[t])
            if t < max(delays):
                assert got is None
            else:
                np.testing.assert_array_equal(got, batch[t])


def test_zero_history_delay_line():
    line = DelayLine(1, [0, 1, 2], zero_history=True)
    np.testing.assert_array_equal(line.push(np.array([5.0])), [5.0, 0.0, 0.0])
    np.testing.assert_array_equal(line.push(np.array([6.0])), [6.0, 5.0, 0.0])
    line.reset()
    np.testing.assert_array_equal(line.push(np.array([7.0])), [7.0, 0.0, 0.0])
