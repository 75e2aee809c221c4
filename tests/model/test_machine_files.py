"""Machine files: presets load; a bad TOML file gives a MachineError that names the field."""

import math

import pytest

from excavator_payload.errors import MachineError
from excavator_payload.model.machine import Machine, list_presets, load_machine

GOOD = """
name = "test-arm"
[boom]
length = 6.55
mass = 4600.0
friction = 3.0e5
angle_range = [-0.7854, 1.0472]
torque_limit = 4.0e6
[dipper]
length = 3.0
mass = 2410.0
friction = 3.0e5
angle_range = [-2.618, -0.2618]
torque_limit = 2.0e6
[bucket]
mass = 2900.0
[payload]
rated = 5000.0
max = 5000.0
"""


def _write(tmp_path, text, name="arm.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["cat345c", "cat345c-1pct", "cat345c-3pct"])
def test_presets_load(name):
    machine = load_machine(name)
    assert machine.name == name
    assert name in list_presets()
    assert machine.boom_inertia == pytest.approx(machine.boom_mass * machine.boom_length**2 / 12)
    assert all(math.isfinite(v) and v > 0 for v in machine.parameter_vector)
    assert machine.boom_angle_range[0] < machine.boom_angle_range[1]


def test_wrong_presets_really_differ_from_the_true_machine():
    true, one, three = (load_machine(n) for n in ("cat345c", "cat345c-1pct", "cat345c-3pct"))
    assert one.parameter_vector.tolist() != true.parameter_vector.tolist()
    assert three.parameter_vector.tolist() != one.parameter_vector.tolist()


def test_good_file_loads_and_round_trips(tmp_path):
    machine = load_machine(_write(tmp_path, GOOD))
    assert machine.name == "test-arm"
    assert machine.dipper_torque_limit == 2.0e6
    again = load_machine(_write(tmp_path, machine.to_toml(), "again.toml"))
    assert again == machine
    assert Machine.from_dict(machine.to_dict()) == machine


@pytest.mark.parametrize(
    "old, new, field",
    [
        ("mass = 4600.0\n", "", "boom.mass"),  # missing field
        ("length = 3.0\n", 'length = "three"\n', "dipper.length"),  # not a number
        ("[bucket]\nmass = 2900.0", "[bucket]\nmass = -2900.0", "bucket.mass"),  # negative mass
        ("angle_range = [-0.7854, 1.0472]", "angle_range = [1.0472, -0.7854]", "boom.angle_range"),
        ("angle_range = [-2.618, -0.2618]", "angle_range = [-2.618]", "dipper.angle_range"),
        ("friction = 3.0e5\nangle_range = [-0.7854", "friction = -1.0\nangle_range = [-0.7854",
         "boom.friction"),
        ("torque_limit = 2.0e6", "torque_limit = 0", "dipper.torque_limit"),
        ("length = 6.55", "length = true", "boom.length"),
    ],
)
def test_bad_field_is_named(tmp_path, old, new, field):
    assert old in GOOD
    with pytest.raises(MachineError, match=field.replace(".", r"\.")):
        load_machine(_write(tmp_path, GOOD.replace(old, new, 1)))


def test_missing_table_is_named(tmp_path):
    text = GOOD.replace("[bucket]\nmass = 2900.0\n", "")
    with pytest.raises(MachineError, match=r"\[bucket\]"):
        load_machine(_write(tmp_path, text))


def test_not_toml_and_missing_file(tmp_path):
    with pytest.raises(MachineError, match="not valid TOML"):
        load_machine(_write(tmp_path, "[boom\nlength = 1"))
    with pytest.raises(MachineError, match="does not exist"):
        load_machine(tmp_path / "nowhere.toml")
    with pytest.raises(MachineError, match="unknown machine"):
        load_machine("cat999")


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_a_machine_file_saved_by_a_windows_editor_loads(tmp_path, encoding):
    """A byte-order mark (Notepad) or UTF-16 (PowerShell's Out-File) with CRLF line ends was
    "not valid TOML: Invalid statement (at line 1, column 1)"."""
    (tmp_path / "windows").mkdir()
    path = tmp_path / "windows" / "arm.toml"
    path.write_bytes(GOOD.replace("\n", "\r\n").encode(encoding))
    assert load_machine(path) == load_machine(_write(tmp_path, GOOD))
