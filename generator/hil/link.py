"""The flight controller's end of PX4's simulator MAVLink API, over UDP or TCP.

The simulator (jMAVSim, PX4's Gazebo-classic plugin, AirSim in PX4 mode) sends HIL_SENSOR (IMU,
magnetometer, pressure), HIL_GPS and, when asked with MAV_CMD_SET_MESSAGE_INTERVAL for message 115,
HIL_STATE_QUATERNION (its ground truth); the flight controller answers every HIL_SENSOR with
HIL_ACTUATOR_CONTROLS (motor commands 0..1), which in lockstep is what advances the simulator's
clock, and sends a HEARTBEAT at least once a second (jMAVSim resets after 3 s without one).

Both transports PX4 uses with its simulators are here: :class:`SimLink` (UDP: jMAVSim's ``-udp``,
Gazebo classic with ``use_tcp`` false, AirSim with ``"UseTcp": false``) and :class:`TcpSimLink`
(TCP: jMAVSim's ``-tcp``, Gazebo classic's default and AirSim with ``"UseTcp": true`` serve a port,
4560 by default, and the flight controller connects, as PX4 does). :func:`open_link` makes either
from an address ``udp:HOST:PORT``, ``tcp:HOST:PORT`` (connect) or ``udp-listen:HOST:PORT`` /
``tcp-listen:HOST:PORT`` (wait for a simulator that speaks or connects first).
"""

from __future__ import annotations

import select
import socket
import time

from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.mavlink import require_pymavlink

mavlink = require_pymavlink()

SYSTEM, COMPONENT = 1, 1
HIL_STATE_QUATERNION = 115
#: base mode flags a PX4 flight controller sends to its simulator
MODE_HIL = mavlink.MAV_MODE_FLAG_HIL_ENABLED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


