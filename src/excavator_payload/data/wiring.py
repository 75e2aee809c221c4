"""Wiring mistakes found from the arm's balance: a cylinder's head and rod pressures swapped.

Swapped head and rod columns pass every magnitude and unit check (both are pressures in Pa) and
weighed −13 t ``ok``. The machine model says which way each cylinder must push: at the measured
angles, rates and the accelerations differentiated from the rates, the symbolic model of
:mod:`excavator_payload.model.hydraulic` gives the force each cylinder carries
(``HydraulicArmModel.motion_signals``' ``load``), with an empty bucket and with the machine's
largest payload. Where both have the same sign and clearly exceed the seal friction (on a
standing or slow arm the boom cylinders always push the arm up), the measured net force
``p_head·A_head − p_rod·A_rod`` must have that sign too. A cylinder whose net force has the wrong
sign on nearly every such sample has its two pressure columns swapped (a swapped pair flips the
sign of the net force whenever one side carries the load).

Per experiment (a wiring may change between recordings), on a thinned set of samples (the model
costs ~60 µs a sample): :data:`SAMPLES_PER_EXPERIMENT` per experiment, at most
:data:`MAX_SAMPLES` over the file.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from excavator_payload.errors import DatasetError

CYLINDER_NAMES = ("boom", "dipper", "bucket")
#: Samples of each experiment the balance is evaluated on (evenly spread).
SAMPLES_PER_EXPERIMENT = 60
#: Samples evaluated over a whole file at most (experiments beyond are thinned further).
MAX_SAMPLES = 6000
#: A sample is judged when the model's force is at least this share of its largest value over the
#: payload range (the sign cannot flip with the payload, a 3 %-off machine file or the dynamics)
#: and above twice the seal friction.
FORCE_MARGIN = 0.25
#: Margin on the force beyond which swapped chambers flip the net force's sign (see check_wiring).
FLIP_MARGIN = 1.5
#: Judged samples an experiment needs for a cylinder to be judged.
MIN_JUDGED = 15
#: A cylinder whose net force agrees in sign with the model on less than this share of the judged
#: samples is swapped (a correct wiring agreed on 100 % of them on every simulated motion family
#: — swings, NMPC, work cycles, slopes, lifts, an empty swing — a swapped one on 0 %; digging, the bucket on the ground, can turn some samples, not most).
AGREEMENT_LIMIT = 0.35
#: Half-width (samples) of the central difference that turns the measured rates into accelerations.
ACCEL_HALF_WIDTH = 5


_MODELS: dict[str, object] = {}


def _model(machine):
    """The machine's compiled model, built once per machine and process."""
    import json

    from excavator_payload.model.hydraulic import HydraulicArmModel

    key = json.dumps(machine.to_dict(), sort_keys=True)
    if key not in _MODELS:
        _MODELS[key] = HydraulicArmModel(machine)
    return _MODELS[key]


def check_wiring(frame: pd.DataFrame, sensors, machine, source: str) -> None:
    """Refuse an experiment whose head and rod pressures of a cylinder are swapped.

    ``frame``: ``experiment``, ``time`` and the machine sensor set's signals. Does nothing for
    another sensor set or a machine that is not hydraulic (the thesis' 2-link arm has no chambers).

    Parameters
    ----------
    frame : pandas.DataFrame
        The sample table.
    sensors : SensorSet
        Its sensor set.
    machine : HydraulicMachine or Machine or None
        The machine the balance is computed for.
    source : str
        Where the data came from (a file name), the start of the error message.

    Raises
    ------
    DatasetError
        One line naming the experiment, the cylinder and the two columns.
    """
    from excavator_payload.model.hydraulic_machine import HydraulicMachine

    if not sensors.cylinder_chambers or not isinstance(machine, HydraulicMachine):
        return
    # an angle in the wrong unit breaks the balance as swapped lines do: say the unit first
    check_angle_scale(frame, sensors, machine, source)
    table = balance_agreement(frame, sensors, machine)
    swapped = table[table["agreement"] < AGREEMENT_LIMIT]
    if len(swapped):
        first = swapped.iloc[0]
        k, name = first["experiment"], first["cylinder"]
        need, got = ("push (extend)", "pulls") if first["pushes"] else ("pull (retract)", "pushes")
        alike = int((swapped["cylinder"] == name).sum())
        total = frame["experiment"].nunique()
        also = f"; {alike} of {total} experiments alike" if alike > 1 else ""
        raise DatasetError(
            f"{source}: experiment {k:.0f}: the {name} cylinder's net force (head × piston area − rod × "
            f"annulus area) {got} on {100 * (1 - first['agreement']):.0f} % of the {first['judged']} "
            f"samples where the arm's balance needs it to {need}: are '{name}_head_pressure' and "
            f"'{name}_rod_pressure' swapped?{also}")


