"""Benchmark the C export: time per ``ep_step``, ``sizeof(ep_state)`` and code size of each model,
against Python's ``step()``; and the CAN replay throughput.

    python benchmarks/bench_export.py                  # all C-exportable models, 20 experiments
    python benchmarks/bench_export.py --experiments 50 --repetitions 400
    python benchmarks/bench_export.py --models machine:inverse-dynamics,machine:calibrated

Protocol: simulate ``--experiments`` NMPC experiments (thesis noise), fit each estimator
(networks: a few epochs only: the cost of a step does not depend on the weights' values),
export to C, compile with the system's ``cc`` (-O2, strict C99 flags), and run every sample of
every experiment ``--repetitions`` times (reset at each experiment start), in double and in
float (``-DEP_SINGLE=1``). Reported: CPU ns per ``ep_step`` (mean over all samples, so warm-up
and the estimate both count), ``sizeof(ep_state)`` in bytes, the model's object-file ``.text``
(code + constant tables) in bytes, Python ``step_values`` µs per sample for comparison, and the
largest difference between the float build's estimates and Python's ``estimate`` (kg, on the
same samples).

Models named ``machine:NAME`` are fitted on the machine sensor set instead: ``--experiments``
swings of the hydraulic machine (``simulate --machine cat345c-hydraulic``, field noise, 100 Hz;
``calibrated`` starts from the 3 %-off file ``cat345c-hydraulic-3pct``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.runtime.c_harness import build  # noqa: E402
from excavator_payload.runtime.export_c import export_c  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402
from excavator_payload.simulation.machine_sim import simulate_machine_dataset  # noqa: E402

MODELS = {
    "inverse-dynamics": {},
    "calibrated": {"machine": "cat345c-3pct"},
    "ekf": {},
    "net1": {"epochs": 3, "progress": False},
    "net2": {"epochs": 3, "progress": False},
    "machine:inverse-dynamics": {"machine": "cat345c-hydraulic"},
    "machine:calibrated": {"machine": "cat345c-hydraulic-3pct"},
    "machine:calibrated-momentum": {"machine": "cat345c-hydraulic-3pct", "balance": "momentum"},
}


def python_step_us(est, dataset, limit: int = 2000) -> float:
    """Mean µs of ``step_values`` over the first ``limit`` samples (reset at experiment starts)."""
    times = dataset.frame["time"].to_numpy(float)[:limit]
    values = dataset.signals()[:limit]
    exp = dataset.frame["experiment"].to_numpy()[:limit]
    start = np.r_[True, exp[1:] != exp[:-1]]
    t0 = time.perf_counter()
    for k in range(len(times)):
        if start[k]:
            est.reset()
        est.step_values(times[k], values[k])
    return 1e6 * (time.perf_counter() - t0) / len(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiments", type=int, default=20)
    parser.add_argument("--repetitions", type=int, default=200)
    parser.add_argument("--models", default=",".join(MODELS))
    args = parser.parse_args()
    torch.set_num_threads(1)
    names = args.models.split(",")
    thesis = simulate_dataset(args.experiments, seed=31, workers=1, noise="thesis", progress=False) \
        if any(not n.startswith("machine:") for n in names) else None
    machine = simulate_machine_dataset(args.experiments, seed=31) \
        if any(n.startswith("machine:") for n in names) else None
    n_train = max(1, args.experiments - 1)
    sizes = ", ".join(f"{d.sensor_set.name} set {len(d)} samples" for d in (thesis, machine) if d is not None)
    print(f"{args.experiments} experiments ({sizes}), {args.repetitions} repetitions; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"{'model':26s} {'C f64 ns':>9s} {'C f32 ns':>9s} {'state f64 B':>11s} {'state f32 B':>11s} "
          f"{'text f64 B':>10s} {'text f32 B':>10s} {'Python µs':>9s} {'f32 max kg':>10s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            options = dict(MODELS[name])
            dataset = machine if name.startswith("machine:") else thesis
            estimator = name.split(":")[-1].split("-momentum")[0]  # machine:calibrated-momentum
            if estimator.startswith("net"):
                options.update(train_experiments=n_train, validation_experiments=1)
            est = create_estimator(estimator, **options).fit(dataset)
            folder = Path(tmp) / name.replace(":", "_")
            paths = export_c(est, folder)
            row = {}
            for single in (False, True):
                b = build(paths[1], folder / "build", single=single)
                row[single] = (b.bench(dataset, args.repetitions), b.state_size(), b.text_size())
                if single:
                    want = est.estimate(dataset)["payload_estimate"].to_numpy()
                    got = b.run(dataset)[0]
                    both = np.isfinite(want) & np.isfinite(got)
                    f32_error = float(np.abs(got[both] - want[both]).max())
            py = python_step_us(est, dataset)
            print(f"{name:26s} {row[False][0]:9.1f} {row[True][0]:9.1f} {row[False][1]:11d} "
                  f"{row[True][1]:11d} {row[False][2]:10d} {row[True][2]:10d} {py:9.1f} {f32_error:10.4f}")


if __name__ == "__main__":
    main()
