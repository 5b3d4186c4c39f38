"""The flight controller's modes and navigation: PX4's commander, navigator and offboard rules, in small.

Modes are PX4's (custom modes in the HEARTBEAT: main mode << 16 | sub mode << 24): Hold
(AUTO.LOITER), Takeoff, Mission, Return (RTL), Land, Offboard, and Position (flown as Hold: there
are no sticks). Every mode ends in a velocity/yaw setpoint for the controller of
:class:`scart_bench.generator.sitl.plant.Plant`, at 50 Hz, like the generator's navigator.

Where the navigation sits: as in the paper and in simulation mode, the mission executor steers
by the telemetry *after* the SCART layer, the view the mission computer receives (its position,
velocity and yaw come from :meth:`Commander.perceive`). So a link attack that deceives the
mission computer deceives the mission it uploaded too, and the true path leaves the plan while
the reported one stays on it. Arming, the land detector and the vehicle state are the flight
controller's own.

Offboard (PX4 rules): switching to Offboard is refused unless setpoints have been arriving (the
last one at most COM_OF_LOSS_T old); in Offboard, when none has come for longer than
COM_OF_LOSS_T, the failsafe of COM_OBL_ACT takes over (Land by default) and a STATUSTEXT says so.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from scart_bench.dataset.schema import HOME_ALT
from scart_bench.generator.flight_software.commander import OFFBOARD_LOSS_ACTIONS, ControlParams
from scart_bench.generator.flight_software.navigator import BRAKE_ACC
from scart_bench.generator.geo import latlon_to_ned, ned_to_latlon
from scart_bench.generator.sitl.bounds import target_ok

# -- PX4 custom modes ------------------------------------------------------------------------------
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = 1, 2, 3, 4, 5, 6, 7
SUB_READY, SUB_TAKEOFF, SUB_LOITER, SUB_MISSION, SUB_RTL, SUB_LAND = 1, 2, 3, 4, 5, 6

HOLD, TAKEOFF, MISSION, RTL, LAND, OFFBOARD, POSCTL = "Hold", "Takeoff", "Mission", "Return", "Land", "Offboard", \
    "Position"
#: mode -> (main mode, sub mode)
MODES = {HOLD: (MAIN_AUTO, SUB_LOITER), TAKEOFF: (MAIN_AUTO, SUB_TAKEOFF), MISSION: (MAIN_AUTO, SUB_MISSION),
         RTL: (MAIN_AUTO, SUB_RTL), LAND: (MAIN_AUTO, SUB_LAND), OFFBOARD: (MAIN_OFFBOARD, 0),
         POSCTL: (MAIN_POSCTL, 0)}
AUTO_MODES = frozenset({HOLD, TAKEOFF, MISSION, RTL, LAND})


def custom_mode(mode: str) -> int:
    """PX4's 32-bit custom mode of ``mode``."""
    main, sub = MODES[mode]
    return (main << 16) | (sub << 24)


def mode_from_custom(main: int, sub: int) -> str | None:
    """The mode of a PX4 (main, sub) pair, or None when this flight controller does not fly it."""
    if main == MAIN_AUTO:
        return {SUB_LOITER: HOLD, SUB_TAKEOFF: TAKEOFF, SUB_MISSION: MISSION, SUB_RTL: RTL, SUB_LAND: LAND}.get(sub)
    if main == MAIN_OFFBOARD:
        return OFFBOARD
    if main in (MAIN_POSCTL, MAIN_ALTCTL):
        return POSCTL
    return None


# -- parameters ------------------------------------------------------------------------------------
REAL32, INT32 = 9, 6  # MAV_PARAM_TYPE


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: float
    kind: int
    unit: str
    meaning: str
    read_only: bool = False
    low: float = -math.inf  # PX4's @min / @max: a value outside is refused
    high: float = math.inf


