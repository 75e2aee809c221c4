"""Why some motion families sit further above the Cramér–Rao bound than others: the error split.

``bench_machine_draws.py`` reports efficiency = RMS error / bound (``crb_machine``) per draw and
family. This benchmark weighs the same test motions (the same seeds as that benchmark's
``--seed``) three ways per calibration draw and splits each cell's error:

* ``calibrated``: the recommended calibration of the draw, zeroed (as the bench);
* ``oracle-zero``: the same calibrated parameters and IMU dynamics, the zero's offsets replaced
  by the reference a perfect zero would find (the calibration's own offsets plus the true
  drift between the sessions): what the zero costs;
* ``oracle``: the simulator's own machine file, session offsets and IMU dynamics (the lag as
  the simulator's filter delays, :func:`~excavator_payload.simulation.machine_sensors.lag_delay`),
  with the draw's noise, coverage and σ terms: what the weighing itself costs.

Per cell it prints the pooled efficiency, the cell's bias (mean over motions of each motion's
mean error), the spread of the motions' biases and the scatter within a motion (kg), and the
bound's median. ``--noise`` weighs the oracle on test data with one noise source of the
``field`` preset taken out (or with white pressure noise alone, the bound's own assumption).

Usage (the numbers of docs/findings/any-motion.md, "Why `multisine` and `joystick` sit above
the bound")::

    PYTHONPATH=src python benchmarks/bench_efficiency_gap.py --cache /tmp/gap --out gap
    PYTHONPATH=src python benchmarks/bench_efficiency_gap.py --cache /tmp/gap --draws 1 \
        --noise pressure-only no-imu-lag no-rate-noise --labels oracle
"""

from __future__ import annotations

import argparse
import copy
import math
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from held_out_motions import joystick_trajectory, lever_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
from excavator_payload.estimators.classical.machine_calibration.settings import (
    CALIBRATED_PARAMETERS, OFFSET_SIGNALS)
from excavator_payload.estimators.classical.machine_calibration.solver import MachineCalibration
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.evaluation.crb_machine import machine_bound
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.platforms import HYDRAULIC
from excavator_payload.platforms.hydraulic import MachineNoise, session_offsets
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.machine_sensors import lag_delay
from excavator_payload.simulation.trajectory import trajectory_from_frame

FIELD = HYDRAULIC.noise("field")
#: Test-data noise variants: the field preset, with one source out, or the bound's own world
#: (white pressure noise; the session offsets kept, so that the oracle's offsets apply).
NOISES = {
    "field": FIELD,
    "pressure-only": MachineNoise("pressure-only", pressure_noise=FIELD.pressure_noise,
                                  pressure_offset=FIELD.pressure_offset, angle_offset=FIELD.angle_offset,
                                  rate_offset=FIELD.rate_offset, inclination_offset=FIELD.inclination_offset),
    **{name: replace(FIELD, name=name, **{f: 0.0 for f in fields}) for name, fields in {
        "no-ripple": ("ripple_fraction",), "no-rate-noise": ("rate_noise",), "no-rate-offset": ("rate_offset",),
        "no-angle-noise": ("angle_noise", "inclination_noise"), "no-imu-lag": ("imu_lag",),
        "no-imu-leak": ("acceleration_leak",), "no-pressure-noise": ("pressure_noise",)}.items()},
}
N_DELTA, N_OFFSETS = len(CALIBRATED_PARAMETERS), len(OFFSET_SIGNALS)


def cached(cache: Path, key: str, make):
    """``make()`` once, pickled under ``cache`` (the calibrations take tens of seconds each)."""
    path = cache / f"{key}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    value = make()
    path.write_bytes(pickle.dumps(value))
    return value


def family(cache: Path, name: str, n: int, seed: int, noise: str = "field"):
    """Test set ``name`` as ``bench_machine_draws.py --seed seed`` simulates it (its first ``n``
    motions), with the noise variant ``noise``."""
    def make():
        common = dict(machine="cat345c-hydraulic", session=dm.SESSION_WORK, with_truth=True, workers=1,
                      progress=False, noise=NOISES[noise])
        if name == "nmpc":  # dm.test_sets(n, seed + 2)'s
            return simulate_dataset(n, seed=seed + 5, motion="nmpc", **common)
        make_table, s = {"lever": (lever_trajectory, seed + 4), "joystick": (joystick_trajectory, seed + 5),
                         "multisine": (multisine_trajectory, seed + 6)}[name]
        traj = trajectory_from_frame(make_table(n, s))
        return simulate_dataset(len(traj.experiments), seed=s, motion="trajectory", trajectory=traj,
                                allow_overspeed=True, **common)
    return cached(cache, f"{name}_{n}_{seed}_{noise}", make)


