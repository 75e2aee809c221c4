"""The learned sensor beside the model-based one, on the machine set: what each needs, how well
it weighs each motion family, what a step costs in Python and in C, how big it is.

``calibrated`` is calibrated from the recommended mix (``dm.calibration_mix``: 7 swings + 3
``reach`` motions of known load, with the machine file 3 % off) and ``balance-net`` trained on
100 logged experiments with known loads and no machine file (25 swings, 25 work cycles up to
the dump, 20 lifts, 30 ``reach``: the mixture of docs/balance-net.md); both zeroed on the same
empty swing of the weighing session and judged on the same test motions: NMPC swings, work
cycles (to the dump), work cycles on 5° slopes, and the held-out ``joystick`` and ``multisine``
families of ``held_out_motions`` (nothing in ``src/`` is tuned on them). Step cost: the
estimator's ``step_values`` over one test experiment (Python, one thread) and the exported C's
``ep_step`` (``-O2``, double), sizes of the saved folder, the C code and its state.

Usage::

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/bench_sensor_table.py --n-test 8 --seed 12400
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_any_motion import RATED, alarms_and_coverage, zero_part  # noqa: E402
from bench_balance_net import mixture, training_motions  # noqa: E402
from held_out_motions import joystick_trajectory, multisine_trajectory  # noqa: E402

from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.evaluation.crb_machine import dataset_machine_bound  # noqa: E402
from excavator_payload.evaluation.metrics import evaluate_estimates  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402

MACHINE = "cat345c-hydraulic"
BALANCE_NET_MIX = {"swing": 25, "work-cycle": 25, "lifts": 20, "reach": 30}


def test_families(n: int, seed: int) -> dict:
    """The judged families, session 2 (the weighing session)."""
    common = dict(machine=MACHINE, session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    return {
        "NMPC swings": simulate_dataset(n, seed=seed, motion="nmpc", **common),
        "work cycles": dm.before_release(simulate_dataset(n, seed=seed + 1, motion="work-cycle", **common)),
        "work cycles, 5° slope": dm.before_release(simulate_dataset(n, seed=seed + 2, motion="slopes", **common)),
        "joystick (held out)": dm.simulate_trajectory(joystick_trajectory(n, seed + 3), seed + 3, dm.SESSION_WORK),
        "multisine (held out)": dm.simulate_trajectory(multisine_trajectory(n, seed + 4), seed + 4, dm.SESSION_WORK),
    }


def judge(est, ds, bound) -> dict:
    """Share within 1 % of rated, mean MAX and efficiency (against ``bound``), 2σ coverage."""
    frame = est.estimate(ds)
    ev = evaluate_estimates(ds, frame, label="m", bound=bound, with_bound=True, discard=dm.DISCARD)
    return {**dm.summary_row(ev, RATED), **alarms_and_coverage(ds, frame, zero_part(est))}


def step_costs(est, data) -> dict:
    """Python ``step_values`` µs per sample, C ``ep_step`` ns per sample and the sizes."""
    from excavator_payload.runtime.c_harness import build
    from excavator_payload.runtime.export_c import export_c

    values = data.signals(est.sensor_set.signals)
    times = data.frame["time"].to_numpy(float)
    est.reset()
    start = time.process_time()
    for i in range(len(times)):
        est.step_values(times[i], values[i])
    python_us = (time.process_time() - start) / len(times) * 1e6
    folder = Path(tempfile.mkdtemp())
    est.save(folder / "model")
    paths = export_c(est, folder / "c")
    binary = build(paths[1], folder / "b")
    return {"python_us": python_us, "c_ns": binary.bench(data, 20), "c_text_kB": binary.text_size() / 1024,
            "c_state_kB": binary.state_size() / 1024, "c_file_kB": paths[1].stat().st_size / 1024,
            "model_kB": sum(p.stat().st_size for p in (folder / "model").rglob("*") if p.is_file()) / 1024}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--seed", type=int, default=12400)
    a = ap.parse_args()
    t0 = time.time()
    tests = test_families(a.n_test, a.seed)
    zero = dm.zero_data(a.seed + 50)
    calibration = dm.calibration_mix(10, a.seed + 100, MACHINE)
    logged = mixture(training_motions(BALANCE_NET_MIX, a.seed + 200), BALANCE_NET_MIX)
    print(f"data simulated ({time.time() - t0:.0f} s)", flush=True)
    sensors = {}
    start = time.process_time()
    sensors["calibrated"] = create_estimator("calibrated", MACHINE + "-3pct").fit(calibration)
    fit_cpu = {"calibrated": time.process_time() - start}
    start = time.process_time()
    sensors["balance-net"] = create_estimator("balance-net", None).fit(logged)
    fit_cpu["balance-net"] = time.process_time() - start
    needs = {"calibrated": f"machine file (3 % off) + {calibration.n_experiments} motions of known load",
             "balance-net": f"{logged.n_experiments} logged motions of known load, no machine file"}
    for est in sensors.values():
        est.zero(zero)
    # one bound per family for both: the calibrated model's (what a model-based sensor with
    # this calibration could reach on the information in the motion)
    bounds = {family: dataset_machine_bound(ds, sensors["calibrated"]) for family, ds in tests.items()}
    rows = []
    for name, est in sensors.items():
        row = {"sensor": name, "needs": needs[name], "fit_cpu_s": fit_cpu[name]}
        for family, ds in tests.items():
            r = judge(est, ds, bounds[family])
            row[family] = (f"{100 * r['within_1pct']:.0f} % · {r['mean_max_kg']:.1f} kg · "
                           f"{r['efficiency']:.2f} · {100 * r['sigma_covers']:.0f} %")
        row.update(step_costs(est, tests["NMPC swings"].subset(tests["NMPC swings"].experiment_ids[:1])))
        rows.append(row)
        print(row, flush=True)
    head = ["sensor", "needs", "fit CPU s", *tests, "Python µs/step", "C ns/step", "C code kB", "C state kB",
            "saved kB"]
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for r in rows:
        cells = [r["sensor"], r["needs"], f"{r['fit_cpu_s']:.0f}", *(r[f] for f in tests),
                 f"{r['python_us']:.0f}", f"{r['c_ns']:.0f}", f"{r['c_text_kB']:.1f}", f"{r['c_state_kB']:.1f}",
                 f"{r['model_kB']:.0f}"]
        print("| " + " | ".join(cells) + " |")
    print(f"cells: within 1 % of rated · mean MAX · efficiency (the calibrated model's bound) · 2σ covers; "
          f"rated {RATED:g} kg; {time.time() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
