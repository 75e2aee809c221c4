"""Payload estimators behind one protocol (see :mod:`excavator_payload.estimators.base`).

The names below are loaded on first use, so that :mod:`excavator_payload.estimators.traits`
(every estimator's facts, read by the CLI's help and the export tables) imports without the
protocol's dependencies.
"""

from __future__ import annotations

import importlib

# Names are imported when first used (PEP 562): a command module of this package must not pay
# for the estimators' base (pandas) at every start.
__all__ = ["Estimator", "Option", "Status", "StepResult", "create_estimator", "estimator_class",
           "estimator_names", "load_estimator", "register"]


def __getattr__(name: str):
    if name in __all__:
        return getattr(importlib.import_module("excavator_payload.estimators.base"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
