"""Compile an exported C model with the system's C compiler and run it on a dataset.

Used by the tests (C output == Python ``estimate``) and ``benchmarks/bench_export.py``
(ns per ``ep_step``, ``sizeof(ep_state)``, code size). The harness program reads samples
from stdin and is not part of the export.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import ExcavatorPayloadError

#: The flags every exported file must compile under without a warning.
STRICT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")

HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "HEADER"

#define MAX_ROWS 200000

static double rows[MAX_ROWS][EP_N_SIGNALS + 1];
static int starts[MAX_ROWS];

int main(int argc, char **argv)
{
    int n = 0, i, j, reps = 0;
    char line[8192];
    ep_state s;
    if (argc > 1 && strcmp(argv[1], "size") == 0) {
        printf("%lu\n", (unsigned long)sizeof(ep_state));
        return 0;
    }
    if (argc > 2 && strcmp(argv[1], "bench") == 0) reps = atoi(argv[2]);
    while (n < MAX_ROWS && fgets(line, sizeof line, stdin)) {
        char *p = line, *end;
        starts[n] = (int)strtol(p, &end, 10);
        p = end;
        for (j = 0; j <= EP_N_SIGNALS; ++j) {
            rows[n][j] = strtod(p, &end);
            p = end;
        }
        ++n;
    }
    if (reps > 0) {
        double sink = 0.0;
        clock_t t0 = clock();
        int r;
        for (r = 0; r < reps; ++r) {
            for (i = 0; i < n; ++i) {
                ep_real v[EP_N_SIGNALS], est;
                if (starts[i]) ep_reset(&s);
                for (j = 0; j < EP_N_SIGNALS; ++j) v[j] = (ep_real)rows[i][j + 1];
                sink += (double)ep_step(&s, (ep_real)rows[i][0], v, &est);
                if (est == est) sink += (double)est;
                est = ep_sigma(&s);  /* the sigma accessor is part of a published sample */
                if (est == est) sink += (double)est;
            }
        }
        printf("%.6f %g\n", 1e9 * (double)(clock() - t0) / CLOCKS_PER_SEC / ((double)reps * n), sink);
        return 0;
    }
    for (i = 0; i < n; ++i) {
        ep_real v[EP_N_SIGNALS], est;
        int status;
        if (starts[i]) ep_reset(&s);
        for (j = 0; j < EP_N_SIGNALS; ++j) v[j] = (ep_real)rows[i][j + 1];
        status = ep_step(&s, (ep_real)rows[i][0], v, &est);
        printf("%.17g %d %.17g\n", (double)est, status, (double)ep_sigma(&s));
    }
    return 0;
}
"""


class CompileError(ExcavatorPayloadError):
    """The C compiler is missing or rejected an exported file."""


def c_compiler() -> str | None:
    """Path of the C compiler on ``PATH`` (``cc``, else ``gcc``), or None when there is none."""
    return shutil.which("cc") or shutil.which("gcc")


