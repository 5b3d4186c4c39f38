"""Where the vehicle may be sent: finite targets on the planet, within a height band around the origin.

The origin is home at boot, where the local NED frame starts. Every target the flight controller
accepts (a waypoint, a reposition, a take-off altitude, an offboard position, a new home) lies
within these bounds; :mod:`scart_bench.generator.sitl.checks` refuses what does not, and the mission
executor holds rather than fly to an item that has left them (a relative altitude after home moved).
"""

from __future__ import annotations

import math

import numpy as np

#: a target higher than this above the origin (m) is refused: a typo or an attack, never a flight plan
MAX_HEIGHT_M = 10_000.0
#: a target lower than this below the origin (m, negative) is refused
MIN_HEIGHT_M = -1_000.0
#: a local (NED) target farther than this from the origin (m) is refused: just over half the Earth's
#: circumference, the farthest a valid latitude/longitude can be
MAX_RANGE_M = 2.1e7


def height_ok(height: float) -> bool:
    """A target height (m above the origin; NaN: "keep the current one") the vehicle may fly to."""
    return math.isnan(height) or MIN_HEIGHT_M <= height <= MAX_HEIGHT_M


def local_ok(north: float, east: float) -> bool:
    """A local target (m from the origin; both NaN: "stay") the vehicle may fly to."""
    if math.isnan(north) and math.isnan(east):
        return True
    return math.isfinite(north) and math.isfinite(east) and math.hypot(north, east) <= MAX_RANGE_M


def target_ok(ned: np.ndarray) -> bool:
    """A resolved NED target (m from the origin) the vehicle may fly to: finite, on the planet, in the height range."""
    ned = np.asarray(ned, dtype=float)
    if not np.isfinite(ned).all():
        return False
    return local_ok(float(ned[0]), float(ned[1])) and height_ok(-float(ned[2]))
