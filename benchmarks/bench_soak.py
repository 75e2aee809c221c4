"""Soak the streaming sensor: memory, step time and estimates over millions of replayed samples.

    python benchmarks/bench_soak.py                          # Python 10^6 samples per path, C 10^7
    python benchmarks/bench_soak.py --python-samples 100000 --c-samples 1000000
    python benchmarks/bench_soak.py --paths step,c           # skip the (slow) CAN path

Protocol: simulate ``--experiments`` minimum-jerk swings of the thesis sensor set (thesis noise,
20 Hz, 101 samples each) and fit ``inverse-dynamics`` on them. The log is these experiments one
after the other with ``--gap`` s of silence between them (new experiments as in a real log), and
it is replayed over and over with the time going on (each copy's stamps shifted by the log's
span plus a gap): the estimator is never reset, every new experiment is a gap in time that its
gap rule handles. Three paths:

* ``can``: :class:`~excavator_payload.runtime.can_sensor.PayloadSensor` fed with the log's CAN
  frames (the generated DBC, 4 frames a sample, each built as a ``can.Message``), and each
  estimate encoded into the frames ``can-run`` would send (``PayloadEstimate``,
  ``VehicleWeight``, DM1).
* ``step``: the estimator's ``step_values`` on the samples directly.
* ``c``: the C export of the same model (``export --format c``, double, -O2) stepped by a small
  C driver (:data:`DRIVER`, not part of the export) over ``--c-samples`` samples, with the time
  going on the same way; the driver reads its own RSS from ``/proc/self/statm``.

Every ``--block`` samples: the process's resident set (``/proc/self/statm``), the CPU time per
sample over the block (CPU, not wall: the machine is shared and wall time measures the others), and each sample against batch ``estimate`` of the log
(``can``: of the log at the DBC's resolution): the estimate within 1e-9 kg (Python) or 1e-6
relative (C, as ``tests/runtime/test_export_c.py``) and the status equal, except at an
experiment's first sample, where the stream's status is ``gap`` (the estimator restarted as the
gap rule says; the same estimate). Reported per path: RSS after the first block and at the end,
its largest value after the first block minus that (the growth; the target is under 1 MB), the
time per sample of the first, slowest, fastest and last block, and the samples that differed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import can  # noqa: E402
import numpy as np  # noqa: E402

from excavator_payload.data.dataset import Dataset  # noqa: E402
from excavator_payload.estimators.base import Status, create_estimator  # noqa: E402
from excavator_payload.runtime.c_harness import STRICT_FLAGS, c_compiler  # noqa: E402
from excavator_payload.runtime.can_sensor import PayloadSensor  # noqa: E402
from excavator_payload.runtime.codec import SignalCodec  # noqa: E402
from excavator_payload.runtime.export_c import export_c  # noqa: E402
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk  # noqa: E402

PAGE_KB = os.sysconf("SC_PAGESIZE") / 1024
STATUS_CODE = {s.value: i for i, s in enumerate(Status)}


def rss_kb() -> float:
    """Resident set of this process, kB (``/proc/self/statm``)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE_KB


@dataclass
class Log:
    """One simulated log as a stream: samples, their stream times, and batch's answer."""

    values: np.ndarray          # samples x signals, SI
    times: np.ndarray           # s, the stream's time of each sample (experiments ``gap`` apart)
    starts: np.ndarray          # bool, an experiment's first sample
    span: float                 # s, shift from one copy to the next
    estimate: np.ndarray        # kg, batch ``estimate`` per sample
    status: list = field(default_factory=list)  # batch status per sample

    def expected_status(self, k: int, i: int) -> str:
        """The stream's status of sample ``i`` of the log as overall sample ``k``."""
        return Status.GAP.value if self.starts[i] and k > 0 else self.status[i]


