"""Arm dynamics (single symbolic source) and machine presets."""

import importlib

# Names are imported when first used (PEP 562): loading a machine file must not pay for CasADi.
_WHERE = {"PARAMETER_NAMES": "dynamics", "ArmModel": "dynamics", "symbolic": "dynamics",
          "Machine": "machine", "list_presets": "machine", "load_machine": "machine"}

__all__ = ["ArmModel", "Machine", "PARAMETER_NAMES", "list_presets", "load_machine", "symbolic"]


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
