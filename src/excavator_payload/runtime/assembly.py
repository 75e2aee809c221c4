"""Sample assembly for the CAN sensor: :mod:`excavator_payload.data.assembly` (it moved down to the
data layer, where the field-log reader uses it too); the names stay importable from here."""

from excavator_payload.data.assembly import (  # noqa: F401
    LEARN_INTERVALS,
    PHASE_GAIN,
    RESTART_BACK,
    STALE_TOLERANCE,
    Sample,
    SampleAssembler,
)
