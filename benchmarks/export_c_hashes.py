"""Hashes of the generated C of every estimator / sensor set combination the C exporter supports.

Fits small models (few experiments, few epochs) on fixed seeds, exports each in double and in
float, and prints (or checks) the SHA-256 of every ``.h``/``.c`` text. Used to prove that a
refactoring of :mod:`excavator_payload.runtime.export_c` leaves the generated C byte-identical::

    python benchmarks/export_c_hashes.py --write benchmarks/export_c_hashes.json   # before
    python benchmarks/export_c_hashes.py --check benchmarks/export_c_hashes.json   # after

The header embeds the package version, so both runs must use the same version. Both runs must
also be on one kind of CPU: the fitted constants are printed to the last bit, and another CPU's
BLAS kernels sum in another order (an AMD EPYC changed 28 of the 60 files in their last digits).
So does BLAS's thread count (the machine calibrations' constants: 10 machine files differed
between one thread and two): the script runs BLAS on one thread, whatever the environment says.
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy loads BLAS
    os.environ[_name] = "1"

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.generate import simulate_dataset
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

NET = dict(train_experiments=3, validation_experiments=1, epochs=3, progress=False)
HYD = "cat345c-hydraulic"


def models():
    """(label, fitted estimator) for every exported kernel and its options that change the C."""
    swings = simulate_dataset(4, seed=8, workers=1, noise="thesis", progress=False)
    yield "thesis/inverse-dynamics", create_estimator("inverse-dynamics").fit(swings)
    yield "thesis/inverse-dynamics-wrong-machine", create_estimator(
        "inverse-dynamics", machine="cat345c-3pct").fit(swings)
    yield "thesis/calibrated", create_estimator("calibrated", machine="cat345c-3pct").fit(swings)
    yield "thesis/ekf", create_estimator("ekf").fit(swings)
    yield "thesis/ekf-thesis", create_estimator("ekf", tuning="thesis").fit(swings)
    yield "thesis/net1", create_estimator("net1", **NET).fit(swings)
    yield "thesis/ffnn", create_estimator("ffnn", **NET).fit(swings)
    yield "thesis/net2", create_estimator("net2", **NET).fit(swings)
    machine = simulate_machine_dataset(3, seed=3)
    yield "machine/inverse-dynamics", create_estimator("inverse-dynamics", machine=HYD).fit(machine)
    for low_speed in ("skip", "downweight", "model"):
        yield f"machine/calibrated-{low_speed}", create_estimator(
            "calibrated", machine=HYD + "-3pct", low_speed=low_speed, wait_for_boom="no").fit(machine)
    momentum = create_estimator("calibrated", machine=HYD + "-3pct", balance="momentum").fit(machine)
    yield "machine/calibrated-momentum", momentum
    # zeroed: the zero's share of σ per estimate (runtime/export_c/offset_share.py)
    from excavator_payload.evaluation import demo_machine as dm

    momentum.zero(dm.zero_data(seed=6))
    yield "machine/calibrated-momentum-zeroed", momentum
    yield "machine/calibrated-differentiated", create_estimator(
        "calibrated", machine=HYD + "-3pct", balance="differentiated").fit(machine)
    yield "machine/calibrated-new-load", create_estimator(
        "calibrated", machine=HYD + "-3pct", balance="differentiated", new_load="detect").fit(machine)


def hashes() -> dict[str, str]:
    """label/precision/file -> SHA-256 of the generated text."""
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, est in models():
            for precision in ("float64", "float32"):
                folder = Path(tmp) / label / precision
                for path in export_c(est, folder, precision=precision):
                    text = path.read_bytes()
                    out[f"{label}/{precision}/{path.name}"] = hashlib.sha256(text).hexdigest()
                    print(f"{label:42s} {precision} {path.name:28s} {len(text):7d} B", file=sys.stderr)
    return out


def main(argv=None) -> int:
    """Write or check the hashes.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--write FILE`` or ``--check FILE``).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", type=Path, help="store the hashes in this JSON file")
    group.add_argument("--check", type=Path, help="compare with the hashes in this JSON file")
    args = parser.parse_args(argv)
    now = hashes()
    if args.write:
        args.write.write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
        print(f"{len(now)} hashes written to {args.write}")
        return 0
    before = json.loads(args.check.read_text())
    changed = sorted(k for k in before.keys() | now.keys() if before.get(k) != now.get(k))
    for key in changed:
        print(f"DIFFERENT: {key}")
    print(f"{len(now)} files, {len(changed)} different")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
