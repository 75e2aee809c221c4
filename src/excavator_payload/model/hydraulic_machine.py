"""Hydraulic machine files: a boom–dipper–bucket arm on a slewing house, driven by cylinders.

A hydraulic machine file (``kind = "hydraulic"``, see ``presets/cat345c-hydraulic.toml``) has
these tables; every value is SI (m, kg, kg·m², rad, m², Pa, m³/s, N, N·s/m)::

    kind = "hydraulic"
    name, description, gravity
    [house]           mass, com, slew_inertia, boom_foot, slew_friction, max_slew_rate,
                      max_slew_torque
    [boom]            length, mass, com, inertia, joint_friction, angle_range
    [dipper]          length, mass, com, inertia, joint_friction, angle_range
    [bucket]          length, mass, com, inertia, joint_friction, angle_range
    [payload]         rated, max, position
    [boom_cylinder]   count, parent_point, child_point, bore, rod, stroke,
                      coulomb, load_coefficient, static_ratio, stribeck_velocity, viscous,
                      presliding
    [dipper_cylinder] (the same keys)
    [bucket_cylinder] (the same keys except child_point: it drives the linkage)
    [linkage]         rocker_pivot, rocker_length, link_length, bucket_point, branch
    [hydraulics]      pump_flow, relief_pressure, back_pressure

Frames (all planar in the arm's plane, the house's x–z plane): the house frame has x forward,
z up along the slew axis; each link frame has its origin at the link's joint, ``u`` along the
line to the next joint (for the bucket: to the teeth) and ``w`` perpendicular to it, up when
the link is horizontal. ``com``, ``child_point``, ``position`` … are ``[u, w]`` in the link's
frame; ``boom_foot`` and the boom cylinder's ``parent_point`` are ``[x, z]`` in the house frame,
the dipper cylinder's ``parent_point`` is in the boom frame, the bucket cylinder's in the dipper
frame. ``inertia`` is ``[along u, about the joint axis, along w]`` about the link's centre of
mass (principal axes along the link frame). ``stroke`` is ``[shortest, longest]`` pin-to-pin
cylinder length.

Loading is strict: unknown tables or keys, missing fields, non-finite numbers and impossible
values are reported in one line that names the field.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

import numpy as np

from excavator_payload.errors import MachineError

#: Value of ``kind`` that marks a hydraulic machine file.
KIND = "hydraulic"


def _f(kind: str, default: Any = None, doc: str = ""):
    """A dataclass field with its TOML kind (``pos``, ``nonneg``, ``real``, ``vec2`` …)."""
    if default is None:
        return field(metadata={"kind": kind, "doc": doc})
    return field(default=default, metadata={"kind": kind, "doc": doc})


@dataclass(frozen=True, kw_only=True)
class House:
    """The slewing upper structure (without the arm).

    Parameters
    ----------
    mass : float
        Mass of the house, kg.
    com : tuple of 3 float
        Centre of mass [x, y, z] in the house frame, m.
    slew_inertia : float
        Inertia about the vertical axis through its centre of mass, kg·m².
    boom_foot : tuple of 2 float
        The boom joint [x, z] in the house frame, m.
    slew_friction : float, default 0.0
        Viscous slew friction, N·m·s/rad.
    max_slew_rate : float, default 0.7
        Fastest slew, rad/s.
    max_slew_torque : float, default 1.5e5
        The swing drive's largest torque, N·m.
    """

    mass: float = _f("pos")
    com: tuple[float, float, float] = _f("vec3")  # [x, y, z] in the house frame
    slew_inertia: float = _f("pos")  # about the vertical axis through its centre of mass, kg·m²
    boom_foot: tuple[float, float] = _f("vec2")  # [x, z] of the boom joint in the house frame
    slew_friction: float = _f("nonneg", 0.0)  # viscous, N·m·s/rad
    max_slew_rate: float = _f("pos", 0.7)  # rad/s
    max_slew_torque: float = _f("pos", 1.5e5)  # N·m, the swing drive's largest torque


@dataclass(frozen=True, kw_only=True)
class Link:
    """One rigid link of the arm (boom, dipper or bucket).

    Parameters
    ----------
    length : float
        Joint to next joint (bucket: joint to teeth), m.
    mass : float
        Mass of the link, kg.
    com : tuple of 2 float
        Centre of mass [u, w] in the link frame, m.
    inertia : tuple of 3 float
        Principal inertia [along u, about the joint axis, along w] about the centre of mass, kg·m².
    angle_range : tuple of 2 float
        [lowest, highest] joint angle, rad.
    joint_friction : float, default 0.0
        Viscous friction of the pin, N·m·s/rad.
    """

    length: float = _f("pos")  # joint to next joint (bucket: joint to teeth), m
    mass: float = _f("pos")
    com: tuple[float, float] = _f("vec2")
    inertia: tuple[float, float, float] = _f("vec3pos")
    angle_range: tuple[float, float] = _f("range")
    joint_friction: float = _f("nonneg", 0.0)  # viscous friction of the pin, N·m·s/rad


@dataclass(frozen=True, kw_only=True)
class Payload:
    """The payload the machine is rated for: rated and largest mass (kg) and the centre of the
    load in the bucket frame ([u, w], m).

    Parameters
    ----------
    rated : float
        Rated payload, kg.
    max : float
        Largest payload, kg.
    position : tuple of 2 float
        Centre of the payload [u, w] in the bucket frame, m.
    """

    rated: float = _f("pos")
    max: float = _f("pos")
    position: tuple[float, float] = _f("vec2")  # centre of the payload in the bucket frame


@dataclass(frozen=True, kw_only=True)
class Cylinder:
    """A hydraulic cylinder (or ``count`` identical ones in parallel) and its seal friction.

    Parameters
    ----------
    count : int, default 1
        Identical cylinders in parallel on this joint.
    parent_point : tuple of 2 float
        Barrel pin in the parent's frame, m: [x, z] in the house frame (boom cylinder), [u, w] in
        the boom frame (dipper cylinder) or the dipper frame (bucket cylinder).
    child_point : tuple of 2 float, optional
        Rod pin [u, w] in the driven link's frame, m; empty for the bucket cylinder (it drives the
        linkage).
    bore : float
        Piston diameter, m.
    rod : float
        Rod diameter, m.
    stroke : tuple of 2 float
        [shortest, longest] pin-to-pin length, m.
    coulomb : float
        Coulomb seal friction, N.
    load_coefficient : float, default 0.0
        Extra Coulomb friction per N of load force.
    static_ratio : float, default 1.0
        Breakaway over Coulomb friction (the Stribeck peak).
    stribeck_velocity : float, default 0.005
        Stribeck velocity, m/s.
    viscous : float, default 0.0
        Viscous friction, N·s/m.
    presliding : float, default 0.001
        Displacement over which the friction reverses, m.
    """

    count: int = _f("count", 1)
    parent_point: tuple[float, float] = _f("vec2")
    child_point: tuple[float, float] | None = _f("vec2opt", ())
    bore: float = _f("pos")
    rod: float = _f("pos")
    stroke: tuple[float, float] = _f("range")  # [shortest, longest] pin-to-pin length, m
    coulomb: float = _f("nonneg")  # Coulomb seal friction, N
    load_coefficient: float = _f("nonneg", 0.0)  # extra Coulomb friction per N of load force
    static_ratio: float = _f("ratio", 1.0)  # breakaway / Coulomb friction (Stribeck peak)
    stribeck_velocity: float = _f("pos", 0.005)  # m/s
    viscous: float = _f("nonneg", 0.0)  # N·s/m
    presliding: float = _f("pos", 0.001)  # displacement over which friction reverses, m

    @property
    def head_area(self) -> float:
        """Piston area on the head side of one cylinder, m²."""
        return math.pi * self.bore**2 / 4

    @property
    def rod_area(self) -> float:
        """Annulus area on the rod side of one cylinder, m²."""
        return math.pi * (self.bore**2 - self.rod**2) / 4


@dataclass(frozen=True, kw_only=True)
class Linkage:
    """The bucket four-bar: the cylinder drives the rocker/link joint G.

    Parameters
    ----------
    rocker_pivot : tuple of 2 float
        Rocker pivot E [u, w] in the dipper frame, m.
    rocker_length : float
        Rocker length |EG|, m.
    link_length : float
        Link length |GF|, m.
    bucket_point : tuple of 2 float
        Link pin F [u, w] in the bucket frame, m.
    branch : int, default 1
        Which of the two circle intersections G is (+1 or -1).
    """

    rocker_pivot: tuple[float, float] = _f("vec2")  # E, dipper frame
    rocker_length: float = _f("pos")  # |EG|
    link_length: float = _f("pos")  # |GF|
    bucket_point: tuple[float, float] = _f("vec2")  # F, bucket frame
    branch: int = _f("sign", 1)  # which of the two circle intersections G is


@dataclass(frozen=True, kw_only=True)
class Hydraulics:
    """The hydraulic supply: pump flow available to one cylinder function (m³/s), relief
    pressure (Pa) and the back pressure held on the return side (Pa).

    Parameters
    ----------
    pump_flow : float
        Largest flow one cylinder function can get, m³/s.
    relief_pressure : float
        Relief valve pressure, Pa.
    back_pressure : float
        Pressure held on the return side, Pa.
    """

    pump_flow: float = _f("pos")  # largest flow one cylinder function can get, m³/s
    relief_pressure: float = _f("pos")  # Pa
    back_pressure: float = _f("nonneg")  # pressure held on the return side, Pa


TABLES: dict[str, type] = {
    "house": House, "boom": Link, "dipper": Link, "bucket": Link, "payload": Payload,
    "boom_cylinder": Cylinder, "dipper_cylinder": Cylinder, "bucket_cylinder": Cylinder,
    "linkage": Linkage, "hydraulics": Hydraulics,
}
TOP_LEVEL = ("kind", "name", "description", "gravity")


@dataclass(frozen=True, kw_only=True)
class HydraulicMachine:
    """A hydraulic excavator: house, three links, cylinders, bucket linkage, hydraulics.

    Parameters
    ----------
    name : str
        The machine's name.
    house : House
        The slewing upper structure.
    boom, dipper, bucket : Link
        The arm's links.
    payload : Payload
        The payload it is rated for.
    boom_cylinder, dipper_cylinder, bucket_cylinder : Cylinder
        The cylinders of the three joints.
    linkage : Linkage
        The bucket four-bar.
    hydraulics : Hydraulics
        The hydraulic supply.
    description : str, default ""
        One line for humans.
    gravity : float, default 9.81
        Gravitational acceleration, m/s².
    """

    name: str
    house: House
    boom: Link
    dipper: Link
    bucket: Link
    payload: Payload
    boom_cylinder: Cylinder
    dipper_cylinder: Cylinder
    bucket_cylinder: Cylinder
    linkage: Linkage
    hydraulics: Hydraulics
    description: str = ""
    gravity: float = 9.81

    kind = KIND

    @property
    def rated_payload(self) -> float:
        return self.payload.rated

    @property
    def max_payload(self) -> float:
        return self.payload.max

    @property
    def links(self) -> tuple[Link, Link, Link]:
        return (self.boom, self.dipper, self.bucket)

    @property
    def cylinders(self) -> tuple[Cylinder, Cylinder, Cylinder]:
        return (self.boom_cylinder, self.dipper_cylinder, self.bucket_cylinder)

    @property
    def angle_ranges(self) -> np.ndarray:
        """(3, 2) array of [low, high] of boom, dipper and bucket angles, rad."""
        return np.array([link.angle_range for link in self.links], dtype=float)

    # -- (de)serialisation -----------------------------------------------------------------
    def to_dict(self) -> dict:
        """The machine file as nested dictionaries (JSON- and TOML-friendly)."""
        out: dict = {"kind": KIND, "name": self.name, "description": self.description,
                     "gravity": self.gravity}
        for table in TABLES:
            values = {}
            for key, value in asdict(getattr(self, table)).items():
                if value is None or value == ():
                    continue
                values[key] = list(value) if isinstance(value, tuple) else value
            out[table] = values
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "machine") -> "HydraulicMachine":
        """Parse (strictly) the nested dictionaries of :meth:`to_dict` or a TOML file.

        Parameters
        ----------
        data : dict
            The machine's tables.
        source : str, default "machine"
            Where they came from (a file name), the start of every error message.
        """
        return parse_hydraulic(data, source, default_name="hydraulic")

    def to_toml(self) -> str:
        """The machine as a TOML machine file that :func:`load_machine` reads back."""
        d = self.to_dict()
        lines = [f'kind = "{KIND}"', f"name = {_toml(d['name'])}",
                 f"description = {_toml(d['description'])}", f"gravity = {_toml(d['gravity'])}"]
        for table in TABLES:
            lines.append(f"\n[{table}]")
            lines += [f"{k} = {_toml(v)}" for k, v in d[table].items()]
        return "\n".join(lines) + "\n"


#: Fields that are limits or counts, not model parameters: a machine file "x % off" keeps them.
LIMIT_FIELDS = frozenset({"max_slew_rate", "max_slew_torque", "angle_range", "rated", "max", "count",
                          "stroke", "branch", "pump_flow", "relief_pressure"})
#: The signs of the "x % off" files, repeated through the file's model numbers in file order.
OFF_BY_SIGNS = (1, -1, -1, 1, -1, 1, 1, -1)


def off_by(machine: HydraulicMachine, fraction: float = 0.03) -> HydraulicMachine:
    """The machine file with every model number moved by ``fraction``, as a technician's roughly
    right file (the calibration's starting point).

    Each non-zero number x of a model parameter (masses, centres of mass, inertias, lengths,
    pins, bores, rods, friction, back pressure) becomes x·(1 ± ``fraction``), the signs following
    :data:`OFF_BY_SIGNS` through the file; limits and counts (:data:`LIMIT_FIELDS`) and gravity
    are unchanged. ``off_by(cat345c-hydraulic)`` is the preset ``cat345c-hydraulic-3pct``.

    Parameters
    ----------
    machine : HydraulicMachine
        The right machine.
    fraction : float, default 0.03
        Relative change of each number, in [0, 1).

    Raises
    ------
    MachineError
        If the moved machine is not a working machine (e.g. its bucket linkage no longer closes
        on the angle range), naming the field.
    """
    if not (math.isfinite(fraction) and 0.0 <= fraction < 1.0):
        raise MachineError(f"off_by: fraction must be in [0, 1), got {fraction}")
    data = machine.to_dict()
    k = 0
    for table in TABLES:
        for key, value in data[table].items():
            if key in LIMIT_FIELDS:
                continue
            values = value if isinstance(value, list) else [value]
            moved = []
            for x in values:
                if x != 0:
                    # 12 significant digits, as a file would be written (the preset's are)
                    x = float(f"{x * (1 + fraction * OFF_BY_SIGNS[k % len(OFF_BY_SIGNS)]):.12g}")
                    k += 1
                moved.append(x)
            data[table][key] = moved if isinstance(value, list) else moved[0]
    percent = f"{100 * fraction:g}"
    data["name"] = f"{machine.name}-{percent}pct"
    data["description"] = f"{machine.name} with every parameter off by {percent} % (calibration starting point)"
    return parse_hydraulic(data, f"{machine.name} off by {percent} %", default_name=data["name"])


def _toml(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def is_hydraulic_data(data: dict) -> bool:
    """Whether parsed TOML/JSON data describe a hydraulic machine (``kind`` or cylinder tables).

    Parameters
    ----------
    data : dict
        Parsed machine file.
    """
    return data.get("kind") == KIND or any(t in data for t in ("boom_cylinder", "cylinders"))


def parse_hydraulic(data: dict, source: str, default_name: str) -> HydraulicMachine:
    """A :class:`HydraulicMachine` from parsed TOML, strictly checked.

    Parameters
    ----------
    data : dict
        The parsed machine file.
    source : str
        Where it came from (a file name), the start of every error message.
    default_name : str
        The name when the file has none.

    Raises
    ------
    MachineError
        One line naming the unknown, missing or bad field.
    """
    unknown = [k for k in data if k not in TOP_LEVEL and k not in TABLES]
    if unknown:
        raise MachineError(f"{source}: unknown table or key(s) {', '.join(map(repr, unknown))} "
                           f"(a hydraulic machine has {', '.join(TABLES)})")
    kind = data.get("kind", KIND)
    if kind != KIND:
        raise MachineError(f"{source}: field 'kind' must be \"{KIND}\", got {kind!r}")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise MachineError(f"{source}: field 'name' must be a non-empty string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise MachineError(f"{source}: field 'description' must be a string")
    gravity = _value(data.get("gravity", 9.81), "pos", "gravity", source)
    tables = {}
    for table, cls in TABLES.items():
        raw = data.get(table)
        if not isinstance(raw, dict):
            raise MachineError(f"{source}: missing table [{table}]")
        known = {f.name: f for f in fields(cls)}
        extra = [k for k in raw if k not in known]
        if extra:
            raise MachineError(f"{source}: unknown key(s) {', '.join(f'{table}.{k}' for k in extra)} "
                               f"(known: {', '.join(known)})")
        values = {}
        for key, f in known.items():
            if key not in raw:
                # Fields with a default may be left out, except the pins of the boom and
                # dipper cylinders (only the bucket cylinder has none: it drives the linkage).
                optional = f.default is not MISSING and (table == "bucket_cylinder" or key != "child_point")
                if optional:
                    continue
                raise MachineError(f"{source}: missing field '{table}.{key}'")
            values[key] = _value(raw[key], f.metadata["kind"], f"{table}.{key}", source)
        tables[table] = cls(**values)
    machine = HydraulicMachine(name=name, description=description, gravity=gravity, **tables)
    _check(machine, source)
    return machine


def _number(value, where: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MachineError(f"{source}: field '{where}' must be a number, got {value!r}")
    if not math.isfinite(value):
        raise MachineError(f"{source}: field '{where}' must be finite, got {value!r}")
    return float(value)


def _value(value, kind: str, where: str, source: str):
    if kind in ("vec2", "vec3", "vec3pos", "range", "vec2opt"):
        n = 3 if kind.startswith("vec3") else 2
        if not isinstance(value, list) or len(value) != n:
            raise MachineError(f"{source}: field '{where}' must be a list of {n} numbers, got {value!r}")
        out = tuple(_number(v, where, source) for v in value)
        if kind == "range" and not out[0] < out[1]:
            raise MachineError(f"{source}: field '{where}' must be [low, high] with low < high, got {value!r}")
        if kind == "vec3pos" and not all(v > 0 for v in out):
            raise MachineError(f"{source}: field '{where}' must hold positive numbers, got {value!r}")
        return out
    if kind == "count":
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise MachineError(f"{source}: field '{where}' must be a whole number ≥ 1, got {value!r}")
        return value
    if kind == "sign":
        if value not in (1, -1) or isinstance(value, bool):
            raise MachineError(f"{source}: field '{where}' must be 1 or -1, got {value!r}")
        return int(value)
    x = _number(value, where, source)
    if kind == "pos" and x <= 0:
        raise MachineError(f"{source}: field '{where}' must be a positive number, got {value!r}")
    if kind == "nonneg" and x < 0:
        raise MachineError(f"{source}: field '{where}' must not be negative, got {value!r}")
    if kind == "ratio" and x < 1:
        raise MachineError(f"{source}: field '{where}' must be ≥ 1, got {value!r}")
    return x


def _check(m: HydraulicMachine, source: str) -> None:
    for table in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder"):
        c = getattr(m, table)
        if not c.rod < c.bore:
            raise MachineError(f"{source}: field '{table}.rod' must be smaller than the bore")
        if not (c.rod_area > 0 and math.isfinite(c.head_area)):
            raise MachineError(f"{source}: fields '{table}.bore' and '{table}.rod' must give a piston "
                               f"and an annulus area (m), got bore {c.bore!r}, rod {c.rod!r}")
        if c.stroke[0] <= 0:
            raise MachineError(f"{source}: field '{table}.stroke' must be positive lengths")
    if m.boom_cylinder.child_point in (None, ()) or m.dipper_cylinder.child_point in (None, ()):
        raise MachineError(f"{source}: boom and dipper cylinders need a child_point")
    if m.bucket_cylinder.child_point not in (None, ()):
        raise MachineError(f"{source}: field 'bucket_cylinder.child_point' is not used: the bucket "
                           "cylinder drives the linkage joint (see [linkage])")
    if m.payload.max < m.payload.rated:
        raise MachineError(f"{source}: field 'payload.max' must be ≥ payload.rated")
    _check_relief(m, source)
    if m.hydraulics.back_pressure >= m.hydraulics.relief_pressure:
        raise MachineError(f"{source}: field 'hydraulics.back_pressure' must be below the relief pressure")
    if not GRAVITY_RANGE[0] <= m.gravity <= GRAVITY_RANGE[1]:
        # calibration does not identify gravity: 1e-300 weighed a 4.8 t load as -4.2 t, 'ok'
        raise MachineError(f"{source}: field 'gravity' must be Earth's gravity in m/s² "
                           f"({GRAVITY_RANGE[0]:g} … {GRAVITY_RANGE[1]:g}), got {m.gravity!r}")
    _check_proportions(m, source)  # lengths against the machine's size first: it names their unit
    for table in TABLES:
        for key, value in asdict(getattr(m, table)).items():
            bound, unit = SIZE_LIMITS.get(key, (None, ""))
            values = value if isinstance(value, tuple) else (value,)
            if bound is not None and any(abs(v) > bound for v in values):
                units = {"m": LENGTH_UNITS, "kg": MASS_UNITS[1:]}.get(unit, ())
                raise MachineError(f"{source}: field '{table}.{key}' must be at most {bound:g} {unit} "
                                   f"in size, got {list(value) if isinstance(value, tuple) else value!r}"
                                   + _fits(list(values), units, lambda v: max(map(abs, v)) <= bound, first=True))
    _check_masses_and_drives(m, source)
    for table in ("boom", "dipper", "bucket"):
        low, high = getattr(m, table).angle_range
        if not -2 * math.pi <= low < high <= 2 * math.pi:
            raise MachineError(f"{source}: field '{table}.angle_range' must lie within -2π … 2π rad "
                               f"(radians, not degrees), got [{low!r}, {high!r}]")
    _check_geometry(m, source)


# -- numbers against the machine's own size ---------------------------------------------------
# A number in another unit (a centre of mass in cm, a pump flow in L/min, a slew rate in °/s)
# passed the absolute limits above and was used. Each is judged against what a machine of this
# file's size can be, and the message names the unit in which the number makes sense.

#: A point on a link (centre of mass, pin) lies within this many link lengths of the link's joint.
POINT_REACH = 1.5
#: A point on the house (its centre of mass, the boom foot, the boom cylinder's pin) lies within this
#: share of the arm's reach (boom + dipper + bucket) of the slew axis.
HOUSE_POINT_REACH = 0.5
#: A cylinder's bore or rod is at most this share of the arm's reach.
BORE_REACH = 0.1
#: A link's mass per metre of its length, kg/m: 60-6600 from a 1-t to a 300-t machine, widened.
LINEAR_DENSITY = (5.0, 5.0e4)
#: The house's mass over the arm's (boom + dipper + bucket): 2 on the presets, widened.
HOUSE_TO_ARM = (0.3, 30.0)
#: The rated payload over the house and arm's mass: 0.17 on the presets, widened.
PAYLOAD_SHARE = (0.005, 1.0)
#: Relief pressure of a mobile machine's implement circuit, Pa (100-700 bar, widened).
RELIEF_RANGE = (5.0e6, 7.0e7)
#: Fastest crossing of a joint's angle range at the pump flow, s (the presets' bucket: 0.24 s at
#: its smallest moment arm).
FASTEST_CROSSING = 0.05
#: Fastest half turn of the house at max_slew_rate, s (the presets: 4.5 s; 30 rpm is a half turn in 1 s).
FASTEST_HALF_TURN = 1.0
#: Time the swing drive takes to reach max_slew_rate at max_slew_torque with the empty arm, s
#: (0.6-4.3 s from a 0.3× to a 2× preset).
SLEW_START = (0.02, 120.0)
#: Stribeck velocity of a seal, m/s, and presliding displacement, m, at most.
MAX_STRIBECK_VELOCITY = 1.0
MAX_PRESLIDING = 0.05

#: Units a length, pressure, flow, rate or torque is mistaken in, with their size in SI.
LENGTH_UNITS = (("cm", 0.01), ("mm", 0.001), ("in", 0.0254))
PRESSURE_UNITS = (("bar", 1.0e5), ("MPa", 1.0e6), ("kPa", 1.0e3), ("psi", 6894.757))
FLOW_UNITS = (("L/min", 1.0e-3 / 60.0), ("L/s", 1.0e-3))
SLEW_RATE_UNITS = (("°/s", math.pi / 180.0), ("rpm", 2.0 * math.pi / 60.0))
TORQUE_UNITS = (("kN·m", 1.0e3),)
MASS_UNITS = (("t", 1000.0), ("g", 0.001))


def _fits(value, units, ok, first: bool = False) -> str:
    """``"; in cm?"``: the units in which ``value`` passes ``ok(value × size)``, for the message
    (``first``: only the first of them, the likeliest: a length that fits in cm fits in mm too)."""
    names = [name for name, size in units if ok(_scaled(value, size))]
    names = names[:1] if first else names
    return f"; in {' or '.join(names)}?" if names else ""


def _scaled(value, size):
    return [v * size for v in value] if isinstance(value, (tuple, list)) else value * size


def _show(value) -> str:
    return f"[{', '.join(f'{v:g}' for v in value)}]" if isinstance(value, (tuple, list)) else f"{value:g}"


def _check_relief(m: HydraulicMachine, source: str) -> None:
    """The relief pressure in Pa (checked before the back pressure is compared with it)."""
    low, high = RELIEF_RANGE
    relief = m.hydraulics.relief_pressure
    if not low <= relief <= high:
        raise MachineError(f"{source}: field 'hydraulics.relief_pressure' {relief:g} Pa is outside what a "
                           f"machine's relief valve is set to ({low:g}-{high:g} Pa = {low / 1e5:g}-{high / 1e5:g} bar)"
                           + _fits(relief, PRESSURE_UNITS, lambda v: low <= v <= high))


def _check_proportions(m: HydraulicMachine, source: str) -> None:
    """Every number against the machine's own size (see the constants above); one line naming
    the field, what a machine of this size has, and the unit the number would make sense in."""
    reach = m.boom.length + m.dipper.length + m.bucket.length

    def norm(v) -> float:
        return math.sqrt(sum(x * x for x in v))

    points = [("house.com", m.house.com, HOUSE_POINT_REACH * reach, "the slew axis (half the arm's reach)"),
              ("house.boom_foot", m.house.boom_foot, HOUSE_POINT_REACH * reach, "the slew axis (half the arm's reach)"),
              ("boom_cylinder.parent_point", m.boom_cylinder.parent_point, HOUSE_POINT_REACH * reach,
               "the slew axis (half the arm's reach)")]
    for link, carried in (("boom", ("boom_cylinder.child_point", "dipper_cylinder.parent_point")),
                          ("dipper", ("dipper_cylinder.child_point", "bucket_cylinder.parent_point",
                                      "linkage.rocker_pivot")),
                          ("bucket", ("payload.position", "linkage.bucket_point"))):
        length = getattr(m, link).length
        what = f"the {link} pin ({POINT_REACH:g} × its {length:g} m length)"
        for name in (f"{link}.com", *carried):
            table, key = name.split(".")
            points.append((name, getattr(getattr(m, table), key), POINT_REACH * length, what))
    for name, value, bound, what in points:
        if value in (None, ()):
            continue
        if norm(value) > bound:
            raise MachineError(f"{source}: field '{name}' {_show(value)} lies {norm(value):.4g} m from "
                               f"{what}, more than {bound:.3g} m on this machine"
                               + _fits(value, LENGTH_UNITS, lambda v: norm(v) <= bound, first=True))
    for name in ("rocker_length", "link_length"):
        value, bound = getattr(m.linkage, name), POINT_REACH * m.bucket.length
        if value > bound:
            raise MachineError(f"{source}: field 'linkage.{name}' {value:g} m is longer than {bound:.3g} m "
                               f"({POINT_REACH:g} × the bucket's length)"
                               + _fits(value, LENGTH_UNITS, lambda v: v <= bound, first=True))
    for table in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder"):
        c, bound = getattr(m, table), BORE_REACH * reach
        for key in ("bore", "rod"):
            value = getattr(c, key)
            if value > bound:
                raise MachineError(f"{source}: field '{table}.{key}' {value:g} m is more than {bound:.3g} m "
                                   f"({BORE_REACH:g} × the arm's {reach:.3g} m reach)"
                                   + _fits(value, LENGTH_UNITS, lambda v: v <= bound, first=True))



def _check_masses_and_drives(m: HydraulicMachine, source: str) -> None:
    """Seal numbers, masses and the slew rate against the machine's size (after the absolute
    sizes: a length of 1e200 m is named as a length, not as a light link)."""
    for table in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder"):
        c = getattr(m, table)
        if c.stribeck_velocity > MAX_STRIBECK_VELOCITY:
            raise MachineError(f"{source}: field '{table}.stribeck_velocity' {c.stribeck_velocity:g} m/s is "
                               f"faster than any rod moves (at most {MAX_STRIBECK_VELOCITY:g} m/s); in mm/s?")
        if c.presliding > MAX_PRESLIDING:
            raise MachineError(f"{source}: field '{table}.presliding' {c.presliding:g} m is more than a "
                               f"seal's elastic travel (at most {MAX_PRESLIDING:g} m); in mm?")
    low, high = LINEAR_DENSITY
    for link in ("boom", "dipper", "bucket"):
        body = getattr(m, link)
        if not low <= body.mass / body.length <= high:
            raise MachineError(f"{source}: field '{link}.mass' {body.mass:g} kg is {body.mass / body.length:.3g} "
                               f"kg per metre of its {body.length:g} m length (links weigh {low:g}-{high:g} kg/m)"
                               + _fits(body.mass, MASS_UNITS, lambda v: low <= v / body.length <= high))
    arm = m.boom.mass + m.dipper.mass + m.bucket.mass
    low, high = HOUSE_TO_ARM
    if not low <= m.house.mass / arm <= high:
        raise MachineError(f"{source}: field 'house.mass' {m.house.mass:g} kg is {m.house.mass / arm:.3g} times "
                           f"the arm's {arm:g} kg (a house weighs {low:g}-{high:g} times its arm)"
                           + _fits(m.house.mass, MASS_UNITS, lambda v: low <= v / arm <= high))
    low, high = PAYLOAD_SHARE
    total = m.house.mass + arm
    if not low <= m.payload.rated / total <= high:
        raise MachineError(f"{source}: field 'payload.rated' {m.payload.rated:g} kg is {m.payload.rated / total:.3g} "
                           f"of the house and arm's {total:g} kg (a machine is rated for {low:g}-{high:g} of it)"
                           + _fits(m.payload.rated, MASS_UNITS, lambda v: low <= v / total <= high))
    half_turn = math.pi / m.house.max_slew_rate
    if half_turn < FASTEST_HALF_TURN:
        raise MachineError(f"{source}: field 'house.max_slew_rate' {m.house.max_slew_rate:g} rad/s turns the "
                           f"house half a turn in {half_turn:.3g} s (a machine takes seconds)"
                           + _fits(m.house.max_slew_rate, SLEW_RATE_UNITS,
                                   lambda v: FASTEST_HALF_TURN <= math.pi / v <= SLOWEST_CROSSING))


#: Earth's gravity at its surface, m/s² (9.78 at the equator to 9.83 at the poles), widened.
GRAVITY_RANGE = (9.7, 9.9)
#: The largest size of a field (m, kg, kg·m²): beyond the largest excavators (≈ 1000 t, 30 m
#: reach) by far; bigger numbers overflowed the geometry or left the simulator without a motion.
#: A mass or payload as the thesis kind's files (``MAX_PAYLOAD``).
SIZE_LIMITS: dict[str, tuple[float, str]] = {
    **{key: (100.0, "m") for key in ("length", "com", "boom_foot", "parent_point", "child_point", "bore",
                                    "rod", "stroke", "position", "rocker_pivot", "rocker_length",
                                    "link_length", "bucket_point", "presliding")},
    **{key: (1.0e6, "kg") for key in ("mass", "rated", "max")},
    **{key: (1.0e10, "kg·m²") for key in ("inertia", "slew_inertia")},
}
#: How far (share of its longest length) a cylinder's pin-to-pin length may leave its
#: ``stroke`` over the joint's angle range; and the share of the range's travel the stroke's
#: travel may fall short by (every preset, scaled and ``off_by`` 10 % file: 1.03-1.21 times
#: it). The stroke enters no computation: a roughly right file (``off_by`` 10 %: the boom's
#: pins need 5.5 % beyond its stroke) passes; a stroke that cannot move the joint through its
#: range (in mm, of another cylinder, too short a travel) does not.
STROKE_TOLERANCE = 0.25
#: The slowest a machine may cross each joint's angle range (the slew: a half turn) at its pump
#: flow and ``max_slew_rate``, s. Real machines take seconds; a pump flow 125× too low (the
#: plausibility notes' example) a minute; beyond this the simulator's motions grow without bound.
SLOWEST_CROSSING = 600.0


def _check_geometry(m: HydraulicMachine, source: str) -> None:
    """The cylinders can move each joint over its angle range, the bucket linkage closes over
    it and the hydraulics move each joint over it in a machine's time (one line naming the
    field otherwise)."""
    from excavator_payload.model.hydraulic import HydraulicArmModel

    arm = HydraulicArmModel(m, compiled=False)
    names = ("boom", "dipper", "bucket")
    points = 200
    for j, (name, cylinder) in enumerate(zip(names, m.cylinders)):
        grid = arm.joint_sweep(j, points)
        with np.errstate(all="ignore"):
            lengths = arm.cylinder_lengths(grid)[:, j]
            if j == 2:
                margin = arm.linkage_margin(grid)
        if j == 2 and not np.all(margin > 0):
            raise MachineError(f"{source}: the bucket linkage does not close over 'bucket.angle_range' "
                               f"{list(m.bucket.angle_range)} rad: check [linkage] (rocker_length, "
                               "link_length, rocker_pivot, bucket_point)")
        short, long = cylinder.stroke
        slack = STROKE_TOLERANCE * long
        if not (np.all(np.isfinite(lengths)) and lengths.min() >= short - slack
                and lengths.max() <= long + slack):
            raise MachineError(f"{source}: field '{name}_cylinder.stroke' [{short:g}, {long:g}] m cannot "
                               f"move the {name} over its angle_range: the pins need "
                               f"{lengths.min():.4g} … {lengths.max():.4g} m")
        travel = float(lengths.max() - lengths.min())
        if long - short < (1.0 - STROKE_TOLERANCE) * travel:
            # both ends within the slack, yet a stroke of 0.5 m where the range needs 1.85 m
            raise MachineError(f"{source}: field '{name}_cylinder.stroke' [{short:g}, {long:g}] m travels "
                               f"{long - short:.4g} m, but moving the {name} over its angle_range takes "
                               f"{travel:.4g} m ({lengths.min():.4g} … {lengths.max():.4g} m pin to pin): a "
                               f"cylinder that cannot reach its joint's range; check the stroke or "
                               f"'{name}.angle_range'")
    with np.errstate(all="ignore"):
        rates = arm.largest_joint_rates(points)
    widths = np.r_[np.diff(m.angle_ranges, axis=1)[:, 0], math.pi]
    crossing = widths[:3] / rates[:3]
    fastest = int(np.argmin(crossing))
    if crossing[fastest] < FASTEST_CROSSING:
        flow = m.hydraulics.pump_flow
        # the crossing time scales as 1/flow: the units in which the flow gives a machine's times
        units = [name for name, size in FLOW_UNITS
                 if FASTEST_CROSSING <= crossing.min() / size and crossing.max() / size <= SLOWEST_CROSSING]
        raise MachineError(f"{source}: field 'hydraulics.pump_flow' {flow:g} m³/s would move the "
                           f"{names[fastest]} across its angle_range in {crossing[fastest]:.3g} s (a machine "
                           f"takes seconds: at least {FASTEST_CROSSING:g} s)"
                           + (f"; in {' or '.join(units)}?" if units else ""))
    with np.errstate(all="ignore"):
        kinetic, _ = arm.energy(arm.joint_sweep(0, 3)[1], np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(2), 0.0)
    slew_inertia = 2.0 * float(np.squeeze(kinetic))  # K = ½ J ψ̇² at ψ̇ = 1 rad/s
    start = slew_inertia * m.house.max_slew_rate / m.house.max_slew_torque
    low, high = SLEW_START
    if np.isfinite(start) and not low <= start <= high:
        units = [name for name, size in TORQUE_UNITS if low <= start / size <= high]
        raise MachineError(f"{source}: field 'house.max_slew_torque' {m.house.max_slew_torque:g} N·m takes "
                           f"{start:.3g} s to bring the house and arm ({slew_inertia:.3g} kg·m²) to max_slew_rate "
                           f"(a machine takes {low:g}-{high:g} s)"
                           + (f"; in {' or '.join(units)}?" if units else ""))
    for name, rate, width in zip((*names, "slew"), rates, widths):
        if not width / rate <= SLOWEST_CROSSING:
            field_ = "house.max_slew_rate" if name == "slew" else \
                f"hydraulics.pump_flow, {name}_cylinder.bore / rod / count"
            raise MachineError(f"{source}: the {name} would take {width / rate:.3g} s to cross "
                               f"{'a half turn' if name == 'slew' else 'its angle_range'} (at most "
                               f"{SLOWEST_CROSSING:g} s): check {field_}")
