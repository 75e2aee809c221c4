"""The ONNX graphs and whole-file exporters, registered against the estimator they export.

A window graph (a ``torch.nn.Module`` built from a fitted estimator) registers with
:func:`onnx_graph_for`; an estimator whose file is not one window graph (``balance-net``: one
step with explicit state) registers its own writer with :func:`onnx_exporter_for`. What each
estimator exports is declared in its traits (:mod:`excavator_payload.estimators.traits`); a
test checks the two agree.
"""

from __future__ import annotations

from typing import Callable

#: The ONNX operator set every exported graph targets.
OPSET = 17

_GRAPHS: dict[str, type] = {}
_EXPORTERS: dict[str, Callable] = {}


def _register(table: dict, names: tuple[str, ...]) -> Callable:
    def register(entry):
        for name in names:
            table[name] = entry
        return entry
    return register


def onnx_graph_for(*names: str) -> Callable[[type], type]:
    """Class decorator: register a graph as the ONNX export of estimators ``names``.

    Parameters
    ----------
    *names : str
        Registry names of the networks it exports.
    """
    return _register(_GRAPHS, names)


def onnx_exporter_for(*names: str) -> Callable[[Callable], Callable]:
    """Decorator: register ``(est, out) -> list[Path]`` as the whole ONNX export of ``names``.

    Parameters
    ----------
    *names : str
        Registry names of the estimators it writes.
    """
    return _register(_EXPORTERS, names)


def graph_for(name: str) -> type | None:
    """The window graph registered for estimator ``name``, or None.

    Parameters
    ----------
    name : str
        Registry name.
    """
    return _GRAPHS.get(name)


def exporter_for(name: str) -> Callable | None:
    """The whole-file writer registered for estimator ``name``, or None.

    Parameters
    ----------
    name : str
        Registry name.
    """
    return _EXPORTERS.get(name)


def registered() -> tuple[str, ...]:
    """Every estimator name with an ONNX export (graph or writer), sorted."""
    return tuple(sorted({*_GRAPHS, *_EXPORTERS}))