#: The parameters a client can read and set (PX4 names, defaults and meanings).
PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, REAL32, "m", "take-off altitude above home when a take-off command gives none",
              low=0.0, high=80.0),
    ParamSpec("MPC_XY_CRUISE", 5.0, REAL32, "m/s", "horizontal speed of missions, Return and repositions",
              low=0.0, high=20.0),
    ParamSpec("MPC_XY_VEL_MAX", 12.0, REAL32, "m/s", "horizontal speed limit (offboard setpoints)", low=0.0, high=20.0),
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, REAL32, "m/s", "climb speed limit", low=0.5, high=8.0),
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, REAL32, "m/s", "descent speed limit", low=0.5, high=4.0),
    ParamSpec("MPC_TKO_SPEED", 1.5, REAL32, "m/s", "take-off climb speed", low=1.0, high=5.0),
    ParamSpec("MPC_LAND_SPEED", 0.7, REAL32, "m/s", "landing descent speed below MPC_LAND_ALT2", low=0.6, high=4.0),
    ParamSpec("MPC_LAND_ALT2", 5.0, REAL32, "m", "below this height above home, land at MPC_LAND_SPEED",
              low=0.0, high=122.0),
    ParamSpec("NAV_ACC_RAD", 2.0, REAL32, "m", "horizontal acceptance radius of a waypoint (an item's param2 > 0 wins)",
              low=0.05, high=200.0),
    ParamSpec("NAV_MC_ALT_RAD", 0.8, REAL32, "m", "vertical acceptance radius of a waypoint", low=0.05, high=200.0),
    ParamSpec("RTL_RETURN_ALT", 60.0, REAL32, "m", "Return climbs to at least this height above home",
              low=0.0, high=150.0),
    # the simulation mode's commander defaults (generator.flight_software.commander.ControlParams)
    ParamSpec("COM_OF_LOSS_T", ControlParams.offboard_loss_s, REAL32, "s", "offboard setpoints older than this are lost",
              low=0.0, high=60.0),
    ParamSpec("COM_OBL_ACT", OFFBOARD_LOSS_ACTIONS.index(ControlParams.offboard_loss_action), INT32, "enum",
              "failsafe when offboard setpoints are lost: 0 Land, 1 Hold, 2 Return", low=0, high=2),
    ParamSpec("COM_DISARM_PRFLT", 10.0, REAL32, "s", "armed on the ground this long without taking off: disarm",
              low=-1.0, high=20.0),
    ParamSpec("MAV_SYS_ID", 1, INT32, "", "MAVLink system id", read_only=True),
    ParamSpec("SYS_AUTOSTART", 10016, INT32, "", "airframe (10016: 3DR Iris, PX4 SITL)", read_only=True),
)


class Params:
    """Parameter values by name, in the order of :data:`PARAM_SPECS`."""

    def __init__(self) -> None:
        self.specs = {p.name: p for p in PARAM_SPECS}
        self.names = [p.name for p in PARAM_SPECS]
        self.values = {p.name: float(p.default) for p in PARAM_SPECS}

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float) -> bool:
        """Set a parameter to ``value`` (decoded, :meth:`from_wire`); False, the value unchanged, when the
        parameter is unknown or read-only or the value is not a number within its range."""
        spec = self.specs.get(name)
        if spec is None or spec.read_only or not (math.isfinite(value) and spec.low <= value <= spec.high):
            return False
        self.values[name] = float(value)
        return True

    def wire_value(self, name: str) -> float:
        """The PARAM_VALUE float of a parameter: INT32 values are carried bytewise (PX4's encoding)."""
        v = self.values[name]
        if self.specs[name].kind == INT32:
            return struct.unpack("<f", struct.pack("<i", int(v)))[0]
        return v

    def from_wire(self, name: str, value: float, kind: int) -> float:
        """A PARAM_SET value: INT32 bytewise-encoded (PX4, MAVSDK, QGC); a plain integral float that
        would decode to an absurd integer (a naive client's ``1.0``) is taken as the number it says."""
        spec = self.specs.get(name)
        if spec is not None and spec.kind == INT32 and kind != REAL32:
            as_int = struct.unpack("<i", struct.pack("<f", value))[0]
            if abs(as_int) > 10_000_000 and math.isfinite(value) and float(value).is_integer():
                return float(value)
            return float(as_int)
        return float(value)


# -- mission items ---------------------------------------------------------------------------------
CMD_WAYPOINT, CMD_LOITER_UNLIM, CMD_LOITER_TURNS, CMD_LOITER_TIME, CMD_RTL, CMD_LAND, CMD_TAKEOFF = \
    16, 17, 18, 19, 20, 21, 22
