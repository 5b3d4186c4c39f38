"""The flight controller's end of PX4's simulator MAVLink API, over UDP.

The simulator (jMAVSim, PX4's Gazebo-classic plugin, AirSim in PX4 mode) sends HIL_SENSOR (IMU,
magnetometer, pressure), HIL_GPS and, when asked with MAV_CMD_SET_MESSAGE_INTERVAL for message 115,
HIL_STATE_QUATERNION (its ground truth); the flight controller answers every HIL_SENSOR with
HIL_ACTUATOR_CONTROLS (motor commands 0..1), which in lockstep is what advances the simulator's
clock, and sends a HEARTBEAT at least once a second (jMAVSim resets after 3 s without one).
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
            msgs = self.mav.parse_buffer(data) or []
            out.extend(m for m in msgs if m.get_type() != "BAD_DATA")
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
