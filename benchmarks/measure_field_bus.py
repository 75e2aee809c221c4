"""Mixed rates, jitter and bursts against the lock-step log: the numbers of docs/field-bus.md.

    OMP_NUM_THREADS=1 python benchmarks/measure_field_bus.py [N_EXPERIMENTS]

A machine-set dataset (field noise, NMPC-free swings) recorded twice: the 100 Hz lock-step log of
the generated DBC, and the field layout (house inclination at 10 Hz from its own address) with
timestamp jitter and bursts. Both replayed through the same trained model; the estimates are
compared sample by sample (on the model's clock) and at each experiment's end.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

# The field layout is a test fixture (tests/runtime/field_bus.py); this script reuses it.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "runtime"))
from field_bus import write_field_files  # noqa: E402

from excavator_payload.estimators.base import create_estimator  # noqa: E402
from excavator_payload.runtime.can_sensor import PayloadSensor  # noqa: E402
from excavator_payload.runtime.codec import SignalCodec  # noqa: E402
from excavator_payload.runtime.record import record_dataset  # noqa: E402
from excavator_payload.runtime.replay import replay_log  # noqa: E402
from excavator_payload.simulation.machine_sim import simulate_machine_dataset  # noqa: E402


def compare(base, other, period, truth):
    a = base.assign(k=np.round(base["time"] / period).astype(int))
    b = other.assign(k=np.round(other["time"] / period).astype(int))
    m = a.merge(b, on=["experiment", "k"], suffixes=("_a", "_b"))
    both = (m["status_a"] == "ok") & (m["status_b"] == "ok")
    d = (m["payload_estimate_b"] - m["payload_estimate_a"])[both].abs()
    last_a = a[a["status"] == "ok"].groupby("experiment")["payload_estimate"].last()
    last_b = b[b["status"] == "ok"].groupby("experiment")["payload_estimate"].last()
    final = (last_b - last_a).abs()
    err_a = (last_a - truth.reindex(last_a.index)).abs()
    err_b = (last_b - truth.reindex(last_b.index)).abs()
    return {"samples": len(b), "ok": int((b["status"] == "ok").sum()), "ok_base": int((a["status"] == "ok").sum()),
            "stale": int((b["status"] == "stale").sum()), "max": d.max(), "p99": d.quantile(0.99),
            "mean": d.mean(), "final_max": final.max(), "err_base": err_a.max(), "err": err_b.max()}


def main(n=6):
    train = simulate_machine_dataset(8, seed=11)
    data = simulate_machine_dataset(n, seed=12, session=1)
    truth = data.frame.groupby("experiment")["payload"].first()
    truth.index = range(len(truth))
    period = data.sensor_set.sample_period
    rows = []
    for name, machine in (("calibrated", "cat345c-hydraulic-3pct"), ("inverse-dynamics", "cat345c-hydraulic")):
        est = create_estimator(name, machine=machine).fit(train)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            dbc_path, map_path = write_field_files(tmp)
            field = SignalCodec.from_files(data.sensor_set, dbc_path, map_path)
            record_dataset(data, tmp / "lock.blf")
            base = replay_log(tmp / "lock.blf", PayloadSensor(est))
            for label, kw, tolerance in (
                    ("10 Hz inclination", {}, 2.5),
                    ("10 Hz + 1 ms jitter", {"jitter": 0.001}, 2.5),
                    ("10 Hz + 1 ms jitter + bursts every 0.5 s, --stale-tolerance 2.5",
                     {"jitter": 0.001, "burst_every": 0.5}, 2.5),
                    ("same, --stale-tolerance 3.5 (default)", {"jitter": 0.001, "burst_every": 0.5}, 3.5)):
                log = tmp / "field.blf"
                record_dataset(data, log, field, **kw)
                got = replay_log(log, PayloadSensor(est, field, stale_tolerance=tolerance))
                rows.append((name, label, compare(base, got, period, truth)))
    print("| model | field log | samples | ok (lock-step) | stale | max abs diff kg | p99 kg | mean kg "
          "| final diff max kg | final error lock-step / field kg |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, label, r in rows:
        print(f"| {name} | {label} | {r['samples']} | {r['ok']} ({r['ok_base']}) | {r['stale']} | {r['max']:.2f} | "
              f"{r['p99']:.2f} | {r['mean']:.3f} | {r['final_max']:.2f} | {r['err_base']:.1f} / {r['err']:.1f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 6)
