"""``excavator-payload export --format onnx``: the networks (``net1``, ``ffnn``, ``net2``) as ONNX.

The graph takes the *raw* signals of the delay window, ``window`` of shape
``[batch, window, n_signals]`` (oldest sample first; the signals of the sensor set in column
order, named comma-separated in the model's metadata entry ``signals``) and does everything
else inside: picks the network's inputs and delays, scales them (``mapminmax``/``mapstd`` of
training), runs the MLP and unscales the output, ``payload`` ``[batch]`` in kg.

``net2`` is recurrent (closed-loop NARX: the network's own past estimates feed back). ONNX
Runtime keeps no state, so the feedback is an explicit input and output: ``feedback``
``[batch, n_feedback]`` holds the last estimates in kg (oldest first), ``feedback_out`` is the
same after this step (shifted, the new estimate last). Start it at the metadata entry
``feedback_initial`` (kg) after a reset, as the estimator does.

Metadata: ``signals``, ``window``, ``estimator``, ``sensor_set``, ``sample_rate``, ``warmup``
(samples after a reset before the first estimate; call the graph from sample ``warmup`` on,
0-based), and for ``net2`` ``feedback_initial`` and ``feedback_delays``. The graph computes in
float32 (what edge runtimes support everywhere).

``balance-net`` exports one step of its weighing instead (float64, explicit state):
:mod:`excavator_payload.runtime.export_onnx_balance`.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import torch

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator
from excavator_payload.runtime import export_onnx_balance  # noqa: F401 (registers balance-net's export)
from excavator_payload.runtime.exportable import ONNX_EXPORTABLE, per_sample_refusal
from excavator_payload.runtime.onnx_registry import OPSET, exporter_for, graph_for, onnx_graph_for


@onnx_graph_for("net1", "ffnn")
class _TimeDelayGraph(torch.nn.Module):
    """net1 / ffnn on a raw window."""

    def __init__(self, est) -> None:
        super().__init__()
        from excavator_payload.estimators.dvs.mlp import mlp_layers

        n_sig = len(est.sensor_set.signals)
        self.window = max(est.delay_list) + 1
        # flat positions in the [window * n_sig] row: delay blocks of all input channels
        index = [(self.window - 1 - d) * n_sig + int(c) for d in est.delay_list for c in est.input_index]
        self.register_buffer("index", torch.tensor(index, dtype=torch.int64))
        tiles = len(est.delay_list)
        self.register_buffer("center", torch.tensor(np.tile(est.input_scaler.center, tiles), dtype=torch.float32))
        self.register_buffer("gain", torch.tensor(np.tile(est.input_scaler.gain, tiles), dtype=torch.float32))
        layers = mlp_layers(np.asarray(est.weights, dtype=float), est._layer_sizes())
        self.linears = torch.nn.ModuleList()
        for W, b in layers:
            lin = torch.nn.Linear(W.shape[1], W.shape[0])
            lin.weight.data = torch.tensor(W, dtype=torch.float32)
            lin.bias.data = torch.tensor(b, dtype=torch.float32)
            self.linears.append(lin)
        self.out_center = float(est.output_scaler.center[0])
        self.out_gain = float(est.output_scaler.gain[0])
        self.n_sig = n_sig

    def forward(self, window: torch.Tensor) -> torch.Tensor:
        flat = window.reshape(window.shape[0], self.window * self.n_sig)
        a = (torch.index_select(flat, 1, self.index) - self.center) * self.gain
        for lin in self.linears[:-1]:
            a = torch.tanh(lin(a))
        y = self.linears[-1](a)[:, 0]
        return y / self.out_gain + self.out_center


@onnx_graph_for("net2")
class _NarxGraph(torch.nn.Module):
    """net2 (closed-loop NARX) on a raw window, feedback state explicit."""

    def __init__(self, est) -> None:
        super().__init__()
        from excavator_payload.estimators.dvs.recurrent import unpack_weights

        st = est.structure
        if st.layer_delays and st.recurrent_layers:
            raise EstimatorError(f"{est.name}: networks with layer feedback (lrn) have no ONNX export yet")
        n_sig = len(est.sensor_set.signals)
        self.window = max(st.input_delays) + 1
        self.n_sig = n_sig
        index = [(self.window - 1 - d) * n_sig + int(c) for d in st.input_delays for c in est.input_index]
        self.register_buffer("index", torch.tensor(index, dtype=torch.int64))
        tiles = len(st.input_delays)
        self.register_buffer("center", torch.tensor(np.tile(est.input_scaler.center, tiles), dtype=torch.float32))
        self.register_buffer("gain", torch.tensor(np.tile(est.input_scaler.gain, tiles), dtype=torch.float32))
        self.n_feedback = max(st.feedback_delays)
        # feedback holds y(t - n_fb) … y(t - 1): delay f is column n_fb - f
        self.register_buffer("fb_index", torch.tensor([self.n_feedback - f for f in st.feedback_delays],
                                                      dtype=torch.int64))
        self.linears = torch.nn.ModuleList()
        for W, b in unpack_weights(np.asarray(est.weights, dtype=float), st):
            lin = torch.nn.Linear(W.shape[1], W.shape[0])
            lin.weight.data = torch.tensor(W, dtype=torch.float32)
            lin.bias.data = torch.tensor(b, dtype=torch.float32)
            self.linears.append(lin)
        self.out_center = float(est.output_scaler.center[0])
        self.out_gain = float(est.output_scaler.gain[0])

    def forward(self, window: torch.Tensor, feedback: torch.Tensor):
        flat = window.reshape(window.shape[0], self.window * self.n_sig)
        u = (torch.index_select(flat, 1, self.index) - self.center) * self.gain
        fb = (torch.index_select(feedback, 1, self.fb_index) - self.out_center) * self.out_gain
        a = torch.cat([u, fb], dim=1)
        for lin in self.linears[:-1]:
            a = torch.tanh(lin(a))
        payload = self.linears[-1](a)[:, 0] / self.out_gain + self.out_center
        feedback_out = torch.cat([feedback[:, 1:], payload[:, None]], dim=1)
        return payload, feedback_out


def onnx_graph(est: Estimator) -> torch.nn.Module:
    """The PyTorch module that is exported (float32).

    Parameters
    ----------
    est : Estimator
        A fitted network with an ONNX export (:data:`~excavator_payload.runtime.exportable.ONNX_EXPORTABLE`).

    Raises
    ------
    EstimatorError
        ``est`` has no ONNX export, or was trained with options that stop one.
    """
    graph = graph_for(est.name)
    if graph is None:
        raise EstimatorError(f"{est.name} has no ONNX export; exportable: {', '.join(ONNX_EXPORTABLE)}")
    refusal = per_sample_refusal(est, "ONNX")
    if refusal:
        raise EstimatorError(refusal)
    return graph(est).eval()


def export_onnx(est: Estimator, out: str | Path) -> list[Path]:
    """Write ``<name>.onnx`` for a fitted network into folder ``out``.

    Parameters
    ----------
    est : Estimator
        A fitted network with an ONNX export.
    out : str or Path
        The folder to write into (created if missing).

    Returns
    -------
    list of Path
        The file written.
    """
    import onnx

    if not est.fitted:
        raise EstimatorError(f"{est.name}: nothing to export, the estimator is not fitted")
    writer = exporter_for(est.name)  # e.g. balance-net: a step with explicit state, not a window
    if writer is not None:
        return writer(est, out)
    graph = onnx_graph(est)
    sensors = est.sensor_set
    window = torch.zeros(1, graph.window, len(sensors.signals))
    meta = {"signals": ",".join(sensors.signals), "window": str(graph.window), "estimator": est.name,
            "sensor_set": sensors.name, "sample_rate": repr(sensors.sample_rate),
            "units": ",".join(sensors.units[s] for s in sensors.signals), "output_unit": "kg"}
    if est.name == "net2":
        args = (window, torch.full((1, graph.n_feedback), float(est.initial_payload)))
        names_in, names_out = ["window", "feedback"], ["payload", "feedback_out"]
        axes = {"window": {0: "batch"}, "feedback": {0: "batch"}, "payload": {0: "batch"},
                "feedback_out": {0: "batch"}}
        meta.update(warmup=str(est.structure.warmup), feedback_initial=repr(float(est.initial_payload)),
                    feedback_delays=",".join(map(str, est.structure.feedback_delays)))
    else:
        args = (window,)
        names_in, names_out = ["window"], ["payload"]
        axes = {"window": {0: "batch"}, "payload": {0: "batch"}}
        meta.update(warmup=str(graph.window - 1))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{est.name}.onnx"
    tmp = out / f".{est.name}.onnx.tmp"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(graph, args, str(tmp), input_names=names_in, output_names=names_out,
                          dynamic_axes=axes, opset_version=OPSET, dynamo=False)
    model = onnx.load(str(tmp))
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.doc_string = (f"excavator-payload {est.name}: payload (kg) from the raw signals of the last "
                        f"{graph.window} samples")
    onnx.checker.check_model(model)
    onnx.save(model, str(tmp))
    os.replace(tmp, path)
    return [path]
