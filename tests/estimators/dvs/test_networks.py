"""net1 / ffnn / dtdnn: preparets semantics, streaming == batch, persistence, CLI."""

import math

import numpy as np
import pandas as pd
import pytest
import torch

from excavator_payload.cli import main
from excavator_payload.data.io import read_estimates, write_dataset
from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, create_estimator, load_estimator
from excavator_payload.estimators.dvs.common import Scaler, experiment_arrays
from excavator_payload.estimators.dvs.trainbr import jacobian_forward

torch.set_num_threads(1)

SMALL = dict(train_experiments=14, validation_experiments=6, progress=False)


@pytest.fixture(scope="module")
def net1(mj_dataset):
    return create_estimator("net1", epochs=30, **SMALL).fit(mj_dataset)


@pytest.fixture(scope="module")
def dtdnn(mj_dataset):
    return create_estimator("dtdnn", hidden="4,4", epochs=4, **SMALL).fit(mj_dataset)


def _batch(est, dataset):
    xs, _ = experiment_arrays(dataset, est.input_names)
    return np.concatenate(est.predict_windows(xs))


def test_net1_is_the_thesis_network(net1):
    assert net1.input_names == ["boom_angle", "boom_rate", "dipper_angle", "dipper_rate",
                                "boom_torque", "dipper_torque"]
    assert net1.delay_list == [0, 1, 2, 3, 4, 5]
    assert net1._layer_sizes() == [36, 10, 10, 10, 1]
    assert net1.weights.shape == (601,)
    log = net1.training_log
    assert log.n_errors == 14 * 96  # preparets: 101 − 5 targets per experiment
    assert not math.isnan(log.validation_sse[-1])
    assert log.sse[-1] < 0.2 * log.sse[0]


def test_net1_learns_the_payload(net1, mj_dataset):
    train = mj_dataset.subset(mj_dataset.experiment_ids[:14])
    est = net1.estimate(train)["payload_estimate"].to_numpy()
    err = est - train.frame["payload"].to_numpy()
    spread = train.payloads.std()
    # far better than guessing the mean payload (a small, short training run)
    assert np.sqrt(np.nanmean(err**2)) < 0.25 * spread


@pytest.mark.parametrize("fixture", ["net1", "dtdnn"])
def test_streaming_equals_batch_and_warms_up(fixture, request, mj_dataset):
    est = request.getfixturevalue(fixture)
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:5])
    frame = est.estimate(ds)  # reset + step() loop, numpy forward
    batch = _batch(est, ds)  # whole-experiment tensors / windows
    np.testing.assert_allclose(frame["payload_estimate"].to_numpy(), batch, rtol=1e-10, atol=1e-8)
    n_warm = max(est.delay_list)
    for _, rows in frame.groupby("experiment"):
        status = rows["status"].tolist()
        assert status[:n_warm] == [Status.WARMING_UP.value] * n_warm
        assert set(status[n_warm:]) == {Status.OK.value}
        assert rows["payload_estimate"].iloc[:n_warm].isna().all()


def test_windows_never_cross_experiments(net1, mj_dataset):
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:4])
    together = net1.estimate(ds)["payload_estimate"].to_numpy()
    alone = np.concatenate([net1.estimate(ds.subset([i]))["payload_estimate"].to_numpy()
                            for i in ds.experiment_ids])
    np.testing.assert_array_equal(together, alone)


def test_training_windows_are_preparets_windows(net1, mj_dataset):
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:2])
    xs, _ = experiment_arrays(ds, net1.input_names)
    win = net1.windows(xs)
    assert win.shape == (2 * 96, 36)
    # second experiment's first window: its own samples 5, 4, …, 0 (never experiment 1's)
    x1 = xs[1]
    np.testing.assert_array_equal(win[96], np.concatenate([x1[5 - d] for d in range(6)]))
    np.testing.assert_array_equal(win[95], np.concatenate([xs[0][100 - d] for d in range(6)]))


def test_save_load_roundtrip(net1, mj_dataset, tmp_path):
    net1.save(tmp_path / "m")
    for f in ("estimator.json", "arrays.npz", "training_log.csv", "training.png"):
        assert (tmp_path / "m" / f).is_file()
    back = load_estimator(tmp_path / "m")
    assert type(back) is type(net1) and back.options == net1.options
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:3])
    pd.testing.assert_frame_equal(back.estimate(ds), net1.estimate(ds))
    pd.testing.assert_frame_equal(back.training_log.to_frame(), net1.training_log.to_frame())
    assert back.training_log.stop_reason == net1.training_log.stop_reason
    log_csv = pd.read_csv(tmp_path / "m" / "training_log.csv")
    assert len(log_csv) == 31 and {"sse", "gamma", "mu", "validation_sse"} <= set(log_csv.columns)


