"""ONNX export of the networks: raw-signal window in, scaling inside, recurrent feedback explicit;
onnxruntime equals PyTorch (and the estimator) within 1e-5."""

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from excavator_payload.cli import main
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.export_onnx import export_onnx, onnx_graph
from excavator_payload.simulation.generate import simulate_dataset

NET = dict(train_experiments=3, validation_experiments=1, epochs=3, progress=False)


@pytest.fixture(scope="module")
def swings():
    return simulate_dataset(4, seed=8, workers=1, noise="thesis", progress=False)


@pytest.fixture(scope="module", params=["net1", "net2"])
def network(request, swings):
    return create_estimator(request.param, **NET).fit(swings)


def _rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b)) / np.maximum(np.abs(np.asarray(b)), 1.0))


def test_onnx_equals_pytorch_and_estimator(network, swings, tmp_path):
    [path] = export_onnx(network, tmp_path)
    model = onnx.load(str(path))
    meta = {e.key: e.value for e in model.metadata_props}
    assert meta["signals"].split(",") == list(network.sensor_set.signals)
    window, warmup = int(meta["window"]), int(meta["warmup"])
    assert window == max(network.delay_list) + 1
    session = ort.InferenceSession(str(path))
    graph = onnx_graph(network)
    estimates = network.estimate(swings)["payload_estimate"].to_numpy()
    exp = swings.frame["experiment"].to_numpy()
    values = swings.signals().astype(np.float32)
    for e in swings.experiment_ids[:2]:
        rows = np.flatnonzero(exp == e)
        windows = np.stack([values[rows][k - window + 1:k + 1] for k in range(warmup, len(rows))])
        want = estimates[rows][warmup:]
        if network.name == "net1":
            got = session.run(None, {"window": windows})[0]          # the whole batch at once
            with torch.no_grad():
                ref = graph(torch.from_numpy(windows)).numpy()
        else:
            assert [i.name for i in session.get_inputs()] == ["window", "feedback"]
            feedback = np.full((1, graph.n_feedback), float(meta["feedback_initial"]), np.float32)
            ref_feedback = torch.from_numpy(feedback.copy())
            got, ref = [], []
            for w in windows:  # the caller carries the state from one step to the next
                y, feedback = session.run(None, {"window": w[None], "feedback": feedback})
                got.append(y[0])
                with torch.no_grad():
                    y_ref, ref_feedback = graph(torch.from_numpy(w[None]), ref_feedback)
                ref.append(float(y_ref[0]))
                assert feedback[0, -1] == pytest.approx(y[0])
        assert _rel(got, ref) < 1e-5
        assert _rel(got, want) < 1e-5


def test_onnx_errors_and_cli(network, swings, tmp_path):
    with pytest.raises(EstimatorError, match="no ONNX export"):
        export_onnx(create_estimator("inverse-dynamics").fit(swings), tmp_path)
    model = tmp_path / "model"
    network.save(model)
    assert main(["export", "--model", str(model), "--format", "onnx", "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / f"{network.name}.onnx").is_file()


@pytest.mark.parametrize("decimation, smoothing, named, not_named", [
    (5, 0.0, "--decimation 5", "--smoothing"), (1, 0.3, "--smoothing 0.3", "--decimation"),
    (5, 0.3, "--decimation 5 and --smoothing 0.3", None)])
def test_a_network_that_does_not_run_on_every_sample_names_its_options(decimation, smoothing, named, not_named):
    """The refusal said '--decimation 5 or --smoothing 0' although --smoothing 0 exports."""
    from types import SimpleNamespace

    from excavator_payload.data.schema import MACHINE_SENSORS

    est = SimpleNamespace(name="ffnn", fitted=True, decimation=decimation, smoothing=smoothing,
                          sensor_set=MACHINE_SENSORS)
    with pytest.raises(EstimatorError) as caught:
        onnx_graph(est)
    message = str(caught.value)
    assert f"trained with {named} has no ONNX export" in message and "--decimation 1 --smoothing 0" in message
    if not_named:
        assert not_named not in message.split("; train it")[0]


def test_the_help_lists_what_exports_to_onnx(capsys):
    """The table comes from the traits (tests/estimators/test_traits.py checks it against the
    registered graphs); the help prints it."""
    from excavator_payload.runtime.exportable import ONNX_EXPORTABLE

    assert main(["export", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert f"onnx ({', '.join(ONNX_EXPORTABLE)})" in text and "ffnn" in ONNX_EXPORTABLE
