"""The registry that names the estimators: command-line name -> class, imported on demand
(:func:`estimator_class`, :func:`create_estimator`; classes join it with :func:`register`)."""

from __future__ import annotations

import importlib
from typing import Any

from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.traits import ESTIMATOR_TRAITS
from excavator_payload.model.machine import Machine

#: Command-line name -> module that defines it (imported on demand, so torch loads only for
#: nets), from the traits.
ESTIMATOR_MODULES: dict[str, str] = {name: t.module for name, t in ESTIMATOR_TRAITS.items()}

#: name -> estimator class (a subclass of :class:`~excavator_payload.estimators.base.Estimator`).
_REGISTRY: dict[str, type] = {}


def register(klass: type) -> type:
    """Class decorator: make an estimator available by its ``name``.

    Parameters
    ----------
    klass : type
        An estimator class with a non-empty ``name``.

    Returns
    -------
    type
        ``klass`` unchanged.
    """
    if not klass.name:
        raise TypeError(f"{klass.__name__} has no name")
    _REGISTRY[klass.name] = klass
    return klass


def estimator_names() -> list[str]:
    """Names of all estimators (``ekf``, ``ukf``, …, ``lrn``), whether imported yet or not."""
    return list(ESTIMATOR_MODULES)


def estimator_class(name: str) -> type:
    """The class registered as ``name`` (importing its module on demand).

    Parameters
    ----------
    name : str
        Command-line name of the estimator (e.g. ``ekf``).

    Returns
    -------
    type
        The estimator class; :class:`EstimatorError` for an unknown or unavailable name.
    """
    if name not in _REGISTRY:
        module = ESTIMATOR_MODULES.get(name)
        if module is None:
            raise EstimatorError(f"unknown estimator '{name}': choose one of {', '.join(ESTIMATOR_MODULES)}")
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("excavator_payload"):
                raise EstimatorError(f"estimator '{name}' is not available in this installation") from None
            raise
    if name not in _REGISTRY:
        raise EstimatorError(f"estimator '{name}' is not available in this installation")
    return _REGISTRY[name]


def create_estimator(name: str, machine: Machine | str | None = None, **options: Any) :
    """A new, unfitted estimator (an :class:`~excavator_payload.estimators.base.Estimator`) called
    ``name`` with the given options.

    Parameters
    ----------
    name : str
        Command-line name of the estimator (e.g. ``ekf``).
    machine : Machine, str or None
        Machine the estimator believes in: object, preset name or TOML file (None: ``cat345c`` where one is needed).
    **options
        The estimator's options (see its ``OPTIONS``).
    """
    return estimator_class(name)(machine=machine, **options)