CMD_CHANGE_SPEED = 178
FRAME_GLOBAL, FRAME_LOCAL_NED, FRAME_MISSION, FRAME_GLOBAL_REL = 0, 1, 2, 3
FRAME_GLOBAL_INT, FRAME_GLOBAL_REL_INT, FRAME_LOCAL_OFFSET, FRAME_BODY_NED, FRAME_BODY_OFFSET = 5, 6, 7, 8, 9
FRAME_GLOBAL_TERRAIN, FRAME_GLOBAL_TERRAIN_INT = 10, 11
GLOBAL_FRAMES = frozenset({FRAME_GLOBAL, FRAME_GLOBAL_REL, FRAME_GLOBAL_INT, FRAME_GLOBAL_REL_INT,
                           FRAME_GLOBAL_TERRAIN, FRAME_GLOBAL_TERRAIN_INT})
RELATIVE_FRAMES = frozenset({FRAME_GLOBAL_REL, FRAME_GLOBAL_REL_INT, FRAME_GLOBAL_TERRAIN, FRAME_GLOBAL_TERRAIN_INT})
MISSION_FRAMES = GLOBAL_FRAMES | {FRAME_LOCAL_NED, FRAME_MISSION}
NAV_POSITION_CMDS = frozenset({CMD_WAYPOINT, CMD_LOITER_UNLIM, CMD_LOITER_TURNS, CMD_LOITER_TIME, CMD_LAND,
                               CMD_TAKEOFF, 82})  # 82: spline waypoint, flown as a waypoint

MISSION_STATE_NO_MISSION, MISSION_STATE_NOT_STARTED, MISSION_STATE_ACTIVE, MISSION_STATE_PAUSED, \
    MISSION_STATE_COMPLETE = 1, 2, 3, 4, 5


@dataclass
class MissionItem:
    """One mission item as MISSION_ITEM_INT carries it (lat/lon in degrees as floats, or local x/y in m)."""

    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: float = 0.0  # latitude (deg) in global frames, north (m) in LOCAL_NED
    y: float = 0.0
    z: float = 0.0
    autocontinue: int = 1


def _nan(x: float) -> bool:
    return not math.isfinite(x)


def _wrap(angle: float) -> float:
    """An angle (rad) in [-pi, pi]: a yaw of 1e30 rad is a heading, not a number to carry."""
    return math.remainder(angle, 2 * math.pi)


# -- the commander ---------------------------------------------------------------------------------
@dataclass
class Offboard:
    """The last offboard setpoint: per axis group, a position and/or velocity (NaN: not given)."""

    t_us: int = -(10**12)
    pos: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    vel: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    yaw: float = float("nan")
    yaw_rate: float = float("nan")
    count: int = 0


