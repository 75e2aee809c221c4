"""Payload estimators behind one protocol (see :mod:`excavator_payload.estimators.base`)."""

import importlib

# Names are imported when first used (PEP 562): a command module of this package must not pay
# for the estimators' base (pandas) at every start.
__all__ = ["Estimator", "Option", "Status", "StepResult", "create_estimator", "estimator_class",
           "estimator_names", "load_estimator", "register"]


def __getattr__(name: str):
    if name in __all__:
        return getattr(importlib.import_module(f"{__name__}.base"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
