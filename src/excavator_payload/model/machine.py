"""Machine descriptions: the physical parameters of one excavator arm, loaded from TOML.

A machine file has four tables (see ``presets/cat345c.toml``)::

    name = "my-machine"
    [boom]    length, mass, friction, angle_range, torque_limit
    [dipper]  length, mass, friction, angle_range, torque_limit
    [bucket]  mass
    [payload] rated, max

Units are SI (m, kg, N·m·s/rad, rad, N·m). Inertias are those of uniform bars about their
centre, ``mass * length**2 / 12``, as in the thesis (appendix A.2).
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from excavator_payload.errors import MachineError
from excavator_payload.textfiles import read_config_text

GRAVITY = 9.81  # m/s², as the thesis


@dataclass(frozen=True)
class Machine:
    """Physical parameters of a two-link excavator arm (boom + dipper, bucket at the tip).

    Parameters
    ----------
    name : str
        The machine's name.
    boom_length, dipper_length : float
        Joint-to-joint lengths (dipper: joint to bucket), m.
    boom_mass, dipper_mass : float
        Link masses (uniform bars), kg.
    boom_friction, dipper_friction : float
        Viscous joint friction, N·m·s/rad.
    bucket_mass : float
        Mass of the empty bucket (a point mass at the dipper tip), kg.
    rated_payload, max_payload : float
        Rated and largest payload, kg.
    boom_angle_range, dipper_angle_range : tuple of 2 float
        [low, high] joint angles, rad (dipper relative to the boom).
    boom_torque_limit, dipper_torque_limit : float
        Largest joint torques, N·m.
    description : str, default ""
        One line for humans.
    gravity : float, default 9.81
        Gravitational acceleration, m/s².
    """

    name: str
    boom_length: float
    boom_mass: float
    boom_friction: float
    dipper_length: float
    dipper_mass: float
    dipper_friction: float
    bucket_mass: float
    rated_payload: float
    max_payload: float
    boom_angle_range: tuple[float, float] = (-math.pi / 4, math.pi / 3)
    dipper_angle_range: tuple[float, float] = (-5 * math.pi / 6, -math.pi / 12)
    boom_torque_limit: float = 4.0e6
    dipper_torque_limit: float = 2.0e6
    description: str = ""
    gravity: float = GRAVITY

    @property
    def boom_inertia(self) -> float:
        """Inertia of the boom about its centre of mass, kg·m² (uniform bar)."""
        return self.boom_mass * self.boom_length**2 / 12.0

    @property
    def dipper_inertia(self) -> float:
        """Inertia of the dipper about its centre of mass, kg·m² (uniform bar)."""
        return self.dipper_mass * self.dipper_length**2 / 12.0

    @property
    def parameter_vector(self) -> np.ndarray:
        """Parameters in the order of :data:`excavator_payload.model.dynamics.PARAMETER_NAMES`."""
        return np.array(
            [
                self.boom_length,
                self.dipper_length,
                self.boom_mass,
                self.dipper_mass,
                self.bucket_mass,
                self.boom_friction,
                self.dipper_friction,
                self.gravity,
            ],
            dtype=float,
        )

    @property
    def torque_limits(self) -> np.ndarray:
        return np.array([self.boom_torque_limit, self.dipper_torque_limit])

    def to_dict(self) -> dict:
        """Flat dictionary (JSON-friendly) that :meth:`from_dict` reads back."""
        d = asdict(self)
        d["boom_angle_range"] = list(self.boom_angle_range)
        d["dipper_angle_range"] = list(self.dipper_angle_range)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Machine":
        """The machine of a flat dict of its fields (as :meth:`to_dict` writes; angle ranges as
        ``[low, high]``), checked for physical sense; :class:`MachineError` otherwise.

        Parameters
        ----------
        d : dict
            The machine's fields.
        """
        if not isinstance(d, dict):
            raise MachineError(f"a machine must be a table of fields, got {type(d).__name__}")
        d = dict(d)
        for key in ("boom_angle_range", "dipper_angle_range"):
            if key in d:
                if not isinstance(d[key], (list, tuple)):
                    raise MachineError(f"machine field '{key}' must be [low, high]")
                d[key] = tuple(d[key])
        try:
            machine = cls(**d)
        except TypeError as exc:
            raise MachineError(f"machine fields are wrong: {exc}") from None
        _check_physics(machine)
        return machine

    def to_toml(self) -> str:
        """The machine as a TOML machine file (:func:`load_machine` reads it back unchanged)."""
        return (
            f"name = {_toml_string(self.name)}\ndescription = {_toml_string(self.description)}\n\n"
            f"[boom]\nlength = {self.boom_length!r}\nmass = {self.boom_mass!r}\n"
            f"friction = {self.boom_friction!r}\nangle_range = {list(self.boom_angle_range)!r}\n"
            f"torque_limit = {self.boom_torque_limit!r}\n\n"
            f"[dipper]\nlength = {self.dipper_length!r}\nmass = {self.dipper_mass!r}\n"
            f"friction = {self.dipper_friction!r}\n"
            f"angle_range = {list(self.dipper_angle_range)!r}\n"
            f"torque_limit = {self.dipper_torque_limit!r}\n\n"
            f"[bucket]\nmass = {self.bucket_mass!r}\n\n"
            f"[payload]\nrated = {self.rated_payload!r}\nmax = {self.max_payload!r}\n"
        )


def _toml_string(text: str) -> str:
    """A TOML basic string: JSON's escapes (quotes, backslashes, control characters, \\uXXXX)
    are TOML's too."""
    return json.dumps(str(text), ensure_ascii=True)


