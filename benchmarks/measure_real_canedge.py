"""Our sensor frames inside a real vehicle's bus: the numbers of docs/field-bus.md ("A real logger's file").

    python benchmarks/measure_real_canedge.py REAL.MF4 DATA.parquet MODEL_DIR OUT_DIR

REAL.MF4 is a CAN log from a real CANedge logger (e.g. the public J1939 sample files of
CSS-Electronics/api-examples; not shipped here). Every frame of it is merged, by time, with the
frames `can-record` makes of DATA (a machine-set dataset), and written as one CANedge-style MF4
(a CAN_DataFrame bus-event group, standard and extended ids, the real frames' own lengths). Both
the clean log and the merged one are replayed through MODEL_DIR: the statuses and the estimates
must be the same, whatever the real bus carries (other ECUs, our proprietary PGNs from another
source address, 11-bit ids).
"""

import sys
from pathlib import Path

import can
import numpy as np

from excavator_payload.data.io import read_dataset
from excavator_payload.estimators.base import load_estimator
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.logs import read_frames
from excavator_payload.runtime.record import record_dataset
from excavator_payload.runtime.replay import replay_log

# The CANedge-layout writer is a test fixture (tests/runtime/field_bus.py); this script reuses it.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "runtime"))
from field_bus import write_canedge_mf4  # noqa: E402


def main(real: str, data: str, model: str, out: str) -> None:
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    real_frames = list(read_frames(real))
    start = real_frames[0].timestamp
    print(f"real log: {len(real_frames)} frames over {real_frames[-1].timestamp - start:.1f} s")
    clean = out_dir / "ours.blf"
    record_dataset(read_dataset(data), clean, start_time=start + 5.0)
    ours = list(can.LogReader(str(clean)))
    print(f"ours: {len(ours)} frames over {ours[-1].timestamp - ours[0].timestamp:.1f} s")
    merged = write_canedge_mf4(sorted(real_frames + ours, key=lambda f: f.timestamp), out_dir / "merged.MF4")
    a = replay_log(clean, PayloadSensor(load_estimator(model)))
    b = replay_log(merged, PayloadSensor(load_estimator(model)))
    ok = (a["status"] == "ok").to_numpy() & (b["status"] == "ok").to_numpy()
    diff = np.abs(a["payload_estimate"].to_numpy()[ok] - b["payload_estimate"].to_numpy()[ok])
    print(f"samples {len(a)} / {len(b)}; statuses equal {np.mean(a['status'].to_numpy() == b['status'].to_numpy()):.4f}; "
          f"ok in both {ok.sum()}; largest |difference| {diff.max() if len(diff) else float('nan'):.3g} kg")
    print("clean:", a["status"].value_counts().to_dict(), "merged:", b["status"].value_counts().to_dict())


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    main(*sys.argv[1:5])
