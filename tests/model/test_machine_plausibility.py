"""Machine-file numbers against what a machine of that size can be (issue 31): a centre of mass in
cm, a pump flow in L/min, a slew rate in °/s were accepted and used. Through ``excavator-payload
machines FILE``: exit status 2 and one line naming the field and the unit the number makes sense
in; the presets and machines of other sizes still load.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from excavator_payload.cli import main
from excavator_payload.model.machine import list_presets, load_machine

ROOT = Path(__file__).resolve().parents[2]


def _preset_text() -> str:
    return load_machine("cat345c-hydraulic").to_toml()


def _set(table: str, key: str, value: str):
    """Replace ``key = ...`` inside ``[table]`` of the preset's machine file."""
    def edit(text: str) -> str:
        head, rest = text.split(f"[{table}]\n", 1)
        body, sep, tail = rest.partition("\n[")
        body, n = re.subn(rf"^{key} = .*$", f"{key} = {value}", body, count=1, flags=re.M)
        assert n == 1, (table, key)
        return f"{head}[{table}]\n{body}{sep}{tail}"
    return edit


CASES = {
    # name: (edit, fragments the one line must hold)
    "bucket-com-in-cm": (_set("bucket", "com", "[75.0, -30.0]"), ("'bucket.com'", "in cm?")),
    "payload-position-in-mm": (_set("payload", "position", "[800.0, -350.0]"), ("'payload.position'", "in mm?")),
    "bore-in-cm": (_set("boom_cylinder", "bore", "19.0"), ("'boom_cylinder.bore'", "in cm?")),
    "pump-flow-in-l-min": (_set("hydraulics", "pump_flow", "750.0"), ("'hydraulics.pump_flow'", "L/min")),
    "slew-rate-in-deg-s": (_set("house", "max_slew_rate", "40.0"), ("'house.max_slew_rate'", "in °/s?")),
    "slew-rate-in-rpm": (_set("house", "max_slew_rate", "6.7"), ("'house.max_slew_rate'", "rpm")),
    "relief-in-bar": (_set("hydraulics", "relief_pressure", "324.0"), ("'hydraulics.relief_pressure'", "in bar?")),
    "relief-in-mpa": (_set("hydraulics", "relief_pressure", "32.4"), ("'hydraulics.relief_pressure'", "MPa")),
    "slew-torque-in-knm": (_set("house", "max_slew_torque", "150.0"), ("'house.max_slew_torque'", "in kN·m?")),
    "boom-mass-in-t": (_set("boom", "mass", "4.6"), ("'boom.mass'", "in t?")),
    "house-mass-in-t": (_set("house", "mass", "20.0"), ("'house.mass'", "in t?")),
    "rated-payload-in-t": (_set("payload", "rated", "5.0"), ("'payload.rated'", "in t?")),
    "stribeck-velocity-in-mm-s": (_set("dipper_cylinder", "stribeck_velocity", "10.0"), ("stribeck_velocity", "mm/s")),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_number_in_another_unit_is_named(tmp_path, capsys, name):
    edit, fragments = CASES[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(edit(_preset_text()))
    code = main(["machines", str(path)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_presets_and_machines_of_other_sizes_load(tmp_path):
    for name in list_presets():
        load_machine(name)
    spec = importlib.util.spec_from_file_location("scaled_machine", ROOT / "benchmarks" / "scaled_machine.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for factor in (0.3, 0.5, 1.3, 2.0):  # a ~1.2-t mini excavator to a ~360-t machine
        machine = module.scaled(factor)
        path = tmp_path / f"scaled-{factor}.toml"
        path.write_text(machine.to_toml())
        assert main(["machines", str(path)]) == 0
