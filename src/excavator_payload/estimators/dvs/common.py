"""What every data-driven virtual sensor (DVS) shares, gathered under one name: each job lives
in a module of its own and this module re-exports their public names, so that
``from excavator_payload.estimators.dvs.common import X`` keeps working (callers, benchmarks,
and pickles of fitted networks written before the split).

Where the names live:

* :mod:`~excavator_payload.estimators.dvs.options`: ``THESIS_INPUTS``, ``DEFAULT_INPUTS``,
  ``TRAINERS``, the ``MAX_*`` limits, ``parse_int_list``, ``parse_hidden``, ``parse_delays``,
  ``parse_inputs``, ``neural_options``;
* :mod:`~excavator_payload.estimators.dvs.scaling`: ``SCALINGS``, ``Scaler``;
* :mod:`~excavator_payload.estimators.dvs.mlp`: ``mlp_sizes``, ``n_weights``, ``mlp_layers``,
  ``nguyen_widrow_init``, ``mlp_forward``, ``mlp_output_jacobian``, ``mlp_forward_numpy``;
* :mod:`~excavator_payload.estimators.dvs.windows`: ``delay_windows``, ``DelayLine``,
  ``experiment_bounds``, ``experiment_arrays``, ``block_means``;
* :mod:`~excavator_payload.estimators.dvs.neural`: ``NeuralEstimator``, ``TrainingProblem``.
"""

from __future__ import annotations

from excavator_payload.estimators.dvs.mlp import (
    mlp_forward,
    mlp_forward_numpy,
    mlp_layers,
    mlp_output_jacobian,
    mlp_sizes,
    n_weights,
    nguyen_widrow_init,
)
from excavator_payload.estimators.dvs.neural import NeuralEstimator, TrainingProblem
from excavator_payload.estimators.dvs.options import (
    DEFAULT_INPUTS,
    MAX_DECIMATION,
    MAX_DELAY,
    MAX_LAYER_SIZE,
    MAX_LIST,
    MAX_WEIGHTS,
    THESIS_INPUTS,
    TRAINERS,
    neural_options,
    parse_delays,
    parse_hidden,
    parse_inputs,
    parse_int_list,
)
from excavator_payload.estimators.dvs.scaling import SCALINGS, Scaler
from excavator_payload.estimators.dvs.windows import (
    DelayLine,
    block_means,
    delay_windows,
    experiment_arrays,
    experiment_bounds,
)

__all__ = ["THESIS_INPUTS", "DEFAULT_INPUTS", "SCALINGS", "TRAINERS", "Scaler", "mlp_sizes", "n_weights", "mlp_layers",
           "nguyen_widrow_init", "mlp_forward", "mlp_output_jacobian", "mlp_forward_numpy", "delay_windows", "DelayLine",
           "experiment_bounds", "experiment_arrays", "neural_options", "NeuralEstimator",
           "parse_int_list", "parse_hidden", "parse_delays", "parse_inputs", "block_means",
           "TrainingProblem", "MAX_LIST", "MAX_LAYER_SIZE", "MAX_DELAY", "MAX_WEIGHTS", "MAX_DECIMATION"]

