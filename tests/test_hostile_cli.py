"""The command line against a hostile or careless user.

Each case runs ``excavator_payload.cli.main(argv)`` in-process on copies of small inputs (a
tiny dataset, a field log, calibration lifts, trained models, machine files) and asserts one
of two outcomes:

* ``error``: exit status 2 and exactly one readable line on stderr (no traceback, no rich
  markup eaten: an expected fragment of the message is checked where it matters);
* ``ok``: exit status 0 and a correct result (checked by the case).

and, always: no input file changed, and after a failure no output left that looks valid.
A few cases run a real subprocess (Ctrl-C, ``--version``).

``benchmarks/hostile_summary.py`` runs the same cases and prints the table for the README.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .hostile import ALL_CASES
from .hostile.harness import build_inputs, run_case


# -- the tests ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_inputs(tmp_path_factory):
    return build_inputs(tmp_path_factory.mktemp("hostile-inputs"))


def test_enough_cases():
    assert len(ALL_CASES) >= 300
    assert len({c.id for c in ALL_CASES}) == len(ALL_CASES)


@pytest.mark.parametrize("case", ALL_CASES, ids=[c.id for c in ALL_CASES])
def test_hostile_case(case, good_inputs, tmp_path, capsys):
    inputs = tmp_path / "in"
    shutil.copytree(good_inputs, inputs)
    work = tmp_path / "work"
    work.mkdir()

    def capture():
        got = capsys.readouterr()
        return got.out, got.err

    outcome = run_case(case, inputs, work, capture)
    assert outcome.problem is None, (f"{outcome.problem}: exit {outcome.code}\nstderr:\n{outcome.err}\n"
                                     f"stdout:\n{outcome.out[-2000:]}\nchanged: {outcome.inputs_changed}\n"
                                     f"half-written: {outcome.half_written}")


# -- real processes -------------------------------------------------------------------------------
def _default_sigint():
    # a shell's background job (``cmd &``) ignores SIGINT, and Python keeps an ignored SIGINT:
    # the child of a suite run that way would never see the Ctrl-C under test
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _cli(*args, **kwargs):
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    return subprocess.Popen([sys.executable, "-m", "excavator_payload.cli", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint, **kwargs)


def test_version_in_a_real_process():
    proc = _cli("--version")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and out.startswith("excavator-payload "), err


def test_ctrl_c_says_nothing_is_half_written(good_inputs, tmp_path):
    proc = _cli("train", "net1", "--data", str(good_inputs / "data.parquet"), "--out", str(tmp_path / "m"),
                "--train-experiments", "4", "--validation-experiments", "2", "--epochs", "100000")
    deadline = time.time() + 120
    while time.time() < deadline and not (tmp_path / "m").exists():
        time.sleep(0.5)
        if proc.poll() is not None:
            break
        # training has started once the process is past its imports; give it a moment
        if time.time() > deadline - 110:
            break
    time.sleep(4)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "half-written" in err and "Traceback" not in err
    assert not (tmp_path / "m" / "estimator.json").exists()  # nothing half-saved looks valid


def test_crash_in_a_real_process_is_one_line(tmp_path):
    proc = _cli("estimate", "--model", str(tmp_path / "[bucket]"), "--data", "x", "--out", "y.parquet")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert err.strip().count("\n") == 0 and "[bucket]" in err


def test_concurrent_runs_into_one_output(good_inputs, tmp_path):
    """Two trainings saving the same folder and two estimates writing the same file at once:
    both finish and what is left is one complete, loadable result."""
    from excavator_payload.data.io import read_estimates
    from excavator_payload.estimators import load_estimator

    procs = [_cli("train", "inverse-dynamics", "--data", str(good_inputs / "data.parquet"),
                  "--out", str(tmp_path / "m")) for _ in range(2)]
    procs += [_cli("estimate", "--model", str(good_inputs / "model"), "--data", str(good_inputs / "data.parquet"),
                   "--out", str(tmp_path / "e.parquet")) for _ in range(2)]
    for proc in procs:
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    load_estimator(tmp_path / "m")
    assert len(read_estimates(tmp_path / "e.parquet")) == 606
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["arrays.npz", "estimator.json"]
