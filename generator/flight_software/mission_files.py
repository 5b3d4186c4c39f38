"""Missions as data: QGroundControl ``.plan`` files and MAVLink WPL (``QGC WPL 110``) mission files.

A file is read into a :class:`MissionFile`: its home and its commands, each resolved to north/east
metres about the mission's own home (WGS-84 tangent plane, :func:`scart_bench.generator.geo.ne_from_latlon`)
and a height above home. The generator's navigator flies it as a table of items
(:meth:`MissionFile.navigator_items`: take-off point, positions, landing spot, each with the speed
of the leg to it and its hold time); the sitl is sent the commands themselves
(:func:`scart_bench.generator.sitl.missions.file_items`).

Flown: MAV_CMD_NAV_TAKEOFF (22), NAV_WAYPOINT (16, param1 hold s), NAV_LOITER_TIME (19, param1 s),
DO_CHANGE_SPEED (178, param2 m/s; -1 no change, -2 back to the default), NAV_RETURN_TO_LAUNCH (20)
and NAV_LAND (21), in the frames global (0 and 5: altitude above mean sea level, taken about the
file's home altitude), global relative altitude (3 and 6) and local NED (1: x north, y east, z down,
metres from home). Camera, gimbal, relay and servo items do not move the vehicle and are skipped.
Anything else (a survey, a loiter without end, a jump) is refused: one line naming the file, the
item and what was expected.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scart_bench.errors import ScartBenchError

CMD_WAYPOINT, CMD_LOITER_TIME, CMD_RTL, CMD_LAND, CMD_TAKEOFF, CMD_CHANGE_SPEED = 16, 19, 20, 21, 22, 178
COMMAND_NAMES = {CMD_WAYPOINT: "NAV_WAYPOINT", CMD_LOITER_TIME: "NAV_LOITER_TIME", CMD_RTL: "NAV_RETURN_TO_LAUNCH",
                 CMD_LAND: "NAV_LAND", CMD_TAKEOFF: "NAV_TAKEOFF", CMD_CHANGE_SPEED: "DO_CHANGE_SPEED"}
POSITION_COMMANDS = frozenset({CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LAND, CMD_TAKEOFF})
#: items that do not move the vehicle (camera, gimbal, relay, servo, region of interest): skipped
SKIPPED_COMMANDS = frozenset({80, 181, 182, 183, 184, 195, 200, 201, 202, 203, 204, 205, 206, 214, 530, 531, 532,
                              1000, 1001, 2000, 2001, 2003, 2004, 2500, 2501})
FRAME_GLOBAL, FRAME_LOCAL_NED, FRAME_MISSION, FRAME_GLOBAL_REL, FRAME_GLOBAL_INT, FRAME_GLOBAL_REL_INT = 0, 1, 2, 3, 5, 6
AMSL_FRAMES = frozenset({FRAME_GLOBAL, FRAME_GLOBAL_INT})
RELATIVE_FRAMES = frozenset({FRAME_GLOBAL_REL, FRAME_GLOBAL_REL_INT})
POSITION_FRAMES = AMSL_FRAMES | RELATIVE_FRAMES | {FRAME_LOCAL_NED}

#: what a mission may ask (beyond it, a typo rather than a flight plan)
MAX_DISTANCE_M = 10_000.0  # from home
MIN_HEIGHT_M, MAX_HEIGHT_M = 1.0, 500.0  # above home, for a position the vehicle flies to
MAX_SPEED = 20.0  # m/s (MPC_XY_VEL_MAX's upper bound)
MAX_HOLD_S = 3600.0
#: items of the navigator's table (take-off, positions, landing spot): the attack layer's MISSION message
#: (generator.flight_software.commander.MAX_MISSION_ITEMS) carries at most this many
MAX_NAV_ITEMS = 32
MAX_FILE_BYTES = 4 * 1024 * 1024


class MissionFileError(ScartBenchError):
    """A mission file that cannot be flown: the file, the item and what was expected."""


@dataclass(frozen=True)
class MissionCommand:
    """One flown item of a mission file, resolved about the mission's home.

    ``north``/``east`` (m from home) and ``up`` (m above home) are the position the item flies to (the
    take-off's is home; a land or return item's is where it lands). ``frame`` is the file's frame,
    kept so the sitl is sent the item as the file states it."""

    index: int  # the item's number (as QGroundControl shows it: home is 0, a .plan's first item 1; a WPL line's index)
    command: int
    frame: int
    hold_s: float = 0.0
    speed: float | None = None  # DO_CHANGE_SPEED: new cruise speed (m/s; None: no change; -2: the default)
    north: float = 0.0
    east: float = 0.0
    up: float = 0.0


@dataclass(frozen=True)
class MissionFile:
    """A mission read from a file: its home (deg, deg, m AMSL), default cruise speed (None: the
    generator's) and the commands it flies."""

    name: str
    home: tuple[float, float, float]
    cruise_speed: float | None
    commands: tuple[MissionCommand, ...]

    def navigator_items(self, cruise: float) -> np.ndarray:
        """(K, 5) the navigator's items: north, east, down (m), speed of the leg to the item (m/s), hold
        at the item (s). Item 0 is the take-off point above home, the last where the vehicle lands.

        No take-off item: the vehicle takes off to the first position's height. A return (RTL) flies
        home at the height it has, at the default cruise speed, and lands there; a land item flies to
        its spot at the height it has and lands; a mission that ends otherwise lands at its last position."""
        base = self.cruise_speed if self.cruise_speed is not None else cruise
        speed = base
        rows: list[list[float]] = []
        for c in self.commands:
            if c.command == CMD_CHANGE_SPEED:
                speed = base if c.speed == -2.0 else (speed if c.speed is None else c.speed)
            elif c.command == CMD_TAKEOFF and not rows:
                rows.append([0.0, 0.0, -c.up, speed, 0.0])
            else:
                if not rows:
                    rows.append([0.0, 0.0, -c.up, speed, 0.0])
                # the return flies at the default cruise speed (PX4's RTL does not keep a mission's speed change)
                rows.append([c.north, c.east, -c.up, base if c.command == CMD_RTL else speed, c.hold_s])
        return np.array(rows, dtype=float)

    def duration_s(self, cruise: float, climb: float = 2.5, land_speed: float = 0.7) -> float:
        """A generous bound of the flight's length (s): ground phase, legs at 70 % of their speed plus
        the braking into each item, holds, climbs and the landing (the flights' time limit)."""
        items = self.navigator_items(cruise)
        t = 30.0 + 10.0 + (-items[0, 2]) / 1.0  # ground phase, take-off hold, the take-off climb (~1 m/s)
        for a, b in zip(items[:-1], items[1:]):
            t += math.hypot(b[0] - a[0], b[1] - a[1]) / (0.7 * b[3]) + abs(b[2] - a[2]) / min(climb, 1.5)
            t += b[3] / 1.5 + b[4] + 5.0
        return t + (-items[-1, 2]) / land_speed + 30.0


def _number(value, what: str, where: str) -> float:
    """A finite number (a .plan's null is NaN: "not given")."""
    if value is None:
        return float("nan")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MissionFileError(f"{where}: expected a number for {what}, got {value!r}")
    return float(value)


def _fail(where: str, expected: str) -> MissionFileError:
    return MissionFileError(f"{where}: expected {expected}")


def _resolve(path: str, rows: list[tuple[int, str, int, int, list[float]]], home: tuple[float, float, float],
             cruise: float | None) -> MissionFile:
    """The flown commands of ``rows`` (item number, where it is in the file, command, frame,
    [p1..p4, x, y, z]) about ``home``."""
    from scart_bench.generator.geo import ne_from_latlon

    lat0, lon0, alt0 = home
    commands: list[MissionCommand] = []
    north, east, up = 0.0, 0.0, float("nan")  # where the vehicle is when the item starts
    ended = None
    for index, place, cmd, frame, p in rows:
        name = COMMAND_NAMES.get(cmd, f"command {cmd}")
        where = f"{path}: item {index} ({place}{name})"
        if cmd in SKIPPED_COMMANDS:
            continue
        if cmd not in COMMAND_NAMES:
            raise _fail(where, "one of NAV_TAKEOFF (22), NAV_WAYPOINT (16), NAV_LOITER_TIME (19), DO_CHANGE_SPEED "
                        "(178), NAV_RETURN_TO_LAUNCH (20), NAV_LAND (21), or a camera/gimbal item")
        if ended is not None:
            raise _fail(where, f"no item after the mission's {COMMAND_NAMES[ended[1]]} (item {ended[0]})")
        if cmd == CMD_CHANGE_SPEED:
            if not (math.isnan(p[0]) or p[0] in (0.0, 1.0)):
                raise _fail(where, f"param1 (speed type) 0 or 1 (airspeed or ground speed), got {p[0]:g}")
            if not (p[1] in (-1.0, -2.0) or 0.0 < p[1] <= MAX_SPEED):
                raise _fail(where, f"param2 (speed) in (0, {MAX_SPEED:g}] m/s, or -1 (no change) or -2 (default), "
                            f"got {p[1]:g}")
            commands.append(MissionCommand(index, cmd, frame, speed=None if p[1] == -1.0 else p[1]))
            continue
        if cmd == CMD_RTL:
            if math.isnan(up):
                raise _fail(where, "a position before the return (a take-off or waypoint)")
            commands.append(MissionCommand(index, cmd, frame, north=0.0, east=0.0, up=up))
            ended = (index, cmd)
            continue
        if frame not in POSITION_FRAMES:
            raise _fail(where, f"frame 0 or 5 (global, AMSL), 3 or 6 (global, relative altitude) or 1 (local NED), "
                        f"got frame {frame}")
        x, y, z = p[4], p[5], p[6]
        for value, what in ((x, "x"), (y, "y"), (z, "z (altitude)")):
            if math.isinf(value):
                raise _fail(where, f"a finite {what}, got {value}")
        if frame == FRAME_LOCAL_NED:
            n, e = (north if math.isnan(x) else x), (east if math.isnan(y) else y)
            h = up if math.isnan(z) else -z
        else:
            given = not (math.isnan(x) or math.isnan(y) or (x == 0.0 and y == 0.0))
            if given and not -90.0 <= x <= 90.0:
                raise _fail(where, f"a latitude within +-90 deg, got {x:g}")
            if given and not -180.0 <= y <= 180.0:
                raise _fail(where, f"a longitude within +-180 deg, got {y:g}")
            if given:
                nn, ee = ne_from_latlon(x, y, lat0, lon0)
                n, e = float(nn), float(ee)
            else:
                n, e = north, east
            h = up if math.isnan(z) else (z - alt0 if frame in AMSL_FRAMES else z)
        if cmd == CMD_TAKEOFF:
            n, e = 0.0, 0.0
            if commands and any(c.command != CMD_CHANGE_SPEED for c in commands):
                raise _fail(where, "the take-off first (before any position)")
        if cmd == CMD_LAND:
            h = up  # flies to the landing spot at the height it has, then descends
        if math.isnan(h):
            raise _fail(where, "an altitude (the first position item must state one)")
        if math.hypot(n, e) > MAX_DISTANCE_M:
            raise _fail(where, f"a position within {MAX_DISTANCE_M:g} m of home, got {math.hypot(n, e):.0f} m")
        if not MIN_HEIGHT_M <= h <= MAX_HEIGHT_M:
            raise _fail(where, f"an altitude {MIN_HEIGHT_M:g} to {MAX_HEIGHT_M:g} m above home, got {h:.1f} m")
        hold = 0.0
        if cmd in (CMD_WAYPOINT, CMD_LOITER_TIME):
            hold = 0.0 if math.isnan(p[0]) else p[0]
            if not 0.0 <= hold <= MAX_HOLD_S:
                raise _fail(where, f"param1 (hold time) 0 to {MAX_HOLD_S:g} s, got {hold:g}")
        commands.append(MissionCommand(index, cmd, frame, hold_s=hold, north=n, east=e, up=h))
        north, east, up = n, e, h
        if cmd == CMD_LAND:
            ended = (index, cmd)
    if not any(c.command in POSITION_COMMANDS and c.command != CMD_TAKEOFF or c.command == CMD_RTL
               for c in commands):
        raise MissionFileError(f"{path}: expected at least one waypoint, loiter, return or land item, found none")
    mission = MissionFile(Path(path).name, (float(lat0), float(lon0), float(alt0)), cruise, tuple(commands))
    k = len(mission.navigator_items(5.0))
    if k > MAX_NAV_ITEMS:
        raise MissionFileError(f"{path}: expected at most {MAX_NAV_ITEMS - 1} positions (take-off point included: "
                               f"{MAX_NAV_ITEMS} navigator items), got {k}")
    return mission


def read_plan(path: str | Path) -> MissionFile:
    """A QGroundControl ``.plan`` file (JSON): its mission's SimpleItems about ``plannedHomePosition``."""
    text = _text(path)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise MissionFileError(f"{path}: expected a QGroundControl .plan (JSON), line {e.lineno}: {e.msg}") from None
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise MissionFileError(f'{path}: expected a QGroundControl .plan ("fileType": "Plan")')
    mission = doc.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise MissionFileError(f'{path}: expected "mission": {{"items": [...]}}')
    home = mission.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) == 3):
        raise MissionFileError(f'{path}: expected "mission.plannedHomePosition": [latitude, longitude, altitude AMSL]')
    home_t = tuple(_number(v, "plannedHomePosition", f"{path}: mission.plannedHomePosition") for v in home)
    if not all(math.isfinite(v) for v in home_t) or not (-90 <= home_t[0] <= 90 and -180 <= home_t[1] <= 180):
        raise MissionFileError(f"{path}: expected mission.plannedHomePosition a finite latitude (+-90), longitude "
                               f"(+-180) and altitude, got {home}")
    cruise = None
    for key in ("hoverSpeed", "cruiseSpeed"):  # a multicopter flies hoverSpeed
        if key in mission:
            v = _number(mission[key], key, f"{path}: mission.{key}")
            if not 0.0 < v <= MAX_SPEED:
                raise MissionFileError(f"{path}: mission.{key}: expected a speed in (0, {MAX_SPEED:g}] m/s, got {v:g}")
            cruise = v
            break
    rows = []
    for i, item in enumerate(mission["items"]):
        where = f"{path}: item {i + 1} (mission.items[{i}])"
        if not isinstance(item, dict):
            raise MissionFileError(f"{where}: expected an object (a SimpleItem)")
        kind = item.get("type")
        if kind == "ComplexItem":
            raise MissionFileError(f"{where[:-1]}, {item.get('complexItemType', 'complex item')}): expected a SimpleItem "
                                   "(surveys, corridor scans and structure scans are not expanded; fly their "
                                   "waypoints as SimpleItems)")
        if kind != "SimpleItem":
            raise MissionFileError(f'{where}: expected "type": "SimpleItem", got {kind!r}')
        cmd, frame, params = item.get("command"), item.get("frame"), item.get("params")
        if not isinstance(cmd, int) or isinstance(cmd, bool):
            raise MissionFileError(f'{where}: expected "command" a MAV_CMD number, got {cmd!r}')
        if not isinstance(frame, int) or isinstance(frame, bool):
            raise MissionFileError(f'{where}: expected "frame" a MAV_FRAME number, got {frame!r}')
        if not (isinstance(params, list) and len(params) == 7):
            raise MissionFileError(f'{where}: expected "params" a list of 7 numbers (param1-4, latitude, longitude, '
                                   f"altitude), got {params!r}")
        p = [_number(v, f"params[{k}]", where) for k, v in enumerate(params)]
        rows.append((i + 1, f"mission.items[{i}], ", cmd, frame, p))
    return _resolve(str(path), rows, home_t, cruise)


