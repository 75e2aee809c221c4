"""A machine file of another size: ``cat345c-hydraulic`` scaled geometrically by a factor s.

Lengths, pin positions, strokes and bores scale with s, masses with s³ (the same steel and
proportions), inertias with s⁵, seal friction with s² (seal circumference × a pressure-driven
contact force per area), torque limits and the house's viscous drag with s⁴, the pump flow with
1.2 s³ (smaller machines turn their arms a little faster) and the rated payload with s³
(rounded to 10 kg); pressures, angle ranges, Stribeck velocity and slew speed stay. s = 0.5 is
a ~6-t mini excavator (620 kg rated), s = 1.3 a ~100-t machine (10 980 kg rated).

Usage::

    PYTHONPATH=src python benchmarks/scaled_machine.py 0.5 > mini.toml
    excavator-payload demo --machine mini.toml --scale quick --out mini-demo

The README's "Your own machine" quotes the demo on s = 0.5 and 1.3: the calibrate → zero →
weigh study on machines whose numbers no preset has.
"""

from __future__ import annotations

import argparse

from excavator_payload.model.hydraulic_machine import HydraulicMachine
from excavator_payload.model.machine import load_machine


def scaled(s: float) -> HydraulicMachine:
    """``cat345c-hydraulic`` scaled by ``s`` (module doc); checked as any machine file is."""
    d = load_machine("cat345c-hydraulic").to_dict()
    length, mass, inertia = s, s**3, s**5

    def sc(v, f):
        return [x * f for x in v] if isinstance(v, list) else v * f

    h = d["house"]
    h["mass"] *= mass
    h["com"] = sc(h["com"], length)
    h["slew_inertia"] *= inertia
    h["boom_foot"] = sc(h["boom_foot"], length)
    h["slew_friction"] *= s**4
    h["max_slew_torque"] *= s**4
    for k in ("boom", "dipper", "bucket"):
        b = d[k]
        b["length"] *= length
        b["mass"] *= mass
        b["com"] = sc(b["com"], length)
        b["inertia"] = sc(b["inertia"], inertia)
    p = d["payload"]
    p["rated"] = round(p["rated"] * mass, -1)
    p["max"] = p["rated"]
    p["position"] = sc(p["position"], length)
    for k in ("boom_cylinder", "dipper_cylinder", "bucket_cylinder"):
        c = d[k]
        for f in ("parent_point", "child_point", "stroke"):
            if f in c:
                c[f] = sc(c[f], length)
        c["bore"] *= length
        c["rod"] *= length
        c["coulomb"] *= s**2
        c["viscous"] *= s**2
    lk = d["linkage"]
    for f in ("rocker_pivot", "bucket_point"):
        lk[f] = sc(lk[f], length)
    lk["rocker_length"] *= length
    lk["link_length"] *= length
    d["hydraulics"]["pump_flow"] *= 1.2 * s**3
    d["name"] = f"cat345c-hydraulic-scaled-{s:g}"
    d["description"] = f"cat345c-hydraulic scaled geometrically by {s:g} (benchmarks/scaled_machine.py)"
    return HydraulicMachine.from_dict(d, source=f"scaled by {s:g}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scale", type=float, help="linear scale factor s (e.g. 0.5 or 1.3)")
    print(scaled(ap.parse_args().scale).to_toml())


if __name__ == "__main__":
    main()
