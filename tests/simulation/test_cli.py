"""``excavator-payload simulate`` and ``export-mat`` end to end."""

import scipy.io

from excavator_payload.cli import main
from excavator_payload.data.io import read_dataset


def _default_sigint():
    """A shell's background job (``cmd &``) ignores SIGINT, and Python keeps an ignored SIGINT:
    the child of a suite run that way would never see the Ctrl-C under test."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)

def test_simulate_nmpc_and_export_mat(tmp_path, capsys):
    out = tmp_path / "d.parquet"
    code = main(["simulate", "--experiments", "2", "--seed", "3", "--out", str(out), "--workers", "1",
                 "--noise", "field", "--with-truth", "--quiet"])
    assert code == 0
    text = capsys.readouterr().out
    assert "wrote 2 experiments" in text and "skipped 0" in text and "reached the target" in text
    ds = read_dataset(out)
    assert ds.n_experiments == 2 and ds.meta["noise"] == "field" and ds.has_truth

    mat = tmp_path / "d.mat"
    assert main(["export-mat", "--data", str(out), "--out", str(mat)]) == 0
    cells = scipy.io.loadmat(mat)["dataset"]
    assert cells.shape == (1, 2)
    assert cells[0, 0]["input"][0, 0].shape == (101, 8)


def test_simulate_other_motion(tmp_path, capsys):
    out = tmp_path / "mj.parquet"
    assert main(["simulate", "-n", "3", "--out", str(out), "--motion", "minimum-jerk", "--quiet"]) == 0
    assert read_dataset(out).meta["motion"] == "minimum-jerk"


def test_user_errors_are_one_line(tmp_path, capsys):
    assert main(["simulate", "-n", "2", "--out", str(tmp_path / "x.parquet"), "--noise", "loud"]) == 2
    assert main(["simulate", "-n", "2", "--out", str(tmp_path / "x.parquet"), "--machine", "nope.toml"]) == 2
    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    assert main(["export-mat", "--data", str(bad), "--out", str(tmp_path / "x.mat")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "unknown noise preset" in err and "nope.toml" in err


def test_output_must_be_named_parquet(tmp_path, capsys):
    """`--out x.csv` wrote a Parquet file under a .csv name: refused before simulating."""
    out = tmp_path / "x.csv"
    assert main(["simulate", "-n", "1", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and ".parquet" in err and "x.csv" in err
    assert not out.exists() and not (tmp_path / "x.csv.partial").exists()


def test_ctrl_c_keeps_finished_chunks_and_says_so(tmp_path, capsys, monkeypatch):
    from excavator_payload.simulation import generate

    real = generate.simulate_chunk
    calls = []

    def interrupted(spec, first, count):
        if calls:
            raise KeyboardInterrupt  # Ctrl-C during the second chunk
        calls.append(first)
        return real(spec, first, count)

    monkeypatch.setattr(generate, "simulate_chunk", interrupted)
    out = tmp_path / "d.parquet"
    args = ["simulate", "-n", "3", "--out", str(out), "--workers", "1", "--quiet"]
    assert main(args) == 130
    assert "rerun the same command to resume" in capsys.readouterr().err
    assert not out.exists() and len(list((tmp_path / "d.parquet.partial").glob("chunk_*.parquet"))) == 1
    monkeypatch.setattr(generate, "simulate_chunk", real)
    assert main(args) == 0 and read_dataset(out).n_experiments == 3


def test_bad_scheduler_address_is_one_line(tmp_path, capsys):
    assert main(["simulate", "-n", "2", "--out", str(tmp_path / "x.parquet"), "--scheduler", "nowhere"]) == 2
    err = capsys.readouterr().err
    assert "tcp://HOST:PORT" in err and "Traceback" not in err


def test_real_ctrl_c_on_a_local_cluster_keeps_chunks_and_leaves_no_worker(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C: exit 130 with the message, the
    finished chunks kept, and no worker process left behind."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    import psutil

    import excavator_payload

    src = str(Path(excavator_payload.__file__).resolve().parents[1])
    out = tmp_path / "d.parquet"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", "from excavator_payload.cli import run; run()", "simulate",
                             # enough work that the run is still going when the first chunk lands
                             # (80 finished before the signal on an idle machine)
                             "-n", "400", "--out", str(out), "--workers", "2", "--quiet"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_default_sigint)
    folder = tmp_path / "d.parquet.partial"
    deadline = time.monotonic() + 120
    children = []
    while time.monotonic() < deadline and not list(folder.glob("chunk_*.parquet")) and proc.poll() is None:
        children = psutil.Process(proc.pid).children(recursive=True) or children
        time.sleep(0.2)
    children = psutil.Process(proc.pid).children(recursive=True) or children
    assert list(folder.glob("chunk_*.parquet")), "no chunk finished in time"
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "rerun the same command to resume" in err and "Traceback" not in err
    assert list(folder.glob("chunk_*.parquet")) and not out.exists()
    gone, alive = psutil.wait_procs(children, timeout=20)
    assert not alive


def test_the_motion_help_lists_every_family_of_both_platforms():
    """``simulate --motion``'s help is made from the platforms' motion families (it once missed
    ``reach`` and ``calibration``, added after the help was written by hand)."""
    from excavator_payload.platforms import HYDRAULIC, THESIS
    from excavator_payload.simulation.commands import _motion_help

    text = _motion_help()
    for platform in (THESIS, HYDRAULIC):
        for name, motion in platform.motions.items():
            assert f"{name} (" in text and motion.description in text
    assert "nmpc (default:" in text and "swing (default:" in text
    assert THESIS.default_motion == "nmpc" and HYDRAULIC.default_motion == "swing"
