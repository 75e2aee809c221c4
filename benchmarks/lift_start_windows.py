"""What biases the boom's windows at the start of a lift after a fill (issue 28): per-window oracles.

A few ``shift`` trucks (``bench_false_alarms.py``'s chunk 0 of ``--seed``: 5 trucks, seed
``seed + 9000``) are re-simulated with effects taken out one at a time and weighed by the user's
default flow (``calibrated``, the benchmark's cached ``study`` estimator) or by an oracle that
weighs with the simulator's own machine file, session offsets and IMU dynamics
(``bench_efficiency_gap.oracle``). Every momentum-balance window the kernel sums is recorded (its
joints' ``w φ r`` and ``w φ²``); per window its own payload (the boom joint's ``r/φ``, and the three
joints' ``Σwφr / Σwφ²``, the nuisances at the calibration's) minus the pass's load is binned by the
window centre's time since the boom started its lift (the first true boom rate above
``--boom-rate`` after the fill's start). Per variant it prints, per bin, the information-weighted
mean signed error, the windows' count and the boom's true acceleration at their centres, and the
weighted error of a pass's first 50 boom windows after the fill's end (what the first ``ok`` is
built from) against that of its later ones.

Variants (``--variants``): ``calibrated`` (field data, the user's flow), ``oracle`` (field data,
the true machine, offsets and IMU dynamics), ``oracle-no-imu`` (data without the IMU's lag and
acceleration leak), ``oracle-quiet`` (data with the session offsets and no other sensor error:
no noise, ripple, IMU dynamics), ``oracle-quiet-nofric`` (as ``oracle-quiet`` with the cylinders'
seal friction nearly off, 1 N Coulomb, in the simulator and the oracle alike),
``calibrated-true-imu`` / ``-true-lag`` / ``-true-house`` (the user's flow with its IMU
dynamics, the lag alone or the house IMU's acceleration sensitivity alone set to the
simulator's), ``oracle-calibrated-imu`` (the oracle with the calibration's IMU dynamics), and
``swap:GROUP[+GROUP…]`` (a group of ``bench_calibration_attribution.GROUPS`` set to the truth and
zeroed again; ``swap:offsets``: the true offsets). ``--first-ok`` adds each pass's first ``ok``
of the estimator itself (``wait_after_load.study_chunk``). The estimator is fitted once and kept
under ``CACHE/alarms/estimator-study`` (as ``bench_false_alarms.calibrated``).

Usage::

    PYTHONPATH=src python benchmarks/lift_start_windows.py --cache /work/scratch/lift28 \\
        --seeds 97000,97100,97200 --first-ok \\
        --variants calibrated,calibrated-true-house,oracle,oracle-no-imu,oracle-quiet,oracle-quiet-nofric
"""

from __future__ import annotations

import argparse
import copy
import pickle
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_false_alarms as bfa  # noqa: E402
import wait_after_load as wal  # noqa: E402
from bench_efficiency_gap import FIELD, N_DELTA, N_OFFSETS  # noqa: E402
from bench_efficiency_gap import oracle_with as oracle  # noqa: E402

from excavator_payload.data.io import write_dataset  # noqa: E402
from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel  # noqa: E402
from excavator_payload.estimators.classical.machine_calibration.settings import BALANCE_HALF_WINDOW  # noqa: E402
from excavator_payload.estimators.classical.pressure_regression import LOOK_AHEAD, PressureKernel  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.model.machine import load_machine  # noqa: E402
from excavator_payload.platforms.hydraulic import MachineNoise  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402
from excavator_payload.simulation.machine_sensors import lag_delay  # noqa: E402

QUIET = MachineNoise("quiet", pressure_offset=FIELD.pressure_offset, angle_offset=FIELD.angle_offset,
                     rate_offset=FIELD.rate_offset, inclination_offset=FIELD.inclination_offset)
NO_IMU = replace(FIELD, name="no-imu", imu_lag=0.0, acceleration_leak=0.0)
#: variant: (estimator, data noise, friction nearly off)
VARIANTS = {"calibrated": ("calibrated", FIELD, False), "oracle": ("oracle", FIELD, False),
            "oracle-no-imu": ("oracle", NO_IMU, False), "oracle-quiet": ("oracle", QUIET, False),
            "oracle-quiet-nofric": ("oracle", QUIET, True), "calibrated-true-imu": ("calibrated-true-imu", FIELD, False),
            "oracle-calibrated-imu": ("oracle", FIELD, False), "calibrated-true-lag": ("calibrated-true-imu", FIELD, False),
            "calibrated-true-house": ("calibrated-true-imu", FIELD, False)}
