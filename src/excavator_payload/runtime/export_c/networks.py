"""C builders of the networks: ``net1``/``ffnn`` (time-delay) and ``net2`` (closed-loop NARX).

Weights are constant arrays. ``net1`` (and ``ffnn``): the input scaling folded into the first
layer and the output scaling into the last (as the Python streaming code does), the delay
line a doubled ring buffer in the state. ``net2``: input scaling, the input delay line and the
fed-back estimates in the state (as :class:`~excavator_payload.estimators.dvs.recurrent.RecurrentStepper`).
Their sigma is the constant RMS validation error the fit measured (``residual_std``). A
network has no noise model: it borrows the gate, does nothing before the sample after
gate-rejected ones and, once that sample is accepted, steps the rejected slots with
interpolated values (``Estimator._interpolate_rejected``), so the delay lines stay evenly spaced.
"""

from __future__ import annotations

import numpy as np

from excavator_payload.errors import EstimatorError
from excavator_payload.runtime.export_c.c_text import (
    TANH_LAYER_C,
    c_array,
    c_number,
    interpolate_rejected_c,
)
from excavator_payload.runtime.export_c.casadi_code import casadi_c_code
from excavator_payload.runtime.export_c.registry import c_builder
from excavator_payload.runtime.export_c.cmodel import CModel, borrowed_gate


def _network_gate(est, model: CModel) -> CModel:
    """A network's borrowed gate (NeuralEstimator: rejected slots interpolated, no bridging)."""
    gate = borrowed_gate(est)
    if gate is None:
        return model
    code = casadi_c_code(gate.functions)
    model.definitions = code + "\n\n" + model.definitions
    gate.apply(model, code)
    model.on_skip = "    /* NeuralEstimator._on_skip: nothing; see ep_model_fill_rejected */\n" \
                    "    (void)s;\n    (void)time;\n    (void)v;"
    model.fill_rejected = interpolate_rejected_c()
    return model



def _network_sigma(est) -> str:
    """``NeuralEstimator._estimate_sigma``: the net's RMS validation error, a constant."""
    source = est.residual_source or "validation"
    return (f"    /* NeuralEstimator._estimate_sigma: RMS error on its {source} experiments */\n"
            f"    (void)s;\n    return {c_number(est.residual_std)};")


