"""The built-in generator speaking MAVLink 2 over UDP: flight-controller and mission-computer endpoints.

:class:`MavlinkLink` plugs into :func:`scart_bench.generator.engine.simulate.simulate` as its hooks object (the
``layer`` argument) at the points ``link`` and ``command``. At every step with telemetry, the
flight-controller endpoint (system 1, component 1) encodes the step's messages
(:data:`scart_bench.generator.mavlink.codec.CODECS`), a HEARTBEAT once a second, and a SYSTEM_TIME that
closes the step, in one datagram to the proxy; the mission-computer endpoint (system 1,
component 191) reads datagrams until that step's SYSTEM_TIME arrives and decodes what came
through. A message that did not arrive is not delivered to the navigator. Setpoints go the other
way the same way: SET_POSITION_TARGET_LOCAL_NED every step, MISSION_CURRENT and COMMAND_LONG
(arm/disarm) when they change. The loop runs in lockstep with the link (simulation time, not
wall-clock time), so a flight through a proxy is reproducible.
"""

from __future__ import annotations

import socket
import time

import numpy as np

from scart_bench.generator.mavlink.codec import (
    ARM_DISARM,
    CODECS,
    COMMAND_LONG_ID,
    HEARTBEAT_ID,
    KNOWN,
    MISSION_CURRENT_ID,
    SYSTEM_TIME_ID,
    LinkState,
    Packer,
    split_frames,
)

FLIGHT_CONTROLLER = (1, 1)
MISSION_COMPUTER = (1, 191)


class LinkTimeout(RuntimeError):
    """A step's messages did not come through the proxy in time."""


