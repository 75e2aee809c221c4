r"""``excavator-payload export --format onnx`` of ``balance-net``: one step of the weighing as an
ONNX graph (float64), every state an explicit input and output.

The sample's balance parts are CasADi's :func:`~excavator_payload.estimators.learned.balance_net.
sample_function` itself: its instruction list is replayed with torch operations (one ONNX node
per CasADi operation, the same order), so the graph computes what the Python streaming and the
C export compute. Around it, :meth:`BalanceNet._step <excavator_payload.estimators.learned.
balance_net.BalanceNet._step>` with selects instead of branches: the machine set's glitch test
of the frame before the newest, the ring of the window's terms (oldest first, shifted by one
per sample), the window sums, the per-channel gate, the new-load restart, the recursive sums.

Inputs ``signals`` ``[n_signals]`` and the state ``num``, ``info``, ``disagree``, ``num_new``, ``info_new``,
``novelty``, ``novelty_new``, ``misfit``, ``misfit_new`` ``[1]``,
``terms`` ``[width, 4·channels]``, ``used`` ``[width, channels]``, ``filled``, ``frames``
``[2, n_signals]``, ``n_frames`` ``[1]`` (all zeros after a reset); outputs ``estimate``,
``status`` (0 ok, 1 warming up, as ``Status``), ``sigma`` and the state after the step (same
names with ``_out``), and ``nis``, ``dof``: the thesis set's innovation of ``signals`` at the
*input* state (the base class's gate; NaN when it cannot judge yet). What the base class does
around the model (unreadable and implausible samples, gaps, the gate's decision, restarts) is
the host's: :class:`OnnxBalanceNet` is that host loop, reading only the file's metadata.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import numpy as np
import torch

from excavator_payload.errors import EstimatorError
from excavator_payload.runtime.onnx_registry import OPSET, onnx_exporter_for, onnx_graph_for

STATE = ("num", "info", "disagree", "num_new", "info_new", "novelty", "novelty_new", "misfit", "misfit_new",
         "terms", "used", "filled", "frames", "n_frames")


def _casadi_torch(fn, inputs: list[torch.Tensor]) -> torch.Tensor:
    """Replay the instruction list of an SX function with torch ops on 1-D float64 inputs."""
    import casadi as ca

    unary = {ca.OP_NEG: torch.neg, ca.OP_SIN: torch.sin, ca.OP_COS: torch.cos, ca.OP_SQRT: torch.sqrt,
             ca.OP_SIGN: torch.sign, ca.OP_FABS: torch.abs, ca.OP_EXP: torch.exp, ca.OP_LOG: torch.log,
             ca.OP_TAN: torch.tan, ca.OP_SQ: lambda a: a * a, ca.OP_TWICE: lambda a: 2.0 * a,
             ca.OP_INV: lambda a: 1.0 / a, ca.OP_ASSIGN: lambda a: a}
    binary = {ca.OP_ADD: torch.add, ca.OP_SUB: torch.sub, ca.OP_MUL: torch.mul, ca.OP_DIV: torch.div,
              ca.OP_FMAX: torch.maximum, ca.OP_FMIN: torch.minimum, ca.OP_POW: torch.pow}
    work: dict[int, torch.Tensor] = {}
    out = [None] * fn.nnz_out(0)
    for k in range(fn.n_instructions()):
        op, a, r = fn.instruction_id(k), fn.instruction_input(k), fn.instruction_output(k)
        if op == ca.OP_CONST:
            # shape [1], not 0-d: the exporter turns 0-d constants into float32 ones
            work[r[0]] = torch.full((1,), fn.instruction_constant(k), dtype=torch.float64)
        elif op == ca.OP_INPUT:
            work[r[0]] = inputs[a[0]][a[1]:a[1] + 1]
        elif op == ca.OP_OUTPUT:
            out[r[1]] = work[a[0]]
        elif op in unary:
            work[r[0]] = unary[op](work[a[0]])
        elif op in binary:
            work[r[0]] = binary[op](work[a[0]], work[a[1]])
        else:
            raise EstimatorError(f"balance-net: CasADi operation {op} has no ONNX rendering")
    zero = torch.zeros(1, dtype=torch.float64)
    return torch.cat([zero if v is None else v for v in out])


@onnx_graph_for("balance-net")
class BalanceStepGraph(torch.nn.Module):
    """One step of ``balance-net`` (module doc), float64.

    Parameters
    ----------
    est : BalanceNet
        The fitted estimator.
    """

    def __init__(self, est) -> None:
        super().__init__()
        from excavator_payload.estimators.learned.balance_net import NEW_LOAD_SHARE, novelty_columns, sample_function

        m = est.model
        L = m.layout
        self.fn = sample_function(m)
        self.n, self.width, self.machine = L.n, m.width, bool(L.differentiate)
        self.n_signals = len(est.sensor_set.signals)
        f64 = lambda a: torch.tensor(np.asarray(a, float), dtype=torch.float64)  # noqa: E731
        off = np.asarray(m.offsets, float) if len(m.offsets) else np.zeros(m.offset_count())
        self.register_buffer("offsets", f64(off))
        self.register_buffer("w", f64(m._w))
        self.register_buffer("u", f64(m._u))
        self.register_buffer("channel_var", f64(m.channel_var))
        low, high = m.limits()
        self.register_buffer("q_low", f64(low))
        self.register_buffer("q_high", f64(high))
        self.register_buffer("q_idx", torch.tensor(L.q, dtype=torch.int64))
        self.register_buffer("v_idx", torch.tensor(L.v, dtype=torch.int64))
        threshold = est.spike_threshold if est.spike_threshold is not None else np.full(self.n_signals, np.inf)
        self.register_buffer("spike", f64(threshold))
        self.span, self.period = float(m._span), float(m.period)
        self.still = float(m.still_rate if L.pressure else 0.0)
        self.kappa, self.kappa_sq = float(est.kappa), float(est.kappa ** 2)
        self.ready_info = float(est.ready_info())
        self.zero_sq = float(m.zero_std ** 2)
        self.floor_a, self.floor_b, self.floor_c = float(est.floor_a), float(est.floor_b), float(est.floor_c)
        k = len(est.novelty_mean)
        self.register_buffer("novelty_idx", torch.tensor(novelty_columns(L) if k else [0], dtype=torch.int64))
        self.register_buffer("novelty_mean", f64(est.novelty_mean if k else [0.0]))
        self.register_buffer("novelty_precision", f64(est.novelty_precision if k else [[0.0]]))
        self.new_load_kg = NEW_LOAD_SHARE * est.payload_scale
        self.gate_sigma = 0.05 * est.payload_scale
        self.channel_gate = float(est.options["gate"]) * est.kappa
        self.new_load = float(est.options["new_load"])
        self.gating = bool(est.gating)

    def initial_state(self) -> dict[str, np.ndarray]:
        """The state after a reset."""
        n, W, N = self.n, self.width, self.n_signals
        return {"num": np.zeros(1), "info": np.zeros(1), "disagree": np.zeros(1),
                "num_new": np.zeros(1), "info_new": np.zeros(1), "novelty": np.zeros(1), "novelty_new": np.zeros(1),
                "misfit": np.zeros(1), "misfit_new": np.zeros(1),
                "terms": np.zeros((W, 4 * n)), "used": np.zeros((W, n)), "filled": np.zeros(1),
                "frames": np.zeros((2, N)), "n_frames": np.zeros(1)}

    def _used(self, x):
        q = x[self.q_idx]
        inside = torch.all((q >= self.q_low) & (q <= self.q_high))
        return (torch.abs(x[self.v_idx]) >= self.still) & inside

    def forward(self, signals, num, info, disagree, num_new, info_new, novelty, novelty_new, misfit, misfit_new,
                terms, used, filled, frames, n_frames):
        """One sample through the step (module doc).

        Parameters
        ----------
        signals : torch.Tensor
            ``[n_signals]`` the sample, SI units.
        num, info, disagree, num_new, info_new, novelty, novelty_new, misfit, misfit_new, terms, used, filled, frames, n_frames : torch.Tensor
            The state (:meth:`initial_state` after a reset).
        """
        n, one, zero = self.n, torch.ones(1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
        nan = torch.full((1,), math.nan, dtype=torch.float64)
        if self.machine:  # judge the frame before this one between its neighbours
            before, mid = frames[0], frames[1]
            d1, d2 = mid - before, mid - signals
            smaller = torch.minimum(torch.abs(d1), torch.abs(d2))
            glitch = torch.any((d1 * d2 > 0) & (smaller > self.spike) & (smaller > torch.abs(signals - before)))
            if self.gating:
                mid = torch.where(glitch, 0.5 * (before + signals), mid)
            first = n_frames == 0
            x = torch.where(n_frames == 1, frames[0], mid)
            frames_out = torch.stack([torch.where(first, signals, x), signals])
            n_frames_out = torch.clamp(n_frames + 1, max=2.0)
            process = ~first
        else:
            x, frames_out, n_frames_out, process = signals, frames, n_frames, torch.ones(1, dtype=torch.bool)
        t = _casadi_torch(self.fn, [x, self.offsets])
        terms_new = torch.cat([terms[1:], t[None, :]])
        used_new = torch.cat([used[1:], self._used(x).to(torch.float64)[None, :]])
        terms_out = torch.where(process, terms_new, terms)
        used_out = torch.where(process, used_new, used)
        filled_out = torch.where(process, torch.clamp(filled + 1, max=float(self.width)), filled)
        full = process & (filled_out >= self.width)
        r = (self.w @ terms_out[:, :n] + (self.u @ terms_out[:, n:2 * n]) / self.period) / self.span
        phi = (self.w @ terms_out[:, 2 * n:3 * n] + (self.u @ terms_out[:, 3 * n:]) / self.period) / self.span
        wch = torch.all(used_out > 0.5, dim=0).to(torch.float64) / self.channel_var
        est = num / info
        cond = (info > 0) & (self.kappa / torch.sqrt(info) <= self.gate_sigma)
        if not self.gating:
            cond = cond & False
        spread = torch.sqrt(1.0 / torch.clamp(wch, min=1e-300) + phi * phi * self.kappa_sq / info)
        agree = torch.abs(r - est * phi) <= self.channel_gate * spread
        any_w = torch.any(wch > 0)
        any_agree = torch.any(agree & (wch > 0))
        all_disagree = full & cond & any_w & ~any_agree
        counted = disagree + 1.0
        # windows no channel of the weighed load explains are weighed on their own; after
        # --new-load seconds they are the new load if they weigh NEW_LOAD_SHARE away
        own_num = num_new + torch.sum(wch * phi * r)
        f = x[self.novelty_idx] - self.novelty_mean  # the sample's distance from the training data
        dist = torch.sqrt(torch.clamp(torch.sum(f * (self.novelty_precision @ f)), min=0.0))[None]
        own_info = info_new + torch.sum(wch * phi * phi)
        own_novelty = novelty_new + torch.sum(wch * phi * phi) * dist
        own_est = own_num / torch.where(own_info > 0, own_info, one)  # the windows' chi^2 at their own estimate
        own_misfit = misfit_new + torch.where(
            own_info > 0, torch.sum(wch * phi * phi) * torch.sum(wch * (r - own_est * phi) ** 2), zero)
        decide = all_disagree & (counted * self.period >= self.new_load)
        replace = decide & (own_info > 0) & (torch.abs(own_num / own_info - est) > self.new_load_kg)
        settled = full & cond & ~all_disagree
        disagree_out = torch.where(all_disagree, torch.where(decide, zero, counted),
                                   torch.where(settled, zero, disagree))
        num_new_out = torch.where(all_disagree, torch.where(decide, zero, own_num),
                                  torch.where(settled, zero, num_new))
        info_new_out = torch.where(all_disagree, torch.where(decide, zero, own_info),
                                   torch.where(settled, zero, info_new))
        novelty_new_out = torch.where(all_disagree, torch.where(decide, zero, own_novelty),
                                      torch.where(settled, zero, novelty_new))
        misfit_new_out = torch.where(all_disagree, torch.where(decide, zero, own_misfit),
                                     torch.where(settled, zero, misfit_new))
        w = torch.where(cond, torch.where(agree, wch, torch.zeros_like(wch)), wch)
        add = full & ~all_disagree
        num_out = torch.where(replace, own_num, torch.where(add, num + torch.sum(w * phi * r), num))
        added = torch.sum(w * phi * phi)
        info_out = torch.where(replace, own_info, torch.where(add, info + added, info))
        novelty_out = torch.where(replace, own_novelty, torch.where(add, novelty + added * dist, novelty))
        after = torch.where(info_out > 0, info_out, one)  # the window's chi^2 at the estimate after it
        chi2 = torch.sum(w * (r - (num_out / after) * phi) ** 2)
        misfit_out = torch.where(replace, own_misfit,
                                 torch.where(add & (info_out > 0), misfit + added * chi2, misfit))
        ready = (info_out > 0) & (info_out >= self.ready_info)  # no weight before it is ready
        estimate = torch.where(ready, num_out / info_out, nan)
        status = torch.where(ready, zero, one)
        floor_sq = torch.clamp(self.floor_a + self.floor_b * (novelty_out / info_out)
                               + self.floor_c * (misfit_out / info_out), min=0.0)
        sigma = torch.where(ready, torch.sqrt(self.kappa_sq / info_out + floor_sq + self.zero_sq), nan)
        # the base class's gate (thesis set): the innovation of the signals at the input state
        # (the machine set has none: its frames are judged between their neighbours)
        if self.machine:
            nis, dof = nan, one
        else:
            u0 = self._used(signals)
            var = self.channel_var + t[2 * n:3 * n] * t[2 * n:3 * n] * self.kappa_sq / info
            e = t[:n] - est * t[2 * n:3 * n]
            nis = torch.sum(torch.where(u0, e * e / var, torch.zeros_like(var)))
            nis = torch.where(info > 0, nis, nan)
            dof = torch.clamp(torch.sum(u0.to(torch.float64)), min=1.0)[None]
        return (estimate, status, sigma, num_out, info_out, disagree_out, num_new_out, info_new_out,
                novelty_out, novelty_new_out, misfit_out, misfit_new_out, terms_out, used_out, filled_out,
                frames_out, n_frames_out, nis, dof)


OUTPUTS = ("estimate", "status", "sigma", *(s + "_out" for s in STATE), "nis", "dof")


@onnx_exporter_for("balance-net")
def export_balance_onnx(est, out: str | Path) -> list[Path]:
    """Write ``balance-net.onnx`` (the step graph, metadata for the host loop) into ``out``.

    Parameters
    ----------
    est : BalanceNet
        The fitted estimator.
    out : str or Path
        The output folder.
    """
    import onnx

    from excavator_payload.estimators.base import gate_threshold, max_consecutive_rejections
    from excavator_payload.estimators.learned.balance_net import MAX_BRIDGED_GAP

    graph = BalanceStepGraph(est).eval()
    state = graph.initial_state()
    sensors = est.sensor_set
    args = (torch.zeros(len(sensors.signals), dtype=torch.float64),
            *(torch.tensor(state[k], dtype=torch.float64) for k in STATE))
    meta = {"signals": ",".join(sensors.signals), "estimator": est.name, "sensor_set": sensors.name,
            "sample_rate": repr(sensors.sample_rate), "sample_period": repr(sensors.sample_period),
            "units": ",".join(sensors.units[s] for s in sensors.signals), "output_unit": "kg",
            "width": str(graph.width), "channels": str(graph.n), "machine_set": str(int(graph.machine)),
            "plausible_low": json.dumps(np.asarray(est.plausible_low, float).tolist()),
            "plausible_high": json.dumps(np.asarray(est.plausible_high, float).tolist()),
            "max_bridged_gap": repr(MAX_BRIDGED_GAP), "gating": str(int(est.gating)),
            "gate_thresholds": json.dumps([gate_threshold(k) for k in range(1, graph.n + 1)]),
            "max_consecutive_rejections": str(int(max_consecutive_rejections(sensors)))}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{est.name}.onnx"
    tmp = out / f".{est.name}.onnx.tmp"
    default = torch.get_default_dtype()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.set_default_dtype(torch.float64)  # the tracer's scalars: float64 constants
        try:
            torch.onnx.export(graph, args, str(tmp), input_names=["signals", *STATE], output_names=list(OUTPUTS),
                              opset_version=OPSET, dynamo=False)
        finally:
            torch.set_default_dtype(default)
    model = onnx.load(str(tmp))
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.doc_string = "excavator-payload balance-net: one step of the weighing (float64, explicit state)"
    onnx.checker.check_model(model)
    onnx.save(model, str(tmp))
    os.replace(tmp, path)
    return [path]


class OnnxBalanceNet:
    """The host loop around the step graph: ``Estimator.step_values`` (base.py) without the
    sensor health monitor, from the file's metadata alone (a reference for an ECU's runner).

    Parameters
    ----------
    path : str or Path
        The exported ``balance-net.onnx``.
    """

    def __init__(self, path: str | Path) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        meta = self.session.get_modelmeta().custom_metadata_map
        self.low = np.array(json.loads(meta["plausible_low"]))
        self.high = np.array(json.loads(meta["plausible_high"]))
        self.period = float(meta["sample_period"])
        self.bridged = float(meta["max_bridged_gap"])
        self.machine_set = meta["machine_set"] == "1"
        self.gating = meta["gating"] == "1"
        self.thresholds = json.loads(meta["gate_thresholds"])
        self.max_rejections = int(meta["max_consecutive_rejections"])
        shapes = {i.name: i.shape for i in self.session.get_inputs()}
        self._initial = {k: np.zeros(shapes[k]) for k in STATE}
        self.reset()

    def reset(self) -> None:
        """Start a new experiment."""
        self.state = {k: v.copy() for k, v in self._initial.items()}
        self.last_time = None
        self.last = (math.nan, math.nan)
        self.n_rejected = 0
        self.gate_scale = 1.0

    def _clear_window(self) -> None:
        for k in ("terms", "used", "filled", "frames", "n_frames"):
            self.state[k] = self._initial[k].copy()

    def step_values(self, time: float, values: np.ndarray) -> tuple[float, str, float]:
        """``(estimate, status, sigma)`` of one sample, as ``Estimator.step_values``.

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            One value per signal, SI units.
        """
        values = np.asarray(values, float)
        if not (math.isfinite(time) and np.all(np.isfinite(values))):
            return self.last[0], "invalid_input", self.last[1]
        if not (np.all(values >= self.low) and np.all(values <= self.high)):
            return self.last[0], "out_of_range", self.last[1]
        gap = self.last_time is not None and not 0 < time - self.last_time <= 1.5 * self.period
        if gap:  # BalanceNet._on_gap
            if self.last_time is None or not 0.0 < time - self.last_time <= self.bridged:
                self.state = {k: v.copy() for k, v in self._initial.items()}
            else:
                self._clear_window()
        elif self.n_rejected:  # BalanceNet._on_skip
            self._clear_window()
        feed = {"signals": values, **self.state}
        result = dict(zip(OUTPUTS, self.session.run(None, feed)))
        reinitialised = False
        if self.gating and not self.machine_set and math.isfinite(result["nis"][0]):
            nis, threshold = float(result["nis"][0]), self.thresholds[int(result["dof"][0]) - 1]
            if not nis <= threshold * self.gate_scale:
                self.n_rejected += 1
                if self.n_rejected <= self.max_rejections:
                    if not gap:
                        self.last_time = time
                    return self.last[0], "rejected_outlier", self.last[1]
                self.state = {k: v.copy() for k, v in self._initial.items()}
                reinitialised = True
                self.gate_scale = max(self.gate_scale, 2.0 * nis / threshold)
                result = dict(zip(OUTPUTS, self.session.run(None, {"signals": values, **self.state})))
            else:
                from excavator_payload.estimators.base import GATE_SCALE_HEADROOM, GATE_SCALE_RATE

                ratio = nis / threshold * GATE_SCALE_HEADROOM
                self.gate_scale = max(1.0, (1 - GATE_SCALE_RATE) * self.gate_scale + GATE_SCALE_RATE * ratio)
        self.n_rejected = 0
        self.last_time = time
        self.state = {k: result[k + "_out"] for k in STATE}
        estimate, sigma = float(result["estimate"][0]), float(result["sigma"][0])
        status = "ok" if result["status"][0] == 0 else "warming_up"
        if not (math.isfinite(self.state["num"][0]) and math.isfinite(self.state["info"][0])):
            self.state = {k: v.copy() for k, v in self._initial.items()}
            self.last_time = None
            estimate, sigma, status = math.nan, math.nan, "state_reset"
        self.last = (estimate, sigma)
        if reinitialised:
            return estimate, "reinitialised", sigma
        if gap and status != "state_reset":
            return estimate, "gap", sigma
        return estimate, status, sigma