#: The fields a machine file may have, per table ('' = top level); anything else is reported.
MACHINE_FILE_FIELDS: dict[str, set[str]] = {
    "": {"name", "description", "boom", "dipper", "bucket", "payload"},
    "boom": {"length", "mass", "friction", "angle_range", "torque_limit"},
    "dipper": {"length", "mass", "friction", "angle_range", "torque_limit"},
    "bucket": {"mass"},
    "payload": {"rated", "max"},
}
#: Largest payload (kg) a machine may declare: beyond any excavator ever built.
MAX_PAYLOAD = 1.0e6


def _check_fields(data: dict, source: str) -> None:
    """One clear line for a misspelt or unknown field (``torque_limt``), naming the closest."""
    import difflib

    for table, allowed in MACHINE_FILE_FIELDS.items():
        content = data if table == "" else data.get(table)
        if not isinstance(content, dict):
            continue
        for key in content:
            if key not in allowed:
                where = f"{table}.{key}" if table else key
                close = difflib.get_close_matches(key, sorted(allowed), n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else f" (known: {', '.join(sorted(allowed))})"
                raise MachineError(f"{source}: unknown field '{where}'{hint}")


def list_presets() -> list[str]:
    """Names of the machine presets shipped with the package."""
    folder = resources.files("excavator_payload.model") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_machine(name_or_path: str | Path | Machine) -> Machine:
    """Load a preset by name (``cat345c``) or a user's TOML machine file by path.

    Parameters
    ----------
    name_or_path : str, pathlib.Path, Machine or HydraulicMachine
        A preset name, a TOML machine file, or a machine (returned as it is).

    Returns
    -------
    Machine or HydraulicMachine
        The machine; a hydraulic machine file (``kind = "hydraulic"`` or cylinder tables) gives a
        :class:`~excavator_payload.model.hydraulic_machine.HydraulicMachine`.

    Raises
    ------
    MachineError
        With a message that names the missing or bad field.
    """
    from excavator_payload.model import hydraulic_machine  # issue 11: a second machine kind

    if isinstance(name_or_path, (Machine, hydraulic_machine.HydraulicMachine)):
        return name_or_path
    text_name = str(name_or_path)
    path = Path(text_name)
    if text_name in list_presets():
        source = f"preset '{text_name}'"
        text = (resources.files("excavator_payload.model") / "presets" / f"{text_name}.toml").read_text(encoding="utf-8")
    elif path.suffix == ".toml" or path.exists():
        if not path.is_file():
            from excavator_payload.textfiles import not_a_file

            raise MachineError(not_a_file(path, "machine file"))
        source = f"machine file '{path}'"
        text = read_config_text(path, errors="replace")
    else:
        raise MachineError(
            f"unknown machine '{text_name}': give a preset ({', '.join(list_presets())}) "
            "or the path of a .toml machine file"
        )
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MachineError(f"{source} is not valid TOML: {exc}") from None
    if hydraulic_machine.is_hydraulic_data(data):
        return hydraulic_machine.parse_hydraulic(data, source, default_name=path.stem)
    return _machine_from_toml(data, source, default_name=path.stem)


def machine_from_dict(data: dict):
    """The machine of the nested dictionaries of a machine's ``to_dict`` (a dataset's or a saved
    model's metadata): a :class:`Machine` or, by its tables, a hydraulic machine.

    Parameters
    ----------
    data : dict
        What ``to_dict`` of either kind of machine gave.

    Raises
    ------
    MachineError
        Naming the bad field.
    """
    from excavator_payload.model import hydraulic_machine

    if hydraulic_machine.is_hydraulic_data(data):
        return hydraulic_machine.HydraulicMachine.from_dict(data)
    return Machine.from_dict(data)


def _machine_from_toml(data: dict, source: str, default_name: str) -> Machine:
    def table(name: str) -> dict:
        value = data.get(name)
        if not isinstance(value, dict):
            raise MachineError(f"{source}: missing table [{name}]")
        return value

    def number(tab: str, key: str, *, positive: bool = True, default: float | None = None) -> float:
        value = table(tab).get(key, default)
        if value is None:
            raise MachineError(f"{source}: missing field '{tab}.{key}'")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MachineError(f"{source}: field '{tab}.{key}' must be a number, got {value!r}")
        if not math.isfinite(value) or (positive and value <= 0):
            raise MachineError(f"{source}: field '{tab}.{key}' must be a positive number, got {value!r}")
        return float(value)

    def angle_range(tab: str, default: tuple[float, float]) -> tuple[float, float]:
        value = table(tab).get("angle_range", list(default))
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            or not all(math.isfinite(v) and abs(v) <= 2 * math.pi for v in value)
            or not value[0] < value[1]
        ):
            raise MachineError(
                f"{source}: field '{tab}.angle_range' must be [low, high] in radians with "
                f"-2π ≤ low < high ≤ 2π, got {value!r}"
            )
        return (float(value[0]), float(value[1]))

    _check_fields(data, source)

    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise MachineError(f"{source}: field 'name' must be a non-empty string")
    machine = Machine(
        name=name,
        description=str(data.get("description", "")),
        boom_length=number("boom", "length"),
        boom_mass=number("boom", "mass"),
        boom_friction=number("boom", "friction", positive=False),
        boom_angle_range=angle_range("boom", Machine.boom_angle_range),
        boom_torque_limit=number("boom", "torque_limit", default=Machine.boom_torque_limit),
        dipper_length=number("dipper", "length"),
        dipper_mass=number("dipper", "mass"),
        dipper_friction=number("dipper", "friction", positive=False),
        dipper_angle_range=angle_range("dipper", Machine.dipper_angle_range),
        dipper_torque_limit=number("dipper", "torque_limit", default=Machine.dipper_torque_limit),
        bucket_mass=number("bucket", "mass"),
        rated_payload=number("payload", "rated"),
        max_payload=number("payload", "max", default=table("payload").get("rated")),
    )
    _check_physics(machine, source)
    return machine


