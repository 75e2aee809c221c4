"""Units of a CAN log's or a live bus's decoded signals (issue 30): a user's DBC in bar, degrees
or °/s mapped with factor 1 is refused with one line naming the signal and the likely unit
(log), or flags the live loadout (no ``ok`` estimate or pass while it lasts); a correct log
weighs as before."""

import logging
import math
import re
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.schema import get_sensor_set
from excavator_payload.estimators.base import load_estimator
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.runtime.loadout_bus import GUARDED, BusLoadout, replay_loadout
from excavator_payload.runtime.loadout_guard import UnitGuard
from excavator_payload.runtime.logs import read_frames

sys.path.insert(0, str(Path(__file__).parent))
from field_bus import field_shift_log, rescaled_dbc, write_field_files  # noqa: E402


@pytest.fixture(scope="module")
def shift(tmp_path_factory):
    """A calibrated model (4 swings), one truck of a shift as a BLF log in the field layout (the
    arm at 100 Hz, the inclinometer at 10 Hz, another ECU's traffic), its DBC and map."""
    from excavator_payload.estimators.base import create_estimator
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    folder = tmp_path_factory.mktemp("guard")
    calibration = simulate_machine_dataset(4, seed=4, session=1)
    create_estimator("calibrated", machine="cat345c-hydraulic-3pct").fit(calibration).save(folder / "model")
    truck = simulate_machine_dataset(1, seed=3, session=1, motion="shift", truck_target=8000.0)
    dbc_path, map_path = write_field_files(folder)
    field_shift_log(truck, folder / "truck.blf", dbc_path, map_path, jitter=0.001, press=False)
    return folder, truck, dbc_path, map_path


def _dbc(shift, tmp_path, changes):
    path = tmp_path / "mine.dbc"
    path.write_text(rescaled_dbc(shift[2].read_text(), changes))
    return path


def _loadout(args, shift, tmp_path, capsys, dbc_path):
    folder, _, _, map_path = shift
    code = main(["loadout", "--model", str(folder / "model"), "--log", str(folder / "truck.blf"), "--dbc",
                 str(dbc_path), "--signal-map", str(map_path), "--db", str(tmp_path / "shift.sqlite"), *args])
    return code, capsys.readouterr()


@pytest.mark.parametrize("changes, words", [
    # one pressure in bar and one angle in degrees: both named in the one line, with the factor
    ({"BoomHeadPressure": (1e-5, "bar"), "BucketAngle": (180 / math.pi, "deg")},
     ["boom_head_pressure (DBC Arm4.BoomHeadPressure in \"bar\", factor 1)", "in bar instead of Pa",
      "set factor = 100000 in [signals.boom_head_pressure]",
      "bucket_angle (DBC Arm2.BucketAngle in \"deg\", factor 1)", "in ° instead of rad",
      "set factor = 0.01745329252 in [signals.bucket_angle]"]),
    # a rate in °/s passes every magnitude check (an arm turns at < 3 rad/s, 170 °/s)
    ({"BoomRate": (180 / math.pi, "deg/s")}, ["boom_rate", "in °/s instead of rad/s"]),
    # a DBC that names no unit: the units that put the peak within the machine's pressures
    ({"DipperRodPressure": (1e-5, "")}, ["dipper_rod_pressure", "in bar or MPa instead of Pa"]),
])
def test_a_dbc_in_another_unit_is_one_line_before_anything_is_recorded(shift, tmp_path, capsys, changes, words):
    code, out = _loadout(["--target", "8000"], shift, tmp_path, capsys, _dbc(shift, tmp_path, changes))
    err = out.err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert all(w in err for w in words), err
    assert "Traceback" not in err and "swapped" not in err  # the units, not a wiring, are blamed
    assert not (tmp_path / "shift.sqlite").exists()


def test_a_correct_log_weighs_the_same_passes_with_the_guard(shift, tmp_path, capsys):
    """The command (guard on) against the same log through the API without a guard: the same
    passes, weights to the gram; the guard judged every 5 s and found nothing."""
    folder, trucks, dbc_path, map_path = shift
    code, out = _loadout(["--target", "8000"], shift, tmp_path, capsys, dbc_path)
    assert code == 0, out.err
    assert "units judged on" in out.out
    with sqlite3.connect(tmp_path / "shift.sqlite") as con:
        got = con.execute("SELECT pass, weight, status FROM passes ORDER BY pass").fetchall()
    estimator = load_estimator(folder / "model")
    codec = SignalCodec.from_files(estimator.sensor_set, dbc_path, map_path)
    plain = BusLoadout(PayloadSensor(estimator, codec), target=8000.0)
    (truck,) = replay_loadout(folder / "truck.blf", plain)
    assert [(p.index, p.weight, p.status) for p in truck.passes] == got
    assert len(got) == len(trucks.experiment_meta[0]["passes"]) and all(s == "ok" for *_, s in got)
    judged = re.search(r"units judged on (\d+) windows", " ".join(out.out.split()))
    assert judged and int(judged.group(1)) >= 10  # every 5 s of the 56 s truck