def read_wpl(path: str | Path) -> MissionFile:
    """A MAVLink WPL file (``QGC WPL 110``): item 0 is home, the others the mission (tab-separated:
    index, current, frame, command, param1-4, x/latitude, y/longitude, z/altitude, autocontinue)."""
    lines = [(k + 1, line) for k, line in enumerate(_text(path).splitlines()) if line.strip()]
    if not lines or lines[0][1].split() != ["QGC", "WPL", "110"]:
        raise MissionFileError(f"{path}: line 1: expected the header 'QGC WPL 110'")
    rows = []
    for lineno, line in lines[1:]:
        fields = line.split()
        where = f"{path}: line {lineno}"
        if len(fields) != 12:
            raise MissionFileError(f"{where}: expected 12 tab-separated fields (index, current, frame, command, "
                                   f"param1-4, x, y, z, autocontinue), got {len(fields)}")
        try:
            index, _, frame, cmd = (int(f) for f in fields[:4])
            p = [float(f) for f in fields[4:11]]
        except ValueError:
            raise MissionFileError(f"{where}: expected whole numbers for index, current, frame and command and "
                                   f"numbers for param1-4, x, y, z, got {line.strip()!r}") from None
        if index != len(rows):
            raise MissionFileError(f"{where}: expected item index {len(rows)}, got {index}")
        rows.append((index, f"line {lineno}, ", cmd, frame, p))
    if not rows:
        raise MissionFileError(f"{path}: expected item 0 (home) and the mission's items, found no items")
    _, _, _, frame0, p0 = rows[0]
    home = (p0[4], p0[5], p0[6] if frame0 in AMSL_FRAMES else float("nan"))
    if frame0 not in AMSL_FRAMES or not all(math.isfinite(v) for v in home) or not (
            -90 <= home[0] <= 90 and -180 <= home[1] <= 180):
        raise MissionFileError(f"{path}: item 0 (home): expected frame 0 (global, AMSL) with a finite latitude "
                               f"(+-90), longitude (+-180) and altitude, got frame {frame0}, {p0[4:7]}")
    return _resolve(str(path), rows[1:], home, None)