@pytest.mark.parametrize("hidden, delays", [("4,4", "0:3"), ("3", "1,3")])
def test_dtdnn_jacobian_equals_forward_mode(hidden, delays, mj_dataset):
    est = create_estimator("dtdnn", hidden=hidden, delays=delays)
    ds = mj_dataset.subset(mj_dataset.experiment_ids[:2])
    est.input_scaler = Scaler().fit(ds.signals(est.input_names))
    est.output_scaler = Scaler().fit(ds.frame["payload"].to_numpy()[:, None])
    inputs, targets = est._scaled(ds)
    residuals, jacobian = est._training_problem(inputs, targets)
    w = est._init_weights(torch.Generator().manual_seed(2))
    np.testing.assert_allclose(jacobian(w).numpy(), jacobian_forward(residuals, w).numpy(), atol=1e-12)


def test_dtdnn_structure(dtdnn):
    assert dtdnn.delay_list == [0, 1, 2, 3]
    assert dtdnn.weights.shape == (dtdnn._n_weights(),) == (6 * 4 * 4 + 4 + 4 * 4 * 4 + 4 + 4 * 4 * 1 + 1,)
    assert dtdnn.training_log.n_errors == 14 * 98  # preparets: only the input delay line fills


def test_ffnn_and_adam_and_options(mj_dataset):
    est = create_estimator("ffnn", hidden="6", inputs="boom_torque,dipper_torque,boom_angle",
                           scaling="mapstd", trainer="adam", epochs=20, learning_rate=0.01,
                           **SMALL).fit(mj_dataset)
    frame = est.estimate(mj_dataset.subset(mj_dataset.experiment_ids[:2]))
    assert (frame["status"] == "ok").all()  # no delays: an estimate from the first sample
    assert est.training_log.trainer == "adam"
    assert est.training_log.sse[-1] < est.training_log.sse[0]


def test_bad_options_and_data_give_clear_errors(mj_dataset):
    with pytest.raises(EstimatorError, match="hidden"):
        create_estimator("net1", hidden="ten")
    with pytest.raises(EstimatorError, match="inputs"):
        create_estimator("net1", inputs="boom_speed")
    with pytest.raises(EstimatorError, match="scaling"):
        create_estimator("net1", scaling="minmax")
    with pytest.raises(EstimatorError, match="train-experiments"):
        create_estimator("net1", progress=False).fit(mj_dataset)  # 20 < 100 experiments
    with pytest.raises(EstimatorError, match="fit"):
        create_estimator("net1").step({"time": 0.0, **{s: 0.0 for s in SIGNALS}})


def test_bad_samples_while_streaming(net1, mj_dataset):
    rows = mj_dataset.frame[mj_dataset.frame["experiment"] == mj_dataset.experiment_ids[0]]
    net1.reset()
    results = [net1.step(r) for r in rows.iloc[:8].to_dict("records")]
    assert results[-1].status is Status.OK
    bad = dict(rows.iloc[8])
    bad["boom_torque"] = float("nan")
    assert net1.step(bad).status is Status.INVALID
    # the next valid sample comes after a hole in time: the delay line restarts
    r = net1.step(dict(rows.iloc[9]))
    assert r.status is Status.GAP and math.isnan(r.estimate)
    statuses = [net1.step(dict(rows.iloc[k])).status for k in range(10, 16)]
    assert statuses == [Status.WARMING_UP] * 4 + [Status.OK] * 2


def test_cli_train_and_estimate(mj_dataset, tmp_path):
    data = tmp_path / "train.parquet"
    write_dataset(mj_dataset, data)
    code = main(["train", "net1", "--data", str(data), "--out", str(tmp_path / "net1"),
                 "--epochs", "3", "--train-experiments", "12", "--validation-experiments", "4",
                 "--hidden", "5,5", "--progress", "false"])
    assert code == 0
    code = main(["estimate", "--model", str(tmp_path / "net1"), "--data", str(data),
                 "--out", str(tmp_path / "est.parquet")])
    assert code == 0
    est = read_estimates(tmp_path / "est.parquet")
    model = load_estimator(tmp_path / "net1")
    np.testing.assert_allclose(est["payload_estimate"].to_numpy(),
                               model.estimate(mj_dataset)["payload_estimate"].to_numpy())
    assert main(["train", "net1", "--data", str(data), "--out", str(tmp_path / "x"),
                 "--hidden", "a"]) == 2
