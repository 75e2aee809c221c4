"""A CAN log played onto a python-can virtual bus, weighed live by the loadout, against the record
of the same log replayed (`loadout --log`).

Usage: python benchmarks/measure_loadout_live.py MODEL LOG DBC MAP LOG_RECORD [TARGET_KG]

The log's frames go onto the bus as fast as the loadout takes them (timestamps kept; the feeder
keeps a few thousand frames queued so the receiver's time-outs never fire on a queue run dry).
Prints the pass and truck counts, the pass weights and totals the bus carried (LoadoutPass,
LoadoutTruck) against what the loadout locked, and against the log record.
"""

from __future__ import annotations

import sys
import threading
import time

import can
import numpy as np

from excavator_payload.estimators.base import load_estimator
from excavator_payload.runtime import dbc
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.codec import SignalCodec
from excavator_payload.runtime.loadout import read_record
from excavator_payload.runtime.loadout_bus import BusLoadout, decode_loadout
from excavator_payload.runtime.loadout_live import run_live
from excavator_payload.runtime.logs import read_frames


def main(model, log, dbc_path, map_path, record, target=None):
    est = load_estimator(model)
    sensor = PayloadSensor(est, SignalCodec.from_files(est.sensor_set, dbc_path, map_path))
    channel = f"measure-{time.time()}"
    bus = can.Bus(interface="virtual", channel=channel)
    feeder = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    listener = can.Bus(interface="virtual", channel=channel)
    loadout = BusLoadout(sensor, target=target, send=True)
    stop = threading.Event()
    result = {}
    worker = threading.Thread(target=lambda: result.update(run_live(bus, loadout, stop)))
    worker.start()
    sent = []
    t0 = time.monotonic()
    for k, frame in enumerate(read_frames(log)):
        while bus.queue.qsize() > 5000:
            time.sleep(0.002)
        feeder.send(frame)
        if k % 2000 == 0:
            while (m := listener.recv(timeout=0)) is not None:
                d = decode_loadout(m)
                if d is not None:
                    sent.append(d)
    while bus.queue.qsize() > 0:
        time.sleep(0.05)
    time.sleep(0.5)
    stop.set()
    worker.join()
    while (m := listener.recv(timeout=0.2)) is not None:
        d = decode_loadout(m)
        if d is not None:
            sent.append(d)
    elapsed = time.monotonic() - t0
    for b in (bus, feeder, listener):
        b.shutdown()
    passes = [p for t in loadout.trucks for p in t.passes]
    frames = [d for d in sent if d["message"] == dbc.LOADOUT_PASS_MESSAGE]
    totals = {}
    for d in sent:
        if d["message"] == dbc.LOADOUT_TRUCK_MESSAGE:
            totals[int(d["TruckNumber"])] = d["TruckTotal"]  # the last one sent for each truck
    bus_vs_locked = np.abs([d["PassWeight"] - p.weight for d, p in zip(frames, passes)])
    totals_vs = np.abs([totals[t.truck] - t.total for t in loadout.trucks])
    rp, rt = read_record(record)
    live_w = np.array([p.weight for p in passes])
    print(f"{elapsed:.0f} s; trucks live / log record: {len(loadout.trucks)} / {len(rt)}; passes "
          f"{len(passes)} / {len(rp)}; LoadoutPass frames {len(frames)}; bus counters {result}")
    print(f"LoadoutPass weight - locked: max {bus_vs_locked.max():.2f} kg; LoadoutTruck total - total: "
          f"max {totals_vs.max():.2f} kg")
    if len(live_w) == len(rp):
        diff = np.abs(live_w - rp["weight"].to_numpy(float))
        tdiff = np.abs(np.array([t.total for t in loadout.trucks]) - rt["total"].to_numpy(float))
        print(f"live - log record: pass weight max {diff.max():.3f} mean {diff.mean():.4f} kg; "
              f"truck total max {tdiff.max():.3f} kg")


if __name__ == "__main__":
    if len(sys.argv) < 6:
        sys.exit(__doc__)  # the usage: too few arguments
    main(*sys.argv[1:6], float(sys.argv[6]) if len(sys.argv) > 6 else None)
