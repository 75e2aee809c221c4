"""The conformance suite's cases, derived from the estimators' traits: every estimator on every
sensor set its traits declare, made with cheap settings (shared by test_conformance.py, the
thesis sensor set, and test_conformance_machine.py, the machine sensor set)."""

from __future__ import annotations

from excavator_payload.estimators.traits import ESTIMATOR_TRAITS, estimators_on


def recipes(sensor_set: str, tiny_net: dict, overrides: dict | None = None) -> dict[str, dict]:
    """Estimator name -> options, for every estimator whose traits declare ``sensor_set``:
    ``tiny_net`` for those that learn from a training set, ``overrides`` on top."""
    overrides = overrides or {}
    return {name: {**(tiny_net if ESTIMATOR_TRAITS[name].needs_training_set else {}), **overrides.get(name, {})}
            for name in estimators_on(sensor_set)}
