"""The mission protocol of the sitl: PX4's ``MavlinkMissionManager`` in small.

Upload (``MISSION_COUNT`` -> ``MISSION_REQUEST_INT`` per item -> ``MISSION_ITEM(_INT)`` -> ``MISSION_ACK``):

- a count above :data:`~scart_bench.generator.sitl.checks.MAX_MISSION_ITEMS` is answered
  MAV_MISSION_NO_SPACE, a count of 0 clears the mission (ACCEPTED), a fence or rally upload is
  UNSUPPORTED (this vehicle flies missions only);
- while an upload runs, a MISSION_COUNT from another client is answered MAV_MISSION_ERROR, a
  repeated one from the same client before its first item restarts the request, a later one is
  refused (ERROR) while the upload goes on, as PX4 does;
- each item is checked (:func:`~scart_bench.generator.sitl.checks.mission_item_result`); a refused
  item ends the upload with its MAV_MISSION_RESULT and a STATUSTEXT, the stored mission unchanged;
- an item whose seq lies outside the announced count is answered MAV_MISSION_INVALID_SEQUENCE; an
  item out of order is ignored (a later one makes the expected one be requested again);
- the request is sent again every :data:`RETRY_S` (0.5 s) without an answer, and after
  :data:`TIMEOUT_S` (5 s) without any item the upload gives up with the STATUSTEXT "Operation
  timeout" and the protocol is idle again (PX4's MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT and
  MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT);
- the last item sent again after the ACK (the client missed it) is acknowledged again.

Download (``MISSION_REQUEST_LIST`` -> ``MISSION_COUNT``, ``MISSION_REQUEST(_INT)`` -> item), clear and
set-current are answered at once. The protocol's clock is the wall clock (``clock``), like PX4's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from scart_bench.generator.mavlink import require_pymavlink
from scart_bench.generator.sitl.checks import MAX_MISSION_ITEMS, height_of, mission_item_result
from scart_bench.generator.sitl.commander import GLOBAL_FRAMES, Commander, MissionItem

mavlink = require_pymavlink()
R = mavlink

RETRY_S = 0.5
TIMEOUT_S = 5.0


@dataclass
class Upload:
    """A mission upload in progress: who sends it, how many items, what has arrived."""

    peer: tuple
    sysid: int
    compid: int
    count: int
    mission_type: int
    items: list[MissionItem] = field(default_factory=list)
    sent: float = 0.0  # wall time the last request went out
    heard: float = 0.0  # wall time the client was last heard in this upload

    def partner(self, addr, sysid: int, compid: int) -> bool:
        return (addr, sysid, compid) == (self.peer, self.sysid, self.compid)


def _mission_type(msg) -> int:
    return getattr(msg, "mission_type", 0)


class MissionProtocol:
    """Mission upload, download, clear and set-current for one vehicle's ``commander``.

    ``reply(msg, addr)`` sends a message to one client; ``flush(addr)`` sends the commander's
    pending notifications (STATUSTEXT, MISSION_CURRENT) to it.
    """

    def __init__(self, commander: Commander, reply: Callable, flush: Callable,
                 clock: Callable[[], float] = time.monotonic):
        self.commander = commander
        self.reply = reply
        self.flush = flush
        self.clock = clock
        self.upload: Upload | None = None
        self._done: tuple | None = None  # (peer, sysid, compid, count) of the last accepted upload

    def handlers(self) -> dict[str, Callable]:
        """Message name -> handler, for the server's dispatch."""
        return {name[4:].upper(): getattr(self, name) for name in dir(self) if name.startswith("_on_")}

    # -- upload -----------------------------------------------------------------------------------
    def _ack(self, addr, sysid: int, compid: int, result: int, mission_type: int = 0) -> None:
        self.reply(mavlink.MAVLink_mission_ack_message(sysid, compid, result, mission_type), addr)

    def _on_mission_count(self, msg, addr) -> None:
        h, mtype = msg.get_header(), _mission_type(msg)
        up = self.upload
        if up is not None:
            self._count_while_busy(up, msg, addr)
            return
        if mtype != R.MAV_MISSION_TYPE_MISSION:
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_UNSUPPORTED, mtype)
            return
        if msg.count > MAX_MISSION_ITEMS:
            self.commander.say(f"Mission rejected: {msg.count} items, at most {MAX_MISSION_ITEMS}", severity=4)
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_NO_SPACE, mtype)
            return
        if msg.count == 0:
            self.commander.set_mission([])
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ACCEPTED, mtype)
            return
        now = self.clock()
        self.upload = Upload(addr, h.srcSystem, h.srcComponent, msg.count, mtype, heard=now)
        self._done = None
        self._request()

    def _count_while_busy(self, up: Upload, msg, addr) -> None:
        h = msg.get_header()
        if not up.partner(addr, h.srcSystem, h.srcComponent):
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ERROR, _mission_type(msg))
            return
        up.heard = self.clock()
        if up.items:
            self.commander.say("Mission upload busy: already receiving items", severity=3)
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ERROR, up.mission_type)
            return
        if 0 < msg.count <= MAX_MISSION_ITEMS:  # our first request was lost: ask again
            up.count = msg.count
        self._request()

    def _request(self) -> None:
        up = self.upload
        self.reply(mavlink.MAVLink_mission_request_int_message(up.sysid, up.compid, len(up.items),
                                                               up.mission_type), up.peer)
        up.sent = self.clock()

    def tick(self) -> None:
        """Ask again for an item not answered within RETRY_S; give up after TIMEOUT_S of silence."""
        up = self.upload
        if up is None:
            return
        now = self.clock()
        if now - up.heard > TIMEOUT_S:
            self.upload = None
            self.commander.say("Operation timeout: mission upload aborted", severity=3)
        elif now - up.sent > RETRY_S:
            self._request()

    def _on_mission_item_int(self, msg, addr) -> None:
        scale = 1e7 if msg.frame in GLOBAL_FRAMES else 1e4
        self._item(msg, msg.x / scale, msg.y / scale, addr)

    def _on_mission_item(self, msg, addr) -> None:
        self._item(msg, msg.x, msg.y, addr)

    def _item(self, msg, x: float, y: float, addr) -> None:
        up, h = self.upload, msg.get_header()
        if up is None:
            self._item_when_idle(msg, addr)
            return
        if not up.partner(addr, h.srcSystem, h.srcComponent):
            self.commander.say("Mission item refused: another client is uploading", severity=3)
            return
        if _mission_type(msg) != up.mission_type:
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ERROR, _mission_type(msg))
            return
        up.heard = self.clock()
        if msg.seq >= up.count:
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_INVALID_SEQUENCE, up.mission_type)
            return
        if msg.seq != len(up.items):
            if msg.seq > len(up.items):
                self._request()
            return
        item = MissionItem(msg.seq, msg.frame, msg.command, msg.param1, msg.param2, msg.param3, msg.param4,
                           x, y, msg.z, msg.autocontinue)
        result = self._check(item)
        if result != R.MAV_MISSION_ACCEPTED:
            self.upload = None
            self.commander.say(f"Mission item {msg.seq} refused ({_result_name(result)})", severity=3)
            self._ack(addr, h.srcSystem, h.srcComponent, result, up.mission_type)
            self.flush(addr)
            return
        up.items.append(item)
        if len(up.items) < up.count:
            self._request()
            return
        self._accept(up, addr)

    def _check(self, item: MissionItem) -> int:
        return mission_item_result(item, height_of(item.frame, item.z, float(self.commander.home[2])))

    def _accept(self, up: Upload, addr) -> None:
        self.upload = None
        self._done = (up.peer, up.sysid, up.compid, up.count)
        self.commander.set_mission(up.items)
        self._ack(addr, up.sysid, up.compid, R.MAV_MISSION_ACCEPTED, up.mission_type)
        self.commander.say(f"Mission of {up.count} items accepted")
        self.flush(addr)

    def _item_when_idle(self, msg, addr) -> None:
        h = msg.get_header()
        done = self._done
        if done is not None and done[:3] == (addr, h.srcSystem, h.srcComponent) and msg.seq == done[3] - 1:
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ACCEPTED, _mission_type(msg))
            return
        self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ERROR, _mission_type(msg))

    # -- download, clear, set current -------------------------------------------------------------
    def _on_mission_request_list(self, msg, addr) -> None:
        h, mtype = msg.get_header(), _mission_type(msg)
        n = len(self.commander.mission) if mtype == R.MAV_MISSION_TYPE_MISSION else 0
        self.reply(mavlink.MAVLink_mission_count_message(h.srcSystem, h.srcComponent, n, mtype), addr)

    def _on_mission_request_int(self, msg, addr) -> None:
        self._send_item(msg, addr, True)

    def _on_mission_request(self, msg, addr) -> None:
        self._send_item(msg, addr, False)

    def _send_item(self, msg, addr, as_int: bool) -> None:
        h, mtype = msg.get_header(), _mission_type(msg)
        items = self.commander.mission
        if mtype != R.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(items):
            self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_INVALID_SEQUENCE, mtype)
            return
        it = items[msg.seq]
        current = 1 if it.seq == self.commander.seq else 0
        args = (h.srcSystem, h.srcComponent, it.seq, it.frame, it.command, current, it.autocontinue, it.param1,
                it.param2, it.param3, it.param4)
        if as_int:
            scale = 1e7 if it.frame in GLOBAL_FRAMES else 1e4
            out = mavlink.MAVLink_mission_item_int_message(*args, _wire_int(it.x, scale), _wire_int(it.y, scale),
                                                           it.z, 0)
        else:
            out = mavlink.MAVLink_mission_item_message(*args, it.x, it.y, it.z, 0)
        self.reply(out, addr)

    def _on_mission_clear_all(self, msg, addr) -> None:
        h, mtype = msg.get_header(), _mission_type(msg)
        if mtype in (R.MAV_MISSION_TYPE_MISSION, R.MAV_MISSION_TYPE_ALL):
            self.upload = None
            self.commander.set_mission([])
        self._ack(addr, h.srcSystem, h.srcComponent, R.MAV_MISSION_ACCEPTED, mtype)
        self.flush(addr)

    def _on_mission_set_current(self, msg, addr) -> None:
        if not self.commander.set_current(msg.seq):
            self.commander.say(f"Mission item {msg.seq} does not exist", severity=4)
        self.flush(addr)