class SimLink:
    """A UDP socket talking MAVLink 2 to a simulator.

    ``address``: the simulator listens there and answers to our port (jMAVSim's ``-udp PORT``).
    ``listen``: instead, we listen there and answer whoever sends first (PX4's side of UDP 14560,
    where Gazebo classic with ``use_tcp`` false and AirSim with ``"UseTcp": false`` send to).
    """

    def __init__(self, address: tuple[str, int] | None = None, listen: tuple[str, int] | None = None):
        if (address is None) == (listen is None):
            raise ValueError("SimLink needs either the simulator's address or a local address to listen on")
        self.address = address
        self.listening = listen is not None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        if listen is not None:
            self.sock.bind(listen)
        else:
            self.sock.bind(("127.0.0.1" if address[0] in ("127.0.0.1", "localhost") else "0.0.0.0", 0))
        self.sock.setblocking(False)
        self._start_counters()

    def _start_counters(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=SYSTEM, srcComponent=COMPONENT)
        self.mav.robust_parsing = True
        self.sent = 0
        self.received = 0
        self.last_heartbeat = 0.0

    def send(self, msg) -> bool:
        """Send ``msg``; False when listening and no simulator has spoken yet (nowhere to send)."""
        if self.address is None:
            return False
        self.sock.sendto(msg.pack(self.mav), self.address)
        self.sent += 1
        return True

    def _parse(self, data: bytes) -> list:
        msgs = self.mav.parse_buffer(data) or []
        return [m for m in msgs if m.get_type() != "BAD_DATA"]

    def heartbeat(self, armed: bool) -> None:
        """A PX4 quadrotor's HEARTBEAT (HIL enabled; the armed flag as the motors are)."""
        mode = MODE_HIL | (ARMED if armed else 0)
        if self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, mode, 0,
                                               mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY)):
            self.last_heartbeat = time.monotonic()

    def request_truth(self, interval_us: int) -> None:
        """Ask for HIL_STATE_QUATERNION every ``interval_us`` (MAV_CMD_SET_MESSAGE_INTERVAL)."""
        self.send(self.mav.command_long_encode(0, 0, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                               float(HIL_STATE_QUATERNION), float(interval_us), 0, 0, 0, 0, 0))

    def actuators(self, t_us: int, controls, armed: bool) -> None:
        """HIL_ACTUATOR_CONTROLS with ``controls`` (up to 16, 0..1) for the simulator time ``t_us``."""
        c = [float(v) for v in controls][:16]
        c += [0.0] * (16 - len(c))
        mode = MODE_HIL | (ARMED if armed else 0)
        self.send(self.mav.hil_actuator_controls_encode(int(t_us), c, mode, 0))

    def receive(self, timeout: float) -> list:
        """The messages that arrive within ``timeout`` s (all that are waiting once one has)."""
        out = []
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return out
        while True:
            try:
                data, peer = self.sock.recvfrom(65536)
            except BlockingIOError:
                break
            if self.listening:
                self.address = peer[:2]  # answer the simulator that sends
            out.extend(self._parse(data))
        self.received += len(out)
        return out

    def wait_first(self, timeout_s: float, alive=None) -> list:
        """Say hello (HEARTBEAT) until the simulator sends anything; HilError after ``timeout_s``.

        ``alive()``: False when the simulator's process has ended (the wait stops at once).
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.heartbeat(False)
            got = self.receive(0.2)
            if got:
                return got
            if alive is not None and not alive():
                raise HilError(f"the simulator ({self.where()}) ended before its first message")
        raise HilError(f"the simulator ({self.where()}) sent no message in {timeout_s:g} s "
                       "(is it running, on this port?)")

    def where(self) -> str:
        if self.listening:
            host, port = self.sock.getsockname()[:2]
            return f"expected on udp:{host}:{port}"
        return f"udp:{self.address[0]}:{self.address[1]}"

    def close(self) -> None:
        self.sock.close()


#: seconds a send on a TCP link may wait for room before the simulator counts as gone
SEND_TIMEOUT_S = 10.0


class TcpSimLink(SimLink):
    """A TCP stream talking MAVLink 2 to a simulator.

    ``address``: the simulator serves there and we connect (jMAVSim's ``-tcp HOST:PORT``; the
    connection is retried until :meth:`wait_first`'s timeout, as the simulator may still be starting).
    ``listen``: we serve there and take the first simulator that connects (for a simulator that is a
    TCP client; jMAVSim, Gazebo classic and AirSim are servers).
    A stream that closes is a :class:`HilError` naming the address.
    """

    def __init__(self, address: tuple[str, int] | None = None, listen: tuple[str, int] | None = None):
        if (address is None) == (listen is None):
            raise ValueError("TcpSimLink needs either the simulator's address or a local address to listen on")
        self.address = address
        self.listening = listen is not None
        self.server: socket.socket | None = None
        self.sock: socket.socket | None = None
        if listen is not None:
            self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.server.bind(listen)
            self.server.listen(1)
            self.server.setblocking(False)
        self._start_counters()

    def _connect(self) -> bool:
        """Connect (or accept) once; True when the stream is up."""
        if self.sock is not None:
            return True
        if self.server is not None:
            ready, _, _ = select.select([self.server], [], [], 0.2)
            if not ready:
                return False
            sock, peer = self.server.accept()
            self.address = peer[:2]
        else:
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.settimeout(1.0)
            try:
                sock.connect(self.address)
            except OSError:
                sock.close()
                time.sleep(0.2)
                return False
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(SEND_TIMEOUT_S)  # blocking sends (a stream takes whole messages); reads go through select
        self.sock = sock
        return True

    def send(self, msg) -> bool:
        """Send ``msg`` on the stream; False while it is not connected yet."""
        if self.sock is None:
            return False
        try:
            self.sock.sendall(msg.pack(self.mav))
        except OSError as exc:
            raise HilError(f"the simulator ({self.where()}) closed the connection: {exc}") from None
        self.sent += 1
        return True

    def receive(self, timeout: float) -> list:
        """The messages that arrive within ``timeout`` s (all that are waiting once one has)."""
        if self.sock is None and not self._connect():
            return []
        out = []
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return out
        while True:
            try:
                data = self.sock.recv(65536)
            except OSError as exc:
                raise HilError(f"the simulator ({self.where()}) closed the connection: {exc}") from None
            if not data:
                if out:
                    break
                raise HilError(f"the simulator ({self.where()}) closed the connection")
            out.extend(self._parse(data))
            if not select.select([self.sock], [], [], 0)[0]:
                break
        self.received += len(out)
        return out

    def wait_first(self, timeout_s: float, alive=None) -> list:
        """Connect (or wait for the simulator to connect), then as :meth:`SimLink.wait_first`."""
        end = time.monotonic() + timeout_s
        while not self._connect():
            if alive is not None and not alive():
                raise HilError(f"the simulator ({self.where()}) ended before it took the connection")
            if time.monotonic() >= end:
                what = "connected" if self.listening else "accepted the connection"
                raise HilError(f"the simulator ({self.where()}) never {what} in {timeout_s:g} s "
                               "(is it running, on this port?)")
        return super().wait_first(max(end - time.monotonic(), 1.0), alive)

    def where(self) -> str:
        if self.listening and self.sock is None:
            host, port = self.server.getsockname()[:2]
            return f"expected on tcp:{host}:{port}"
        return f"tcp:{self.address[0]}:{self.address[1]}"

    def close(self) -> None:
        for s in (self.sock, self.server):
            if s is not None:
                s.close()


def parse_sim_address(text: str) -> tuple[str, tuple[str, int]]:
    """``udp:HOST:PORT``, ``tcp:HOST:PORT``, ``udp-listen:HOST:PORT`` or ``tcp-listen:HOST:PORT`` as
    (kind, (host, port)); a one-line HilError otherwise."""
    kinds = ("udp", "tcp", "udp-listen", "tcp-listen")
    kind, _, rest = str(text).partition(":")
    host, _, port = rest.rpartition(":")
    lowest = 0 if kind.endswith("-listen") else 1  # a listener may take any free port (0)
    if kind not in kinds or not host or not port.isdigit() or not lowest <= int(port) < 65536:
        raise HilError(f"simulator address {text!r}: expected one of {', '.join(k + ':HOST:PORT' for k in kinds)}")
    return kind, (host, int(port))


def open_link(text: str) -> SimLink:
    """The link to the simulator at ``text`` (see :func:`parse_sim_address`)."""
    kind, addr = parse_sim_address(text)
    if kind == "udp":
        return SimLink(address=addr)
    if kind == "udp-listen":
        return SimLink(listen=addr)
    if kind == "tcp":
        return TcpSimLink(address=addr)
    return TcpSimLink(listen=addr)
