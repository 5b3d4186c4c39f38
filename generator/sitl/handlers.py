"""What the SITL flight controller answers to a client: commands (COMMAND_LONG / COMMAND_INT), mode
changes, parameters, offboard setpoints and time sync, as PX4 answers them.

:class:`ClientRequests` is the request side of :class:`~scart_bench.generator.sitl.server.SitlServer`
(which owns the socket, the clock, the telemetry and the recording); the mission protocol is
:mod:`~scart_bench.generator.sitl.missions`', the refusals :mod:`~scart_bench.generator.sitl.checks`'.
"""

from __future__ import annotations

import math

import numpy as np

from scart_bench.generator.mavlink import require_pymavlink
from scart_bench.generator.sitl import checks
from scart_bench.generator.sitl.commander import (
    FRAME_BODY_NED,
    FRAME_BODY_OFFSET,
    FRAME_LOCAL_NED,
    FRAME_LOCAL_OFFSET,
    GLOBAL_FRAMES,
    HOLD,
    LAND,
    MISSION,
    POSCTL,
    RTL,
    mode_from_custom,
)

mavlink = require_pymavlink()

SYSTEM = 1  # this flight controller's MAVLink system id
FORCE_DISARM = 21196

R = mavlink  # short alias for the enums below
ACCEPTED, TEMP_REJECTED, DENIED, UNSUPPORTED = (
    R.MAV_RESULT_ACCEPTED, R.MAV_RESULT_TEMPORARILY_REJECTED, R.MAV_RESULT_DENIED, R.MAV_RESULT_UNSUPPORTED)
_CAPABILITIES = (R.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | R.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                 | R.MAV_PROTOCOL_CAPABILITY_MISSION_INT | R.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                 | R.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                 | R.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT | R.MAV_PROTOCOL_CAPABILITY_MAVLINK2)


def _text(value) -> str:
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    return value.split("\x00", 1)[0]


