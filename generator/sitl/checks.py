"""What the flight controller refuses: mission items, command parameters and setpoints, with the answer.

PX4 refuses a mission upload whose count exceeds its storage (MAV_MISSION_NO_SPACE), an item of a
frame or command it does not fly (MAV_MISSION_UNSUPPORTED_FRAME / MAV_MISSION_UNSUPPORTED, the
lists of ``MavlinkMissionManager::parse_mavlink_mission_item``), and commands it cannot execute
(MAV_RESULT_DENIED / UNSUPPORTED). Where PX4's mission manager stores a value unchecked and leaves
it to the navigator's feasibility check before flight (coordinates, altitude), this flight
controller answers at once, with the codes the MAVLink mission protocol defines for them:
MAV_MISSION_INVALID_PARAM5_X (latitude / north), PARAM6_Y (longitude / east), PARAM7 (altitude),
PARAM1..4 (the command's own parameters). A client learns what is wrong before the vehicle moves.

The rules, for every handled item and command: NaN keeps MAVLink's meaning of "not given / use
the current value" where the message defines one (a position, an altitude, a yaw); an infinite
value, a latitude outside +-90 deg, a longitude outside +-180 deg, an altitude more than
:data:`MAX_HEIGHT_M` above or :data:`MIN_HEIGHT_M` below the origin (home at boot, where the local
frame starts), a local position beyond :data:`MAX_RANGE_M` from it, and a NaN or negative speed
(other than MAVLink's -1 "no change" and -2 "default") are refused. Home itself moves only within
these bounds, so every target the vehicle accepts is finite and within them: on the planet, and
between 1 km below and 10 km above its starting point.
"""

from __future__ import annotations

import math

import numpy as np

from scart_bench.dataset.schema import HOME_ALT
from scart_bench.generator.sitl.bounds import (  # noqa: F401  (re-exported: the checks' bounds)
    MAX_HEIGHT_M,
    MAX_RANGE_M,
    MIN_HEIGHT_M,
    height_ok,
    local_ok,
    target_ok,
)
from scart_bench.generator.sitl.commander import (
    CMD_CHANGE_SPEED,
    FRAME_LOCAL_NED,
    FRAME_MISSION,
    GLOBAL_FRAMES,
    MISSION_FRAMES,
    RELATIVE_FRAMES,
    MissionItem,
)

#: PX4 SITL's mission capacity: NUM_MISSIONS_SUPPORTED on POSIX builds is UINT16_MAX - 1
MAX_MISSION_ITEMS = 65534

# MAV_MISSION_RESULT and MAV_RESULT values (MAVLink common.xml), kept here so the checks stay plain data
MISSION_ACCEPTED, MISSION_UNSUPPORTED_FRAME, MISSION_UNSUPPORTED = 0, 2, 3
MISSION_INVALID_PARAM1, MISSION_INVALID_PARAM2 = 6, 7
MISSION_INVALID_PARAM5_X, MISSION_INVALID_PARAM6_Y, MISSION_INVALID_PARAM7 = 10, 11, 12

#: commands PX4 accepts in a mission item with a position (global frames; this sitl adds LOCAL_NED)
POSITION_ITEM_COMMANDS = frozenset({
    16, 17, 18, 19, 21, 22, 31, 82,  # waypoint, loiter unlimited/turns/time, land, take-off, loiter to alt, spline
    80, 201, 195,  # region of interest
    84, 85,  # VTOL take-off and land
    4501, 5000, 400, 212,  # gate, fence return point, arm/disarm, autotune
})
#: commands PX4 accepts in a MAV_FRAME_MISSION item (no position)
MISSION_FRAME_COMMANDS = frozenset({
    177, 80, 201, 42600, 211,  # jump, region of interest, winch, gripper
    178, 179, 189, 2003, 203, 204, 205, 1000, 532, 1001,  # speed, home, land start, camera and gimbal
    2000, 2001, 2500, 2501, 200, 206, 260, 214, 530, 534,  # image, video, camera triggers and modes
    3000, 93, 20, 198, 197, 112, 114, 187, 212, 400,  # VTOL transition, delay, return, ROI, conditions, actuator
})
SPEED_NO_CHANGE, SPEED_DEFAULT = -1.0, -2.0


def lat_lon_result(lat: float, lon: float) -> int:
    """MAV_MISSION_RESULT of a latitude/longitude pair (both NaN: "the current position", accepted)."""
    if math.isnan(lat) and math.isnan(lon):
        return MISSION_ACCEPTED
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        return MISSION_INVALID_PARAM5_X
    if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
        return MISSION_INVALID_PARAM6_Y
    return MISSION_ACCEPTED


def position_result(frame: int, x: float, y: float, z: float, height: float) -> int:
    """MAV_MISSION_RESULT of a position in ``frame``; ``height`` is ``z`` as metres above the origin."""
    if frame in GLOBAL_FRAMES:
        res = lat_lon_result(x, y)
        if res != MISSION_ACCEPTED:
            return res
    elif frame == FRAME_LOCAL_NED:
        if not local_ok(x, 0.0 if math.isnan(y) else y):
            return MISSION_INVALID_PARAM5_X
        if not local_ok(0.0 if math.isnan(x) else x, y):
            return MISSION_INVALID_PARAM6_Y
    if math.isinf(z) or not height_ok(height):
        return MISSION_INVALID_PARAM7
    return MISSION_ACCEPTED