#: rad by which a joint's range is widened before an angle is judged outside it (more than the
#: angle sensors' plausibility margin, 0.094 rad boom, 0.173 rad dipper and bucket).
RANGE_MARGIN = 0.2


def check_angle_scale(frame: pd.DataFrame, sensors, machine, source: str) -> None:
    """Refuse an experiment whose boom, dipper or bucket angle is scaled to radians twice (a DBC
    already in rad given the degree factor π/180): it weighed nothing, and the arm's balance
    blamed the cylinder's head and rod lines ("dipper … swapped?"). Judged, per experiment and
    angle, by the machine's joint range (every value outside it, widened by
    :data:`RANGE_MARGIN`, while 180/π times every value lies inside: a dipper, whose range stops
    short of 0, at any motion) or by the angle's rate
    (:func:`~excavator_payload.data.units.shrunk_angle`: the angle changes π/180 times what the
    rate integrates to; a boom or bucket, whose ranges hold 0, once it moves).

    Parameters
    ----------
    frame : pandas.DataFrame
        ``experiment``, ``time`` and the machine sensor set's signals.
    sensors : SensorSet
        Its sensor set.
    machine : HydraulicMachine
        Its joints' angle ranges (rows boom, dipper, bucket).
    source : str
        The start of the error message.

    Raises
    ------
    DatasetError
        One line naming the experiment and the angle, saying it is the unit and not the wiring.
    """
    import math

    from excavator_payload.data.units import shrunk_angle, shrunk_message

    ranges = np.asarray(machine.angle_ranges, dtype=float)
    codes, ids = pd.factorize(frame["experiment"].to_numpy())
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    bounds = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1], True])
    time = frame["time"].to_numpy(dtype=float)[order]
    scale = 180.0 / math.pi
    for j, name in enumerate(CYLINDER_NAMES):
        column, rate = f"{name}_angle", f"{name}_rate"
        if column not in frame:
            continue
        angle = frame[column].to_numpy(dtype=float)[order]
        rates = frame[rate].to_numpy(dtype=float)[order] if rate in frame else None
        low, high = ranges[j, 0] - RANGE_MARGIN, ranges[j, 1] + RANGE_MARGIN
        for a, b in zip(bounds[:-1], bounds[1:]):
            values = angle[a:b][np.isfinite(angle[a:b])]
            if values.size < 2:
                continue
            where = f"{source}: experiment {ids[codes[a]]}: column '{column}'"
            outside = np.all((values < low) | (values > high))
            if outside and np.all((values * scale >= low) & (values * scale <= high)):
                raise DatasetError(
                    f"{where} reads {values.min():.3g} … {values.max():.3g} rad, outside the machine's {name} "
                    f"range ({ranges[j, 0]:.3g} … {ranges[j, 1]:.3g} rad), and {scale:.4g} times that lies "
                    f"inside it: an angle in radians scaled by π/180 once more (a degree factor on a signal "
                    f"already in rad)? The unit, not the wiring")
            if rates is not None:
                factor = shrunk_angle(time[a:b], angle[a:b], rates[a:b], sensors.sample_period, 0.02,
                                      sensors.plausible_abs[column])
                if factor is not None:
                    peak = float(np.max(np.abs(values)))
                    raise DatasetError(f"{source}: experiment {ids[codes[a]]}: column "
                                       + shrunk_message(column, rate, factor, peak))


