"""One platform per world (the thesis' arm, the hydraulic machine): see :mod:`.base`."""

from excavator_payload.platforms.base import Motion, Platform
from excavator_payload.platforms.hydraulic import HYDRAULIC, HydraulicPlatform
from excavator_payload.platforms.registry import PLATFORMS, platform_for
from excavator_payload.platforms.thesis import THESIS, ThesisPlatform

__all__ = ["HYDRAULIC", "Motion", "PLATFORMS", "Platform", "THESIS", "HydraulicPlatform",
           "ThesisPlatform", "platform_for"]