def speed_ok(speed: float) -> bool:
    """A DO_CHANGE_SPEED speed: finite and non-negative, or MAVLink's -1 (no change) / -2 (default)."""
    return math.isfinite(speed) and (speed >= 0.0 or speed in (SPEED_NO_CHANGE, SPEED_DEFAULT))


def item_params_result(item: MissionItem) -> int:
    """MAV_MISSION_RESULT of an item's param1..4: never infinite (NaN is "default"); a speed must be a number."""
    for i, v in enumerate((item.param1, item.param2, item.param3, item.param4)):
        if math.isinf(v):
            return MISSION_INVALID_PARAM1 + i
    if item.command == CMD_CHANGE_SPEED and not speed_ok(item.param2):
        return MISSION_INVALID_PARAM2
    return MISSION_ACCEPTED


def mission_item_result(item: MissionItem, height: float) -> int:
    """MAV_MISSION_RESULT of one uploaded item; ``height``: its altitude as metres above the origin (NaN if none)."""
    if item.frame not in MISSION_FRAMES:
        return MISSION_UNSUPPORTED_FRAME
    allowed = MISSION_FRAME_COMMANDS if item.frame == FRAME_MISSION else POSITION_ITEM_COMMANDS
    if item.command not in allowed:
        return MISSION_UNSUPPORTED
    res = item_params_result(item)
    if res != MISSION_ACCEPTED or item.frame == FRAME_MISSION:
        return res
    return position_result(item.frame, item.x, item.y, item.z, height)


def height_of(frame: int, z: float, home_down: float) -> float:
    """The altitude ``z`` of a ``frame`` as metres above the origin (NaN stays NaN); ``home_down``: home's NED z."""
    if frame in RELATIVE_FRAMES:
        return z - home_down
    if frame in GLOBAL_FRAMES:
        return z - HOME_ALT
    return -z  # LOCAL_NED: z is down



# -- commands (COMMAND_LONG / COMMAND_INT) ----------------------------------------------------------
CMD_ARM_DISARM, CMD_TAKEOFF, CMD_LAND, CMD_REPOSITION, CMD_SET_HOME, CMD_SET_MODE = 400, 22, 21, 192, 179, 176
CMD_SET_MISSION_CURRENT, CMD_REQUEST_MESSAGE, CMD_SET_MESSAGE_INTERVAL = 224, 512, 511


def _position_refusal(p: list[float], height: float) -> str | None:
    res = lat_lon_result(p[4], p[5])
    if res == MISSION_INVALID_PARAM5_X:
        return f"latitude {p[4]:g} is not within +-90 deg"
    if res == MISSION_INVALID_PARAM6_Y:
        return f"longitude {p[5]:g} is not within +-180 deg"
    if not height_ok(height):
        return f"altitude {p[6]:g} m is {height:.0f} m from the origin (at most {MAX_HEIGHT_M:.0f} above, " \
               f"{-MIN_HEIGHT_M:.0f} below)"
    return None


def _needs_numbers(p: list[float], *indices: int) -> str | None:
    for i in indices:
        if math.isnan(p[i]):
            return f"param{i + 1} is NaN; this command needs a number"
    return None


def command_refusal(command: int, p: list[float], height: float) -> str | None:
    """Why a command's parameters are refused (answered MAV_RESULT_DENIED), or None.

    ``p``: param1..7 (param5/6 as degrees of latitude/longitude); ``height``: param7 as metres above
    the origin (NaN when not given). No parameter may be infinite; NaN is "not given" where MAVLink says so.
    """
    for i, v in enumerate(p):
        if math.isinf(v):
            return f"param{i + 1} is infinite"
    if command == CMD_ARM_DISARM:
        if math.isnan(p[0]) or round(p[0]) not in (0, 1):
            return f"param1 {p[0]:g} is neither 1 (arm) nor 0 (disarm)"
        return None
    if command in (CMD_TAKEOFF, CMD_LAND, CMD_REPOSITION) or (command == CMD_SET_HOME and not p[0] > 0.5):
        return _position_refusal(p, height)
    if command == CMD_CHANGE_SPEED:
        return None if speed_ok(p[1]) else f"speed {p[1]:g} m/s is not a speed (>= 0, or -1 / -2)"
    if command == CMD_SET_MODE:
        return _needs_numbers(p, 0, 1)
    if command in (CMD_SET_MISSION_CURRENT, CMD_REQUEST_MESSAGE):
        return _needs_numbers(p, 0)
    if command == CMD_SET_MESSAGE_INTERVAL:
        return _needs_numbers(p, 0, 1)
    return None


def setpoint_ok(pos: np.ndarray, vel: np.ndarray, yaw: float, yaw_rate: float) -> bool:
    """An offboard setpoint (NED; NaN: that component not commanded) the vehicle may follow.

    Refused (ignored: setpoints are not acknowledged): an infinite component, a position beyond
    :data:`MAX_RANGE_M` from the origin or outside the height range.
    """
    values = np.concatenate([np.asarray(pos, dtype=float), np.asarray(vel, dtype=float), [yaw, yaw_rate]])
    if np.isinf(values).any():
        return False
    north, east, down = (float(v) for v in pos)
    if not (math.isnan(north) or math.isnan(east)) and not local_ok(north, east):
        return False
    return math.isnan(down) or height_ok(-down)
