"""Hydraulic machine files: presets, strict loading, round trip."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.errors import MachineError
from excavator_payload.model.hydraulic import HydraulicArmModel
from excavator_payload.model.hydraulic_machine import HydraulicMachine
from excavator_payload.model.machine import Machine, list_presets, load_machine


def test_presets_of_both_kinds_load():
    assert {"cat345c-hydraulic", "cat345c-hydraulic-3pct", "cat345c"} <= set(list_presets())
    nominal = load_machine("cat345c-hydraulic")
    assert isinstance(nominal, HydraulicMachine) and isinstance(load_machine("cat345c"), Machine)
    # the thesis' link lengths and masses
    thesis = load_machine("cat345c")
    assert nominal.boom.length == thesis.boom_length and nominal.bucket.mass == thesis.bucket_mass


def test_three_percent_file_is_about_three_percent_off():
    def numbers(machine):  # every number of the machine file, in file order
        d = machine.to_dict()
        return np.array([x for t in d.values() if isinstance(t, dict) for v in t.values()
                         for x in (v if isinstance(v, list) else [v])], dtype=float)

    nominal = numbers(load_machine("cat345c-hydraulic"))
    off = numbers(load_machine("cat345c-hydraulic-3pct"))
    changed = (nominal != 0) & (off != nominal)
    ratios = np.abs(off[changed] / nominal[changed] - 1)
    assert changed.sum() > 50 and np.all(ratios < 0.031) and np.median(ratios) > 0.029
    # the perturbed machine is still a working machine: the bucket linkage closes on its range
    arm = HydraulicArmModel(load_machine("cat345c-hydraulic-3pct"))
    grid = np.tile([0.2, -1.3, 0.0, 0.0], (200, 1))
    grid[:, 2] = np.linspace(*arm.machine.bucket.angle_range, 200)
    assert np.all(arm.linkage_margin(grid) > 0)


def test_off_by_reproduces_the_3pct_preset_and_keeps_the_limits():
    from excavator_payload.model.hydraulic_machine import off_by

    nominal = load_machine("cat345c-hydraulic")
    assert off_by(nominal, 0.03) == load_machine("cat345c-hydraulic-3pct")
    moved = off_by(nominal, 0.05)
    assert moved.name == "cat345c-hydraulic-5pct"
    assert moved.boom.angle_range == nominal.boom.angle_range and moved.payload.rated == nominal.payload.rated
    assert moved.boom_cylinder.stroke == nominal.boom_cylinder.stroke
    assert abs(moved.house.mass / nominal.house.mass - 1.05) < 1e-12
    assert off_by(nominal, 0.0).to_dict()["boom"] == nominal.to_dict()["boom"]
    with pytest.raises(MachineError, match="fraction"):
        off_by(nominal, float("nan"))


def test_to_toml_parses_back(tmp_path):
    machine = load_machine("cat345c-hydraulic")
    path = tmp_path / "mine.toml"
    path.write_text(machine.to_toml())
    assert load_machine(path) == machine
    assert HydraulicMachine.from_dict(machine.to_dict()) == machine


def _write(tmp_path, edit):
    data = tomllib.loads(load_machine("cat345c-hydraulic").to_toml())
    edit(data)
    path = tmp_path / "m.toml"
    path.write_text(_dump(data))
    return path


def _dump(data):
    from excavator_payload.model.hydraulic_machine import _toml

    lines = [f"{k} = {_toml(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for table, values in data.items():
        if isinstance(values, dict):
            lines.append(f"[{table}]")
            lines += [f"{k} = {_toml(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["boom"].update(colour=1.0), "unknown key.*boom.colour"),
    (lambda d: d.update(wheels=4), "unknown table or key"),
    (lambda d: d["dipper"].pop("mass"), "missing field 'dipper.mass'"),
    (lambda d: d["boom_cylinder"].pop("child_point"), "missing field 'boom_cylinder.child_point'"),
    (lambda d: d["bucket"].update(mass=-1.0), "'bucket.mass' must be a positive"),
    (lambda d: d["hydraulics"].update(relief_pressure=math.inf), "'hydraulics.relief_pressure' must be finite"),
    (lambda d: d["boom"].update(com=[1.0]), "'boom.com' must be a list of 2"),
    (lambda d: d["dipper_cylinder"].update(rod=0.5), "rod' must be smaller than the bore"),
    (lambda d: d["linkage"].update(branch=0), "'linkage.branch' must be 1 or -1"),
    (lambda d: d.pop("linkage"), r"missing table \[linkage\]"),
])
def test_strict_loading_names_the_field(tmp_path, edit, message):
    path = _write(tmp_path, edit)
    with pytest.raises(MachineError, match=message):
        load_machine(path)


def test_machines_command_lists_both_kinds(capsys):
    assert main(["machines"]) == 0
    out = capsys.readouterr().out
    assert "cat345c-hydraulic-3pct" in out and "hydraulic" in out and "2-link" in out
    assert main(["machines", "cat345c-hydraulic"]) == 0
    assert 'kind = "hydraulic"' in capsys.readouterr().out