def calibrated(cache: Path, motions: int, reach: int, seed: int, zero_kind: str):
    """(the zeroed estimator, the calibration's z before the zero) of one draw, as the bench."""
    def fitted():
        return CalibratedEstimator("cat345c-hydraulic-3pct", balance="momentum").fit(
            dm.calibration_mix(motions, seed, reach=reach))

    def make():
        est = fitted()
        if zero_kind == "empty-swing":
            zero = dm.zero_data(seed + 1)
        else:
            zero = dm.simulate_trajectory(lever_trajectory(1, seed + 1, payloads=[0.0], slow=True), seed + 1,
                                          dm.SESSION_WORK)
        est.zero(zero)
        return est
    est = cached(cache, f"est_{motions}_{reach}_{seed}_{zero_kind}_[]", make)
    before_zero = cached(cache, f"prez_{motions}_{reach}_{seed}", lambda: fitted().calibration.z.copy())
    return est, before_zero


def oracle_zero(est, before_zero: np.ndarray):
    """``est`` with the offsets a perfect zero finds: the calibration's own plus the true drift."""
    a = session_offsets(dm.SESSION_CALIBRATION, FIELD)
    b = session_offsets(dm.SESSION_WORK, FIELD)
    cal = copy.deepcopy(est.calibration)
    cal.z = cal.z.copy()
    drift = np.array([b[s] - a[s] for s in OFFSET_SIGNALS])
    cal.z[N_DELTA:N_DELTA + N_OFFSETS] = before_zero[N_DELTA:N_DELTA + N_OFFSETS] + drift
    out = copy.deepcopy(est)
    out.use_calibration(cal)
    return out


def oracle(est, noise: str = "field"):
    """``est`` weighing with the simulator's own machine file, session offsets and IMU dynamics."""
    return oracle_with(est, NOISES[noise], load_machine("cat345c-hydraulic"))


def oracle_with(est, nz, machine):
    """``est`` weighing with ``machine`` (a machine file), the session's true offsets and the IMU
    dynamics of the noise preset ``nz`` (a ``MachineNoise``; no lag where it has none)."""
    src = est.calibration
    cal = MachineCalibration(HydraulicArmModel(machine, compiled=False))
    offsets = session_offsets(dm.SESSION_WORK, nz)
    z = np.zeros_like(src.z)
    z[N_DELTA:N_DELTA + N_OFFSETS] = [offsets[s] for s in OFFSET_SIGNALS]
    k_link = nz.acceleration_leak * nz.link_imu_distance / 9.81
    z[N_DELTA + N_OFFSETS:] = [lag_delay(nz.imu_lag, 0.01) if nz.imu_lag > 0 else 0.0, k_link, k_link, k_link,
                               nz.acceleration_leak * nz.house_imu_radius / 9.81]
    cal.z = z
    for name in ("covariance", "pressure_std", "rate_var", "window_inflation", "angle_coverage", "model_std",
                 "zero_std", "balance", "accel_var"):
        setattr(cal, name, copy.deepcopy(getattr(src, name)))
    out = copy.deepcopy(est)
    out.use_calibration(cal)
    out.health = False  # noise-free variants would read as stuck sensors
    return out


def per_motion(est, ds, bound: np.ndarray) -> pd.DataFrame:
    """Per test motion: the judged samples (after ``dm.DISCARD``) with an estimate, the sum of
    (error / bound)², the mean and RMS error and the bound's median."""
    frame = est.estimate(ds)
    f = ds.frame
    exp = f["experiment"].to_numpy()
    rows = []
    for e in pd.unique(exp):
        sel = np.flatnonzero(exp == e)[dm.DISCARD:]
        err = frame["payload_estimate"].to_numpy(float)[sel] - f["payload"].to_numpy(float)[sel]
        b = bound[sel]
        use = np.isfinite(err) & np.isfinite(b) & (b > 0)
        if use.any():
            rows.append({"experiment": e, "n": int(use.sum()), "ss": float(np.sum((err[use] / b[use]) ** 2)),
                         "mean_err": float(err[use].mean()), "rms_err": float(np.sqrt(np.mean(err[use] ** 2))),
                         "bound_med": float(np.median(b[use]))})
    return pd.DataFrame(rows)