#: the IMU dynamics a ``calibrated-true-*`` variant sets to the truth (lag, three link
#: sensitivities, the house's)
TRUE_IMU = {"calibrated-true-imu": slice(None), "calibrated-true-lag": slice(0, 1), "calibrated-true-house": slice(4, 5)}
#: the recorded windows: (step time, boom windows, new loads, dnum × 3, dinfo × 3)
WINDOWS: list[tuple] = []
_NOW = [0.0, -1, np.inf]  # step time, experiment index (a step back in time starts the next), last time


def machine_of(no_friction: bool):
    """The simulator's machine, its cylinders' seal friction nearly off when asked (1 N Coulomb,
    no load share, no viscous part, breakaway = Coulomb)."""
    m = load_machine("cat345c-hydraulic")
    if not no_friction:
        return m
    off = dict(coulomb=1.0, load_coefficient=0.0, viscous=0.0, static_ratio=1.0)
    return replace(m, boom_cylinder=replace(m.boom_cylinder, **off), dipper_cylinder=replace(m.dipper_cylinder, **off),
                   bucket_cylinder=replace(m.bucket_cylinder, **off))


def true_imu(est, noise: MachineNoise, which=slice(None)):
    """``est`` with its calibration's IMU dynamics (lag, acceleration sensitivities; ``which`` of
    these five) set to the simulator's, every other parameter and offset as calibrated and zeroed."""
    cal = copy.deepcopy(est.calibration)
    cal.z = cal.z.copy()
    k_link = noise.acceleration_leak * noise.link_imu_distance / 9.81
    truth = [lag_delay(noise.imu_lag, 0.01), k_link, k_link, k_link, noise.acceleration_leak * noise.house_imu_radius / 9.81]
    print("IMU dynamics calibrated / true:", np.round(cal.z[N_DELTA + N_OFFSETS:], 5), np.round(truth, 5))
    cal.z[N_DELTA + N_OFFSETS:][which] = np.asarray(truth)[which]
    out = copy.deepcopy(est)
    out.use_calibration(cal)
    return out


def swapped(est, group: str):
    """``est`` with one group of calibrated parameters (``bench_calibration_attribution.GROUPS``,
    or ``offsets``: the session's true offsets, not zeroed again) set to the simulator's, zeroed
    again on the flow's empty swing (``dm.zero_data(9150)``)."""
    import bench_calibration_attribution as bca

    if group == "offsets":
        return bca.with_offsets(est, np.arange(N_OFFSETS))
    out = copy.deepcopy(est)
    idx = np.concatenate([bca.group_index(g) for g in group.split("+")])
    z = out.calibration.z.copy()
    z[idx] = bca.true_delta()[idx]
    out.calibration.z = z
    out.zero(dm.zero_data(9150), force=True)
    return out


def _patch() -> None:
    step, accumulate = PressureKernel.step, CalibratedKernel._accumulate

    def recording_step(self, time, values, judge=True, joint_check=False):
        if time < _NOW[2]:
            _NOW[1] += 1
        _NOW[0] = _NOW[2] = time
        return step(self, time, values, judge, joint_check)

    def recording_accumulate(self, d_num_joint, d_info_joint):
        WINDOWS.append((_NOW[1], _NOW[0], self.boom_windows, self.new_loads, self.half_window, *d_num_joint, *d_info_joint))
        return accumulate(self, d_num_joint, d_info_joint)

    PressureKernel.step = wal._recording_step(recording_step)
    CalibratedKernel._accumulate = recording_accumulate


def data(cache: Path, seed: int, noise: MachineNoise, no_friction: bool):
    """Chunk 0 of ``bench_false_alarms``' ``shift`` at ``seed`` (5 trucks), with ``noise``."""
    path = cache / f"shift_{seed}_{noise.name}_{int(no_friction)}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    ds = simulate_dataset(5, seed=seed + 1000 * bfa.FAMILY_NAMES.index("shift"), motion="shift",
                          machine=machine_of(no_friction), session=dm.SESSION_WORK, with_truth=True, workers=1,
                          progress=False, noise=noise)
    path.write_bytes(pickle.dumps(ds))
    write_dataset(ds, path.with_suffix(".parquet"))
    return ds


