"""The command line as a user meets it: clear errors, exit codes, no tracebacks."""

from excavator_payload.cli import main
from excavator_payload.model.machine import load_machine


def test_machines_lists_presets(capsys):
    assert main(["machines"]) == 0
    out = capsys.readouterr().out
    assert "cat345c-3pct" in out


def test_machine_template_round_trips(tmp_path, capsys):
    assert main(["machines", "cat345c-1pct"]) == 0
    path = tmp_path / "mine.toml"
    path.write_text(capsys.readouterr().out)
    assert load_machine(path) == load_machine("cat345c-1pct")


def test_bad_machine_file_names_the_field(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(load_machine("cat345c").to_toml().replace("[bucket]\nmass = 2900.0", "[bucket]\nmass = 'heavy'"))
    assert main(["machines", str(path)]) == 2
    err = capsys.readouterr().err
    assert "bucket.mass" in err and "Traceback" not in err


def test_unknown_estimator_is_a_clear_error(tmp_path, capsys):
    assert main(["train", "no-such", "--data", str(tmp_path / "x.parquet"), "--out", str(tmp_path / "m")]) == 2
    assert "unknown estimator" in capsys.readouterr().err


def test_missing_dataset_is_a_clear_error(tmp_path, capsys):
    code = main(["estimate", "--model", str(tmp_path / "m"), "--data", str(tmp_path / "x.parquet"),
                 "--out", str(tmp_path / "e.parquet")])
    assert code == 2
    assert "does not exist" in capsys.readouterr().err


def _run(args, env_update, cwd=None):
    import os
    import subprocess
    import sys
    from pathlib import Path

    src = str(Path(__file__).resolve().parents[1] / "src")
    env = {**os.environ, "PYTHONPATH": src, **env_update}
    return subprocess.run([sys.executable, "-m", "excavator_payload.cli", *args], capture_output=True,
                          env=env, cwd=cwd, timeout=120)


def test_a_console_that_cannot_show_unicode_gets_replacements_not_a_crash():
    """An ASCII or cp1252 console (a serial terminal, Windows): the "—", "σ" and "≤" of the
    tables raised UnicodeEncodeError, an internal error after the work was done."""
    for encoding in ("ascii", "cp1252"):
        done = _run(["estimators", "calibrated"], {"PYTHONIOENCODING": encoding})
        assert done.returncode == 0, done.stderr.decode(errors="replace")
        assert b"?" in done.stdout and b"internal error" not in done.stderr


def test_files_are_utf8_in_a_c_locale(tmp_path):
    """Under LC_ALL=C without UTF-8 mode the shift report (its "—" for a truck without a target)
    was written in the locale's ASCII: an internal error, and no report."""
    from excavator_payload.runtime.loadout import Pass, Truck
    from excavator_payload.runtime.shift_record import ShiftRecord

    record = ShiftRecord(tmp_path / "s.sqlite")
    run = record.start_run("src", "d", "m")
    record.write_truck("src", run, Truck(1, [Pass(1, 1, 1.0, 2.0, 1.5, 4000.0, 20.0, "ok")], target=None))
    record.finish_run(run)
    record.close()
    done = _run(["report", "--db", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "r")],
                {"LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONIOENCODING": ""})
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    assert "| — |" in (tmp_path / "r" / "shift.md").read_text(encoding="utf-8")


def test_a_deleted_current_folder_is_named(tmp_path, capsys):
    """A relative --out in a folder deleted under us was "error: No such file or directory"."""
    gone = tmp_path / "gone"
    gone.mkdir()
    import os

    here = os.getcwd()
    os.chdir(gone)
    try:
        gone.rmdir()
        code = main(["can-dbc", "--out", "x.dbc"])
    finally:
        os.chdir(here)
    assert code == 2 and "the current folder was deleted" in capsys.readouterr().err