@dataclass
class CBuild:
    """A compiled export: the harness binary and the object file of the model.

    Parameters
    ----------
    binary : Path
        The linked harness program (the model and :data:`HARNESS`).
    object_file : Path
        The model's object file (for code and data sizes).
    """

    binary: Path
    object_file: Path

    def text_size(self) -> int:
        """Code size of the model (``.text`` bytes of its object file)."""
        size = shutil.which("size")
        if size is None:
            raise CompileError("no 'size' program")
        out = subprocess.run([size, str(self.object_file)], check=True, capture_output=True,
                             text=True).stdout.splitlines()
        return int(out[1].split()[0])

    def data_size(self) -> tuple[int, int]:
        """(data, bss) bytes of the model's object file (constant tables are in .rodata,
        counted in ``text`` by ``size``)."""
        size = shutil.which("size")
        out = subprocess.run([size, str(self.object_file)], check=True, capture_output=True,
                             text=True).stdout.splitlines()
        parts = out[1].split()
        return int(parts[1]), int(parts[2])

    def state_size(self) -> int:
        """``sizeof(ep_state)`` in bytes."""
        return int(subprocess.run([str(self.binary), "size"], check=True, capture_output=True,
                                  text=True).stdout)

    def run(self, dataset: Dataset, signals=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Estimates, status codes and ``ep_sigma`` of every sample (reset at each experiment).

        Parameters
        ----------
        dataset : Dataset
            The samples to run, reset at the start of each experiment.
        signals : sequence of str, optional
            The columns fed to ``ep_step``, in order (default: the dataset's sensor-set signals).

        Returns
        -------
        estimate : ndarray
            kg, per sample (NaN where none).
        status : ndarray of int
            ``ep_step``'s status code per sample.
        sigma : ndarray
            kg, ``ep_sigma`` after each sample.
        """
        out = subprocess.run([str(self.binary)], input=_rows(dataset, signals), check=True,
                             capture_output=True, text=True, timeout=120).stdout.split()
        est = np.array([float(v) for v in out[0::3]])
        status = np.array([int(v) for v in out[1::3]])
        sigma = np.array([float(v) for v in out[2::3]])
        return est, status, sigma

    def bench(self, dataset: Dataset, repetitions: int) -> float:
        """Mean time of one ``ep_step``, ns (CPU time over all samples × repetitions).

        Parameters
        ----------
        dataset : Dataset
            The samples stepped through (its sensor-set signals).
        repetitions : int
            How many times the whole dataset is stepped.

        Returns
        -------
        float
            ns per ``ep_step`` (CPU time).
        """
        out = subprocess.run([str(self.binary), "bench", str(repetitions)], input=_rows(dataset),
                             check=True, capture_output=True, text=True, timeout=600).stdout
        return float(out.split()[0])


def _rows(dataset: Dataset, signals=None) -> str:
    signals = dataset.sensor_set.signals if signals is None else signals
    exp = dataset.frame["experiment"].to_numpy()
    start = np.r_[True, exp[1:] != exp[:-1]]
    times = dataset.frame["time"].to_numpy(dtype=float)
    values = dataset.signals(signals)
    lines = []
    for k in range(len(times)):
        lines.append(f"{int(start[k])} {float(times[k]).hex()} "
                     + " ".join(float(v).hex() if np.isfinite(v) else str(v) for v in values[k]))
    return "\n".join(lines) + "\n"


def build(c_file: str | Path, folder: str | Path, single: bool = False, optimise: str = "-O2",
          extra_flags: tuple[str, ...] = ()) -> CBuild:
    """Compile ``c_file`` under :data:`STRICT_FLAGS` and link it with the harness.

    Parameters
    ----------
    c_file : str or Path
        The exported ``.c`` file; its ``.h`` must sit beside it.
    folder : str or Path
        Where the object file, harness source and binary are written (created if missing).
    single : bool, optional
        Compile with ``EP_SINGLE=1`` (``float`` arithmetic) instead of ``double``.
    optimise : str, optional
        The optimisation flag passed to the compiler.
    extra_flags : tuple of str, optional
        More compiler flags for the model's object file.

    Returns
    -------
    CBuild
        The harness binary and the model's object file.

    Raises
    ------
    CompileError
        No C compiler, a warning or error in ``c_file``, or the harness does not link.
    """
    cc = c_compiler()
    if cc is None:
        raise CompileError("no C compiler (cc or gcc) on this machine")
    c_file = Path(c_file)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    defines = ["-DEP_SINGLE=1" if single else "-DEP_SINGLE=0"]
    obj = folder / (c_file.stem + (".f32" if single else ".f64") + ".o")
    result = subprocess.run([cc, *STRICT_FLAGS, optimise, *defines, *extra_flags, "-c", str(c_file),
                             "-o", str(obj)], capture_output=True, text=True)
    if result.returncode != 0 or result.stderr.strip():
        raise CompileError(f"{c_file.name} does not compile cleanly:\n{result.stderr}")
    harness = folder / "harness.c"
    harness.write_text(HARNESS.replace("HEADER", str(c_file.with_suffix(".h").resolve())), encoding="utf-8")
    binary = folder / (c_file.stem + ("_f32" if single else "_f64"))
    result = subprocess.run([cc, "-std=c99", optimise, *defines, str(harness), str(obj), "-o",
                             str(binary), "-lm"], capture_output=True, text=True)
    if result.returncode != 0:
        raise CompileError(f"harness does not link:\n{result.stderr}")
    return CBuild(binary, obj)
