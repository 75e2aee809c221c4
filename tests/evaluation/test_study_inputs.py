"""A study's size said and confirmed before it starts, refused past a limit (issue 31): a study
asking for 10⁹ experiments started without a word, a 10⁶-cell grid hung silently, and
``options`` given as a string crashed with "internal error"."""

from __future__ import annotations

import time

from excavator_payload.cli import main
from excavator_payload.evaluation.study import (
    CONFIRM_CELLS,
    CONFIRM_EXPERIMENTS,
    MAX_CELLS,
    load_study,
    shipped_studies,
    study_experiments,
)


def _study(tmp_path, text: str):
    path = tmp_path / "study.toml"
    path.write_text(text)
    return str(path)


def _one_line(capsys, code) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("study '")]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    return lines[0]


def test_options_as_a_string_is_one_line(tmp_path, capsys):
    config = _study(tmp_path, '[[estimators]]\nname = "net1"\noptions = "epochs=3"\n')
    line = _one_line(capsys, main(["study", "--config", config, "--out", str(tmp_path / "out")]))
    assert "'options' must be a table" in line and "epochs=3" in line


def test_a_billion_experiments_is_refused(tmp_path, capsys):
    config = _study(tmp_path, '[grid]\ntest_experiments = [1000000000]\n[[estimators]]\nname = "inverse-dynamics"\n')
    line = _one_line(capsys, main(["study", "--config", config, "--out", str(tmp_path / "out")]))
    assert "1e+09 experiments" in line and "split the study" in line
    assert not (tmp_path / "out").exists()


def test_a_million_cell_grid_is_refused_at_once(tmp_path, capsys):
    seeds = ", ".join(str(s) for s in range(1000))
    config = _study(tmp_path, f'[grid]\nseed = [{seeds}]\ntest_experiments = [{", ".join(map(str, range(1, 1001)))}]\n'
                              '[[estimators]]\nname = "inverse-dynamics"\n')
    start = time.perf_counter()
    line = _one_line(capsys, main(["study", "--config", config, "--out", str(tmp_path / "out")]))
    assert time.perf_counter() - start < 20  # counted, not built
    assert "1,000,000 cells" in line and f"{MAX_CELLS:,}" in line


def test_a_big_study_says_its_size_and_needs_yes(tmp_path, capsys):
    seeds = ", ".join(str(s) for s in range(10))
    config = _study(tmp_path, f'[grid]\nseed = [{seeds}]\ntest_experiments = [20000]\n'
                              '[[estimators]]\nname = "inverse-dynamics"\n')
    assert study_experiments(load_study(config)) > CONFIRM_EXPERIMENTS
    code = main(["study", "--config", config, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert "study 'study': 10 cells (1 estimator(s)), 201,510 experiments to simulate" in err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(lines) == 1 and "add --yes" in lines[0]
    assert not (tmp_path / "out").exists()


def test_the_shipped_studies_start_without_asking():
    for name in shipped_studies():
        study = load_study(name)
        assert len(study.cells) <= CONFIRM_CELLS and study_experiments(study) <= CONFIRM_EXPERIMENTS, name