def split(pe: pd.DataFrame) -> dict:
    """A cell's pooled efficiency and its error split (kg): the cell's bias, the spread of the
    motions' biases about it, the scatter within a motion, the RMS error and the bound."""
    within = np.sqrt(np.maximum(pe["rms_err"] ** 2 - pe["mean_err"] ** 2, 0.0))
    return {"efficiency": math.sqrt(pe["ss"].sum() / pe["n"].sum()), "cell_bias": pe["mean_err"].mean(),
            "motion_spread": pe["mean_err"].std(ddof=0), "within": float(np.sqrt(np.mean(within ** 2))),
            "rms": float(np.sqrt(np.mean(pe["rms_err"] ** 2))), "bound": pe["bound_med"].median()}


def draw_arguments(ap, out: str, draws: int):
    """``ap`` with the options every calibration-draw benchmark takes: --cache, --out (default
    ``out``), --runs, --draws (default ``draws``), --n-test, --families."""
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path(out))
    ap.add_argument("--runs", nargs="+", default=["10:3:1401", "5:2:1501"],
                    help="MOTIONS:REACH:SEED, as bench_machine_draws.py --motions --reach --seed (draws 1000 seeds apart)")
    ap.add_argument("--draws", type=int, default=draws, help="zeros alternate: empty swing, slow lever motion")
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--families", nargs="+", default=["nmpc", "joystick", "multisine", "lever"])
    return ap


def draws(runs: list[str], n: int):
    """Each calibration draw of ``runs`` (``MOTIONS:REACH:SEED``), ``n`` per run: (motions, reach,
    the run's seed, the draw, the draw's seed, its zero motion — empty swing and slow lever in
    turn)."""
    for run in runs:
        motions, reach, seed = (int(x) for x in run.split(":"))
        for draw in range(n):
            yield motions, reach, seed, draw, seed + 1000 * draw, ("empty-swing", "slow-lever")[draw % 2]


def main() -> None:
    ap = draw_arguments(argparse.ArgumentParser(), "efficiency-gap", 4)
    ap.add_argument("--labels", nargs="+", default=["calibrated", "oracle-zero", "oracle"],
                    choices=["calibrated", "oracle-zero", "oracle"])
    ap.add_argument("--noise", nargs="+", default=["field"], choices=list(NOISES),
                    help="test-data noise variants (the calibrations stay on the field preset)")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    rows = []
    for motions, reach, seed, draw, s, zero_kind in draws(a.runs, a.draws):
        est, before_zero = calibrated(a.cache, motions, reach, s, zero_kind)
        for noise in a.noise:
            for name in a.families:
                ds = family(a.cache, name, a.n_test, seed, noise)
                bound = cached(a.cache, f"bound_{name}_{seed}_{draw}_{noise}",
                               lambda: machine_bound(ds, est.calibration, pressure_std=FIELD.pressure_noise))
                ways = {"calibrated": lambda: est, "oracle-zero": lambda: oracle_zero(est, before_zero),
                        "oracle": lambda: oracle(est, noise)}
                for label in a.labels:
                    row = {"motions": motions, "seed": seed, "draw": draw, "zero": zero_kind, "noise": noise,
                           "family": name, "label": label, **split(per_motion(ways[label](), ds, bound))}
                    rows.append(row)
                    print(f"{seed} draw {draw} ({zero_kind:11s}) {noise:13s} {name:10s} {label:11s} "
                          f"eff {row['efficiency']:.2f}  bias {row['cell_bias']:+5.1f}  motions ±"
                          f"{row['motion_spread']:4.1f}  within {row['within']:4.1f}  bound {row['bound']:.1f} kg"
                          f"  ({time.time() - t0:.0f} s)", flush=True)
        pd.DataFrame(rows).to_csv(a.out / "gap.csv", index=False)
    table = pd.DataFrame(rows)
    print("\nmedian over draws (efficiency; kg):")
    print(table.groupby(["noise", "family", "label"], sort=False)[
        ["efficiency", "cell_bias", "motion_spread", "within", "rms", "bound"]].agg(
        lambda x: x.abs().median() if x.name == "cell_bias" else x.median()).round(2).to_string())
    print(f"total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