class Commander:
    """Modes, arming, the mission executor and offboard control; one setpoint per :meth:`tick` (50 Hz).

    ``plant`` is the :class:`scart_bench.generator.sitl.plant.Plant` whose arming and estimate it reads.
    Notifications for the link (STATUSTEXT, MISSION_ITEM_REACHED, MISSION_CURRENT, home, mode)
    are appended to :attr:`outbox` as tuples and sent by the server.
    """

    APPROACH_GAIN = 1.0  # 1/s: speed = gain x distance near a target (as the generator's navigator)

    def __init__(self, plant, params: Params | None = None):
        self.plant = plant
        self.params = params or Params()
        self.mode = HOLD
        self.armed = False
        self.in_air = False
        self.outbox: list[tuple] = []
        self.pos = np.zeros(3)  # perceived (nav view) position, velocity, yaw
        self.vel = np.zeros(3)
        self.yaw = float(plant.yaw)
        self.yaw_sp = self.yaw
        self.target: np.ndarray | None = None
        self.prev: np.ndarray | None = None  # start of the current leg (line following)
        self.speed = self.params["MPC_XY_CRUISE"]
        self.home = np.zeros(3)
        self.home_set = False
        self.mission: list[MissionItem] = []
        self.seq = 0
        self.mission_state = MISSION_STATE_NO_MISSION
        self.mission_speed: float | None = None
        self.mission_climb: np.ndarray | None = None  # take-off target of a mission started on the ground
        self.item_phase = 0
        self.hold_until: float | None = None
        self.rtl_phase = 0
        self.takeoff_alt = 0.0
        self.offboard = Offboard()
        self.landed_since: float | None = None
        self.xt_int = 0.0
        self.t = 0.0

    # -- inputs -----------------------------------------------------------------------------------
    def perceive(self, topic: str, values: np.ndarray) -> None:
        """A telemetry message as delivered past the layer (one row of the topic's fields)."""
        if topic == "local_position_ned":
            self.pos = np.asarray(values[0:3], dtype=float).copy()
            self.vel = np.asarray(values[3:6], dtype=float).copy()
        elif topic == "attitude":
            self.yaw = float(values[2])

    def say(self, text: str, severity: int = 6) -> None:
        """A STATUSTEXT for the client (MAV_SEVERITY: 4 warning, 6 info)."""
        self.outbox.append(("statustext", severity, text))

    # -- home -------------------------------------------------------------------------------------
    def set_home(self, ned: np.ndarray) -> None:
        self.home = np.asarray(ned, dtype=float).copy()
        self.home_set = True
        self.outbox.append(("home",))

    def home_global(self) -> tuple[float, float, float]:
        lat, lon = ned_to_latlon(self.home[0], self.home[1])
        return float(lat), float(lon), HOME_ALT - float(self.home[2])

    def to_ned(self, frame: int, x: float, y: float, z: float) -> np.ndarray:
        """A position of a MAVLink frame as local NED; NaN (or 0, 0 lat/lon) components take the current ones."""
        cur = self.pos
        if frame in GLOBAL_FRAMES:
            if _nan(x) or _nan(y) or (x == 0.0 and y == 0.0):
                n, e = cur[0], cur[1]
            else:
                n, e = (float(v) for v in latlon_to_ned(x, y))
            if _nan(z):
                d = cur[2]
            elif frame in RELATIVE_FRAMES:
                d = self.home[2] - z
            else:
                d = -(z - HOME_ALT)
            return np.array([n, e, d])
        if frame == FRAME_LOCAL_NED:
            return np.array([cur[0] if _nan(x) else x, cur[1] if _nan(y) else y, cur[2] if _nan(z) else z])
        return cur.copy()

    # -- arming -----------------------------------------------------------------------------------
    def arm(self) -> tuple[bool, str]:
        """Arm if the preflight checks pass; (accepted, reason)."""
        if self.armed:
            return True, ""
        if not self.plant.position_valid:
            return False, "Arming denied: no valid global position estimate yet"
        if self.mode == OFFBOARD and not self.offboard_alive():
            return False, "Arming denied: no offboard setpoints"
        if self.mode in (LAND, RTL):
            self.set_mode(HOLD)
        self.plant.set_armed(True)
        self.armed = True
        self.in_air = False
        self.landed_since = self.t
        self.xt_int = 0.0
        self.set_home(self.plant.position)
        self.yaw_sp = self.yaw
        if self.mode in (HOLD, POSCTL):
            self._hold_here()
        self.say("Armed by external command")
        return True, ""

    def disarm(self, force: bool = False) -> tuple[bool, str]:
        if not self.armed:
            return True, ""
        if self.in_air and not force:
            return False, "Disarming denied: not landed"
        self._disarmed("Disarmed by external command")
        return True, ""

    def _disarmed(self, text: str) -> None:
        self.mission_climb = None
        self.plant.set_armed(False)
        self.armed = False
        self.in_air = False
        self.landed_since = None
        if self.mode != OFFBOARD:
            self.mode = HOLD
            self.outbox.append(("mode",))
        self.target = None
        self.say(text)

    # -- modes ------------------------------------------------------------------------------------
    def offboard_alive(self) -> bool:
        return self.offboard.count > 0 and self.t - self.offboard.t_us / 1e6 <= self.params["COM_OF_LOSS_T"]

    def set_mode(self, mode: str) -> tuple[bool, str]:
        """Switch to ``mode`` under PX4's rules; (accepted, reason)."""
        if mode == OFFBOARD and not self.offboard_alive():
            return False, "Switching to Offboard denied: no offboard setpoints streaming"
        if mode == MISSION and not self.mission:
            return False, "Mission rejected: no mission uploaded"
        if mode == TAKEOFF:
            return self.takeoff(float("nan"))
        changed = mode != self.mode
        self.mode = mode
        if mode in (HOLD, POSCTL):
            self._hold_here()
        elif mode == LAND:
            self.target = np.array([self.pos[0], self.pos[1], self.pos[2]])
        elif mode == RTL:
            self.rtl_phase = 0
        elif mode == MISSION:
            if self.mission_state == MISSION_STATE_COMPLETE:
                self.seq = 0
                self._announce_current()
            self.mission_state = MISSION_STATE_ACTIVE
            self._start_item()
        if changed:
            self.outbox.append(("mode",))
        return True, ""

    def _hold_here(self) -> None:
        self.target = self.pos.copy() if self.in_air else None
        self.prev = None
        self.speed = self.params["MPC_XY_CRUISE"]

    def takeoff(self, alt_amsl: float, yaw: float = float("nan")) -> tuple[bool, str]:
        """MAV_CMD_NAV_TAKEOFF: climb to ``alt_amsl`` (NaN: MIS_TAKEOFF_ALT above home), then Hold."""
        if not self.armed:
            return False, "Takeoff denied: disarmed"
        rel = self.params["MIS_TAKEOFF_ALT"] if _nan(alt_amsl) else alt_amsl - (HOME_ALT - self.home[2])
        if rel <= 0.5:
            rel = self.params["MIS_TAKEOFF_ALT"]
        self.takeoff_alt = rel
        self.target = np.array([self.pos[0], self.pos[1], self.home[2] - rel])
        self.prev = None
        if not _nan(yaw):
            self.yaw_sp = _wrap(math.radians(yaw))
        changed = self.mode != TAKEOFF
        self.mode = TAKEOFF
        if changed:
            self.outbox.append(("mode",))
        return True, ""

    def reposition(self, target: np.ndarray, speed: float, yaw: float) -> tuple[bool, str]:
        """MAV_CMD_DO_REPOSITION: fly to ``target`` and hold there."""
        if not self.armed:
            return False, "Reposition denied: disarmed"
        changed = self.mode != HOLD
        self.mode = HOLD
        self.target = np.asarray(target, dtype=float)
        self.prev = self.pos.copy()
        self.speed = self.cruise_speed(speed) if speed > 0 else self.params["MPC_XY_CRUISE"]
        if not _nan(yaw):
            self.yaw_sp = _wrap(math.radians(yaw))
        if changed:
            self.outbox.append(("mode",))
        return True, ""

    def cruise_speed(self, speed: float) -> float:
        """A commanded horizontal speed, capped at MPC_XY_VEL_MAX as PX4 caps it."""
        return min(float(speed), self.params["MPC_XY_VEL_MAX"])

    def change_speed(self, speed: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED (checked: finite, >= 0 or -1/-2): -2 back to MPC_XY_CRUISE, <= 0 no change."""
        if speed == -2.0:
            self.speed = self.params["MPC_XY_CRUISE"]
            self.mission_speed = None
        elif speed > 0:
            self.speed = self.cruise_speed(speed)
            if self.mode == MISSION:
                self.mission_speed = self.speed

    # -- mission ----------------------------------------------------------------------------------
    def set_mission(self, items: list[MissionItem]) -> None:
        """A new mission (uploaded or cleared): restarts at item 0."""
        self.mission = list(items)
        self.seq = 0
        self.mission_state = MISSION_STATE_NOT_STARTED if items else MISSION_STATE_NO_MISSION
        self.mission_speed = None
        if self.mode == MISSION:
            if items:
                self.mission_state = MISSION_STATE_ACTIVE
                self._start_item()
            else:
                self.set_mode(HOLD)
        self._announce_current()

    def set_current(self, seq: int) -> bool:
        if not 0 <= seq < len(self.mission):
            return False
        self.seq = seq
        if self.mission_state == MISSION_STATE_COMPLETE:
            self.mission_state = MISSION_STATE_NOT_STARTED
        if self.mode == MISSION:
            self._start_item()
        self._announce_current()
        return True

    def _announce_current(self) -> None:
        self.outbox.append(("current", self.seq))

    def _start_item(self) -> None:
        self.item_phase = 0
        self.hold_until = None
        self.prev = self.pos.copy()
        self.xt_int = 0.0

    def _item_done(self) -> None:
        self.outbox.append(("reached", self.seq))
        if self.seq + 1 >= len(self.mission):
            self.mission_state = MISSION_STATE_COMPLETE
            last = self.mission[self.seq] if self.mission else None
            if last is not None and last.command in (CMD_LAND, CMD_RTL):
                return
            self.say("Mission finished, loitering")
            self.mode = HOLD
            self.outbox.append(("mode",))
            self._hold_here()
            return
        self.seq += 1
        self._announce_current()
        self._start_item()

    # -- the 50 Hz step ---------------------------------------------------------------------------
    def tick(self, t: float) -> np.ndarray:
        """The setpoint (6,): vx, vy, vz, yaw, seq, armed (the generator's setpoint topic)."""
        self.t = t
        p = self.params
        if self.armed and not self.plant.armed:
            self._disarmed("Landing detected, disarmed" if self.plant.landed_by_detector() else "Disarmed")
        alt = -(self.plant.position[2] - self.home[2])
        if self.armed and not self.in_air and alt > 0.5:
            self.in_air = True
            self.landed_since = None
            self.say("Takeoff detected")
        if self.armed and not self.in_air and self.mode in (HOLD, POSCTL, LAND) and p["COM_DISARM_PRFLT"] > 0:
            if self.landed_since is None:
                self.landed_since = t
            elif t - self.landed_since > p["COM_DISARM_PRFLT"]:
                self._disarmed("Disarmed: not taken off in time")
        if self.mode == OFFBOARD and self.offboard.count and not self.offboard_alive():
            self._offboard_failsafe()
        v = np.zeros(3)
        if self.armed:
            v = self._velocity()
        out = np.zeros(6)
        out[0:3] = v
        out[3] = self.yaw_sp
        out[4] = self.seq
        out[5] = 1.0 if self.armed else 0.0
        return out

    def _offboard_failsafe(self) -> None:
        action = OFFBOARD_LOSS_ACTIONS[int(self.params["COM_OBL_ACT"])]
        mode = {"hold": HOLD, "return": RTL, "land": LAND}[action]
        self.say(f"Failsafe: offboard signal lost, activating {mode}", severity=4)
        self.outbox.append(("failsafe", mode))
        self.offboard.count = 0
        self.set_mode(mode)

    def _velocity(self) -> np.ndarray:
        p = self.params
        if self.mode in (HOLD, POSCTL):
            if self.target is None:
                return np.zeros(3)
            return self._goto(self.target, self.speed, line=self.prev is not None)
        if self.mode == TAKEOFF:
            v = self._goto(self.target, p["MPC_XY_CRUISE"], vz_up=p["MPC_TKO_SPEED"])
            if abs(self.pos[2] - self.target[2]) < p["NAV_MC_ALT_RAD"] and self.in_air:
                self.mode = HOLD
                self.outbox.append(("mode",))
                self.prev = None
            return v
        if self.mode == LAND:
            return self._land()
        if self.mode == RTL:
            return self._rtl()
        if self.mode == MISSION:
            return self._mission()
        if self.mode == OFFBOARD:
            return self._offboard()
        return np.zeros(3)

    def _goto(self, target: np.ndarray, speed: float, line: bool = False, vz_up: float | None = None) -> np.ndarray:
        """Velocity toward ``target``: cruise at ``speed``, slow down near it, follow the leg from ``prev``."""
        p = self.params
        d = target - self.pos
        dist_h = math.hypot(d[0], d[1])
        spd = min(speed, self.APPROACH_GAIN * dist_h)
        dir_h = d[:2] / max(dist_h, 1e-6)
        vh = dir_h * spd
        if line and self.prev is not None:
            leg = target[:2] - self.prev[:2]
            leg_len = float(np.linalg.norm(leg))
            if leg_len > 1.0:
                u = leg / leg_len
                normal = np.array([-u[1], u[0]])
                xt = float((self.pos[:2] - self.prev[:2]) @ normal)
                if abs(xt) < 5.0:
                    self.xt_int = float(np.clip(self.xt_int + xt / 50.0, -10.0, 10.0))
                side = float(np.clip(-(0.8 * xt + 0.3 * self.xt_int), -0.7 * spd, 0.7 * spd))
                along = math.sqrt(max(spd * spd - side * side, 0.0))
                vh = along * dir_h + side * normal
        up = p["MPC_Z_VEL_MAX_UP"] if vz_up is None else vz_up
        vz = float(np.clip(1.0 * d[2], -up, p["MPC_Z_VEL_MAX_DN"]))
        if dist_h > 3.0:
            self.yaw_sp = math.atan2(d[1], d[0])
        return np.array([vh[0], vh[1], vz])

    def _land(self, xy: np.ndarray | None = None) -> np.ndarray:
        p = self.params
        if self.target is None:
            self.target = self.pos.copy()
        goal = self.target[:2] if xy is None else xy
        vh = np.clip(1.0 * (goal - self.pos[:2]), -1.0, 1.0)
        height = -(self.pos[2] - self.home[2])
        vz = p["MPC_Z_VEL_MAX_DN"] if height > p["MPC_LAND_ALT2"] else p["MPC_LAND_SPEED"]
        return np.array([vh[0], vh[1], vz])

    def _rtl(self) -> np.ndarray:
        p = self.params
        cruise_d = min(self.pos[2], self.home[2] - p["RTL_RETURN_ALT"])
        if self.rtl_phase == 0:  # climb
            self.say(f"RTL: start return at {self.home[2] - cruise_d:.0f} m above home")
            self.rtl_phase = 1
            self.target = np.array([self.pos[0], self.pos[1], cruise_d])
            self.prev = None
        if self.rtl_phase == 1:
            v = self._goto(self.target, p["MPC_XY_CRUISE"])
            if abs(self.pos[2] - self.target[2]) < p["NAV_MC_ALT_RAD"]:
                self.rtl_phase = 2
                self.target = np.array([self.home[0], self.home[1], self.target[2]])
                self.prev = self.pos.copy()
            return v
        if self.rtl_phase == 2:  # return
            v = self._goto(self.target, p["MPC_XY_CRUISE"], line=True)
            if math.hypot(*(self.target[:2] - self.pos[:2])) < p["NAV_ACC_RAD"]:
                self.rtl_phase = 3
                self.say("RTL: land at home")
            return v
        return self._land(self.home[:2])

    def _mission(self) -> np.ndarray:
        p = self.params
        if not self.mission or self.mission_state == MISSION_STATE_COMPLETE:
            return np.zeros(3) if self.target is None else self._goto(self.target, self.speed)
        if not self.in_air and self.mission_climb is None:  # a mission started on the ground takes off first
            first = self.mission[self.seq]
            alt = p["MIS_TAKEOFF_ALT"]
            if first.command in NAV_POSITION_CMDS and first.frame in MISSION_FRAMES:
                alt = max(alt, -(self.to_ned(first.frame, first.x, first.y, first.z)[2] - self.home[2]))
            self.mission_climb = np.array([self.pos[0], self.pos[1], self.home[2] - alt])
            self.say(f"Mission: take-off to {alt:.1f} m first")
        if self.mission_climb is not None:  # straight up to the take-off altitude, as PX4 does
            if self.in_air and abs(self.pos[2] - self.mission_climb[2]) < p["NAV_MC_ALT_RAD"]:
                self.mission_climb = None
                self._start_item()
            else:
                return self._goto(self.mission_climb, 0.0, vz_up=p["MPC_TKO_SPEED"])
        for _ in range(len(self.mission)):  # non-navigation items complete at once
            item = self.mission[self.seq]
            if item.command in NAV_POSITION_CMDS or item.command == CMD_RTL:
                break
            if item.command == CMD_CHANGE_SPEED and item.param2 > 0:
                self.mission_speed = self.cruise_speed(item.param2)
            self._item_done()
            if self.mode != MISSION or self.mission_state == MISSION_STATE_COMPLETE:
                return self._velocity() if self.armed else np.zeros(3)
        item = self.mission[self.seq]
        speed = self.mission_speed or p["MPC_XY_CRUISE"]
        if item.command == CMD_RTL:
            self._item_done()
            self.set_mode(RTL)
            return self._rtl()
        if self.item_phase == 0:
            target = self.to_ned(item.frame, item.x, item.y, item.z)
            if item.command == CMD_TAKEOFF:
                target[:2] = self.pos[:2]
            if item.command == CMD_LAND:
                target[2] = self.pos[2]
            if not target_ok(target):  # a relative altitude that home's move took out of range
                self.say(f"Mission item {self.seq}: target out of range, holding", severity=4)
                self.set_mode(HOLD)
                return self._velocity()
            self.target = target
            self.item_phase = 1
        if item.command == CMD_LAND and self.item_phase >= 2:
            return self._land(self.target[:2])
        if self.item_phase == 1:  # slow down so as to stop at the item: a fast leg or a sharp turn does not overshoot
            speed = min(speed, math.sqrt(2.0 * BRAKE_ACC * math.hypot(*(self.target[:2] - self.pos[:2]))))
        v = self._goto(self.target, speed, line=item.command != CMD_TAKEOFF)
        if not _nan(item.param4) and item.command == CMD_WAYPOINT:
            self.yaw_sp = _wrap(math.radians(item.param4))
        if self.item_phase == 1:
            acc = item.param2 if item.command == CMD_WAYPOINT and item.param2 > 0 else p["NAV_ACC_RAD"]
            d = self.target - self.pos
            if math.hypot(d[0], d[1]) < acc and abs(d[2]) < p["NAV_MC_ALT_RAD"]:
                self.item_phase = 2
                hold = item.param1 if item.command in (CMD_WAYPOINT, CMD_LOITER_TIME) else 0.0
                self.hold_until = self.t + (max(hold, 0.0) if math.isfinite(hold) else 0.0)
                if item.command == CMD_LOITER_UNLIM:
                    self.outbox.append(("reached", self.seq))
                if item.command == CMD_LAND:
                    self.outbox.append(("reached", self.seq))
                    self.mode = LAND
                    self.outbox.append(("mode",))
                    self.mission_state = MISSION_STATE_COMPLETE
                    return self._land(self.target[:2])
        if self.item_phase == 2 and item.command != CMD_LOITER_UNLIM and self.t >= self.hold_until:
            self._item_done()
        return v

    def _offboard(self) -> np.ndarray:
        p, o = self.params, self.offboard
        v = np.zeros(3)
        vmax_h = p["MPC_XY_VEL_MAX"]
        if not _nan(o.pos[0]) and not _nan(o.pos[1]):
            d = o.pos[:2] - self.pos[:2]
            dist = math.hypot(*d)
            vh = d / max(dist, 1e-6) * min(vmax_h, 0.95 * dist)
            if not _nan(o.vel[0]) and not _nan(o.vel[1]):
                vh = vh + o.vel[:2]
            v[:2] = vh
        elif not _nan(o.vel[0]) and not _nan(o.vel[1]):
            v[:2] = o.vel[:2]
        if not _nan(o.pos[2]):
            v[2] = 1.0 * (o.pos[2] - self.pos[2]) + (0.0 if _nan(o.vel[2]) else o.vel[2])
        elif not _nan(o.vel[2]):
            v[2] = o.vel[2]
        sp = math.hypot(v[0], v[1])
        if sp > vmax_h:
            v[:2] *= vmax_h / sp
        v[2] = float(np.clip(v[2], -p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"]))
        if not _nan(o.yaw):
            self.yaw_sp = _wrap(o.yaw)
        elif not _nan(o.yaw_rate):
            self.yaw_sp = float(math.remainder(self.yaw_sp + o.yaw_rate / 50.0, 2 * math.pi))
        return v

    def offboard_setpoint(self, t_us: int, pos: np.ndarray, vel: np.ndarray, yaw: float, yaw_rate: float) -> None:
        """An offboard setpoint (NED; NaN components are not commanded)."""
        o = self.offboard
        o.t_us, o.pos, o.vel, o.yaw, o.yaw_rate = int(t_us), pos, vel, yaw, yaw_rate
        o.count += 1

    def landed_state(self) -> int:
        """MAV_LANDED_STATE: 1 on ground, 2 in air, 3 taking off, 4 landing."""
        if not self.armed or not self.in_air:
            return 1
        if self.mode == TAKEOFF:
            return 3
        if self.mode == LAND or (self.mode == RTL and self.rtl_phase == 3):
            return 4
        return 2
