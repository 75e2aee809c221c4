"""The platforms the package knows, and :func:`platform_for`: which one a thing belongs to."""

from __future__ import annotations

from typing import Any

from excavator_payload.data.schema import SensorSet
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.platforms.base import Platform
from excavator_payload.platforms.hydraulic import HYDRAULIC
from excavator_payload.platforms.thesis import THESIS

#: Every platform by name.
PLATFORMS: dict[str, Platform] = {p.name: p for p in (THESIS, HYDRAULIC)}

#: What ``--discard`` defaults to, per platform (for ``--help``).
DISCARD_DEFAULT_HELP = (f"default: {THESIS.default_discard()} on the thesis sensor set, as in thesis "
                        f"Table 7.1 at {THESIS.sample_rate:g} Hz; the first "
                        f"{HYDRAULIC.default_discard() / HYDRAULIC.sample_rate:g} s, "
                        f"{HYDRAULIC.default_discard()} samples at {HYDRAULIC.sample_rate:g} Hz, on the machine set")


def platform_for(thing: Any) -> Platform:
    """The platform of ``thing``, resolved once at the edge.

    Parameters
    ----------
    thing : Platform, Dataset, SensorSet, machine object, estimator or str
        A dataset (by its sensor set), a sensor set, a machine (thesis arm or hydraulic
        machine), anything with a ``sensor_set`` attribute, or a platform's or sensor set's
        name (``thesis``, ``hydraulic``, ``machine``).

    Raises
    ------
    ExcavatorPayloadError
        When ``thing`` belongs to no platform.
    """
    if isinstance(thing, Platform):
        return thing
    if isinstance(thing, SensorSet):
        for platform in PLATFORMS.values():
            if platform.sensors.name == thing.name:
                return platform
        raise ExcavatorPayloadError(f"no platform carries the {thing.name} sensor set")
    if isinstance(thing, str):
        if thing in PLATFORMS:
            return PLATFORMS[thing]
        for platform in PLATFORMS.values():
            if platform.sensors.name == thing:
                return platform
        raise ExcavatorPayloadError(f"unknown platform '{thing}': choose one of {', '.join(PLATFORMS)}")
    sensors = getattr(thing, "sensor_set", None)
    if isinstance(sensors, SensorSet):  # a dataset, an estimator, a sensor
        return platform_for(sensors)
    for platform in PLATFORMS.values():
        if platform.owns(thing):
            return platform
    raise ExcavatorPayloadError(f"{type(thing).__name__} belongs to no platform")
