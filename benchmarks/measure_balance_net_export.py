"""Measure balance-net's exports (docs/balance-net-export.md): step cost in C, Python and ONNX
(graph alone and with the host loop), sizes. Run:
``OMP_NUM_THREADS=1 python benchmarks/measure_balance_net_export.py``."""

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from excavator_payload.runtime.c_harness import build
from excavator_payload.runtime.export_c import export_c
from excavator_payload.runtime.export_onnx import export_onnx
from excavator_payload.runtime.export_onnx_balance import STATE, OnnxBalanceNet

# The two trained models are the export tests' fixtures; this script times them.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.runtime.test_export_balance_net import _machine, _thesis  # noqa: E402


def main() -> None:
    for name, (est, data) in (("thesis", _thesis()), ("machine", _machine())):
        folder = Path(tempfile.mkdtemp())
        values = data.signals(est.sensor_set.signals)
        times = data.frame["time"].to_numpy(float)
        n = len(times)
        est.reset()
        t0 = time.perf_counter()
        for k in range(3):
            est.reset()
            for i in range(n):
                est.step_values(times[i], values[i])
        py = (time.perf_counter() - t0) / (3 * n) * 1e6
        paths = export_c(est, folder / "c")
        b = build(paths[1], folder / "b")
        c_ns = b.bench(data, 200)
        onnx_path = export_onnx(est, folder / "o")[0]
        runner = OnnxBalanceNet(onnx_path)
        t0 = time.perf_counter()
        for i in range(n):
            runner.step_values(times[i], values[i])
        host = (time.perf_counter() - t0) / n * 1e6
        feed = {"signals": values[n // 2], **runner.state}
        t0 = time.perf_counter()
        for _ in range(2000):
            runner.session.run(None, feed)
        graph = (time.perf_counter() - t0) / 2000 * 1e6
        model = folder / "model"
        est.save(model)
        print(f"{name}: {n} samples; Python step {py:.1f} us; C step {c_ns:.0f} ns (-O2); ONNX graph "
              f"{graph:.0f} us, with host loop {host:.0f} us; C .text {b.text_size()} B, sizeof(ep_state) "
              f"{b.state_size()} B, .c {paths[1].stat().st_size} B; ONNX {os.path.getsize(onnx_path)} B, "
              f"{len(runner.session.get_inputs()) - 1} state inputs ({', '.join(STATE)}); model folder "
              f"{sum(p.stat().st_size for p in model.iterdir())} B; width {est.model.width}, "
              f"{est.model.layout.n} channels, {int(np.count_nonzero(est.model.coef))} coefficients")


if __name__ == "__main__":
    main()
