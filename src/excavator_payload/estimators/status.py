"""What a streaming step returns: the :class:`Status` beside each estimate and the
:class:`StepResult` that carries them (the estimator protocol is in :mod:`.base`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class Status(str, Enum):
    """What the estimate beside it means."""

    OK = "ok"                    #: a valid estimate
    WARMING_UP = "warming_up"    #: not enough samples yet (delay lines filling, filter converging)
    NO_DATA = "no_data"          #: no sample seen since the last reset
    GAP = "gap"                  #: time jumped; the estimator restarted
    INVALID = "invalid_input"    #: a signal was missing, NaN or infinite: sample ignored
    OUT_OF_RANGE = "out_of_range"  #: a signal outside its plausibility limits: sample ignored
    REJECTED = "rejected_outlier"  #: inconsistent with the noise model (gate): sample ignored
    REINITIALISED = "reinitialised"  #: restarted after too many rejections in a row; sample used
    STATE_RESET = "state_reset"  #: the estimator's state went non-finite: restarted
    #: the CAN sensor's inputs are older than their period allows (only the runtime says it; here
    #: so that its code, 9 on the bus since the first release, stays one list with the others)
    STALE = "stale"
    #: an estimate outside :data:`PLAUSIBLE_PAYLOAD` of the rated payload: not physical
    IMPLAUSIBLE = "implausible"
    LOAD_CHANGING = "load_changing"  #: the load is changing (a dump, a fill): estimate of the load before
    #: a sensor is faulty (stuck, dropped out, disagreeing with its redundancy; named in
    #: ``StepResult.fault``): sample not used, estimate kept (see :mod:`.health`)
    SENSOR_FAULT = "sensor_fault"
    #: weighed without a faulty signal (named in ``StepResult.fault``): a link's rate replaced by
    #: its differentiated angle, sigma widened (see :meth:`.health.HealthMonitor.substitute`)
    DEGRADED = "degraded"


@dataclass(frozen=True)
class StepResult:
    """One streaming result.

    Parameters
    ----------
    estimate : float
        Payload, kg (NaN: none).
    status : Status
        What the estimate means.
    sigma : float
        One-sigma uncertainty, kg (NaN: unknown).
    fault : str
        Faulty signals and kinds, ``"signal:kind,..."`` (with ``sensor_fault``, and with
        every status while the estimator weighs degraded).

    Attributes
    ----------
    estimate : float
        Payload, kg; NaN when there is no estimate yet.
    status : Status
        What the estimate means (see :class:`Status`).
    sigma : float
        One-sigma uncertainty of ``estimate``, kg; NaN where the estimator cannot tell. How each
        estimator computes it is in its ``_estimate_sigma`` docstring (filters: square root of the payload
        covariance; least squares: of its inverse information; networks: the spread of their
        validation residuals).
    """

    estimate: float
    status: Status
    sigma: float = math.nan
    #: the faulty signals and kinds, ``"signal:kind,..."``, while ``status`` is ``sensor_fault``
    #: or the estimator weighs without them (``degraded``, or any status of a degraded sample)
    fault: str = ""
