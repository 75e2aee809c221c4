"""Arm dynamics (single symbolic source) and machine presets."""

from excavator_payload.model.dynamics import PARAMETER_NAMES, ArmModel, symbolic
from excavator_payload.model.machine import Machine, list_presets, load_machine

__all__ = ["ArmModel", "Machine", "PARAMETER_NAMES", "list_presets", "load_machine", "symbolic"]
