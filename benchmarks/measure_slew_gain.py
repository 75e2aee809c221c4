"""A slew rate's scale (gain) error: what it does to the weighing, and whether it is named
(issue 31; docs/sensor-health.md, "The slew rate's scale error on a slope").

On the cached clean chunks of :mod:`bench_false_alarms` (``--seed``; the user's default flow,
``calibrated`` on the 3 % machine file, zeroed), per experiment: the clean run, then the slew
rate scaled from 1.5 s to the experiment's end by each of ``--gains``, and one fault as
:mod:`bench_faults` draws them (× 1 ± 0.1…0.3, onset 1.5 s … end − 2 s, 0.5…3 s long). Per case:
the worst |ok estimate − payload| from the onset on (and the clean run's over the same samples),
whether and when ``slew_rate`` is named, and the house's tilt (its least size over the
experiment). Run it with ``main``'s source and with a branch's on the same chunks to compare.

    PYTHONPATH=src python benchmarks/measure_slew_gain.py --seed 93100 --n 8 \\
        --families nmpc,operator,nmpc-slope5,slopes --out /tmp/slew
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_false_alarms as bfa  # noqa: E402

from excavator_payload.data.dataset import Dataset  # noqa: E402
from excavator_payload.data.io import read_dataset  # noqa: E402


def worst_ok(out: pd.DataFrame, truth: np.ndarray, a: int) -> float:
    """Largest |ok estimate − truth| from sample ``a`` on (NaN: no ok estimate there)."""
    ok = out["status"].astype(str).to_numpy() == "ok"
    ok[:a] = False
    if not ok.any():
        return np.nan
    return float(np.max(np.abs(out["payload_estimate"].to_numpy(float)[ok] - truth[ok])))


def named_after(out: pd.DataFrame, t: np.ndarray, a: int, signal: str = "slew_rate") -> tuple[float, str]:
    """Seconds from sample ``a`` to the first name of ``signal`` (NaN: never), and its kinds."""
    named = out["fault"].astype(str).str.contains(f"{signal}:", regex=False).to_numpy().copy()
    named[:a] = False
    hit = np.flatnonzero(named)
    kinds = sorted({item.split(":")[1] for f in out["fault"].to_numpy()[hit] for item in str(f).split(",")
                    if item.startswith(signal + ":")})
    return (float(t[hit[0]] - t[a]) if len(hit) else np.nan), "/".join(kinds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True, help="the bench_false_alarms chunks' seed")
    ap.add_argument("--families", default="nmpc,work-cycle,operator,lever,joystick,nmpc-slope5,"
                    "lever-slope5,joystick-slope7,slopes")
    ap.add_argument("--n", type=int, default=8, help="experiments per family (the first chunk's first n)")
    ap.add_argument("--gains", default="0.7,1.3", help="factors from 1.5 s to the end")
    ap.add_argument("--cache", type=Path, default=Path("/work/scratch/alarms"))
    ap.add_argument("--out", type=Path, default=Path("slew-gain"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    est = bfa.calibrated("study", a.cache)
    gains = [float(g) for g in a.gains.split(",") if g]
    rng = np.random.default_rng(a.seed)
    rows = []
    for family in a.families.split(","):
        path = next(bfa.chunks(family, 1, a.cache, generate=True, seed=a.seed))[1]
        ds = read_dataset(path, validate=False)
        for e in ds.frame["experiment"].unique()[: a.n]:
            one = ds.frame[ds.frame["experiment"] == e].reset_index(drop=True)
            t = one["time"].to_numpy(float)
            truth = one["payload"].to_numpy(float)
            n = len(one)
            if n < 500:
                continue
            tilt = float(np.min(np.hypot(np.sin(one["house_pitch"]), np.sin(one["house_roll"]))))
            clean = est.estimate(Dataset(one, ds.meta))
            onset = int(np.flatnonzero(t - t[0] >= 1.5)[0])
            draw_a = int(rng.integers(150, n - 200))
            draw_b = min(n, draw_a + int(rng.integers(50, 301)))
            draw_g = 1 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.3)
            cases = [(f"x{g:g} to end", g, onset, n) for g in gains]
            cases.append((f"bench x{draw_g:.2f} {0.01 * (draw_b - draw_a):.1f} s", draw_g, draw_a, draw_b))
            for label, g, lo, hi in cases:
                bad = one.copy()
                w = bad["slew_rate"].to_numpy(float).copy()
                w[lo:hi] *= g
                bad["slew_rate"] = w
                out = est.estimate(Dataset(bad, ds.meta))
                flag_s, kinds = named_after(out, t, lo)
                rows.append({"family": family, "experiment": int(e), "case": label, "gain": g,
                             "least_tilt_deg": np.degrees(tilt), "peak_slew_rate": float(np.abs(one["slew_rate"]).max()),
                             "worst_ok": worst_ok(out, truth, lo), "worst_ok_clean": worst_ok(clean, truth, lo),
                             "ok_share": float((out["status"].astype(str).to_numpy()[lo:hi] == "ok").mean()),
                             "named_s": flag_s, "named_as": kinds,
                             "other_faults": ";".join(sorted({f for f in out["fault"].astype(str).to_numpy()[lo:]
                                                              if f and f != "nan" and "slew_rate" not in f}))[:120]})
            pd.DataFrame(rows).to_csv(a.out / "slew_gain.csv", index=False)
        d = pd.DataFrame(rows)
        d = d[d["family"] == family]
        print(f"{family}: worst ok {d['worst_ok'].max():.0f} kg (clean {d['worst_ok_clean'].max():.0f}), "
              f"slew_rate named {int(d['named_s'].notna().sum())} of {len(d)}", flush=True)
    d = pd.DataFrame(rows)
    d["to_end"] = d["case"].str.contains("to end")
    summary = d.groupby(["family", "to_end"]).agg(cases=("worst_ok", "size"), worst_ok=("worst_ok", "max"),
                                                  worst_clean=("worst_ok_clean", "max"),
                                                  named=("named_s", lambda s: int(s.notna().sum())),
                                                  median_named_s=("named_s", "median"))
    with pd.option_context("display.width", 200):
        print(summary.to_string())
    summary.to_csv(a.out / "summary.csv")


if __name__ == "__main__":
    main()