class ClientRequests:
    """Handlers of the messages a client sends; mixed into the server, whose state they use
    (``commander``, ``plant``, ``stats``, ``_reply``, ``_handlers``)."""

    def _for_us(self, msg) -> bool:
        ts = getattr(msg, "target_system", 0)
        return ts in (0, SYSTEM)

    def handle(self, msg, addr) -> None:
        """Answer one message from a client."""
        name = msg.get_type()
        if name in ("BAD_DATA", "HEARTBEAT") or not self._for_us(msg):
            return
        handler = self._handlers.get(name)
        if handler is not None:
            handler(msg, addr)

    # commands
    def _ack(self, msg, command: int, result: int, addr) -> None:
        self.stats.commands += 1
        if result != ACCEPTED:
            self.stats.rejected += 1
        h = msg.get_header()
        self._reply(mavlink.MAVLink_command_ack_message(command, result, 0, 0, h.srcSystem, h.srcComponent), addr)

    def _on_command_long(self, msg, addr) -> None:
        p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        self._ack(msg, msg.command, self.command(msg.command, p, R.MAV_FRAME_GLOBAL, addr), addr)

    def _on_command_int(self, msg, addr) -> None:
        x = msg.x / 1e7 if msg.frame in GLOBAL_FRAMES else msg.x / 1e4
        y = msg.y / 1e7 if msg.frame in GLOBAL_FRAMES else msg.y / 1e4
        if msg.frame in GLOBAL_FRAMES and msg.x == 0 and msg.y == 0:
            x = y = float("nan")
        p = [msg.param1, msg.param2, msg.param3, msg.param4, x, y, msg.z]
        self._ack(msg, msg.command, self.command(msg.command, p, msg.frame, addr), addr)

    def _height(self, command: int, frame: int, z: float) -> float:
        """A command's param7 as metres above the origin: AMSL, except DO_REPOSITION in a relative frame."""
        fr = frame if command == R.MAV_CMD_DO_REPOSITION and frame in GLOBAL_FRAMES else R.MAV_FRAME_GLOBAL
        return checks.height_of(fr, z, float(self.commander.home[2]))

    def command(self, command: int, p: list[float], frame: int, addr) -> int:
        """Execute one command; the MAV_RESULT (DENIED, with a STATUSTEXT, for refused parameters)."""
        refusal = checks.command_refusal(command, p, self._height(command, frame, p[6]))
        if refusal is not None:
            name = R.enums["MAV_CMD"][command].name if command in R.enums["MAV_CMD"] else str(command)
            self.commander.say(f"{name.removeprefix('MAV_CMD_')} denied: {refusal}", severity=4)
            return DENIED
        return self._execute(command, p, frame, addr)

    def _execute(self, command: int, p: list[float], frame: int, addr) -> int:
        cmd = self.commander

        def result(ok_reason):
            ok, reason = ok_reason
            if not ok and reason:
                cmd.say(reason, severity=4)
            return ACCEPTED if ok else TEMP_REJECTED

        if command == R.MAV_CMD_COMPONENT_ARM_DISARM:
            if round(p[0]) == 1:
                return result(cmd.arm())
            return result(cmd.disarm(force=math.isfinite(p[1]) and int(round(p[1])) == FORCE_DISARM))
        if command == R.MAV_CMD_NAV_TAKEOFF:
            return result(cmd.takeoff(p[6], p[3]))
        if command == R.MAV_CMD_NAV_LAND:
            ok = cmd.set_mode(LAND)
            if ok[0] and not (math.isnan(p[4]) or math.isnan(p[5])):
                cmd.target = cmd.to_ned(R.MAV_FRAME_GLOBAL, p[4], p[5], float("nan"))
            return result(ok)
        if command == R.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return result(cmd.set_mode(RTL))
        if command == R.MAV_CMD_NAV_LOITER_UNLIM:
            return result(cmd.set_mode(HOLD))
        if command == R.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & R.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return UNSUPPORTED
            mode = mode_from_custom(int(p[1]), int(p[2]) if math.isfinite(p[2]) else 0)
            if mode is None:
                cmd.say(f"Mode {int(p[1])}.{int(p[2])} is not flown by this vehicle (no RC)", severity=4)
                return DENIED
            return result(cmd.set_mode(mode))
        if command == R.MAV_CMD_MISSION_START:
            if not cmd.mission:
                cmd.say("Mission rejected: no mission uploaded", severity=4)
                return DENIED
            if math.isfinite(p[0]) and 0 < p[0] < len(cmd.mission):
                cmd.set_current(int(p[0]))
            return result(cmd.set_mode(MISSION))
        if command == R.MAV_CMD_DO_SET_MISSION_CURRENT:
            return ACCEPTED if cmd.set_current(int(p[0])) else DENIED
        if command == R.MAV_CMD_DO_REPOSITION:
            fr = frame if frame in GLOBAL_FRAMES else R.MAV_FRAME_GLOBAL
            target = cmd.to_ned(fr, p[4], p[5], p[6])
            if not checks.target_ok(target):
                return self._denied("DO_REPOSITION", target)
            return result(cmd.reposition(target, p[0], p[3]))
        if command == R.MAV_CMD_DO_CHANGE_SPEED:
            cmd.change_speed(p[1])
            return ACCEPTED
        if command == R.MAV_CMD_DO_SET_HOME:
            home = self.plant.position if p[0] > 0.5 else cmd.to_ned(R.MAV_FRAME_GLOBAL, p[4], p[5], p[6])
            if not checks.target_ok(home):
                return self._denied("DO_SET_HOME", home)
            cmd.set_home(home)
            return ACCEPTED
        if command in (R.MAV_CMD_SET_MESSAGE_INTERVAL,):
            return ACCEPTED  # rates are fixed (the link topics' schedule); acknowledged like PX4
        if command == R.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(int(p[0]), addr)
        if command == R.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._request_message(R.MAVLINK_MSG_ID_AUTOPILOT_VERSION, addr)
        if command == R.MAV_CMD_GET_HOME_POSITION:
            return self._request_message(R.MAVLINK_MSG_ID_HOME_POSITION, addr)
        return UNSUPPORTED

    def _denied(self, what: str, ned: np.ndarray) -> int:
        self.commander.say(f"{what} denied: target {np.round(ned, 1).tolist()} m is out of range", severity=4)
        return DENIED

    def _request_message(self, msgid: int, addr) -> int:
        t_us = self.plant.t_us
        if msgid == R.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            msg = mavlink.MAVLink_autopilot_version_message(
                _CAPABILITIES, (1 << 24) | (14 << 16) | (0 << 8) | 255, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                0, 0, 0x5CA7, [0] * 18)
        elif msgid == R.MAVLINK_MSG_ID_HOME_POSITION:
            msg = self._home(t_us)
        elif msgid == R.MAVLINK_MSG_ID_HEARTBEAT:
            msg = self.heartbeat()
        elif msgid == R.MAVLINK_MSG_ID_MISSION_CURRENT:
            msg = self._mission_current()
        elif msgid == R.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            msg = mavlink.MAVLink_extended_sys_state_message(R.MAV_VTOL_STATE_UNDEFINED,
                                                             self.commander.landed_state())
        else:
            return UNSUPPORTED
        self._reply(msg, addr)
        return ACCEPTED

    def _on_set_mode(self, msg, addr) -> None:
        mode = mode_from_custom((msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF)
        if mode is not None:
            self.commander.set_mode(mode)

    # parameters
    def _param_value(self, name: str):
        idx = self.params.names.index(name)
        return mavlink.MAVLink_param_value_message(name.encode(), self.params.wire_value(name),
                                                   self.params.specs[name].kind, len(self.params.names), idx)

    def _on_param_request_list(self, msg, addr) -> None:
        for name in self.params.names:
            self._reply(self._param_value(name), addr)

    def _on_param_request_read(self, msg, addr) -> None:
        name = _text(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index >= len(self.params.names):
                return
            name = self.params.names[msg.param_index]
        if name in self.params.specs:
            self._reply(self._param_value(name), addr)

    def _on_param_set(self, msg, addr) -> None:
        name = _text(msg.param_id)
        if name not in self.params.specs:
            self.commander.say(f"Parameter {name} unknown", severity=4)
            self._outbox_now(addr)
            return
        value = self.params.from_wire(name, msg.param_value, msg.param_type)
        if not self.params.set(name, value):
            spec = self.params.specs[name]
            self.commander.say(f"Parameter {name}: {value:g} refused" + (
                " (read-only)" if spec.read_only else f" (range {spec.low:g} to {spec.high:g})"), severity=4)
        if name == "MPC_XY_CRUISE" and self.commander.mode in (HOLD, POSCTL):
            self.commander.speed = self.params[name]
        self._broadcast(self._pack(self._param_value(name)))

    def _outbox_now(self, addr) -> None:
        frames = self._outbox(self.plant.t_us)
        if frames:
            self._sendto(b"".join(frames), addr)

    # offboard
    def _on_set_position_target_local_ned(self, msg, addr) -> None:
        mask, cmd = msg.type_mask, self.commander
        pos = np.array([msg.x, msg.y, msg.z], dtype=float)
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        pos[[bool(mask & 1), bool(mask & 2), bool(mask & 4)]] = np.nan
        vel[[bool(mask & 8), bool(mask & 16), bool(mask & 32)]] = np.nan
        c, s = math.cos(cmd.yaw), math.sin(cmd.yaw)
        rot = np.array([[c, -s], [s, c]])  # body (forward, right) -> (north, east) at the current heading
        if msg.coordinate_frame in (FRAME_BODY_NED, FRAME_BODY_OFFSET):
            if not np.isnan(pos[:2]).any():
                pos[:2] = rot @ pos[:2]
            pos = cmd.pos + pos  # NaN stays NaN: that axis is not commanded
            if not np.isnan(vel[:2]).any():
                vel[:2] = rot @ vel[:2]
        elif msg.coordinate_frame == FRAME_LOCAL_OFFSET:
            pos = cmd.pos + pos
        elif msg.coordinate_frame != FRAME_LOCAL_NED:
            return
        self._offboard(msg, pos, vel)

    def _on_set_position_target_global_int(self, msg, addr) -> None:
        mask, cmd = msg.type_mask, self.commander
        pos = np.full(3, np.nan)
        if not mask & 7 and msg.coordinate_frame in GLOBAL_FRAMES:
            lat, lon = msg.lat_int / 1e7, msg.lon_int / 1e7
            if checks.lat_lon_result(lat, lon) != checks.MISSION_ACCEPTED:
                self.stats.ignored_setpoints += 1
                return
            pos = cmd.to_ned(msg.coordinate_frame, lat, lon, msg.alt)
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        vel[[bool(mask & 8), bool(mask & 16), bool(mask & 32)]] = np.nan
        self._offboard(msg, pos, vel)

    def _offboard(self, msg, pos: np.ndarray, vel: np.ndarray) -> None:
        mask = msg.type_mask
        yaw = float("nan") if mask & 1024 else float(msg.yaw)
        rate = float("nan") if mask & 2048 else float(msg.yaw_rate)
        if not checks.setpoint_ok(pos, vel, yaw, rate):
            self.stats.ignored_setpoints += 1
            return
        self.stats.offboard_setpoints += 1
        self.commander.offboard_setpoint(self.plant.t_us, pos, vel, yaw, rate)

    def _on_timesync(self, msg, addr) -> None:
        if msg.tc1 == 0:
            now_ns = int(self.time_s * 1e9)
            self._reply(mavlink.MAVLink_timesync_message(now_ns, msg.ts1), addr)

    # -- the recorded flight ------------------------------------------------------------------------