def balance_agreement(frame: pd.DataFrame, sensors, machine) -> pd.DataFrame:
    """Per experiment and cylinder: ``judged`` samples (where the balance fixes the sign of the
    cylinder's force), the share of them whose measured net force has that sign (``agreement``)
    and whether the model needs a push there (``pushes``). Cylinders with fewer than
    :data:`MIN_JUDGED` judged samples are left out.

    Parameters
    ----------
    frame : pandas.DataFrame
        The sample table (``experiment``, ``time``, the machine sensor set's signals).
    sensors : SensorSet
        Its sensor set (with head and rod pressures).
    machine : HydraulicMachine
        The hydraulic machine whose arm balance is computed.

    Returns
    -------
    pandas.DataFrame
        Columns ``experiment``, ``cylinder``, ``judged``, ``agreement``, ``pushes``.
    """
    out = pd.DataFrame(columns=["experiment", "cylinder", "judged", "agreement", "pushes"])
    experiments = pd.unique(frame["experiment"].to_numpy())
    per = max(10, min(SAMPLES_PER_EXPERIMENT, MAX_SAMPLES // max(1, len(experiments))))
    picks, owners = [], []
    codes = frame["experiment"].to_numpy()
    for k in experiments:
        rows = np.flatnonzero(codes == k)
        if len(rows) < 3 * ACCEL_HALF_WIDTH:
            continue
        inner = rows[ACCEL_HALF_WIDTH:-ACCEL_HALF_WIDTH]
        chosen = inner[np.linspace(0, len(inner) - 1, min(per, len(inner))).astype(int)]
        picks.append(chosen)
        owners.append(np.full(len(chosen), k))
    if not picks:
        return out
    rows = np.concatenate(picks)
    owner = np.concatenate(owners)
    signal = {c: frame[c].to_numpy(dtype=float) for c in sensors.signals}
    time = frame["time"].to_numpy(dtype=float)
    names = ("boom", "dipper", "bucket")
    h = ACCEL_HALF_WIDTH
    span = time[rows + h] - time[rows - h]
    q = np.zeros((len(rows), 4))
    qd = np.zeros((len(rows), 4))
    qdd = np.zeros((len(rows), 4))
    for j, name in enumerate(names):
        q[:, j] = signal[f"{name}_angle"][rows]
        qd[:, j] = signal[f"{name}_rate"][rows]
        rate = signal[f"{name}_rate"]
        with np.errstate(all="ignore"):
            qdd[:, j] = (rate[rows + h] - rate[rows - h]) / span
    qd[:, 3] = signal["slew_rate"][rows]
    with np.errstate(all="ignore"):
        qdd[:, 3] = (signal["slew_rate"][rows + h] - signal["slew_rate"][rows - h]) / span
    # the house inclination at slew angle 0 is the ground's tilt in the house frame
    tilt = np.column_stack([signal["house_pitch"][rows], signal["house_roll"][rows]])
    head = np.column_stack([signal[f"{n}_head_pressure"][rows] for n in names])
    rod = np.column_stack([signal[f"{n}_rod_pressure"][rows] for n in names])
    usable = np.all(np.isfinite(np.hstack([q, qd, qdd, tilt, head, rod])), axis=1) & (span > 0)
    if not usable.any():
        return out
    rows, owner, q, qd, qdd, tilt, head, rod = (a[usable] for a in (rows, owner, q, qd, qdd, tilt, head, rod))
    arm = _model(machine)
    empty = arm.motion_signals(q, qd, qdd, tilt, 0.0)
    full = arm.motion_signals(q, qd, qdd, tilt, float(machine.max_payload))
    f0, f1 = empty["load"], full["load"]
    speed = np.abs(empty["speed"])
    cylinders = machine.cylinders
    head_area = np.array([c.head_area for c in cylinders])
    rod_area = np.array([c.rod_area for c in cylinders])
    measured = head * head_area - rod * rod_area
    largest = np.maximum(np.abs(f0), np.abs(f1))
    friction = np.array([[c.static_ratio * c.coulomb for c in cylinders]]) \
        + np.array([[c.static_ratio * c.load_coefficient for c in cylinders]]) * largest \
        + np.array([[c.viscous for c in cylinders]]) * speed
    # A swap flips the sign of a pushing cylinder's net force only once the head side's pressure
    # exceeds the back pressure × A_head / A_rod: the force at which that happens, with a margin
    # (a pulling one's flips as soon as its rod side carries the load).
    flips = np.where(f0 > 0, FLIP_MARGIN * machine.hydraulics.back_pressure * head_area**2 / rod_area, 0.0)
    definite = (np.sign(f0) == np.sign(f1)) & (np.minimum(np.abs(f0), np.abs(f1))
                                               > np.maximum.reduce([FORCE_MARGIN * largest, 2 * friction, flips]))
    records = []
    for k in pd.unique(owner):
        mine = owner == k
        for j, name in enumerate(names):
            judged = mine & definite[:, j]
            n = int(judged.sum())
            if n < MIN_JUDGED:
                continue
            agree = float(np.mean(np.sign(measured[judged, j]) == np.sign(f0[judged, j])))
            records.append((k, name, n, agree, bool(np.median(np.sign(f0[judged, j])) > 0)))
    return pd.DataFrame(records, columns=out.columns) if records else out
