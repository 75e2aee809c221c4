"""benchmarks/bench_faults.py's fair time to name: from when a fault's effect on the weighing
(the monitor off against the clean run) first passes 15 kg, not from its onset (a drift from 0
cannot be seen there)."""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_faults import EFFECT_KG, effect_time, in_time  # noqa: E402


def test_effect_time_is_the_first_sample_past_the_limit_after_the_onset():
    t = np.arange(10) * 0.1
    clean = pd.DataFrame({"payload_estimate": np.full(10, 1000.0)})
    off = clean.copy()
    off.loc[1, "payload_estimate"] = 1000.0 + 2 * EFFECT_KG  # before the onset: not counted
    off.loc[6, "payload_estimate"] = np.nan  # not weighed: not counted
    off.loc[7, "payload_estimate"] = 1000.0 - EFFECT_KG - 1.0
    assert np.isclose(effect_time(off, clean, t, 3), 0.4)
    off.loc[7, "payload_estimate"] = 1000.0 - EFFECT_KG  # at the limit: not past it
    assert np.isnan(effect_time(off, clean, t, 3))


def test_in_time_counts_the_cases_that_mattered():
    g = pd.DataFrame({"effect_s": [0.5, 1.0, np.nan, 2.0],
                      "flag_s": [0.3, 1.6, 0.2, np.nan]})  # before it, 0.6 s late, harmless, never
    assert in_time(g) == "1/3 (+0.20 s)"  # the median of -0.2 and +0.6 s