@c_builder("net1", "ffnn", sensor_set="thesis")
def time_delay_model(est) -> CModel:
    """The C of ``net1`` and ``ffnn``: the streaming time-delay network.

    Parameters
    ----------
    est : Estimator
        The fitted estimator.
    """
    from excavator_payload.estimators.dvs.mlp import mlp_layers

    sensors = est.sensor_set
    n_sig = len(sensors.signals)
    L = max(est.delay_list) + 1
    layers = mlp_layers(np.asarray(est.weights, dtype=float), est._layer_sizes())
    # fold the input scaling into the first layer, reading all signals of the last L samples
    # (oldest first): W1 ((x - c) * g) + b1 = (W1 diag g) x + (b1 - W1 (c * g))
    W1, b1 = layers[0]
    gain, center = est.input_scaler.gain, est.input_scaler.center
    W1s = np.zeros((W1.shape[0], L * n_sig))
    b1s = np.array(b1, dtype=float)
    for j, d in enumerate(est.delay_list):
        for c, signal in enumerate(est.input_index):
            column = W1[:, j * est.n_inputs + c]
            W1s[:, (L - 1 - d) * n_sig + signal] = column * gain[c]
            b1s -= column * gain[c] * center[c]
    WL, bL = layers[-1]
    g_out, c_out = float(est.output_scaler.gain[0]), float(est.output_scaler.center[0])
    stream = [(W1s, b1s), *[(np.asarray(W), np.asarray(b)) for W, b in layers[1:-1]]]
    w_out, b_out = np.asarray(WL[0]) / g_out, float(bL[0]) / g_out + c_out
    hidden = [W.shape[0] for W, _ in stream]
    defs = ["/* Layers of the streaming network (tanh hidden layers, linear output), input and",
            " * output scaling folded in; layer 1 reads the last EP_WINDOW samples, oldest first. */",
            f"#define EP_MAX_HIDDEN {max(hidden)}"]
    for k, (W, b) in enumerate(stream):
        defs.append(c_array(f"EP_W{k + 1}", W))
        defs.append(c_array(f"EP_B{k + 1}", b))
    defs.append(c_array("EP_W_OUT", w_out))
    defs.append(f"#define EP_B_OUT {c_number(b_out)}")
    defs.append(TANH_LAYER_C)
    calls = []
    sizes = [L * n_sig, *hidden]
    for k in range(len(stream)):
        src = "window" if k == 0 else ("a" if k % 2 == 1 else "b")
        dst = "a" if k % 2 == 0 else "b"
        calls.append(f"    ep_tanh_layer(EP_W{k + 1}, EP_B{k + 1}, {hidden[k]}, {sizes[k]}, {src}, {dst});")
    last = "a" if (len(stream) - 1) % 2 == 0 else "b"
    step = f"""    /* TimeDelayNetwork._step: each sample is written twice, EP_WINDOW blocks apart, so the
     * last EP_WINDOW samples are always one contiguous slice (oldest first) */
    ep_real a[EP_MAX_HIDDEN], b[EP_MAX_HIDDEN], y;
    const ep_real *window;
    int i, p;
    (void)time;
    p = s->newest = (s->newest + 1) % EP_WINDOW;
    for (i = 0; i < EP_N_SIGNALS; ++i) {{
        s->buffer[p * EP_N_SIGNALS + i] = v[i];
        s->buffer[(p + EP_WINDOW) * EP_N_SIGNALS + i] = v[i];
    }}
    s->count += 1;
    if (s->count < EP_WINDOW) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    if (s->count > EP_WINDOW) s->count = EP_WINDOW;  /* no overflow on long runs */
    window = s->buffer + (p + 1) * EP_N_SIGNALS;
{chr(10).join(calls)}
    y = EP_B_OUT;
    for (i = 0; i < {hidden[-1]}; ++i) y += EP_W_OUT[i] * {last}[i];
    (void)b;
    *estimate = y;
    return EP_STATUS_OK;"""
    return _network_gate(est, CModel(
        description=f"{est.name}: time-delay network, delays {est.delay_list}, hidden {hidden}, "
                    f"inputs {', '.join(est.input_names)}",
        state_fields=["ep_real buffer[2 * EP_WINDOW * EP_N_SIGNALS];  /* doubled ring of raw samples */",
                      "int newest;  /* ring position of the newest sample */",
                      "int count;   /* samples since the reset (saturates at EP_WINDOW) */"],
        definitions="\n".join(defs),
        reset="    int i;\n    s->newest = -1;\n    s->count = 0;\n"
              "    for (i = 0; i < 2 * EP_WINDOW * EP_N_SIGNALS; ++i) s->buffer[i] = EP_C(0.0);",
        step=step, header_defines=[f"#define EP_WINDOW {L}  /* samples in the delay line */"],
        sigma=_network_sigma(est)))