def first_ok(est, cache: Path, seed: int, noise: MachineNoise, no_friction: bool) -> pd.DataFrame:
    """Per load of :func:`data`'s trucks, ``wait_after_load.study_chunk``'s row: the wait to the
    first ``ok``, its error and σ (the estimator's own output, the IMU nuisances re-estimated)."""
    path = cache / f"shift_{seed}_{noise.name}_{int(no_friction)}.parquet"
    if not path.exists():
        write_dataset(data(cache, seed, noise, no_friction), path)
    t = wal.study_chunk(est, path, "shift", 0)
    return t[(t["changing_truth"] != True) & (t["load"] > 0)]  # noqa: E712


def windows_of(est, ds, boom_rate: float, first: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(one row per recorded window after a fill, one row per pass) of ``ds`` weighed by ``est``.

    Parameters
    ----------
    est : Estimator
        The zeroed estimator.
    ds : Dataset
        Shift trucks with their truth and per-pass meta.
    boom_rate : float
        The true boom rate that starts the lift, rad/s.
    first : int
        The boom windows a pass's first weight is built from.
    """
    frame = ds.frame.reset_index(drop=True)
    rows, passes = [], []
    WINDOWS.clear()
    _NOW[1:] = [-1, np.inf]
    est.estimate(ds)
    every = pd.DataFrame(WINDOWS, columns=["index", "t", "boom_windows", "new_loads", "half", "n0", "n1", "n2",
                                           "i0", "i1", "i2"])
    for index, (exp, sub) in enumerate(frame.groupby("experiment", sort=False)):
        w = every[every["index"] == index].reset_index(drop=True)
        t = sub["time"].to_numpy(float)
        t0 = t[0]
        dt = float(np.median(np.diff(t)))
        delay = (LOOK_AHEAD + w["half"].to_numpy() + BALANCE_HALF_WINDOW) * dt
        centre = w["t"].to_numpy() - t0 - delay
        rate = sub["true_boom_rate"].to_numpy(float)
        accel = sub["true_boom_accel"].to_numpy(float)
        brate = sub["true_bucket_rate"].to_numpy(float)
        srate, saccel = sub["true_slew_rate"].to_numpy(float), sub["true_slew_accel"].to_numpy(float)
        for p in ds.experiment_meta[exp]["passes"]:
            fs, fe = p["fill"]
            rel = p["release"][0]
            tt = t - t0
            lift = np.flatnonzero((tt >= fs) & (rate > boom_rate))
            if not len(lift):
                continue
            tb = tt[lift[0]]
            sel = np.flatnonzero((centre >= fe - 1.0) & (centre < rel - 0.3))
            if not len(sel):
                continue
            n = w[["n0", "n1", "n2"]].to_numpy()[sel]
            i = w[["i0", "i1", "i2"]].to_numpy()[sel]
            k = np.clip(np.searchsorted(tt, centre[sel]), 0, len(tt) - 1)
            load = float(p["payload"])
            part = pd.DataFrame({"experiment": exp, "pass": p["pass"], "since_boom": centre[sel] - tb,
                                 "since_fill": centre[sel] - fe, "n0": n[:, 0], "i0": i[:, 0],
                                 "n": n.sum(axis=1), "i": i.sum(axis=1), "load": load,
                                 "boom_accel": accel[k], "boom_rate": rate[k], "bucket_rate": brate[k],
                                 "slew_rate": srate[k], "slew_accel": saccel[k]})
            rows.append(part)
            # the first ``first`` boom windows after the fill's end against the later ones
            boom = part[(part["i0"] > 0) & (part["since_fill"] >= 0)]
            a, b = boom.iloc[:first], boom.iloc[first:]
            passes.append({"experiment": exp, "pass": p["pass"], "load": load, "boom_from_fill": tb - fe,
                           "first_boom_err": a["n0"].sum() / a["i0"].sum() - load if len(a) else np.nan,
                           "first_all_err": a["n"].sum() / a["i"].sum() - load if len(a) else np.nan,
                           "later_boom_err": b["n0"].sum() / b["i0"].sum() - load if len(b) else np.nan,
                           "later_all_err": b["n"].sum() / b["i"].sum() - load if len(b) else np.nan,
                           "first_span": (a["since_boom"].iloc[-1] if len(a) else np.nan)})
    return pd.concat(rows, ignore_index=True), pd.DataFrame(passes)


def binned(win: pd.DataFrame, width: float, upto: float) -> pd.DataFrame:
    """Information-weighted mean signed error per bin of time since the boom started."""
    boom = win[win["i0"] > 0]
    edges = np.arange(-0.5, upto + 1e-9, width)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        b = boom[(boom["since_boom"] >= lo) & (boom["since_boom"] < hi)]
        if not len(b):
            continue
        e0 = b["n0"].sum() / b["i0"].sum() - np.average(b["load"], weights=b["i0"])
        ea = b["n"].sum() / b["i"].sum() - np.average(b["load"], weights=b["i"])
        pw = (b["n0"] / b["i0"] - b["load"]).groupby([b["experiment"], b["pass"]]).median()
        out.append({"from_s": round(lo, 2), "windows": len(b), "boom_err_kg": e0, "all_err_kg": ea,
                    "pass_median_kg": float(pw.median()), "boom_accel": b["boom_accel"].mean(),
                    "boom_rate": b["boom_rate"].mean(), "bucket_rate": b["bucket_rate"].mean(),
                    "slew_rate": b["slew_rate"].abs().mean(), "slew_accel": (b["slew_accel"] * np.sign(b["slew_rate"])).mean()})
    return pd.DataFrame(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/lift28"))
    ap.add_argument("--seeds", default="97000")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--boom-rate", type=float, default=0.02, help="the true boom rate that starts the lift, rad/s")
    ap.add_argument("--first", type=int, default=50, help="boom windows of a pass's first weight")
    ap.add_argument("--width", type=float, default=0.25)
    ap.add_argument("--upto", type=float, default=4.0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--first-ok", action="store_true", help="also each pass's first ok (wait_after_load)")
    a = ap.parse_args()
    _patch()
    base = bfa.calibrated("study", a.cache / "alarms")
    for name in a.variants.split(","):
        if name.startswith("swap:"):
            est, noise, no_friction = swapped(base, name[5:]), FIELD, False
        else:
            kind, noise, no_friction = VARIANTS[name]
            est = base if kind == "calibrated" else true_imu(base, noise, TRUE_IMU[name]) if kind == "calibrated-true-imu" else \
                oracle(base, noise, machine_of(no_friction))
            if name == "oracle-calibrated-imu":  # the oracle weighing with the calibration's IMU dynamics
                cal = copy.deepcopy(est.calibration)
                cal.z = cal.z.copy()
                cal.z[N_DELTA + N_OFFSETS:] = base.calibration.z[N_DELTA + N_OFFSETS:]
                est.use_calibration(cal)
        wins, passes = [], []
        for seed in (int(s) for s in a.seeds.split(",")):
            w, p = windows_of(est, data(a.cache, seed, noise, no_friction), a.boom_rate, a.first)
            wins.append(w.assign(seed=seed))
            if a.first_ok:
                ok = first_ok(est, a.cache, seed, noise, no_friction)[["experiment", "load", "wait", "first_error",
                                                                        "first_sigma"]]
                p = p.merge(ok, on=["experiment", "load"], how="left")
            passes.append(p.assign(seed=seed))
        report(name, pd.concat(wins, ignore_index=True), pd.concat(passes, ignore_index=True), a)


def report(name: str, win: pd.DataFrame, pas: pd.DataFrame, a) -> None:
    """Print (and with ``--out`` write) one variant's windows and passes.

    Parameters
    ----------
    name : str
        The variant.
    win, pas : pandas.DataFrame
        Its windows and passes (:func:`windows_of`).
    a : argparse.Namespace
        The options (``out``, ``width``, ``upto``).
    """
    if a.out:
        win.to_csv(f"{a.out}-{name.replace(':', '_')}-windows.csv", index=False)
        pas.to_csv(f"{a.out}-{name.replace(':', '_')}-passes.csv", index=False)
    later = pas[pas["pass"] > 1]
    with pd.option_context("display.width", 200, "display.max_rows", 200):
        print(f"== {name}: {len(pas)} passes ({len(later)} after a truck's first)")
        print(binned(win, a.width, a.upto).round(2).to_string(index=False))
        print(later[["boom_from_fill", "first_span", "first_boom_err", "later_boom_err", "first_all_err",
                     "later_all_err"]].describe().round(1).to_string())
        print("median:", later[["first_boom_err", "later_boom_err", "first_all_err", "later_all_err"]]
              .median().round(1).to_dict(), flush=True)
        if "first_error" in later:
            e, sd = later["first_error"], later["first_sigma"]
            print(f"first ok (passes after a truck's first): wait {later['wait'].mean():.2f} s, |error| mean "
                  f"{e.abs().mean():.1f} largest {e.abs().max():.1f} kg, signed median {e.median():.1f} kg, within "
                  f"50 kg {100 * (e.abs() <= 50).mean():.0f} %, within 2σ {100 * (e.abs() <= 2 * sd).mean():.0f} %, "
                  f"corr. with the first {a.first} boom windows' error {np.corrcoef(e, later['first_boom_err'])[0, 1]:.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
