"""Hostile-input figures for the README: cases tried, crashes, silent wrong results, data lost.

Runs every case of ``tests/test_hostile_cli.py`` (``tests/hostile``; the same code the suite runs) against
the package on ``PYTHONPATH`` and prints one row per group of cases and a total. A case is

* a **crash** if it ends with a traceback, an "internal error", an exit status other than 0
  or 2, or more than one line of error;
* a **silent wrong result** if it exits 0 where an error was due, fails without the expected
  message (e.g. rich markup ate it), or its result is wrong;
* **data lost** if an input file changed, or a failed run left an output that looks valid.

Usage::

    PYTHONPATH=src python benchmarks/hostile_summary.py [--verbose]

(about a minute; point ``PYTHONPATH`` at an older checkout to measure it).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path
from types import SimpleNamespace

HERE = Path(__file__).resolve().parent


def load_cases():
    """The suite's cases and harness (``tests/hostile``), as one namespace."""
    sys.path.insert(0, str(HERE.parent))  # the repository root: ``tests`` is a package there
    from tests import hostile
    from tests.hostile import harness

    return SimpleNamespace(ALL_CASES=hostile.ALL_CASES, build_inputs=harness.build_inputs,
                           run_case=harness.run_case, Outcome=harness.Outcome)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--verbose", action="store_true", help="print every case that is not right")
    args = parser.parse_args()
    cases = load_cases()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            good = cases.build_inputs(tmp / "good")
        rows: dict[str, Counter] = defaultdict(Counter)
        for k, case in enumerate(cases.ALL_CASES):
            inputs, work = tmp / f"c{k}" / "in", tmp / f"c{k}" / "work"
            shutil.copytree(good, inputs)
            work.mkdir()
            out, err = io.StringIO(), io.StringIO()

            def capture():
                o, e = out.getvalue(), err.getvalue()
                out.seek(0), out.truncate(), err.seek(0), err.truncate()
                return o, e

            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    outcome = cases.run_case(case, inputs, work, capture)
                except BaseException as exc:  # the case's own setup broke: count as a crash
                    outcome = cases.Outcome(-1, "", repr(exc), [], [], "crash")
            rows[case.group]["cases"] += 1
            if outcome.problem:
                rows[case.group][outcome.problem] += 1
                if args.verbose:
                    last = (outcome.err.strip().splitlines() or [""])[-1][:160]
                    print(f"{outcome.problem:13s} {case.id}: exit {outcome.code}: {last}", file=sys.stderr)
            shutil.rmtree(tmp / f"c{k}", ignore_errors=True)
    columns = ("cases", "crash", "silent wrong", "data lost")
    print("| group | cases | crashes | silent wrong results | data lost |")
    print("|---|---|---|---|---|")
    total = Counter()
    for group, counts in rows.items():
        total.update(counts)
        print(f"| {group} | " + " | ".join(str(counts[c]) for c in columns) + " |")
    print("| **total** | " + " | ".join(f"**{total[c]}**" for c in columns) + " |")


if __name__ == "__main__":
    main()