def make_log(estimator, dataset: Dataset, gap: float, quantise: SignalCodec | None = None) -> Log:
    """The dataset as one stream (experiments ``gap`` s apart) with batch's estimates; values at
    the codec's resolution when ``quantise`` is given (what arrives over CAN)."""
    if quantise is not None:
        frame = dataset.frame.copy()
        frame[list(dataset.sensor_set.signals)] = quantise.quantise(dataset.signals())
        dataset = Dataset(frame, dataset.meta)
    batch = estimator.estimate(dataset)
    exp = dataset.frame["experiment"].to_numpy()
    starts = np.r_[True, exp[1:] != exp[:-1]]
    local = dataset.frame["time"].to_numpy(float)
    times = np.empty_like(local)
    offset = 0.0
    for k in range(len(local)):
        if starts[k] and k > 0:
            offset = times[k - 1] + gap - local[k]
        times[k] = local[k] + offset
    return Log(dataset.signals(), times, starts, float(times[-1] + gap - times[0]),
               batch["payload_estimate"].to_numpy(float), list(batch["status"]))


@dataclass
class Block:
    samples: int       # samples done at the end of the block
    rss_kb: float      # kB
    us: float          # µs of CPU time per sample over the block
    differing: int     # samples whose estimate or status differed from batch
    max_diff: float    # kg, largest |stream - batch| over the block


def _compare(log: Log, k0: int, got_est: np.ndarray, got_status: list, tol: float) -> tuple[int, float]:
    n = len(log.times)
    idx = (k0 + np.arange(len(got_est))) % n
    want = log.estimate[idx]
    both = np.isfinite(want) & np.isfinite(got_est)
    diff = np.abs(got_est[both] - want[both]).max(initial=0.0)
    bad = (np.isfinite(want) != np.isfinite(got_est))
    bad[both] |= np.abs(got_est[both] - want[both]) > tol
    expected = [log.expected_status(k0 + j, i) for j, i in enumerate(idx)]
    bad |= np.array([g != w for g, w in zip(got_status, expected)])
    return int(bad.sum()), float(diff)


