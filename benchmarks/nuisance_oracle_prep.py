"""Data and calibrated machines for ``bench_nuisance_oracle.py``, cached (pickled) in a folder.

The cells are those of ``bench_any_motion.py`` (same seeds: test families ``families(n, 9100)``,
calibrations ``calibrations(9200)``, zeros ``zeros(9150)``), so its table and this one speak of
the same calibrated machines.
"""

from __future__ import annotations

import pickle
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_any_motion import MACHINE, _copy, calibrations, zeros  # noqa: E402
from held_out_motions import lever_trajectory  # noqa: E402

from excavator_payload.estimators.classical.calibrated import CalibratedEstimator  # noqa: E402
from excavator_payload.evaluation import demo_machine as dm  # noqa: E402
from excavator_payload.simulation.generate import simulate_dataset  # noqa: E402

#: (calibration, zero): the weak cells of docs/findings/any-motion.md and one good one
CELLS = (("10 swings (study)", "empty swing"), ("5 swings", "empty swing"),
         ("8 operator motions", "slow empty lever motion"), ("8 operator motions", "empty swing"))


def family(name: str, n: int, seed: int):
    common = dict(machine=MACHINE, session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False)
    if name == "nmpc":
        return simulate_dataset(n, seed=seed, motion="nmpc", **common)
    if name == "operator":
        return simulate_dataset(n, seed=seed + 2, motion="operator", **common)
    if name == "lever":
        return dm.simulate_trajectory(lever_trajectory(n, seed + 3), seed + 3, dm.SESSION_WORK)
    raise ValueError(name)


def cached(cache: Path, key: str, make):
    path = cache / (key.replace(" ", "_").replace("(", "").replace(")", "") + ".pkl")
    if path.exists():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    t0 = time.time()
    obj = make()
    with open(path, "wb") as fh:
        pickle.dump(obj, fh)
    print(f"made {key} ({time.time() - t0:.0f} s)", flush=True)
    return obj


def estimator(cache: Path, cal_name: str, zero_name: str, seed: int = 9100):
    """The calibrated and zeroed estimator of a cell (saved with the estimator's own save)."""
    from excavator_payload.estimators import load_estimator

    folder = cache / f"est_{cal_name}_{zero_name}".replace(" ", "_").replace("(", "").replace(")", "")
    if folder.exists():
        return load_estimator(folder)
    base_dir = cache / f"base_{cal_name}".replace(" ", "_").replace("(", "").replace(")", "")
    if base_dir.exists():
        base = load_estimator(base_dir)
    else:
        t0 = time.time()
        base = CalibratedEstimator("cat345c-hydraulic-3pct").fit(calibrations(seed + 100)[cal_name]())
        base.save(base_dir)
        print(f"calibrated {cal_name} ({time.time() - t0:.0f} s)", flush=True)
    zero = cached(cache, f"zero_{zero_name}", lambda: zeros(seed + 50)[zero_name])
    est = _copy(base)
    est.zero(zero)
    est.save(folder)
    return load_estimator(folder)


if __name__ == "__main__":
    cache = Path(sys.argv[1])
    n = int(sys.argv[2])
    cache.mkdir(parents=True, exist_ok=True)
    for fam in ("nmpc", "lever", "operator"):
        cached(cache, f"family_{fam}_{n}", lambda: family(fam, n, 9100))
    for cal_name, zero_name in CELLS:
        estimator(cache, cal_name, zero_name)
    print("done", flush=True)
