"""Exceptions a user can cause. The CLI prints these as one clear message, never a traceback."""


class ExcavatorPayloadError(Exception):
    """Base class of every error caused by bad input (files, options, data)."""


class MachineError(ExcavatorPayloadError):
    """A machine file is missing, malformed or physically impossible."""


class DatasetError(ExcavatorPayloadError):
    """A dataset file is missing, truncated or violates the schema."""


class EstimatorError(ExcavatorPayloadError):
    """An estimator was misused: bad options, not fitted, or a corrupt save directory."""
