"""Hostile inputs as files: datasets (the thesis set's and the machine set's unit mistakes),
trajectory files, model folders, machine files (the thesis arm's and the hydraulic machine's)."""

from __future__ import annotations

import json
import math
import os
import shutil
from typing import Callable

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from excavator_payload.model.machine import load_machine

from .harness import Case, _edit, _frame, _meta, _raw, _write, _write_frame


def _truncated(work, inputs):
    raw = (inputs / "data.parquet").read_bytes()
    return _write(work / "bad.parquet", raw[: len(raw) // 2])


def _flipped(work, inputs):
    raw = bytearray((inputs / "data.parquet").read_bytes())
    for k in range(len(raw) // 3, len(raw) // 3 + 64):
        raw[k] ^= 0xFF
    return _write(work / "bad.parquet", bytes(raw))


def _unsorted_experiments(frame):
    # Valid column by column, but experiment 1's rows are split by experiment 2's.
    a = frame[frame["experiment"] == frame["experiment"].unique()[1]]
    b = frame[frame["experiment"] == frame["experiment"].unique()[2]]
    rest = frame[~frame.index.isin(a.index) & ~frame.index.isin(b.index)]
    return pd.concat([rest, a.iloc[:50], b, a.iloc[50:]])


def _degrees(frame):
    for c in ("boom_angle", "dipper_angle"):
        frame[c] = np.degrees(frame[c])
    return frame


def _set(column, value, rows=slice(None)):
    def fn(frame):
        frame = frame.copy()
        if column in frame:
            frame[column] = frame[column].astype(object if isinstance(value, str) else float)
        frame.loc[frame.index[rows], column] = value
        return frame
    return fn


BAD_DATASETS: dict[str, tuple[Callable, str | None]] = {
    "missing-file": (lambda work, inputs: work / "nope.parquet", "does not exist"),
    "empty-file": (_raw(b""), None),
    "random-bytes": (_raw(os.urandom(3000)), None),
    "csv-renamed": (_raw("experiment,time\n0,0.0\n"), None),
    "truncated": (_truncated, None),
    "byte-flipped": (_flipped, None),
    "folder": (lambda work, inputs: (work / "adir.parquet").mkdir() or work / "adir.parquet", "folder"),
    "estimates-file": (lambda work, inputs: inputs / "estimates.parquet", "estimates"),
    "degrees": (_edit(_degrees), "degrees"),
    "nan-time": (_edit(_set("time", math.nan, slice(3, 4))), "time"),
    "time-backwards": (_edit(lambda f: f.assign(time=f["time"].to_numpy()[::-1])), "time"),
    "ungrouped": (_edit(_unsorted_experiments), "grouped"),
    "negative-payload": (_edit(_set("payload", -5.0)), "payload"),
    "huge-payload": (_edit(_set("payload", 1e300)), "payload"),
    "payload-varies": (_edit(_set("payload", 17.0, slice(5, 6))), "payload"),
    "text-column": (_edit(_set("boom_torque", "12,5")), "boom_torque"),
    "missing-column": (_edit(lambda f: f.drop(columns=["dipper_torque"])), "dipper_torque"),
    "no-rows": (_edit(lambda f: f.iloc[:0]), None),
    "torque-1e400": (_edit(_set("boom_torque", math.inf, slice(10, 11))), None),
    "implausible-torque": (_edit(_set("boom_torque", 5e9, slice(10, 11))), "boom_torque"),
    "time-in-ms": (_edit(lambda f: f.assign(time=f["time"] * 1000.0)), "seconds"),
    "sampled-at-100hz": (_edit(lambda f: f.assign(time=f["time"] / 5.0)), "Hz"),
    "fractional-experiment": (_edit(lambda f: f.assign(experiment=f["experiment"] + 0.5)), "experiment"),
    "bad-metadata-json": (lambda work, inputs: _write_frame(work / "bad.parquet", _frame(inputs), b"{not json"),
                          "JSON"),
    # an edited metadata: train and evaluate crashed (AttributeError, TypeError)
    "metadata-machine-text": (lambda work, inputs: _write_frame(work / "bad.parquet", _frame(inputs), json.dumps(
        {**json.loads(_meta(inputs)), "machine": "cat345c"}).encode()), "metadata 'machine'"),
    "metadata-experiments-text": (lambda work, inputs: _write_frame(work / "bad.parquet", _frame(inputs), json.dumps(
        {**json.loads(_meta(inputs)), "experiments": "all"}).encode()), "metadata 'experiments'"),
    # the machine of the metadata, broken: "machine: field 'boom_mass' ..." did not name the file
    "metadata-machine-broken": (lambda work, inputs: _write_frame(work / "bad.parquet", _frame(inputs), json.dumps(
        {**json.loads(_meta(inputs)), "machine": {**json.loads(_meta(inputs))["machine"], "boom_mass": -1.0}}
    ).encode()), "bad.parquet: the machine in its metadata"),
    "unknown-sensor-set": (lambda work, inputs: _write_frame(
        work / "bad.parquet", _frame(inputs), json.dumps({"sensor_set": "sonar"}).encode()), "sensor set"),
}


def dataset_cases() -> list[Case]:
    cases = []
    commands = {
        "estimate": ["estimate", "--model", "{in}/model", "--data", "{bad}", "--out", "{work}/e.parquet"],
        "train-id": ["train", "inverse-dynamics", "--data", "{bad}", "--out", "{work}/m"],
        "train-net1": ["train", "net1", "--data", "{bad}", "--out", "{work}/m", "--epochs", "1",
                       "--train-experiments", "2", "--progress", "false"],
        "evaluate": ["evaluate", "--data", "{bad}", "--model", "{in}/model", "--json", "{work}/e.json"],
        "report": ["report", "--data", "{bad}", "--model", "{in}/model", "--out", "{work}/r"],
        "export-mat": ["export-mat", "--data", "{bad}", "--out", "{work}/d.mat"],
    }
    outputs = {"estimate": ["{work}/e.parquet"], "train-id": ["{work}/m/estimator.json"],
               "train-net1": ["{work}/m/estimator.json"], "evaluate": ["{work}/e.json"],
               "report": ["{work}/r/report.html"], "export-mat": ["{work}/d.mat"]}
    for bad, (setup, message) in BAD_DATASETS.items():
        for command, argv in commands.items():
            expect = "error"
            check = None
            if bad == "torque-1e400" and command in ("estimate", "evaluate", "export-mat", "train-id"):
                # One unreadable sample is data, not a broken file: estimated around, reported.
                expect = "ok"
                check = _check_invalid_reported if command == "estimate" else None
            if bad == "torque-1e400" and command == "report":
                continue  # covered by evaluate; a report takes seconds
            if bad == "metadata-machine-broken" and command in ("estimate", "train-net1", "export-mat"):
                continue  # they do not read the data's machine
            cases.append(Case(f"data-{bad}-{command}", "bad dataset", argv, expect,
                              message if expect == "error" else None,
                              setup, check, outputs[command] if expect == "error" else []))
    return cases


# -- machine-set datasets: unit mistakes that pass every magnitude check
def _machine_edit(fn):
    """A machine-set dataset maker: ``fn(frame) -> frame`` applied to the good machine dataset."""
    def make(work, inputs):
        return _write_frame(work / "bad.parquet", fn(_frame(inputs, "machine.parquet").copy()),
                            _meta(inputs, "machine.parquet"))
    return make


def _to_degrees(*columns):
    def fn(frame):
        for c in columns:
            frame[c] = np.degrees(frame[c])
        return frame
    return fn


def _to_radians(*columns):
    def fn(frame):
        for c in columns:
            frame[c] = np.radians(frame[c])
        return frame
    return fn


BAD_MACHINE_DATASETS: dict[str, tuple[Callable, str | None]] = {
    # °/s pass the 50 rad/s limit and were weighed as rad/s: -3700 kg 'ok' for 1890 kg.
    "rates-in-degrees": (_machine_edit(_to_degrees("boom_rate", "dipper_rate", "slew_rate")),
                         "°/s instead of rad/s"),
    "boom-rate-in-degrees": (_machine_edit(_to_degrees("boom_rate")), "'boom_rate'"),
    "dipper-rate-in-degrees": (_machine_edit(_to_degrees("dipper_rate")), "'dipper_rate'"),
    # A machine on a slope of several degrees: its tilt in degrees is no tilt in radians.
    "house-tilt-in-degrees": (_machine_edit(_to_degrees("house_pitch", "house_roll")), "house_"),
    # An angle scaled to radians twice (57 times too small): blamed on the dipper's swapped lines,
    # or weighed nothing without a word; each angle named as a unit, never as the wiring.
    **{f"{joint}-angle-scaled-to-radians-twice": (_machine_edit(_to_radians(f"{joint}_angle")),
                                                  f"'{joint}_angle'")
       for joint in ("boom", "dipper", "bucket")},
}


def machine_dataset_cases() -> list[Case]:
    cases = []
    commands = {
        "estimate": ["estimate", "--model", "{in}/model", "--data", "{bad}", "--out", "{work}/e.parquet"],
        "export-mat": ["export-mat", "--data", "{bad}", "--out", "{work}/d.mat"],
    }
    outputs = {"estimate": ["{work}/e.parquet"], "export-mat": ["{work}/d.mat"]}
    for bad, (setup, message) in BAD_MACHINE_DATASETS.items():
        for command, argv in commands.items():
            cases.append(Case(f"machine-{bad}-{command}", "bad machine dataset", argv, "error", message,
                              setup, None, outputs[command]))
    return cases


# -- trajectory files (simulate --trajectory): motions from the outside world
def _trajectory_edit(fn, name="bad.parquet"):
    def make(work, inputs):
        frame = fn(_frame(inputs, "trajectory.parquet").copy())
        if name.endswith(".csv"):
            return _write(work / name, frame.to_csv(index=False))
        return _write_frame(work / name, frame)
    return make


def _column(column, fn):
    def edit(frame):
        frame[column] = fn(frame[column]) if callable(fn) else fn
        return frame
    return edit


def _nan_at(column, row):
    def edit(frame):
        frame[column] = frame[column].astype(float)
        frame.loc[frame.index[row], column] = math.nan
        return frame
    return edit


BAD_TRAJECTORIES: dict[str, tuple[Callable, str | None]] = {
    "csv": (_trajectory_edit(lambda f: f, "t.csv"), "must be a Parquet file"),
    "empty-file": (_raw(b""), "it is empty"),
    "folder": (lambda work, inputs: (work / "t.parquet").mkdir() or work / "t.parquet", "is a folder"),
    "missing": (lambda work, inputs: work / "nope.parquet", "does not exist"),
    "degrees": (_trajectory_edit(lambda f: f.assign(**{c: np.degrees(f[c]) for c in
                                                    ("boom_angle", "dipper_angle", "bucket_angle")})), "radians"),
    "slew-in-degrees": (_trajectory_edit(_column("slew_angle", np.degrees)), "times faster"),
    "nan-row": (_trajectory_edit(_nan_at("boom_angle", 5)), "NaN"),
    "unsorted-time": (_trajectory_edit(lambda f: f.sample(frac=1.0, random_state=0)), "increase"),
    "duplicated-time": (_trajectory_edit(lambda f: pd.concat([f.iloc[:10], f.iloc[9:]])), "increase"),
    "one-row": (_trajectory_edit(lambda f: f.iloc[:1]), "at least 4"),
    "two-rows": (_trajectory_edit(lambda f: f.iloc[:2]), "at least 4"),
    "no-rows": (_trajectory_edit(lambda f: f.iloc[:0]), "no rows"),
    "huge-angle": (_trajectory_edit(_column("dipper_angle", 1e6)), "2π"),
    "boom-out-of-range": (_trajectory_edit(_column("boom_angle", lambda a: a + 1.5)), "outside the machine's range"),
    "dipper-out-of-range": (_trajectory_edit(_column("dipper_angle", lambda a: -a)), "outside the machine's range"),
    "negative-payload": (_trajectory_edit(_column("payload", -100.0)), "negative"),
    "nan-payload": (_trajectory_edit(_nan_at("payload", 3)), "payload"),
    "huge-payload": (_trajectory_edit(_column("payload", 1e7)), "payload"),
    "no-slew-angle": (_trajectory_edit(lambda f: f.drop(columns=["slew_angle"])), "slew_angle"),
    "text-column": (_trajectory_edit(_column("boom_angle", lambda a: a.astype(str))), "numeric"),
    "fractional-experiment": (_trajectory_edit(_column("experiment", lambda e: e + 0.5)), "whole numbers"),
    "time-in-ms": (_trajectory_edit(_column("time", lambda t: t * 1000.0)), "seconds"),
    "hour-gap": (_trajectory_edit(lambda f: f.assign(time=f["time"] + 3600.0 * (f.index >= 20))),
                 "split it into two experiments"),
    "ground-in-degrees": (_trajectory_edit(lambda f: f.assign(ground_pitch=5.0)), "ground_pitch"),
}


def trajectory_cases() -> list[Case]:
    argv = ["simulate", "--machine", "cat345c-hydraulic", "--trajectory", "{bad}", "--out", "{work}/s.parquet",
            "--workers", "1", "--quiet"]
    cases = [Case(f"trajectory-{bad}", "trajectory file", argv, "error", message, setup, None,
                  ["{work}/s.parquet"]) for bad, (setup, message) in BAD_TRAJECTORIES.items()]

    def replayed(work, inputs, out, err):
        frame = pq.read_table(work / "s.parquet").to_pandas()
        assert sorted(frame["experiment"].unique()) == [0, 1] and len(frame) == 802

    cases.append(Case("trajectory-ok", "trajectory file", [a.replace("{bad}", "{in}/trajectory.parquet")
                                                           for a in argv], "ok", check=replayed))

    def follows_the_load(work, inputs, out, err):
        # a load that changes within an experiment is the true load at each time (a shift
        # replayed): accepted; as for --motion shift the payload column, constant within an
        # experiment, holds the sum of its passes (one pass of 2000 kg), the passes the metadata
        table = pq.read_table(work / "s.parquet")
        frame = table.to_pandas()
        assert (frame["payload"] == 2000.0).all()
        meta = json.loads(table.schema.metadata[b"excavator_payload"])
        assert '"passes"' in json.dumps(meta) and '2000.0' in json.dumps(meta)

    # the bucket filled over each 4 s motion: 0 -> 2000 kg in 50 kg steps at 10 Hz
    filling = _trajectory_edit(lambda f: f.assign(payload=f.groupby("experiment").cumcount() * 50.0))
    cases.append(Case("trajectory-payload-changes", "trajectory file", argv, "ok", setup=filling,
                      check=follows_the_load))
    return cases


def _check_invalid_reported(work, inputs, out, err):
    frame = pq.read_table(work / "e.parquet").to_pandas()
    assert (frame["status"] == "invalid_input").sum() == 1
    assert "invalid_input" in out  # the summary line breaks the statuses down


# -- model folders
def _model_copy(work, inputs, name="model"):
    target = work / "m"
    shutil.copytree(inputs / name, target)
    return target


def _model_edit(edit, name="model"):
    def make(work, inputs):
        target = _model_copy(work, inputs, name)
        edit(target)
        return target
    return make


def _json_edit(fn):
    def edit(target):
        cfg = json.loads((target / "estimator.json").read_text())
        fn(cfg)
        (target / "estimator.json").write_text(json.dumps(cfg))
    return edit


def _npz_edit(fn):
    def edit(target):
        with np.load(target / "arrays.npz") as npz:
            arrays = {k: npz[k] for k in npz.files}
        fn(arrays)
        np.savez(target / "arrays.npz", **arrays)
    return edit


def _bytes_edit(fn, file="arrays.npz"):
    def edit(target):
        raw = (target / file).read_bytes()
        (target / file).write_bytes(fn(raw))
    return edit


def _flip_middle(raw: bytes) -> bytes:
    raw = bytearray(raw)
    for k in range(len(raw) // 2, len(raw) // 2 + 32):
        raw[k] ^= 0x5A
    return bytes(raw)


BAD_MODELS: dict[str, tuple[Callable, str | None]] = {
    "missing-folder": (lambda work, inputs: work / "none", "does not exist"),
    "empty-folder": (lambda work, inputs: (work / "m").mkdir() or work / "m", "not a saved estimator"),
    "a-file": (lambda work, inputs: _write(work / "m", "x"), None),
    "no-arrays": (_model_edit(lambda t: (t / "arrays.npz").unlink()), "arrays.npz"),
    "truncated-arrays": (_model_edit(_bytes_edit(lambda r: r[: len(r) // 2])), "arrays.npz"),
    "flipped-arrays": (_model_edit(_bytes_edit(_flip_middle)), None),
    "arrays-not-zip": (_model_edit(_bytes_edit(lambda r: b"hello")), "arrays.npz"),
    "nan-parameters": (_model_edit(_npz_edit(lambda a: a["theta_empty"].__setitem__(0, np.nan))), "finite"),
    "nan-net-weights": (_model_edit(_npz_edit(lambda a: a["weights"].__setitem__(3, np.nan)), "net1"), "finite"),
    "inf-ekf-covariance": (_model_edit(_npz_edit(lambda a: a["Q"].__setitem__((0, 0), np.inf)), "ekf"), "finite"),
    "wrong-shape": (_model_edit(_npz_edit(lambda a: a.__setitem__("theta_empty", np.zeros(3)))), "shape"),
    "object-array": (_model_edit(lambda t: np.savez(t / "arrays.npz", theta_empty=np.array([{}], dtype=object))),
                     "arrays.npz"),
    "json-garbage": (_model_edit(_bytes_edit(lambda r: b"{{{", "estimator.json")), "corrupt"),
    "json-truncated": (_model_edit(_bytes_edit(lambda r: r[:40], "estimator.json")), "corrupt"),
    "json-list": (_model_edit(_bytes_edit(lambda r: b"[1, 2]", "estimator.json")), None),
    "json-foreign": (_model_edit(_json_edit(lambda c: c.__setitem__("format", "sklearn"))), None),
    "json-version": (_model_edit(_json_edit(lambda c: c.__setitem__("version", "2"))), "version"),
    "json-estimator-int": (_model_edit(_json_edit(lambda c: c.__setitem__("estimator", 7))), None),
    "json-unknown-estimator": (_model_edit(_json_edit(lambda c: c.__setitem__("estimator", "magic"))), "magic"),
    "json-options-list": (_model_edit(_json_edit(lambda c: c.__setitem__("options", [1]))), "options"),
    "json-bad-option": (_model_edit(_json_edit(lambda c: c["options"].__setitem__("forgetting", "lots"))), None),
    "json-machine-string": (_model_edit(_json_edit(lambda c: c.__setitem__("machine", "cat"))), None),
    "json-machine-inf": (_model_edit(_json_edit(lambda c: c["machine"].__setitem__("boom_mass", float("inf")))),
                         None),
    "json-machine-text": (_model_edit(_json_edit(lambda c: c["machine"].__setitem__("boom_length", "long"))),
                          None),
    "json-machine-extra": (_model_edit(_json_edit(lambda c: c["machine"].__setitem__("wings", 2))), None),
    "json-state-list": (_model_edit(_json_edit(lambda c: c.__setitem__("state", []))), None),
    "json-sensor-set": (_model_edit(_json_edit(lambda c: c.__setitem__("sensor_set", "sonar"))), "sensor set"),
    "json-plausibility": (_model_edit(_json_edit(lambda c: c.__setitem__("plausibility", {"low": [0], "high": [1]}))),
                          "plausibility"),
    "json-net-tuning": (_model_edit(_json_edit(lambda c: c["options"].__setitem__("hidden", "100000")), "net1"),
                        None),
    "json-sentinel-text": (_model_edit(_json_edit(lambda c: c.__setitem__("gate_sentinel", "x")), "net1"),
                           "gate_sentinel"),
    "json-sentinel-machine-inf": (_model_edit(_json_edit(
        lambda c: c["gate_sentinel"]["machine"].__setitem__("dipper_mass", float("inf"))), "net1"), "dipper_mass"),
    "json-sentinel-noise": (_model_edit(_json_edit(lambda c: c["gate_sentinel"].__setitem__("noise", "loud")),
                                        "net1"), "loud"),
    "ekf-tuning-mismatch": (_model_edit(_json_edit(lambda c: c["options"].__setitem__("tuning", "thesis")), "ekf"),
                            "inconsistent"),
}


def model_cases() -> list[Case]:
    cases = []
    commands = {
        "estimate": (["estimate", "--model", "{bad}", "--data", "{in}/data.parquet", "--out", "{work}/e.parquet"],
                     ["{work}/e.parquet"]),
        "evaluate": (["evaluate", "--data", "{in}/data.parquet", "--model", "{bad}", "--json", "{work}/e.json"],
                     ["{work}/e.json"]),
        "report": (["report", "--data", "{in}/data.parquet", "--model", "{bad}", "--out", "{work}/r"],
                   ["{work}/r/report.html"]),
    }
    for bad, (setup, message) in BAD_MODELS.items():
        for command, (argv, outputs) in commands.items():
            cases.append(Case(f"model-{bad}-{command}", "bad model folder", argv, "error", message, setup,
                              None, outputs))
    return cases


# -- machine files
def _machine_text(fn):
    def make(work, inputs):
        return _write(work / "bad.toml", fn((inputs / "machine.toml").read_text()))
    return make


BAD_MACHINES: dict[str, tuple[Callable, str | None]] = {
    "misspelt-key": (_machine_text(lambda t: t.replace("torque_limit", "torque_limt", 1)), "torque_limt"),
    "unknown-table": (_machine_text(lambda t: t + "\n[stick]\nmass = 3.0\n"), "stick"),
    "inf-range": (_machine_text(lambda t: t.replace("angle_range = [", "angle_range = [-inf, inf] #", 1)),
                  "angle_range"),
    "nan-mass": (_machine_text(lambda t: t.replace("mass = ", "mass = nan #", 1)), "mass"),
    "inf-mass": (_machine_text(lambda t: t.replace("mass = ", "mass = inf #", 1)), "mass"),
    "negative-length": (_machine_text(lambda t: t.replace("length = ", "length = -", 1)), "length"),
    "zero-mass": (_machine_text(lambda t: t.replace("[bucket]\nmass = ", "[bucket]\nmass = 0 #")), "mass"),
    "text-mass": (_machine_text(lambda t: t.replace("[bucket]\nmass = ", "[bucket]\nmass = 'heavy' #")),
                  "bucket.mass"),
    "bool-length": (_machine_text(lambda t: t.replace("length = ", "length = true #", 1)), "length"),
    "missing-table": (_machine_text(lambda t: t.split("[payload]")[0]), "payload"),
    "reversed-range": (_machine_text(lambda t: t.replace("angle_range = [", "angle_range = [1.0, 0.5] #", 1)),
                       "angle_range"),
    "range-of-three": (_machine_text(lambda t: t.replace("angle_range = [", "angle_range = [0, 1, 2] #", 1)),
                       "angle_range"),
    "huge-payload": (_machine_text(lambda t: t.replace("rated = ", "rated = 1e300 #")), "payload"),
    "not-toml": (lambda work, inputs: _write(work / "bad.toml", "this is = = not toml ["), "TOML"),
    "empty": (lambda work, inputs: _write(work / "bad.toml", ""), None),
    "binary": (lambda work, inputs: _write(work / "bad.toml", os.urandom(200)), None),
    "folder": (lambda work, inputs: (work / "bad.toml").mkdir() or work / "bad.toml", None),
    "missing": (lambda work, inputs: work / "none.toml", "does not exist"),
    "name-empty": (_machine_text(lambda t: t.replace('name = "cat345c"', 'name = ""')), "name"),
    "name-number": (_machine_text(lambda t: t.replace('name = "cat345c"', "name = 5")), "name"),
}


def machine_cases() -> list[Case]:
    cases = []
    commands = {
        "machines": ["machines", "{bad}"],
        "train-id": ["train", "inverse-dynamics", "--data", "{in}/data.parquet", "--machine", "{bad}",
                     "--out", "{work}/m"],
        "train-ekf": ["train", "ekf", "--data", "{in}/data.parquet", "--machine", "{bad}", "--out", "{work}/m"],
    }
    for bad, (setup, message) in BAD_MACHINES.items():
        for command, argv in commands.items():
            cases.append(Case(f"machine-{bad}-{command}", "bad machine file", argv, "error", message, setup,
                              None, ["{work}/m/estimator.json"]))
    return cases


# -- hydraulic machine files: absurd but finite numbers that loaded, then hung the simulator,
# failed it with numpy's words or weighed silently wrong
def _hydraulic_text(table: str, key: str, value: str, *more: tuple[str, str, str]):
    """The preset cat345c-hydraulic with ``table.key = value`` (and ``more`` such edits)."""
    edits = {(table, key): value, **{(t, k): v for t, k, v in more}}

    def make(work, inputs):
        lines, current = [], ""  # "": the top-level keys
        for line in load_machine("cat345c-hydraulic").to_toml().splitlines():
            if line.startswith("["):
                current = line.strip("[]")
            name = line.split(" = ")[0]
            if (current, name) in edits:
                line = f"{name} = {edits[current, name]}"
            lines.append(line)
        return _write(work / "bad.toml", "\n".join(lines) + "\n")
    return make


BAD_HYDRAULIC_MACHINES: dict[str, tuple[Callable, str | None]] = {
    # simulate ran for ever (a motion over 2000 rad)
    "angle-range-huge": (_hydraulic_text("boom", "angle_range", "[-1000.0, 1000.0]"), "boom.angle_range"),
    "angle-range-in-degrees": (_hydraulic_text("dipper", "angle_range", "[-150.0, -15.0]"), "degrees"),
    # the strokes were never compared with the angle ranges (simulate wrote data)
    "stroke-unreachable": (_hydraulic_text("boom_cylinder", "stroke", "[0.5, 0.6]"), "boom_cylinder.stroke"),
    "stroke-in-mm": (_hydraulic_text("bucket_cylinder", "stroke", "[1950.0, 3100.0]"), "bucket_cylinder.stroke"),
    "linkage-open": (_hydraulic_text("linkage", "rocker_length", "0.01"), "linkage"),
    # "Maximum allowed size exceeded" / out of memory from the motion planner
    "pump-flow-1e-300": (_hydraulic_text("hydraulics", "pump_flow", "1e-300"), "pump_flow"),
    "cylinder-count-1e12": (_hydraulic_text("boom_cylinder", "count", "1000000000000"), "count"),
    "slew-rate-1e-300": (_hydraulic_text("house", "max_slew_rate", "1e-300"), "max_slew_rate"),
    "bore-1e10": (_hydraulic_text("boom_cylinder", "bore", "1e10"), "boom_cylinder.bore"),
    # calibration does not identify gravity: a 4.8 t load weighed as -4.2 t, 'ok'
    "gravity-1e-300": (_hydraulic_text("", "gravity", "1e-300"), "gravity"),
    "gravity-in-ft": (_hydraulic_text("", "gravity", "32.17"), "gravity"),
    "boom-mass-1e300": (_hydraulic_text("boom", "mass", "1e300"), "boom.mass"),
    "boom-length-1e200": (_hydraulic_text("boom", "length", "1e200"), "boom.length"),
    "inertia-1e300": (_hydraulic_text("dipper", "inertia", "[1e300, 1e300, 1e300]"), "dipper.inertia"),
    "payload-position-1e6": (_hydraulic_text("payload", "position", "[1e6, 0.0]"), "payload.position"),
    "payload-max-1e300": (_hydraulic_text("payload", "max", "1e300"), "payload.max"),
    # bore² underflows to 0: a division by zero in the rate limits
    "bore-1e-170": (_hydraulic_text("dipper_cylinder", "bore", "1e-170", ("dipper_cylinder", "rod", "1e-171")),
                    "dipper_cylinder.bore"),
}


def hydraulic_machine_cases() -> list[Case]:
    cases = []
    commands = {
        "machines": (["machines", "{bad}"], []),
        "simulate": (["simulate", "--machine", "{bad}", "-n", "1", "--out", "{work}/s.parquet", "--workers", "1",
                      "--quiet"], ["{work}/s.parquet"]),
        "train-calibrated": (["train", "calibrated", "--machine", "{bad}", "--data", "{in}/machine.parquet",
                              "--out", "{work}/m"], ["{work}/m/estimator.json"]),
    }
    for bad, (setup, message) in BAD_HYDRAULIC_MACHINES.items():
        for command, (argv, outputs) in commands.items():
            cases.append(Case(f"hydraulic-{bad}-{command}", "bad machine file", argv, "error", message, setup,
                              None, outputs))

    # a hydraulic machine file with thesis-set data (calibrated crashed: AttributeError)
    for estimator in ("calibrated", "inverse-dynamics", "quasi-static"):
        cases.append(Case(f"hydraulic-machine-thesis-data-train-{estimator}", "bad machine file",
                          ["train", estimator, "--machine", "cat345c-hydraulic", "--data", "{in}/data.parquet",
                           "--out", "{work}/m"], "error", "machine-sensor-set data",
                          outputs=["{work}/m/estimator.json"]))

    # issue 28: the Kalman filters left the machine sensor set; asked for there, in one line,
    # why and what to use instead (with the dataset's hydraulic machine, or a thesis machine file)
    for estimator in ("ekf", "ukf"):
        cases.append(Case(f"machine-set-train-{estimator}", "bad machine file",
                          ["train", estimator, "--data", "{in}/machine.parquet", "--out", "{work}/m"],
                          "error", "use 'calibrated'", outputs=["{work}/m/estimator.json"]))
        cases.append(Case(f"machine-set-thesis-file-train-{estimator}", "bad machine file",
                          ["train", estimator, "--machine", "cat345c", "--data", "{in}/machine.parquet",
                           "--out", "{work}/m"], "error", "use 'calibrated'", outputs=["{work}/m/estimator.json"]))

    def ten_percent_off(work, inputs):
        from excavator_payload.model.hydraulic_machine import off_by

        return _write(work / "mine.toml", off_by(load_machine("cat345c-hydraulic"), 0.10).to_toml())

    # a roughly right file (every number 10 % off: the boom's pins need 5.5 % beyond its stroke,
    # which enters no computation) is fine
    cases.append(Case("hydraulic-10pct-off-simulate", "bad machine file",
                      ["simulate", "--machine", "{bad}", "-n", "1", "--out", "{work}/s.parquet", "--workers", "1",
                       "--quiet"], "ok", setup=ten_percent_off,
                      check=lambda work, inputs, out, err: pq.read_table(work / "s.parquet")))
    return cases


def _check_round_trip(work, inputs, out, err):
    path = _write(work / "round.toml", out)
    machine = load_machine(path)
    assert machine.name == 'odd "name" [with] \\ chars' and machine.description == "line\nbreak"


def _odd_machine(work, inputs):
    text = (inputs / "machine.toml").read_text()
    text = text.replace('name = "cat345c"', 'name = "odd \\"name\\" [with] \\\\ chars"')
    text = text.replace('description = "', 'description = "line\\nbreak" #', 1)
    return _write(work / "odd.toml", text)
