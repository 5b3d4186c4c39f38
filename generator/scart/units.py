"""Converting attack magnitudes given in physical units (m, m/s, rad, ...) into a field's unit.

A field's quantity comes from scart_bench.dataset.schema for the project's own topics and is guessed
from the field name for imported logs (PX4 uORB names); a scenario may override it.

Latitude/longitude fields are never scaled by a fixed number of metres per degree: actions and
conditions convert a message's lat/lon pair to north/east metres in the WGS-84 tangent plane at
the flight's own origin (generator.geo), work in metres and convert back. In that metric
space a latitude is a north position and a longitude an east position (scale 1).
"""

from __future__ import annotations

import functools
import math
import re

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.geo import metres_per_degree
from scart_bench.generator.telemetry.mavros import field_quantity

#: Metres per degree at the generator's home (WGS-84): for tests and plots only, never for attacks.
M_PER_DEG_LAT, M_PER_DEG_LON = (float(v) for v in metres_per_degree())
#: hPa per metre of altitude near the home altitude (ISA: rho * g)
HPA_PER_M = 0.1127

#: quantity -> (field units per physical unit, horizontal axis "n"/"e" or "", sign for "up")
_QUANTITY = {
    "latitude": (1.0, "n", 1.0),  # in the tangent plane at the flight's origin (see module doc)
    "longitude": (1.0, "e", 1.0),
    "position_n": (1.0, "n", 1.0),
    "position_e": (1.0, "e", 1.0),
    "velocity_n": (1.0, "n", 1.0),
    "velocity_e": (1.0, "e", 1.0),
    "position_up": (1.0, "", 1.0),
    "position_d": (1.0, "", -1.0),
    "velocity_d": (1.0, "", -1.0),
    "velocity_up": (1.0, "", 1.0),  # ROS (MAVROS): ENU velocities
    "rate_flu": (1.0, "", -1.0),  # ROS body axes y, z (FLU) against the project's FRD magnitudes
    "accel_flu": (1.0, "", -1.0),
    "field_tesla": (1e-4, "", 1.0),  # ROS magnetic field in tesla, magnitudes in gauss
    "field_tesla_flu": (1e-4, "", -1.0),
    "pressure": (HPA_PER_M, "", -1.0),
    "pressure_pa": (HPA_PER_M * 100.0, "", -1.0),
    "angle_deg": (180.0 / math.pi, "", 1.0),  # magnitudes in rad, the field in degrees (ArduPilot)
}

_GUESSES = [
    (r"^(lat|latitude|latitude_deg)$", "latitude"),
    (r"^(lon|longitude|longitude_deg)$", "longitude"),
    (r"^(x|north|pos_n)$", "position_n"),
    (r"^(y|east|pos_e)$", "position_e"),
    (r"^(z|down|pos_d)$", "position_d"),
    (r"^(cog|cog_rad|course|course_rad)$", "angle"),
    (r"^(vx|vn|vel_n_m_s|vel_n)$", "velocity_n"),
    (r"^(vy|ve|vel_e_m_s|vel_e)$", "velocity_e"),
    (r"^(vz|vd|vel_d_m_s|vel_d)$", "velocity_d"),
    (r"^(alt|altitude.*|relative_alt|alt_ellipsoid|pressure_alt|baro_alt_meter)$", "position_up"),
    # ArduPilot DataFlash fields (capitalised, in ArduPilot's units: degrees for angles and courses)
    (r"^Lat$", "latitude"),
    (r"^(Lng|Lon)$", "longitude"),
    (r"^PN$", "position_n"),
    (r"^PE$", "position_e"),
    (r"^PD$", "position_d"),
    (r"^VN$", "velocity_n"),
    (r"^VE$", "velocity_e"),
    (r"^(VD|VZ)$", "velocity_d"),
    (r"^(Alt|RelAlt|RelHomeAlt|BarAlt|HAGL)$", "position_up"),
    (r"^(Roll|Pitch|Yaw|GCrs|DesRoll|DesPitch|DesYaw)$", "angle_deg"),
    (r"^Press$", "pressure_pa"),
]


@functools.lru_cache(maxsize=4096)
def quantity(topic: str, field: str) -> str:
    """The physical quantity of ``topic.field`` (see scart_bench.dataset.schema.Field.quantity); cached, as
    actions ask on every message."""
    t = TOPICS.get(topic)
    if t is not None and field in t.field_names:
        return t.fields[t.field_names.index(field)].quantity
    ros = field_quantity(topic, field)  # MAVROS topics (ENU, FLU): not guessed from the field name
    if ros is not None:
        return ros
    for pattern, q in _GUESSES:
        if re.match(pattern, field):
            return q
    return "other"


@functools.lru_cache(maxsize=1024)
def latlon_pair(topic: str, names: tuple[str, ...]) -> tuple[int, int] | None:
    """Indices of the latitude and longitude fields of a message, or None if it has not both."""
    lat = lon = None
    for i, n in enumerate(names):
        q = quantity(topic, n)
        if q == "latitude" and lat is None:
            lat = i
        elif q == "longitude" and lon is None:
            lon = i
    return (lat, lon) if lat is not None and lon is not None else None


def scale(topic: str, field: str) -> float:
    """Field units per physical unit, direction-free (for noise and ranges)."""
    return _QUANTITY.get(quantity(topic, field), (1.0, "", 1.0))[0]


def axis(topic: str, field: str) -> str:
    """Horizontal axis of a position/velocity field: "n", "e" or ""."""
    return _QUANTITY.get(quantity(topic, field), (1.0, "", 1.0))[1]


def is_velocity(topic: str, field: str) -> bool:
    return quantity(topic, field).startswith("velocity")


def signed(topic: str, field: str, direction: float) -> float:
    """Field units per physical unit for a displacement along heading ``direction`` (rad).

    Horizontal fields take the north or east component; vertical fields take an upward
    displacement (so ``z`` and pressure move the other way); other fields take it as is.
    """
    unit, ax, sign = _QUANTITY.get(quantity(topic, field), (1.0, "", 1.0))
    if ax == "n":
        return unit * math.cos(direction)
    if ax == "e":
        return unit * math.sin(direction)
    return unit * sign