def _check_physics(machine: Machine, source: str = "machine") -> None:
    """Every field of the right type, finite and physical (a file, or a dict from a model folder)."""
    if not isinstance(machine.name, str) or not machine.name or not isinstance(machine.description, str):
        raise MachineError(f"{source}: field 'name' must be a non-empty string")
    for key, value in asdict(machine).items():
        if key in ("name", "description"):
            continue
        values = value if key.endswith("_range") else (value,)
        if key.endswith("_range") and len(values) != 2:
            raise MachineError(f"{source}: field '{key}' must be [low, high]")
        for v in values:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise MachineError(f"{source}: field '{key}' must be a finite number, got {v!r}")
    for key in ("boom_length", "boom_mass", "dipper_length", "dipper_mass", "bucket_mass",
                "boom_torque_limit", "dipper_torque_limit", "gravity"):
        if not getattr(machine, key) > 0:
            raise MachineError(f"{source}: field '{key}' must be positive")
    for key in ("boom_angle_range", "dipper_angle_range"):
        low, high = getattr(machine, key)
        if not (-2 * math.pi <= low < high <= 2 * math.pi):
            raise MachineError(f"{source}: field '{key}' must satisfy -2π ≤ low < high ≤ 2π")
    if not (machine.rated_payload <= MAX_PAYLOAD and machine.max_payload <= MAX_PAYLOAD):
        raise MachineError(f"{source}: payload.rated and payload.max must be at most {MAX_PAYLOAD:g} kg")
    if machine.boom_friction < 0:
        raise MachineError(f"{source}: field 'boom.friction' must not be negative")
    if machine.dipper_friction < 0:
        raise MachineError(f"{source}: field 'dipper.friction' must not be negative")
    if machine.max_payload < 0 or machine.rated_payload <= 0:
        raise MachineError(f"{source}: payload.rated must be > 0 and payload.max >= 0")