def _live_statuses(shift, dbc_path, guarded):
    """The truck's first 20 s (its first pass) decoded through ``dbc_path`` as on a live bus
    (``send``): the loadout, the statuses of the PayloadEstimate frames sent, the live view."""
    from rich.console import Console

    from excavator_payload.runtime.loadout_live import live_view

    folder, _, _, map_path = shift
    estimator = load_estimator(folder / "model")
    codec = SignalCodec.from_files(estimator.sensor_set, dbc_path, map_path)
    sensor = PayloadSensor(estimator, codec)
    guard = UnitGuard(estimator.sensor_set, codec, estimator.machine) if guarded else None
    loadout = BusLoadout(sensor, target=8000.0, send=True, guard=guard)
    loadout.guard_source = "bus virtual:test"
    statuses = []
    for frame in read_frames(folder / "truck.blf"):
        if frame.timestamp > 20.0:
            break
        for sent in loadout.feed(frame, frame.timestamp):
            decoded = sensor.encoder.decode(sent)
            if decoded is not None:
                statuses.append((sent.timestamp, decoded[1]))
    console = Console(width=300, record=True)
    console.print(live_view(loadout, "t: next truck"))
    loadout.finish()
    return loadout, statuses, console.export_text()


def test_a_live_bus_in_kpa_sends_no_ok_weight_and_warns_once(shift, tmp_path, caplog):
    """A bucket rod line in kPa (mapped with factor 1): without the guard it is weighed ``ok``
    (up to 3.7 t off on the data the guard was written on) or blamed on a sensor (the health
    monitor's ``sensor_fault``), never on its unit. With it, as on a live bus: one warning naming
    the signal, no PayloadEstimate ``ok`` after the first window, the pass not weighed with the
    finding as its reason, the live view says it in red (and shows the operator's keys)."""
    bad = _dbc(shift, tmp_path, {"BucketRodPressure": (1e-3, "kPa")})
    _, unguarded, _ = _live_statuses(shift, bad, guarded=False)
    with caplog.at_level(logging.WARNING, logger="excavator_payload.runtime.loadout_bus"):
        loadout, statuses, view = _live_statuses(shift, bad, guarded=True)
    guard = loadout.guard
    warnings = [r.getMessage() for r in caplog.records if "bucket_rod_pressure" in r.getMessage()]
    assert len(warnings) == 1 and "in kPa instead of Pa" in warnings[0] and "no pass is weighed" in warnings[0]
    first_flag = guard.since + guard.size * loadout.sensor.sensor_set.sample_period
    unguarded_after = [s for t, s in unguarded if t >= first_flag - 1e-9]
    # the mistake the guard names: weighed as if right, or blamed on a sensor
    assert "ok" in unguarded_after or "sensor_fault" in unguarded_after
    after = [s for t, s in statuses if t >= first_flag - 1e-9]
    # what would have gone out ok goes out as the guard's status; a sensor fault stays one
    assert after and "ok" not in after
    assert GUARDED in after or "ok" not in unguarded_after
    assert "NOT WEIGHING: bus virtual:test: bucket_rod_pressure" in view and "t: next truck" in view
    passes = loadout.trucks[0].passes
    assert passes and all(p.status == "not_weighed" and p.weight is None
                          and p.reason == "signal units: bucket_rod_pressure in kPa?" for p in passes)


def _window(seconds=5.0, rate=100.0, moving=True, pressure=2.0e6):
    """A guard window of the machine set: the boom swinging 0.3 rad (or still), pressures flat."""
    sensors = get_sensor_set("machine")
    t = np.arange(int(seconds * rate)) / rate
    values = np.zeros((len(t), len(sensors.signals)))
    index = {c: i for i, c in enumerate(sensors.signals)}
    amplitude = 0.15 if moving else 0.0
    values[:, index["boom_angle"]] = 0.5 + amplitude * np.sin(t)
    values[:, index["boom_rate"]] = amplitude * np.cos(t)
    for c in sensors.signals:
        if sensors.units[c] == "Pa":
            values[:, index[c]] = pressure
    return sensors, t, values


@pytest.mark.parametrize("moving, pressure, flagged", [
    (True, 2.0e6, False),   # a working arm in Pa
    (True, 20.0, True),     # ... in bar
    (False, 0.3, False),    # the engine off, the arm still: pressures near 0 are no unit
    (True, 0.0, False),     # every line dead (0): a sensor fault (DM1), not a unit
])
def test_the_guard_blames_only_what_it_has_seen(moving, pressure, flagged):
    sensors, t, values = _window(moving=moving, pressure=pressure)
    guard = UnitGuard(sensors)
    judged = [guard.add(ti, v) for ti, v in zip(t, values)]
    assert sum(judged) == 1 and guard.flagged == flagged, guard.findings
    if flagged:
        assert guard.message("log").startswith("log: boom_head_pressure peaks at 20 Pa while the arm works")