def soak_step(estimator, log: Log, samples: int, block: int) -> list[Block]:
    """``step_values`` over ``samples`` samples of the log replayed with the time going on."""
    estimator.reset()
    n = len(log.times)
    blocks = []
    k = 0
    while k < samples:
        m = min(block, samples - k)
        est, status = np.empty(m), []
        t0 = time.process_time()
        for j in range(m):
            i = (k + j) % n
            result = estimator.step_values(log.times[i] + (k + j) // n * log.span, log.values[i])
            est[j] = result.estimate
            status.append(result.status.value)
        us = 1e6 * (time.process_time() - t0) / m
        differing, diff = _compare(log, k, est, status, 1e-9)
        k += m
        blocks.append(Block(k, rss_kb(), us, differing, diff))
    return blocks


def soak_can(estimator, log: Log, codec: SignalCodec, samples: int, block: int) -> list[Block]:
    """:class:`PayloadSensor` over the log's CAN frames, each estimate encoded for the bus."""
    sensor = PayloadSensor(estimator, codec)
    frames = [codec.encode(v) for v in log.values]  # (id, data, extended) per message
    n = len(log.times)
    blocks = []
    k = 0
    while k < samples:
        m = min(block, samples - k)
        est, status = [], []
        sent = 0
        t0 = time.process_time()
        for j in range(m):
            i = (k + j) % n
            stamp = float(log.times[i] + (k + j) // n * log.span)
            for fid, data, ext in frames[i]:
                for output in sensor.feed(can.Message(timestamp=stamp, arbitration_id=fid, data=data,
                                                      is_extended_id=ext), stamp):
                    sent += len(sensor.frames(output))
                    est.append(output.estimate)
                    status.append(output.status)
        us = 1e6 * (time.process_time() - t0) / m
        if len(est) != m:
            raise RuntimeError(f"{m} samples gave {len(est)} estimates")
        differing, diff = _compare(log, k, np.array(est), status, 1e-9)
        k += m
        blocks.append(Block(k, rss_kb(), us, differing, diff))
    return blocks


#: The C soak driver: reads the log (start flag, stream time, signals, batch estimate, batch
#: status code; hex floats) from stdin, steps ``ep_step`` over argv[1] samples of it replayed
#: with the time going on (copy shift argv[3] s), and prints one line a block of argv[2]:
#: samples, RSS kB, CPU ns per sample, samples differing from batch, largest difference kg.
DRIVER = r"""
#define _POSIX_C_SOURCE 200809L  /* sysconf */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>
#include "HEADER"

static long rss_kb(void)
{
    long size = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (f) {
        if (fscanf(f, "%ld %ld", &size, &resident) != 2) resident = 0;
        fclose(f);
    }
    return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

static double now(void)  /* CPU time of the process: the machine is shared */
{
    return (double)clock() / CLOCKS_PER_SEC;
}

int main(int argc, char **argv)
{
    long total, block, n = 0, cap = 1024, k = 0;
    double span;
    int *start, *want_status;
    double *rows, *want;
    ep_state s;
    if (argc < 4) return 2;
    total = atol(argv[1]);
    block = atol(argv[2]);
    span = atof(argv[3]);
    start = malloc(cap * sizeof *start);
    want_status = malloc(cap * sizeof *want_status);
    want = malloc(cap * sizeof *want);
    rows = malloc(cap * (EP_N_SIGNALS + 1) * sizeof *rows);
    for (;;) {
        int j;
        if (n == cap) {
            cap *= 2;
            start = realloc(start, cap * sizeof *start);
            want_status = realloc(want_status, cap * sizeof *want_status);
            want = realloc(want, cap * sizeof *want);
            rows = realloc(rows, cap * (EP_N_SIGNALS + 1) * sizeof *rows);
        }
        if (scanf("%d", &start[n]) != 1) break;
        for (j = 0; j <= EP_N_SIGNALS; ++j)
            if (scanf("%la", &rows[n * (EP_N_SIGNALS + 1) + j]) != 1) return 3;
        if (scanf("%la %d", &want[n], &want_status[n]) != 2) return 3;
        ++n;
    }
    if (n == 0) return 3;
    /* stdio's buffer is allocated at the first line: before the soak, not inside it */
    printf("# %ld samples read, RSS %ld kB\n", n, rss_kb());
    ep_reset(&s);
    while (k < total) {
        long begin = k, end = k + block < total ? k + block : total, differing = 0;
        double worst = 0.0, t0 = now(), dt;
        for (; k < end; ++k) {
            long i = k % n;
            const double *row = &rows[i * (EP_N_SIGNALS + 1)];
            ep_real v[EP_N_SIGNALS], est;
            int j, status, expected = (start[i] && k > 0) ? EP_STATUS_GAP : want_status[i];
            for (j = 0; j < EP_N_SIGNALS; ++j) v[j] = (ep_real)row[j + 1];
            status = ep_step(&s, (ep_real)(row[0] + (double)(k / n) * span), v, &est);
            if (isnan((double)est) != isnan(want[i]) || status != expected) {
                ++differing;
            } else if (!isnan(want[i])) {
                double d = fabs((double)est - want[i]);
                if (d > worst) worst = d;
                if (d > 1e-6 + 1e-6 * fabs(want[i])) ++differing;
            }
        }
        dt = now() - t0;
        printf("%ld %ld %.3f %ld %.6g\n", k, rss_kb(), 1e9 * dt / (double)(end - begin), differing, worst);
        fflush(stdout);
    }
    return 0;
}
"""


def soak_c(estimator, log: Log, samples: int, block: int, folder: Path) -> list[Block]:
    """The C export stepped ``samples`` times by :data:`DRIVER` (double, -O2)."""
    cc = c_compiler()
    if cc is None:
        raise RuntimeError("no C compiler (cc or gcc)")
    header, source = export_c(estimator, folder / "export")
    obj = folder / "model.o"
    subprocess.run([cc, *STRICT_FLAGS, "-O2", "-DEP_SINGLE=0", "-c", str(source), "-o", str(obj)],
                   check=True, capture_output=True, text=True)
    driver = folder / "soak.c"
    driver.write_text(DRIVER.replace("HEADER", str(header.resolve())))
    binary = folder / "soak"
    subprocess.run([cc, "-std=c99", "-O2", "-DEP_SINGLE=0", str(driver), str(obj), "-o", str(binary), "-lm"],
                   check=True, capture_output=True, text=True)
    lines = []
    for i in range(len(log.times)):
        values = " ".join(float(v).hex() for v in log.values[i])
        lines.append(f"{int(log.starts[i])} {float(log.times[i]).hex()} {values} "
                     f"{float(log.estimate[i]).hex() if np.isfinite(log.estimate[i]) else 'nan'} "
                     f"{STATUS_CODE[log.status[i]]}")
    out = subprocess.run([str(binary), str(samples), str(block), repr(log.span)], input="\n".join(lines) + "\n",
                         check=True, capture_output=True, text=True).stdout
    blocks = []
    for line in out.splitlines():
        if line.startswith("#"):
            continue
        k, rss, ns, differing, worst = line.split()
        blocks.append(Block(int(k), float(rss), float(ns) / 1000, int(differing), float(worst)))
    return blocks


def summary(name: str, blocks: list[Block]) -> dict:
    """One row of the table: RSS growth after the first block, time per sample, differences."""
    after = blocks[1:] or blocks
    first_rss = blocks[0].rss_kb
    us = [b.us for b in blocks]
    return {"path": name, "samples": blocks[-1].samples, "rss_first_kb": first_rss,
            "rss_end_kb": blocks[-1].rss_kb, "growth_kb": max(b.rss_kb for b in after) - first_rss,
            "us_first": us[0], "us_max": max(us), "us_min": min(us), "us_last": us[-1],
            "differing": sum(b.differing for b in blocks), "max_diff": max(b.max_diff for b in blocks)}


def print_table(rows: list[dict]) -> None:
    print("| path | samples | RSS after block 1 MB | RSS end MB | growth kB | CPU µs/sample first / max / min / last "
          "block | samples differing from batch | max diff kg |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['path']} | {r['samples']:,} | {r['rss_first_kb'] / 1024:.1f} | {r['rss_end_kb'] / 1024:.1f} | "
              f"{r['growth_kb']:.0f} | {r['us_first']:.3g} / {r['us_max']:.3g} / {r['us_min']:.3g} / "
              f"{r['us_last']:.3g} | {r['differing']} | {r['max_diff']:.2g} |")


def run(paths, experiments: int, gap: float, python_samples: int, can_samples: int, c_samples: int,
        block: int, seed: int = 5, verbose: bool = True) -> list[dict]:
    """The soak of each path in ``paths`` (``can``, ``step``, ``c``); one summary row each."""
    dataset = simulate_minimum_jerk(experiments, seed=seed, noise="thesis")
    estimator = create_estimator("inverse-dynamics").fit(dataset)
    codec = SignalCodec.for_sensor_set(dataset.sensor_set)
    rows = []
    for path in paths:
        t0 = time.perf_counter()
        if path == "step":
            blocks = soak_step(estimator, make_log(estimator, dataset, gap), python_samples, block)
        elif path == "can":
            blocks = soak_can(estimator, make_log(estimator, dataset, gap, codec), codec, can_samples, block)
        elif path == "c":
            with tempfile.TemporaryDirectory() as folder:
                blocks = soak_c(estimator, make_log(estimator, dataset, gap), c_samples, block, Path(folder))
        else:
            raise SystemExit(f"unknown path {path!r}: can, step or c")
        if verbose:
            print(f"{path}: {blocks[-1].samples} samples in {time.perf_counter() - t0:.0f} s; RSS kB per block: "
                  + " ".join(f"{b.rss_kb:.0f}" for b in blocks), file=sys.stderr)
            print(f"{path}: µs/sample per block: " + " ".join(f"{b.us:.3g}" for b in blocks), file=sys.stderr)
        rows.append(summary(path, blocks))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paths", default="c,step,can")
    parser.add_argument("--experiments", type=int, default=4)
    parser.add_argument("--gap", type=float, default=3.0, help="s of silence between experiments")
    parser.add_argument("--python-samples", type=int, default=1_000_000)
    parser.add_argument("--can-samples", type=int, default=None, help="default: --python-samples")
    parser.add_argument("--c-samples", type=int, default=10_000_000)
    parser.add_argument("--block", type=int, default=100_000)
    args = parser.parse_args()
    rows = run(args.paths.split(","), args.experiments, args.gap, args.python_samples,
               args.can_samples or args.python_samples, args.c_samples, args.block)
    print_table(rows)


if __name__ == "__main__":
    main()
