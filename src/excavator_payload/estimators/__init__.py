"""Payload estimators behind one protocol (see :mod:`excavator_payload.estimators.base`)."""

from excavator_payload.estimators.base import (
    Estimator,
    Option,
    Status,
    StepResult,
    create_estimator,
    estimator_class,
    estimator_names,
    load_estimator,
    register,
)

__all__ = ["Estimator", "Option", "Status", "StepResult", "create_estimator", "estimator_class",
           "estimator_names", "load_estimator", "register"]