@c_builder("net2", sensor_set="thesis")
def narx_model(est) -> CModel:
    """The C of ``net2``: the closed-loop NARX network (``RecurrentStepper``).

    Parameters
    ----------
    est : Estimator
        The fitted estimator.
    """
    from excavator_payload.estimators.dvs.recurrent import unpack_weights

    st = est.structure
    if st.layer_delays and st.recurrent_layers:
        raise EstimatorError(f"{est.name}: networks with layer feedback (lrn) have no C export yet")
    layers = unpack_weights(np.asarray(est.weights, dtype=float), st)
    n_in = est.n_inputs
    max_in = max(st.input_delays)
    fb = st.feedback_delays
    n_fb = max(fb, default=0)
    g_out, c_out = float(est.output_scaler.gain[0]), float(est.output_scaler.center[0])
    hidden = list(st.hidden)
    defs = ["/* NARX network (closed loop): layer 1 sees the input delay line and the fed-back",
            " * estimates (scaled); tanh hidden layers; linear output. */",
            f"#define EP_WARMUP {st.warmup}",
            f"#define EP_MAX_HIDDEN {max(hidden)}",
            f"#define EP_N_X {st.n_tdl + len(fb)}",
            f"static const int EP_INPUT_INDEX[{n_in}] = {{{', '.join(str(int(i)) for i in est.input_index)}}};",
            c_array("EP_INPUT_CENTER", est.input_scaler.center),
            c_array("EP_INPUT_GAIN", est.input_scaler.gain),
            f"#define EP_OUTPUT_CENTER {c_number(c_out)}",
            f"#define EP_OUTPUT_GAIN {c_number(g_out)}",
            f"#define EP_INITIAL_OUTPUT {c_number(est._initial_scaled)}  /* scaled initial payload */",
            f"static const int EP_INPUT_DELAYS[{len(st.input_delays)}] = "
            f"{{{', '.join(map(str, st.input_delays))}}};"]
    if fb:
        defs.append(f"static const int EP_FEEDBACK_DELAYS[{len(fb)}] = {{{', '.join(map(str, fb))}}};")
    for k, (W, b) in enumerate(layers):
        defs.append(c_array(f"EP_W{k + 1}", W))
        defs.append(c_array(f"EP_B{k + 1}", b))
    defs.append(TANH_LAYER_C)
    calls = [f"    ep_tanh_layer(EP_W1, EP_B1, {hidden[0]}, EP_N_X, x, a);"]
    for k in range(1, len(hidden)):
        src, dst = ("a", "b") if k % 2 == 1 else ("b", "a")
        calls.append(f"    ep_tanh_layer(EP_W{k + 1}, EP_B{k + 1}, {hidden[k]}, {hidden[k - 1]}, {src}, {dst});")
    last = "a" if (len(hidden) - 1) % 2 == 0 else "b"
    n_out_layer = len(layers)
    fb_code = ""
    if fb:
        fb_code = f"""    for (j = 0; j < {len(fb)}; ++j)
        x[k++] = s->y_past[EP_N_FEEDBACK - EP_FEEDBACK_DELAYS[j]];  /* y(t - f), newest last */"""
    push_fb = ""
    if fb:
        push_fb = """    for (j = 0; j + 1 < EP_N_FEEDBACK; ++j) s->y_past[j] = s->y_past[j + 1];
    s->y_past[EP_N_FEEDBACK - 1] = y;"""
    step = f"""    /* RecurrentStepper.step on the scaled input u = (v[index] - center) * gain */
    ep_real x[EP_N_X], a[EP_MAX_HIDDEN], b[EP_MAX_HIDDEN], y;
    int i, j, k = 0;
    (void)time;
    for (j = 0; j < EP_MAX_INPUT_DELAY; ++j)          /* shift the input line, newest last */
        for (i = 0; i < EP_N_INPUTS; ++i)
            s->u_past[j * EP_N_INPUTS + i] = s->u_past[(j + 1) * EP_N_INPUTS + i];
    for (i = 0; i < EP_N_INPUTS; ++i)
        s->u_past[EP_MAX_INPUT_DELAY * EP_N_INPUTS + i] =
            (v[EP_INPUT_INDEX[i]] - EP_INPUT_CENTER[i]) * EP_INPUT_GAIN[i];
    if (s->n < EP_WARMUP + 1) s->n += 1;
    if (s->n <= EP_WARMUP) {{
        *estimate = EP_NAN;
        return EP_STATUS_WARMING_UP;
    }}
    for (j = 0; j < {len(st.input_delays)}; ++j)       /* u(t - d) for d in the input delays */
        for (i = 0; i < EP_N_INPUTS; ++i)
            x[k++] = s->u_past[(EP_MAX_INPUT_DELAY - EP_INPUT_DELAYS[j]) * EP_N_INPUTS + i];
{fb_code}
{chr(10).join(calls)}
    y = EP_B{n_out_layer}[0];
    for (i = 0; i < {hidden[-1]}; ++i) y += EP_W{n_out_layer}[i] * {last}[i];
{push_fb}
    (void)b;
    *estimate = y / EP_OUTPUT_GAIN + EP_OUTPUT_CENTER;
    return EP_STATUS_OK;"""
    return _network_gate(est, CModel(
        description=f"{est.name}: closed-loop NARX network, input delays {list(st.input_delays)}, "
                    f"feedback delays {list(fb)}, hidden {hidden}, inputs {', '.join(est.input_names)}",
        state_fields=["ep_real u_past[(EP_MAX_INPUT_DELAY + 1) * EP_N_INPUTS];  /* scaled inputs, newest last */",
                      "ep_real y_past[EP_N_FEEDBACK];  /* fed-back scaled estimates, newest last */",
                      "int n;  /* samples since the reset (saturates) */"],
        definitions="\n".join(defs),
        reset="    int i;\n    s->n = 0;\n"
              "    for (i = 0; i < (EP_MAX_INPUT_DELAY + 1) * EP_N_INPUTS; ++i) s->u_past[i] = EP_C(0.0);\n"
              "    for (i = 0; i < EP_N_FEEDBACK; ++i) s->y_past[i] = EP_INITIAL_OUTPUT;",
        step=step, header_defines=[f"#define EP_N_INPUTS {n_in}  /* network inputs */",
                                   f"#define EP_MAX_INPUT_DELAY {max_in}",
                                   f"#define EP_N_FEEDBACK {max(n_fb, 1)}  /* fed-back estimates kept */"],
        sigma=_network_sigma(est)))