def _text(path: str | Path) -> str:
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > MAX_FILE_BYTES:
            raise MissionFileError(f"{path}: expected a mission file of at most {MAX_FILE_BYTES // 2**20} MiB, "
                                   f"got {size / 2**20:.1f} MiB")
        return p.read_text(encoding="utf-8")
    except MissionFileError:
        raise
    except UnicodeDecodeError:
        raise MissionFileError(f"{path}: expected a UTF-8 text file (a .plan or QGC WPL 110 mission)") from None
    except OSError as e:
        raise MissionFileError(f"{path}: cannot read the mission file ({e.strerror or e})") from None


def read_mission(path: str | Path) -> MissionFile:
    """A ``.plan`` (JSON) or WPL (``.waypoints``, ``.txt``: ``QGC WPL 110``) mission file, by its content."""
    text = _text(path)
    if text.lstrip().startswith("{"):
        return read_plan(path)
    if text.lstrip().startswith("QGC WPL"):
        return read_wpl(path)
    raise MissionFileError(f"{path}: expected a QGroundControl .plan (JSON) or a 'QGC WPL 110' waypoint file")


def read_missions(paths) -> tuple[MissionFile, ...]:
    """Every file of ``paths``, read and checked (the first bad one raises :class:`MissionFileError`)."""
    return tuple(read_mission(p) for p in paths)


def mission_for_seed(missions, seed: int) -> int:
    """Which of ``missions`` the flight with ``seed`` flies: ``seed mod len(missions)`` (the same in any
    batch, and for the attacked copies of a flight, which keep its seed)."""
    return int(seed) % len(missions)


def with_missions(config, missions):
    """``config`` (a FlightConfig) flying ``missions`` (flight ``i``: file ``seed mod len(missions)``), with a
    time limit long enough for the longest of them."""
    import dataclasses

    m = config.mission
    missions = tuple(missions)
    if not missions:
        return config
    longest = max(mf.duration_s(m.cruise_speed, m.climb_speed, m.land_speed) for mf in missions)
    mission = dataclasses.replace(m, missions=missions, max_duration_s=max(m.max_duration_s, float(math.ceil(longest))))
    return dataclasses.replace(config, mission=mission)
