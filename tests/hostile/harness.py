"""The hostile cases' harness: the good inputs every case starts from, a case and its outcome,
the helpers that make bad files, and running one case through ``cli.main``."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import write_dataset
from excavator_payload.estimators import create_estimator
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.lifts import simulate_lifts
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


# -- inputs ---------------------------------------------------------------------------------------
def build_inputs(folder: Path) -> Path:
    """Write every good input the cases start from into ``folder`` (cheap: a few seconds)."""
    folder.mkdir(parents=True, exist_ok=True)
    data = simulate_minimum_jerk(6, seed=41, noise="thesis")
    write_dataset(data, folder / "data.parquet")
    field_log = Dataset(data.frame.drop(columns=["payload"]), {k: v for k, v in data.meta.items()
                                                                 if k != "experiments"})
    write_dataset(field_log, folder / "field.parquet")
    other = simulate_minimum_jerk(6, seed=42, noise="thesis")
    write_dataset(other, folder / "other.parquet")
    # Two lifts per reference payload: too few dipper angles for a trustworthy map.
    write_dataset(simulate_lifts(4, seed=43, noise="thesis"), folder / "lifts.parquet")
    create_estimator("inverse-dynamics", "cat345c").fit(data).save(folder / "model")
    create_estimator("ekf", "cat345c").fit(data).save(folder / "ekf")
    create_estimator("net1", hidden="3", epochs=2, train_experiments=4, validation_experiments=2,
                     progress=False).fit(data).save(folder / "net1")
    (folder / "machine.toml").write_text(load_machine("cat345c").to_toml())
    # The machine sensor set (IMUs, slew rate, house tilt, pressures), on a slope.
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset
    write_dataset(simulate_machine_dataset(2, seed=44, motion="slopes"), folder / "machine.parquet")
    # A hand-made motion for simulate --trajectory: 2 experiments at 10 Hz.
    t = np.arange(0, 4.0001, 0.1)
    pq.write_table(pa.Table.from_pandas(pd.concat([pd.DataFrame(
        {"experiment": k, "time": t, "boom_angle": 0.1 + 0.3 * np.sin(0.5 * t),
         "dipper_angle": -1.2 + 0.2 * np.sin(0.7 * t), "bucket_angle": -1.0 + 0.3 * np.sin(0.9 * t),
         "slew_angle": 0.4 * np.sin(0.4 * t), "payload": 1000.0 * k}) for k in (0, 1)]),
        preserve_index=False), folder / "trajectory.parquet")
    assert main(["estimate", "--model", str(folder / "model"), "--data", str(folder / "data.parquet"),
                 "--out", str(folder / "estimates.parquet")]) == 0
    return folder


def fingerprint(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folder`` (to prove inputs are untouched)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            out[str(path.relative_to(folder))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


# -- the cases ------------------------------------------------------------------------------------
@dataclass
class Case:
    """One hostile invocation.

    ``argv`` may use ``{in}`` (the copy of the good inputs) and ``{work}`` (an empty folder);
    ``setup(work, inputs)`` makes the bad file(s); ``expect`` is ``"error"`` or ``"ok"``;
    ``message`` a fragment the error must contain; ``check(work, inputs, out, err)`` extra
    checks of an ``ok`` result; ``outputs`` the paths (templates) that must not look valid after
    a failure.
    """

    id: str
    group: str
    argv: list[str]
    expect: str = "error"
    message: str | None = None
    setup: Callable | None = None
    check: Callable | None = None
    outputs: list[str] = field(default_factory=list)


@dataclass
class Outcome:
    code: int
    out: str
    err: str
    inputs_changed: list[str]
    half_written: list[str]
    problem: str | None  # None: as expected; else "crash", "silent wrong" or "data lost"


def _write(path: Path, data: bytes | str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)
    return path


def _frame(inputs: Path, name: str = "data.parquet") -> pd.DataFrame:
    return pq.read_table(inputs / name).to_pandas()


def _write_frame(path: Path, frame: pd.DataFrame, meta: bytes | None = None) -> Path:
    table = pa.Table.from_pandas(frame, preserve_index=False)
    if meta is not None:
        table = table.replace_schema_metadata({b"excavator_payload": meta})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
    return path


def _meta(inputs: Path, name: str = "data.parquet") -> bytes:
    return pq.read_schema(inputs / name).metadata[b"excavator_payload"]


def _edit(fn):
    """A dataset maker: ``fn(frame) -> frame`` applied to the good dataset, metadata kept."""
    def make(work, inputs):
        return _write_frame(work / "bad.parquet", fn(_frame(inputs).copy()), _meta(inputs))
    return make


def _raw(data: bytes | str):
    return lambda work, inputs: _write(work / "bad.parquet", data)


# -- running a case -------------------------------------------------------------------------------
def _fill(text: str, inputs: Path, work: Path, bad: Path | None) -> str:
    return (text.replace("{in}", str(inputs)).replace("{work}", str(work))
            .replace("{bad}", str(bad) if bad is not None else ""))


def run_case(case: Case, inputs: Path, work: Path, capture) -> Outcome:
    """Run ``case`` on ``inputs`` (a private copy) in the empty folder ``work``.

    ``capture()`` returns ``(stdout, stderr)`` printed since the last call (pytest's capsys, or
    the summary script's redirection).
    """
    bad = case.setup(work, inputs) if case.setup else None
    before_inputs = fingerprint(inputs)
    outputs = [Path(_fill(o, inputs, work, bad)) for o in case.outputs]
    before_outputs = {o: (o.read_bytes() if o.is_file() else None) for o in outputs}
    capture()
    try:
        code = main([_fill(a, inputs, work, bad) for a in case.argv])
    except BaseException as exc:  # anything escaping main() is a crash
        out, err = capture()
        return Outcome(-1, out, err + f"\n{type(exc).__name__}: {exc}", [], [], "crash")
    out, err = capture()
    after_inputs = fingerprint(inputs)
    changed = sorted(k for k in set(before_inputs) | set(after_inputs)
                     if before_inputs.get(k) != after_inputs.get(k))
    half = [str(o) for o in outputs if code != 0 and o.is_file() and o.read_bytes() != before_outputs[o]]
    problem = None
    lines = [line for line in err.splitlines() if line.strip()]
    if changed or half:
        problem = "data lost"
    elif code not in (0, 2) or "Traceback" in err or "internal error" in err:
        problem = "crash"
    elif case.expect == "error":
        click_usage = lines and lines[-1].startswith("Error:")
        if code != 2 or not lines:
            problem = "silent wrong"
        elif not click_usage and not (len(lines) == 1 and lines[0].startswith("error:")):
            problem = "crash"  # not one readable line
        elif case.message and case.message.lower() not in err.lower():
            problem = "silent wrong"  # the message lost what matters (e.g. markup ate it)
    else:
        if code != 0:
            problem = "silent wrong"
        elif case.check is not None:
            try:
                case.check(work, inputs, out, err)
            except BaseException:
                problem = "silent wrong"
    return Outcome(code, out, err, changed, half, problem)
