"""Where the machine-set weighing's error comes from: the estimator's floor with perfect data.

Usage::

    PYTHONPATH=src python benchmarks/bench_machine_floor.py --n 20 --seed 2026

On NMPC swings with *perfect* sensors (noise preset ``none``) and the *true* machine file, the
only error left in ``calibrated``'s regression is how it obtains what the machine does not
measure: the joint accelerations. This runs the regression of
:mod:`~excavator_payload.estimators.classical.calibrated_machine` (same residual function, same
weights, same forgetting) in batch, with the simulator's true accelerations and with the centred
smoothing differentiator of several half windows, and prints mean MAX / RMS / mean |bias| per
experiment (first second not judged). It also prints the structural residual of a moving
cylinder (kg of payload) on the same noise-free data, true accelerations: what remains of the
model–simulator mismatch.
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

from excavator_payload.estimators.classical import calibrated_machine as cm
from excavator_payload.evaluation import demo_machine as dm
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.machine import load_machine
from excavator_payload.simulation.generate import simulate_dataset


def regression(cal, ds, qdd, forgetting=1.0, pressure_std=3e4):
    """Per-sample estimates of calibrated's recursive weighted regression, in batch."""
    f = ds.frame
    ok = np.all(np.isfinite(qdd), axis=1)
    values = f[list(cm.SIGNALS)].to_numpy(float)
    r, _, lever, speed, stiction = cal.evaluate(values, np.nan_to_num(qdd), np.zeros(len(f)), cal.z)
    phi = -cal._payload_sensitivity
    w = np.where(ok[:, None], cal.weights(lever, speed, stiction, "downweight", pressure_std), 0.0)
    out = np.full(len(f), np.nan)
    exp = f["experiment"].to_numpy()
    for e in np.unique(exp):
        num = info = 0.0
        for i in np.flatnonzero(exp == e):
            num = forgetting * num + w[i] @ (phi[i] * r[i])
            info = forgetting * info + w[i] @ (phi[i] * phi[i])
            out[i] = num / info if info > 0 else np.nan
    return out, speed


def judged(ds, estimate):
    f = ds.frame
    df = pd.DataFrame({"exp": f["experiment"], "t": f["time"], "err": estimate - f["payload"].to_numpy()})
    g = df[df.t >= 1.0].groupby("exp").err
    return {"mean_max_kg": g.apply(lambda x: np.nanmax(np.abs(x))).mean(),
            "mean_rms_kg": g.apply(lambda x: np.sqrt(np.nanmean(x**2))).mean(),
            "mean_abs_bias_kg": g.mean().abs().mean()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2026)
    a = ap.parse_args()
    machine = load_machine("cat345c-hydraulic")
    cal = cm.MachineCalibration(HydraulicArmModel(machine, compiled=False))
    ds = simulate_dataset(a.n, seed=a.seed, machine=machine, motion="nmpc", noise="none",
                          session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    true_qdd = ds.frame[["true_boom_accel", "true_dipper_accel", "true_bucket_accel",
                         "true_slew_accel"]].to_numpy(float)
    rows = []
    estimate, speed = regression(cal, ds, true_qdd)
    f = ds.frame
    r, *_ = cal.evaluate(f[list(cm.SIGNALS)].to_numpy(float), true_qdd, f["payload"].to_numpy(float), cal.z)
    kg = r / cal._payload_sensitivity  # residual at the true payload, in kg of payload
    v_s = np.array([c.stribeck_velocity for c in machine.cylinders])
    moving = np.abs(speed) > 3 * v_s
    print("structural residual of a moving cylinder, kg of payload (median, 95th pct of |.|): "
          + ", ".join(f"{j} {np.median(kg[moving[:, i], i]):+.2f} / {np.percentile(np.abs(kg[moving[:, i], i]), 95):.2f}"
                      for i, j in enumerate(("boom", "dipper", "bucket"))))
    rows.append({"accelerations": "true (simulator)", **judged(ds, estimate)})
    for hw in (3, 5, 8):
        estimate, _ = regression(cal, ds, cm.accelerations(ds, hw))
        rows.append({"accelerations": f"centred differentiator ±{hw}", **judged(ds, estimate)})
    table = pd.DataFrame(rows)
    print(f"perfect sensors, true machine file, {a.n} NMPC swings:")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.1f}"))


if __name__ == "__main__":
    main()