def file_items(mission, home: tuple[float, float, float]) -> list[MissionItem]:
    """The items of a mission file (:class:`scart_bench.generator.flight_software.mission_files.MissionFile`) to upload to a
    vehicle whose home is ``home`` (deg, deg, m AMSL), as a ground station would send them.

    The mission is moved to the vehicle's home: each position keeps its north/east offset and its height
    above the file's home (the WGS-84 tangent plane, generator.geo), in the frame the file states it
    (global AMSL, global relative or local NED); commands and parameters are the file's. Skipped items
    (camera, gimbal) are not sent."""
    from scart_bench.generator.flight_software.mission_files import (
        AMSL_FRAMES,
        CMD_CHANGE_SPEED,
        CMD_LOITER_TIME,
        CMD_RTL,
        CMD_WAYPOINT,
        FRAME_LOCAL_NED,
        FRAME_MISSION,
    )
    from scart_bench.generator.geo import latlon_from_ne

    lat0, lon0, alt0 = (float(v) for v in home)
    out: list[MissionItem] = []
    for c in mission.commands:
        seq = len(out)
        if c.command == CMD_CHANGE_SPEED:
            speed = -1.0 if c.speed is None else c.speed
            out.append(MissionItem(seq, FRAME_MISSION, c.command, 1.0, speed, -1.0, 0.0, 0.0, 0.0, 0.0))
            continue
        if c.command == CMD_RTL:
            out.append(MissionItem(seq, FRAME_MISSION, c.command))
            continue
        hold = c.hold_s if c.command in (CMD_WAYPOINT, CMD_LOITER_TIME) else 0.0
        if c.frame == FRAME_LOCAL_NED:
            out.append(MissionItem(seq, c.frame, c.command, hold, 0.0, 0.0, float("nan"), c.north, c.east, -c.up))
            continue
        lat, lon = latlon_from_ne(c.north, c.east, lat0, lon0)
        z = alt0 + c.up if c.frame in AMSL_FRAMES else c.up
        out.append(MissionItem(seq, c.frame, c.command, hold, 0.0, 0.0, float("nan"), float(lat), float(lon), z))
    return out


def _wire_int(value: float, scale: float) -> int:
    """A coordinate as MISSION_ITEM_INT carries it; NaN ("the current position") goes out as 0."""
    return 0 if math.isnan(value) else int(round(value * scale))


def _result_name(result: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else str(result)
