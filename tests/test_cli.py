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
