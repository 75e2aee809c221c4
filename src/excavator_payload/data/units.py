"""Units judged per experiment and per signal, on datasets and on decoded CAN samples.

A file-wide check (a column's largest value over the whole file) lets one experiment in another
unit through among others in SI: one experiment's pressures logged in bar beside the rest in Pa
weighed −8960 kg ``ok``; one calibration experiment in bar calibrated without a word, then read
2822 kg for 1890. Here every experiment is judged on its own, and each signal against the same
signal in the other experiments:

* **pressures** (Pa): no cylinder line of a working arm stays below 1 bar in *every* line for a
  whole experiment (the boom cylinders hold the arm's weight, tens of bar); and a line whose peak
  in one experiment is below 1 bar and :data:`SCALE_RATIO_LIMIT` times below its peak in the
  other experiments is in another unit (bar 10⁵, kPa 10³, MPa 10⁶, psi 6895: the nearest is
  named);
* **torques** (N·m, the thesis set): an experiment's peak :data:`SCALE_RATIO_LIMIT` times below
  the other experiments' is in kN·m (the arm's own weight loads both joints in every pose, so the
  peaks of two experiments never differ that much).

:class:`SampleWatch` applies the same checks (and the rate-unit check,
:func:`check_signal_units`) to samples decoded from a CAN log after the signal map: a user
DBC whose pressures are in bar with factor 1 is refused as a dataset in bar is.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from excavator_payload.data.schema import SensorSet
from excavator_payload.errors import DatasetError

#: Below this peak (Pa, 1 bar) a pressure line is suspected of another unit.
MIN_PEAK_PRESSURE = 1.0e5
#: An experiment's peak of a signal this many times below the same signal's median peak over the
#: other experiments is in another unit (the smallest unit factor checked is kN·m's and kPa's 1000;
#: a real idle line at 0.5 bar beside 300 bar elsewhere is 600 times, so the 1-bar condition
#: guards pressures as well).
SCALE_RATIO_LIMIT = 300.0
#: Units a pressure column is found in, with their size in Pa.
PRESSURE_UNITS = (("bar", 1.0e5), ("kPa", 1.0e3), ("MPa", 1.0e6), ("psi", 6894.757))
#: Units a torque column is found in, with their size in N·m.
TORQUE_UNITS = (("kN·m", 1.0e3),)
#: A suspected unit is named when the ratio is within this factor of its size (else all are listed).
UNIT_NAMING_TOLERANCE = 4.0


def _unit_hint(ratio: float, units: tuple[tuple[str, float], ...], si: str) -> str:
    """``"in bar instead of Pa"``: the unit whose size is nearest ``ratio`` (log scale), or all."""
    name, size = min(units, key=lambda u: abs(math.log(ratio / u[1])))
    if abs(math.log(ratio / size)) < math.log(UNIT_NAMING_TOLERANCE) or len(units) == 1:
        return f"in {name} instead of {si}"
    return f"in {', '.join(u for u, _ in units)} instead of {si}"


def experiment_peaks(frame: pd.DataFrame, columns) -> pd.DataFrame:
    """Largest finite ``|value|`` of each column in each experiment (experiments in file order;
    NaN where an experiment has no finite value).

    Parameters
    ----------
    frame : pandas.DataFrame
        A sample table with an ``experiment`` column.
    columns : iterable of str
        The columns to take the peaks of.

    Returns
    -------
    pandas.DataFrame
        One row per experiment, one column per given column.
    """
    values = frame[list(columns)].abs()
    values = values.where(np.isfinite(values))
    experiments = frame["experiment"].to_numpy()
    if np.all(np.isfinite(experiments)) and np.all(experiments == np.round(experiments)):
        experiments = experiments.astype(np.int64)  # named in messages as 3, not 3.0
    return values.groupby(experiments, sort=False).max()


def check_experiment_units(frame: pd.DataFrame, sensors, source: str) -> None:
    """Refuse an experiment (or one signal of it) in another unit than the rest (see the module
    docstring). ``frame`` has ``experiment`` and the sensor set's signals.

    Parameters
    ----------
    frame : pandas.DataFrame
        The sample table.
    sensors : SensorSet
        Its sensor set; its pressure (Pa) and torque (N*m) signals are checked.
    source : str
        Where the data came from (a file name), the start of every error message.

    Raises
    ------
    DatasetError
        One line naming the experiment, the column and the unit it looks to be in.
    """
    columns = [c for c in sensors.signals if sensors.units[c] in ("Pa", "N*m") and c in frame.columns]
    if columns:
        check_peaks(experiment_peaks(frame, columns), sensors, source)


def check_peaks(peaks: pd.DataFrame, sensors, source: str) -> None:
    """:func:`check_experiment_units` on the per-experiment peaks (:func:`experiment_peaks`) of
    the pressure and torque columns.

    Parameters
    ----------
    peaks : pandas.DataFrame
        Per-experiment peak ``|value|`` of the columns, from :func:`experiment_peaks`.
    sensors : SensorSet
        The sensor set whose units name the pressure (Pa) and torque (N*m) columns.
    source : str
        Where the data came from (a file name), the start of every error message.
    """
    pressures = [c for c in peaks.columns if sensors.units.get(c) == "Pa"]
    torques = [c for c in peaks.columns if sensors.units.get(c) == "N*m"]
    if pressures:
        loudest = peaks[pressures].max(axis=1)
        quiet = loudest[loudest < MIN_PEAK_PRESSURE]
        others = loudest.drop(quiet.index).dropna()
        if len(quiet) and len(others):
            k, top = quiet.index[0], float(quiet.iloc[0])
            ratio = float(others.median()) / max(top, 1e-300)
            where = (f"{len(quiet)} of {len(loudest)} experiments, first experiment {k}"
                     if len(quiet) > 1 else f"experiment {k}")
            raise DatasetError(
                f"{source}: {where}: no pressure exceeds {top:.4g} Pa (1 bar = 1e5 Pa) while the "
                f"other experiments reach {float(others.median()):.4g} Pa; are its pressures "
                f"{_unit_hint(ratio, PRESSURE_UNITS, 'Pa')} (or all its pressure sensors unplugged)?")
        # every experiment quiet: the file-wide message of io.validate_frame says it
        _check_scale(peaks[pressures], "Pa", PRESSURE_UNITS, source, ceiling=MIN_PEAK_PRESSURE)
    if torques:
        _check_scale(peaks[torques], "N·m", TORQUE_UNITS, source, ceiling=math.inf)


def _check_scale(peaks: pd.DataFrame, si: str, units, source: str, ceiling: float) -> None:
    """A column whose peak in one experiment is below ``ceiling`` and far below its median peak
    over the other experiments."""
    if len(peaks) < 2:
        return
    for column in peaks.columns:
        series = peaks[column].dropna()
        if len(series) < 2:
            continue
        for k, peak in series.items():
            if not 0 < peak < ceiling:
                continue  # 0: a dead line (all zeros) is a sensor fault, not a unit
            rest = float(series.drop(k).median())
            ratio = rest / peak
            if ratio > SCALE_RATIO_LIMIT:
                raise DatasetError(
                    f"{source}: experiment {k}: column '{column}' peaks at {peak:.4g}, {ratio:.3g} times "
                    f"below its peak in the other experiments ({rest:.4g} {si}); is this experiment's "
                    f"'{column}' {_unit_hint(ratio, units, si)}?")


#: Largest house pitch or roll of a working machine, rad: 35° (70 %, the gradeability of a tracked
#: excavator, far beyond its working limits). Tighter than the sensor set's 1 rad (which also
#: spans the DBC's range): a tilt in degrees reads as that many radians.
HOUSE_TILT_LIMIT = math.radians(35.0)

#: Length of the windows the rate check compares over, s.
RATE_WINDOW = 0.5
#: Moving windows an experiment needs to be judged by the rate check.
RATE_MIN_WINDOWS = 2
#: A rate whose integral is more than this times its signal's change (median over the moving
#: windows) is in degrees: 180/π = 57.3 ≫ √57.3 ≈ 7.6 ≫ 1 (the geometric middle).
RATE_RATIO_LIMIT = math.sqrt(180.0 / math.pi)
#: A rate beyond that limit is called one in degrees when it is within this factor of 180/π
#: (else another joint's rate or another signal: two swapped rates read 14.3 and 0.06).
DEGREE_TOLERANCE = 2.0
#: A rate running against its angle is called one of the wrong sign within this factor of -1.
SIGN_TOLERANCE = 1.25


def check_signal_units(frame: pd.DataFrame, sensors: SensorSet, source: str, rates: bool = True) -> None:
    """The unit checks of :func:`validate_frame` on a sample table (``experiment``, ``time`` and
    the signals): magnitudes, house tilt and boom angle in radians, every experiment's pressures
    and torques against the others' (:func:`excavator_payload.data.units.check_experiment_units`),
    pressures in Pa, and (``rates``) rates against their angles. Also run on the samples decoded
    from a CAN log (:class:`SampleWatch`).

    Parameters
    ----------
    frame : pandas.DataFrame
        The sample table.
    sensors : SensorSet
        Its sensor set (units, plausible magnitudes, rate pairs).
    source : str
        Where the data came from (a file name), the start of every error message.
    rates : bool, default True
        Also check each rate against the change of its angle (degrees for radians).
    """
    for c in sensors.signals:
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = np.where(np.isfinite(values), values, np.nan)
        if np.any(values > sensors.plausible_abs[c]):
            top = int(np.nanargmax(values))
            unit = sensors.units[c]
            beyond = int(np.sum(values > sensors.plausible_abs[c]))
            # a pressure of 5e8 Pa was asked whether it was in degrees, and so was an angle of
            # 1e300 rad, which no angle in degrees reaches
            in_degrees = unit.startswith("rad") and values[top] <= 1.05 * math.degrees(sensors.plausible_abs[c])
            hint = ("are the units degrees instead of SI?" if in_degrees
                    else f"a glitch, or not in {unit}?")
            raise DatasetError(
                f"{source}: column '{c}' reaches {values[top]:.4g} (experiment "
                f"{frame['experiment'].iloc[top]:.0f}), implausible in {unit} ({hint}); {beyond} of "
                f"{len(values)} samples beyond the sensor set's ±{sensors.plausible_abs[c]:g} {unit}"
            )
    # A house tilt in degrees passes the 1 rad limit up to 1°: 0.8° read as 46° weighed ~200 kg off.
    for c in ("house_pitch", "house_roll"):
        if c not in sensors.signals:
            continue
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]
        if values.size and values.max() > HOUSE_TILT_LIMIT:
            raise DatasetError(f"{source}: column '{c}' reaches {values.max():.4g}, implausible in rad "
                               f"(more than 35° of tilt; are the units degrees instead of radians?)")
    # One experiment (or one signal of it) in another unit among others in SI passes the file-wide
    # checks (-8960 kg 'ok'): each experiment is judged against the others.
    check_experiment_units(frame, sensors, source)
    # Pressures in bar, kPa, MPa or psi pass the magnitude check above and were weighed as Pa
    # without a word (-6200 kg 'ok' for a 1900 kg payload): the boom cylinder of a working arm
    # holds the arm's weight, tens of bar, and no cylinder line stays below 1 bar for a whole file.
    for c in sensors.signals:
        if sensors.units[c] != "Pa":
            continue
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]
        if values.size and values.max() < MIN_PEAK_PRESSURE:
            raise DatasetError(f"{source}: column '{c}' never exceeds {values.max():.4g} Pa (1 bar = "
                               f"1e5 Pa); are the pressures in bar, kPa, MPa or psi instead of Pa?")
    # Angles in degrees are the most likely unit mistake: a boom never swings ±3 rad.
    for c in ("boom_angle",):
        values = np.abs(frame[c].to_numpy(dtype=float))
        values = values[np.isfinite(values)]  # a NaN or inf is a bad sample, not a unit
        if values.size and values.max() > 2 * np.pi:
            raise DatasetError(f"{source}: column '{c}' exceeds 2π; angles must be in radians")
    if rates:
        _check_rates(frame, sensors, source)


def window_ratios(time: np.ndarray, signal: np.ndarray, rate: np.ndarray, period: float,
                  min_change: float, by_rate: bool = False) -> np.ndarray:
    """How many times its signal's change a rate's integral is, per moving window of one run.

    The run is cut into windows of :data:`RATE_WINDOW` (the last one may be shorter); over a
    window where the signal changes by more than ``min_change`` (a moving one) and which has at
    least two samples, no NaN and no time gap, the ratio is (integral of the rate, trapezoidal)
    / (last - first value of the signal): 1 if both are in the same unit, whatever the noise,
    offsets or an IMU lag (both lag alike).

    Parameters
    ----------
    time, signal, rate : numpy.ndarray
        s, the signal and its rate, one value per sample of one run (an experiment, a window).
    period : float
        s, the sample period.
    min_change : float
        The signal's change over a window that makes it moving.
    by_rate : bool, default False
        Moving windows are those whose rate integrates to more than ``min_change``, and the
        ratio is the other way round (the signal's change / the rate's integral): an angle
        scaled far too small (:func:`shrunk_angle`) has no window where it changes enough.

    Returns
    -------
    numpy.ndarray
        The moving windows' ratios, in order.
    """
    width = max(2, int(round(RATE_WINDOW / period)))
    t, x, r = (np.asarray(a, dtype=float) for a in (time, signal, rate))
    n = len(t)
    if n < 2:
        return np.zeros(0)
    starts = np.arange(0, n, width)
    step = np.diff(t)
    with np.errstate(all="ignore"):
        increment = 0.5 * (r[1:] + r[:-1]) * step
        # a step belongs to the window of its later sample, never across a window's start
        inner = np.ones(n - 1, dtype=bool)
        inner[starts[1:] - 1] = False
        bad_step = inner & ((step > 2.5 * period) | ~np.isfinite(increment))
        bad_sample = ~np.isfinite(x) | ~np.isfinite(r)
        integral = np.add.reduceat(np.r_[0.0, np.where(inner & ~bad_step, increment, 0.0)], starts)
        bad = np.logical_or.reduceat(bad_sample, starts) | np.logical_or.reduceat(np.r_[False, bad_step], starts)
        ends = np.r_[starts[1:], n] - 1
        change = x[ends] - x[starts]
        if by_rate:
            moving = ~bad & (ends > starts) & (np.abs(integral) > min_change)
            return change[moving] / integral[moving]
        moving = ~bad & (ends > starts) & (np.abs(change) > min_change)
        return integral[moving] / change[moving]


#: An angle scaled to radians twice (a DBC already in rad given the degree factor π/180, or a
#: degree factor applied on top of the DBC's) changes π/180 times what its rate integrates to:
#: named when the median of that ratio over the rate's moving windows lies within this factor of
#: π/180 ...
SHRUNK_TOLERANCE = 2.0
#: ... and this share of those windows agrees in sign with it (a stuck angle's changes are noise
#: of either sign: a sensor fault, not a unit).
SHRUNK_AGREEMENT = 0.8


def shrunk_angle(time: np.ndarray, angle: np.ndarray, rate: np.ndarray, period: float, min_change: float,
                 plausible: float) -> float | None:
    """How many times too small an angle scaled from degrees to radians once too often is (≈ 57.3),
    or None when it is not.

    Such an angle never leaves ±``plausible`` × π/180 and barely changes, so the rate check's
    windows (where the angle moves) never judge it and the arm's balance blamed the cylinder
    lines instead ("dipper head and rod swapped?"). Judged where the *rate* says the joint moves
    (:func:`window_ratios` with ``by_rate``): there the angle changes π/180 times the rate's
    integral, consistently (:data:`SHRUNK_TOLERANCE`, :data:`SHRUNK_AGREEMENT`).

    Parameters
    ----------
    time, angle, rate : numpy.ndarray
        s, the angle (rad) and its rate (rad/s), one value per sample of one run.
    period : float
        s, the sample period.
    min_change : float
        rad, the rate's integral over a window that makes it moving.
    plausible : float
        rad, the largest magnitude the angle has (the sensor set's limit, 2π).

    Returns
    -------
    float or None
        The factor the angle is too small by, or None.
    """
    values = np.abs(np.asarray(angle, dtype=float))
    values = values[np.isfinite(values)]
    if not values.size or values.max() > 1.05 * plausible * math.pi / 180.0:
        return None
    ratios = window_ratios(time, angle, rate, period, min_change, by_rate=True)
    if len(ratios) < RATE_MIN_WINDOWS:
        return None
    middle = float(np.median(ratios))
    if middle == 0 or abs(math.log(abs(middle) / (math.pi / 180.0))) > math.log(SHRUNK_TOLERANCE):
        return None
    if np.mean(np.sign(ratios) == np.sign(middle)) < SHRUNK_AGREEMENT:
        return None
    return 1.0 / abs(middle)


def shrunk_message(column: str, rate: str, factor: float, peak: float) -> str:
    """``column 'dipper_angle' changes 57.3 times less than …``: the one line's words for
    :func:`shrunk_angle` (the factor to set is said by the caller, which knows the signal map).

    Parameters
    ----------
    column, rate : str
        The angle and its rate.
    factor : float
        How many times too small the angle is.
    peak : float
        rad, the angle's largest magnitude.
    """
    return (f"'{column}' changes {factor:.3g} times less than '{rate}' integrates to and never leaves "
            f"±{peak:.3g} rad: an angle in radians scaled by π/180 once more (a degree factor on a signal "
            f"already in rad)? Its values must be {180 / math.pi:.4g} times larger; the unit, not the wiring")


def _rate_ratios(frame: pd.DataFrame, signal: str, rate: str, period: float,
                 min_change: float) -> tuple[pd.Series, float]:
    """How many times its signal's change each rate's integral is, per experiment
    (:func:`window_ratios` of each experiment).

    Returns the median ratio of every experiment with :data:`RATE_MIN_WINDOWS` moving windows
    or more, and the median of all moving windows of the file (NaN if fewer): a still
    experiment cannot be judged and is not.
    """
    codes, ids = pd.factorize(frame["experiment"].to_numpy())
    order = np.argsort(codes, kind="stable")  # each experiment's samples together, in their order
    codes = codes[order]
    t = frame["time"].to_numpy(dtype=float)[order]
    x = frame[signal].to_numpy(dtype=float)[order]
    r = frame[rate].to_numpy(dtype=float)[order]
    bounds = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1], True])
    judged, every = {}, []
    for a, b in zip(bounds[:-1], bounds[1:]):
        ratios = window_ratios(t[a:b], x[a:b], r[a:b], period, min_change)
        every.append(ratios)
        if len(ratios) >= RATE_MIN_WINDOWS:
            experiment = ids[codes[a]]
            judged[experiment] = float(np.median(ratios))
    every = np.concatenate(every) if every else np.zeros(0)
    pooled = float(np.median(every)) if every.size >= RATE_MIN_WINDOWS else math.nan
    return pd.Series(judged, dtype=float), pooled


def _check_rates(frame: pd.DataFrame, sensors: SensorSet, source: str) -> None:
    """Refuse a rate in degrees (°/s, °/s²) whose signal is in radians.

    Rates in °/s pass every magnitude check (an arm turns at < 3 rad/s, 170 °/s) and were
    weighed as rad/s without a word (-3700 kg 'ok' for a 1890 kg payload).
    """
    for signal, rate, unit, min_change in sensors.rate_pairs:
        if sensors.units[signal] == "rad":  # an angle (the thesis set also pairs rates with accelerations)
            _check_shrunk(frame, sensors, signal, rate, min_change, source)
        judged, pooled = _rate_ratios(frame, signal, rate, sensors.sample_period, min_change)
        worst = judged[judged.abs() > RATE_RATIO_LIMIT]
        where = f" (experiment {worst.index[0]})" if len(worst) else ""
        ratio = float(worst.iloc[0]) if len(worst) else pooled
        if np.isfinite(ratio) and abs(ratio) > RATE_RATIO_LIMIT:
            degrees = unit.replace("rad", "°")
            if abs(math.log(abs(ratio) / math.degrees(1.0))) <= math.log(DEGREE_TOLERANCE):
                guess = f"is it in {degrees} instead of {unit}?" + (" (and of the wrong sign)" if ratio < 0 else "")
            else:  # two joints' rates swapped read 14.3 and 0.06: "in °/s?" sent the user to the units
                guess = (f"not {180 / math.pi:.3g} times, as a rate in {degrees} would be: is it another "
                         f"joint's rate (two rates swapped in the wiring or the signal map) or another signal?")
            raise DatasetError(f"{source}: column '{rate}' is {ratio:.3g} times the rate of change of "
                               f"'{signal}'{where}; {guess}")
        # A rate of the wrong sign (a sensor mounted the other way round, a negative factor or a
        # signed/unsigned slip in a DBC) passed: the health monitor then held every estimate as a
        # sensor fault (boom) or weighed on without the rate, and nothing said why. So did two
        # swapped rates whose ratios stayed below the degree limit. Valid data: every experiment's
        # ratio 0.93-1.08; a ratio near 0 is a dead rate sensor, the health monitor's to name.
        backwards = judged[(judged < -1.0 / RATE_RATIO_LIMIT) & (judged > -RATE_RATIO_LIMIT)]
        if len(backwards) and len(backwards) >= 0.5 * len(judged):
            first = float(backwards.iloc[0])
            flip = abs(math.log(-first)) <= math.log(SIGN_TOLERANCE)
            guess = ("a rate of the wrong sign (the sensor mounted the other way round, or a negative factor or a "
                     "signed/unsigned slip in the DBC or signal map)? Flip its sign" if flip else
                     "another joint's rate (two rates swapped in the wiring or the signal map), or one of the "
                     "wrong sign?")
            raise DatasetError(f"{source}: column '{rate}' runs against '{signal}': its integral is {first:.3g} "
                               f"times the angle's change (experiment {backwards.index[0]}; {len(backwards)} of "
                               f"{len(judged)} experiments judged); {guess}")


def _check_shrunk(frame: pd.DataFrame, sensors: SensorSet, signal: str, rate: str, min_change: float,
                  source: str) -> None:
    """Refuse an experiment whose angle is scaled to radians twice (:func:`shrunk_angle`), before
    the rate check blames its rate and the wiring check its cylinder lines."""
    codes, ids = pd.factorize(frame["experiment"].to_numpy())
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    t = frame["time"].to_numpy(dtype=float)[order]
    x = frame[signal].to_numpy(dtype=float)[order]
    r = frame[rate].to_numpy(dtype=float)[order]
    bounds = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1], True])
    for a, b in zip(bounds[:-1], bounds[1:]):
        factor = shrunk_angle(t[a:b], x[a:b], r[a:b], sensors.sample_period, min_change,
                              sensors.plausible_abs[signal])
        if factor is not None:
            peak = float(np.nanmax(np.abs(x[a:b])))
            raise DatasetError(f"{source}: experiment {ids[codes[a]]}: column "
                               + shrunk_message(signal, rate, factor, peak))


#: Known loads whose largest is below this share of the machine's rated payload are taken for
#: tonnes (a 5 t rated machine's calibration read 0.4–3.1 as kg: refused for its model error,
#: "add calibration motions", not for its unit).
MIN_PAYLOAD_SHARE = 0.005
#: Known loads above this many times the machine's largest payload cannot have been lifted.
MAX_PAYLOAD_FACTOR = 2.0


def check_payload_unit(payload: np.ndarray, machine, source: str) -> None:
    """Refuse known loads that cannot be in kg for ``machine``: all of them below
    :data:`MIN_PAYLOAD_SHARE` of its rated payload (tonnes?) or any above
    :data:`MAX_PAYLOAD_FACTOR` times its largest (pounds, grams?). Without a machine (or without a
    nonzero load) nothing is judged.

    Parameters
    ----------
    payload : ndarray
        The known loads, kg (the ``payload`` column).
    machine : Machine or None
        The machine the data are of or fitted to (``rated_payload``, ``max_payload``).
    source : str
        What the data are, for the message.
    """
    rated = float(getattr(machine, "rated_payload", 0.0) or 0.0)
    largest = float(getattr(machine, "max_payload", 0.0) or 0.0) or rated
    payload = np.asarray(payload, float)
    if not (rated > 0 and payload.size and np.all(np.isfinite(payload))):
        return
    top = float(np.max(payload))
    if 0.0 < top < MIN_PAYLOAD_SHARE * rated:
        raise DatasetError(f"{source}: the known loads reach only {top:.4g} kg, {100 * top / rated:.2g} % of the "
                           f"machine's rated payload ({rated:g} kg): is column 'payload' in tonnes? (kg expected)")
    if top > MAX_PAYLOAD_FACTOR * largest:
        raise DatasetError(f"{source}: the known loads reach {top:.4g} kg, {top / largest:.3g} times the most the "
                           f"machine lifts ({largest:g} kg): is column 'payload' in pounds or grams? (kg expected)")
