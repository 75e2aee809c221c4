"""The ground's tilt from the house IMU's inclination: one source for Python and the C export.

At slew angle 0 the house's z row is (cos r sin p, sin r, cos r cos p)
(``HydraulicArmModel.house_inclination``), so the ground's roll is the house's and
sin(pitch_house) = cos r sin p. :func:`ground_tilt` inverts that with floats (``trig=math``) or
with CasADi symbols (``trig=casadi``, for the C export's generated code); both clamp the
arcsine's argument to [-1, 1] and the cosine away from 0.
"""

from __future__ import annotations

import math

#: Smallest cos(roll) divided by: a house on its side gives a finite ratio.
COS_ROLL_FLOOR = 1e-9


def ground_tilt(house_pitch, house_roll, trig=math):
    """Ground [pitch, roll] that gives the house this inclination at slew angle 0.

    Parameters
    ----------
    house_pitch : float or casadi.SX
        The house IMU's pitch, rad.
    house_roll : float or casadi.SX
        The house IMU's roll, rad.
    trig : module
        ``math`` for floats, ``casadi`` for symbols (then ``fmin``/``fmax`` clamp).

    Returns
    -------
    tuple
        ``(ground pitch, ground roll)``, rad.
    """
    low, high = (max, min) if trig is math else (trig.fmax, trig.fmin)
    ratio = trig.sin(house_pitch) / low(trig.cos(house_roll), COS_ROLL_FLOOR)
    return trig.asin(high(1.0, low(-1.0, ratio))), house_roll
