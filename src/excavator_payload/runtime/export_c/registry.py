"""The C builders, registered against the estimator name and sensor set they export.

A builder (``est -> CModel``) declares what it exports with :func:`c_builder`; the exporter
looks it up with :func:`builder_for`. What each estimator exports is declared in its traits
(:mod:`excavator_payload.estimators.traits`); a test checks the two agree.
"""

from __future__ import annotations

from typing import Callable

_BUILDERS: dict[tuple[str, str], Callable] = {}


def c_builder(*names: str, sensor_set: str) -> Callable[[Callable], Callable]:
    """Decorator: register a builder as the C export of estimators ``names`` fitted on
    ``sensor_set``.

    Parameters
    ----------
    *names : str
        Registry names of the estimators it builds.
    sensor_set : str
        The sensor set they were fitted on.
    """
    def register(builder: Callable) -> Callable:
        for name in names:
            if (sensor_set, name) in _BUILDERS:
                raise ValueError(f"two C builders for {name} on the {sensor_set} sensor set")
            _BUILDERS[(sensor_set, name)] = builder
        return builder
    return register


def builder_for(name: str, sensor_set: str) -> Callable | None:
    """The builder of estimator ``name`` fitted on ``sensor_set``, or None.

    Parameters
    ----------
    name : str
        Registry name.
    sensor_set : str
        The sensor set's name.
    """
    return _BUILDERS.get((sensor_set, name))


def registered() -> dict[str, tuple[str, ...]]:
    """Estimator name -> the sensor sets a builder is registered for."""
    out: dict[str, tuple[str, ...]] = {}
    for sensor_set, name in _BUILDERS:
        out[name] = (*out.get(name, ()), sensor_set)
    return out