class _Endpoint:
    """One side of the link: a UDP socket, a packer with its own sequence numbers, a decoder state."""

    def __init__(self, bind: tuple[str, int], ident: tuple[int, int], packer: Packer):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(bind)
        self.system, self.component = ident
        self.packer = packer
        self.seq = 0
        self.state = LinkState()
        self.last_heartbeat_us = -(10**9)
        self.sent: list[bytes] = []
        self.received: list[bytes] = []

    def pack(self, msg) -> bytes:
        out = self.packer.pack(msg, self.system, self.component, self.seq)
        self.seq = (self.seq + 1) & 0xFF
        return out

    def heartbeat(self, t_us: int, mav_type: int, autopilot: int) -> list[bytes]:
        """A HEARTBEAT (system state active) when the last one is a second old."""
        if t_us - self.last_heartbeat_us < 1_000_000:
            return []
        self.last_heartbeat_us = t_us
        return [self.pack(KNOWN[HEARTBEAT_ID](mav_type, autopilot, 0, 0, 4, 3))]

    def closing(self, t_us: int) -> bytes:
        return self.pack(KNOWN[SYSTEM_TIME_ID](0, int(t_us // 1000) & 0xFFFFFFFF))

    def receive_step(self, t_us: int, peer: tuple[int, int], timeout_s: float, keep: bool
                     ) -> tuple[list[tuple[int, object]], tuple[str, int] | None]:
        """Decoded (msgid, message) of the frames that arrive before ``peer``'s SYSTEM_TIME of ``t_us``."""
        want_ms = int(t_us // 1000) & 0xFFFFFFFF
        out: list[tuple[int, object]] = []
        deadline = time.monotonic() + timeout_s
        addr = None
        self.sock.settimeout(timeout_s)
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                data = None
            if data is None or time.monotonic() > deadline:
                raise LinkTimeout(f"no MAVLink traffic for t={t_us / 1e6:.3f} s came through the proxy within "
                                  f"{timeout_s:g} s (is the proxy running and forwarding to "
                                  f"{self.sock.getsockname()}?)")
            if keep:
                self.received.append(data)
            frames, _ = split_frames(data)
            done = False
            for f in frames:
                if f.msgid not in KNOWN:
                    continue
                msg = self.packer.decode(data[f.start:f.end])
                h = msg.get_header()
                if f.msgid == SYSTEM_TIME_ID and (h.srcSystem, h.srcComponent) == peer:
                    done = done or msg.time_boot_ms == want_ms
                    continue
                out.append((f.msgid, msg))
            if done:
                return out, addr


class MavlinkLink:
    """Hooks for :func:`scart_bench.generator.engine.simulate.simulate` that carry the link over MAVLink/UDP through a proxy.

    ``mission_computer`` is where the mission-computer endpoint listens (the proxy's forward
    address); the flight-controller endpoint binds an ephemeral port and sends to the proxy set
    with :meth:`connect`. ``keep_raw`` keeps every datagram sent and received (for checks that
    traffic passed byte-identical). One flight per batch.
    """

    points = frozenset({"link", "command"})

    def __init__(self, mission_computer: tuple[str, int] = ("127.0.0.1", 0), host: str = "127.0.0.1",
                 timeout_s: float = 5.0, keep_raw: bool = False):
        self.packer = Packer()
        self.fc = _Endpoint((host, 0), FLIGHT_CONTROLLER, self.packer)
        self.mc = _Endpoint(mission_computer, MISSION_COMPUTER, self.packer)
        self.proxy: tuple[str, int] | None = None
        self.command_peer: tuple[str, int] | None = None
        self.timeout_s = float(timeout_s)
        self.keep_raw = bool(keep_raw)
        self._last_seq: float | None = None
        self._last_armed: float | None = None

    @property
    def mission_computer_address(self) -> tuple[str, int]:
        return self.mc.sock.getsockname()[:2]

    def connect(self, proxy: tuple[str, int]) -> MavlinkLink:
        """Send telemetry to the proxy listening at ``proxy``."""
        self.proxy = tuple(proxy)
        return self

    def close(self) -> None:
        self.fc.sock.close()
        self.mc.sock.close()

    def __enter__(self) -> MavlinkLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the hooks simulate() calls ---------------------------------------------------------------
    def on_physics(self, step: int, t_us: int) -> dict[str, np.ndarray]:
        return {}

    def on_finish(self, step: int) -> None:
        pass

    def on_messages(self, point: str, step: int, t_us: int, messages: dict[str, np.ndarray]
                    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        if any(v.shape[0] != 1 for v in messages.values()):
            raise ValueError("MavlinkLink carries one flight: simulate with a single seed")
        if point == "link":
            return self._telemetry(t_us, messages)
        if point == "command":
            return self._command(t_us, messages)
        return {t: (v, np.ones(1, bool)) for t, v in messages.items()}

    def _send(self, ep: _Endpoint, frames: list[bytes], addr) -> None:
        data = b"".join(frames)
        if self.keep_raw:
            ep.sent.append(data)
        ep.sock.sendto(data, addr)

    def _collect(self, messages, got, ep: _Endpoint) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        arrived: dict[str, np.ndarray] = {}
        for msgid, msg in got:
            ep.state.observe(msgid, msg)
            for topic in (t for t in messages if t in CODECS):
                codec = CODECS[topic]
                if codec.msgid == msgid:
                    arrived[topic] = np.asarray(codec.decode(msg, ep.state), dtype=np.float64)[None, :]
        out = {}
        for topic, vals in messages.items():
            if topic in arrived:
                out[topic] = (arrived[topic], np.ones(1, bool))
            else:
                out[topic] = (vals, np.zeros(1, bool))
        return out

    def _telemetry(self, t_us: int, messages: dict[str, np.ndarray]) -> dict:
        if self.proxy is None:
            raise RuntimeError("MavlinkLink: call connect(proxy_address) before flying")
        fc = self.fc
        frames = fc.heartbeat(t_us, 2, 12)  # MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4
        frames += [fc.pack(CODECS[t].new_message(v[0], t_us)) for t, v in messages.items()]
        frames.append(fc.closing(t_us))
        self._send(fc, frames, self.proxy)
        got, addr = self.mc.receive_step(t_us, FLIGHT_CONTROLLER, self.timeout_s, self.keep_raw)
        self.command_peer = addr
        return self._collect(messages, got, self.mc)

    def _command(self, t_us: int, messages: dict[str, np.ndarray]) -> dict:
        if self.command_peer is None:
            raise RuntimeError("MavlinkLink: no telemetry has come through the proxy yet")
        mc = self.mc
        sp = messages["setpoint"][0]
        frames = mc.heartbeat(t_us, 18, 8)  # MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID
        if sp[4] != self._last_seq:
            frames.append(mc.pack(KNOWN[MISSION_CURRENT_ID](int(sp[4]))))
            self._last_seq = sp[4]
        if sp[5] != self._last_armed:
            frames.append(mc.pack(KNOWN[COMMAND_LONG_ID](1, 1, ARM_DISARM, 0, 1.0 if sp[5] > 0.5 else 0.0,
                                                         0, 0, 0, 0, 0, 0)))
            self._last_armed = sp[5]
        frames.append(mc.pack(CODECS["setpoint"].new_message(sp, t_us)))
        frames.append(mc.closing(t_us))
        self._send(mc, frames, self.command_peer)
        got, _ = self.fc.receive_step(t_us, MISSION_COMPUTER, self.timeout_s, self.keep_raw)
        # a COMMAND_LONG other than the mission computer's arm request is a command for the flight
        # controller's commander (generator.flight_software.commander), which decides whether to obey it
        commands = [m for i, m in got if i == COMMAND_LONG_ID and not (m.command == ARM_DISARM and m.param1 > 0.5)]
        out = self._collect(messages, [(i, m) for i, m in got if not any(m is c for c in commands)], self.fc)
        for topic, vals in messages.items():
            if topic == "command_long":
                row = vals.copy()
                if commands:
                    c = commands[-1]
                    row[0] = (c.command, c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                              c.target_system, c.target_component)
                out[topic] = (row, np.ones(1, bool))
            elif topic not in CODECS:  # the mission items stay on the mission computer's side here
                out[topic] = (vals, np.ones(1, bool))
        return out