def test_an_idle_window_does_not_clear_a_pressure_finding():
    """Live: the flag raised on a working arm stays through a still one (which cannot show the
    pressures' unit) and clears on the next working window in Pa."""
    sensors, t, bar = _window(pressure=20.0)
    _, _, still = _window(moving=False, pressure=20.0)
    _, _, right = _window(pressure=2.0e6)
    guard = UnitGuard(sensors)
    seen = []
    for block, offset in ((bar, 0.0), (still, 5.0), (right, 10.0)):
        for ti, v in zip(t + offset, block):
            if guard.add(ti, v):
                seen.append(guard.flagged)
    assert seen == [True, True, False] and guard.since is None



@pytest.mark.parametrize("unit", [1.0, 180 / math.pi])
def test_the_window_rate_ratio_is_the_dataset_checks(unit):
    """The guard's numpy rate ratio gives the dataset check's (units._rate_ratios) on a window
    with noise, a NaN and a still stretch; a rate in °/s reads 57.3."""
    import pandas as pd

    from excavator_payload.data.units import _rate_ratios
    from excavator_payload.runtime.loadout_guard import rate_ratio

    rng = np.random.default_rng(1)
    t = np.arange(500) * 0.01
    angle = 0.4 * np.sin(1.3 * t) * (t > 1.0) + rng.normal(0, 1e-3, t.size)
    rate = unit * np.gradient(0.4 * np.sin(1.3 * t) * (t > 1.0), t) + rng.normal(0, 5e-3, t.size)
    angle[321] = np.nan
    frame = pd.DataFrame({"experiment": 0, "time": t, "a": angle, "r": rate})
    want = _rate_ratios(frame, "a", "r", 0.01, 0.02)[1]
    got = rate_ratio(t, angle, rate, 0.01, 0.02)
    assert got == pytest.approx(want, rel=1e-12) and got == pytest.approx(unit, rel=0.1)


def test_a_log_cut_short_is_weighed_to_the_cut_with_one_warning(shift, tmp_path, capsys):
    """The truck's BLF cut at 60 % (its last container incomplete): the passes before the cut are
    weighed and recorded, and one line on stderr says the log ends early (it was weighed as if
    whole, without a word); the whole log says nothing."""
    folder, _, dbc_path, map_path = shift
    cut = tmp_path / "cut.blf"
    raw = (folder / "truck.blf").read_bytes()
    cut.write_bytes(raw[:int(0.6 * len(raw))])
    code = main(["loadout", "--model", str(folder / "model"), "--log", str(cut), "--dbc", str(dbc_path),
                 "--signal-map", str(map_path), "--db", str(tmp_path / "cut.sqlite"), "--target", "8000"])
    out = capsys.readouterr()
    # the fixture's model is not zeroed, which is said too
    lines = [line for line in out.err.splitlines() if line.strip() and "never zeroed" not in line]
    assert code == 0 and len(lines) == 1, out.err
    assert lines[0].startswith("warning: CAN log") and "ends early" in lines[0] and "last truck may be partial" in lines[0]
    with sqlite3.connect(tmp_path / "cut.sqlite") as con:
        assert con.execute("SELECT COUNT(*) FROM passes WHERE status = 'ok'").fetchone()[0] >= 1
    code, whole = _loadout(["--target", "8000"], shift, tmp_path, capsys, dbc_path)
    assert code == 0 and "ends early" not in whole.err


@pytest.mark.parametrize("signal, name", [("BoomAngle", "boom_angle"), ("DipperAngle", "dipper_angle"),
                                          ("BucketAngle", "bucket_angle")])
def test_an_angle_scaled_to_radians_twice_is_named_as_a_unit_not_as_the_wiring(shift, tmp_path, capsys, signal,
                                                                                name):
    """A DBC already in rad whose angle got the degree factor too (57 times too small): the dipper's
    was blamed on its swapped head and rod lines (loadout and can-replay), the boom's and bucket's
    weighed nothing (`not_weighed`, exit 0) or blamed the bucket's lines. Now each is one line
    naming the angle as a unit mistake, before the wiring check; loadout says the factor to set."""
    folder, _, _, map_path = shift
    dbc_path = _dbc(shift, tmp_path, {signal: (math.pi / 180, "rad")})
    code, out = _loadout(["--target", "8000"], shift, tmp_path, capsys, dbc_path)
    err = out.err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert name in err and "π/180" in err and f"set factor = 57.29577951 in [signals.{name}]" in err, err
    assert "swapped" not in err and not (tmp_path / "shift.sqlite").exists()
    code = main(["can-replay", "--model", str(folder / "model"), "--log", str(folder / "truck.blf"), "--dbc",
                 str(dbc_path), "--signal-map", str(map_path), "--out", str(tmp_path / "e.parquet")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"'{name}'" in err and "π/180" in err and "swapped" not in err, err
