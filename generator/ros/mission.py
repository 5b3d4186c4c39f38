"""The mission computer's square, flown from the position it perceives (no ROS here).

The paper's Navigator: it reads the telemetry it is given (after the SCART node), and sends velocity
setpoints toward its next waypoint, so an attack on the telemetry changes the path really flown, as
the generator's navigator does in simulation mode. The mission is the generator's default
(:class:`scart_bench.generator.params.MissionParams`): arm, take off over home, fly the four corners of
the 30 m square, come back over home, land. Positions are ENU metres from the origin (MAVROS's
``local_position/pose``); corners are given north, east as in the generator.

:meth:`SquareMission.step` is called on every position message and returns the setpoint and, at
the moments the flight controller must act (arm, switch to offboard, land), a request for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scart_bench.generator.params import MissionParams

#: Seconds (flight time) between two repetitions of an unanswered request to the flight controller.
REQUEST_EVERY_S = 1.0
#: Proportional gains: horizontal speed per metre to go (capped at cruise), climb speed per metre.
APPROACH_GAIN = 1.0
CLIMB_GAIN = 1.0
CLIMB_SPEED = 2.0  # m/s, upward cap
DESCENT_SPEED = 1.5  # m/s, downward cap
VERTICAL_ACCEPT = 0.8  # m


@dataclass
class Setpoint:
    """What the navigator sends for one position message: an ENU velocity, the mission item and a request."""

    velocity: np.ndarray  # (3,) m/s east, north, up
    seq: int  # the item flown to: 0..3 the corners, 4 the return over home
    phase: str
    request: str | None = None  # "arm", "offboard", "land" (to the flight controller), or None


class SquareMission:
    """The default square as a state machine over perceived positions (see the module doc)."""

    PHASES = ("arm", "offboard", "takeoff", "corners", "return", "land", "done")

    def __init__(self, mission: MissionParams | None = None):
        m = mission or MissionParams()
        self.altitude = float(m.altitude)
        self.cruise = float(m.cruise_speed)
        self.accept = float(m.acceptance_radius)
        #: waypoints ENU at mission altitude: the corners, then home
        self.waypoints = [np.array([e, n, self.altitude]) for n, e in m.corners] + [
            np.array([0.0, 0.0, self.altitude])
        ]
        self.phase = "arm"
        self.seq = 0
        self._asked_at: float | None = None
        self.was_armed = False
        self.log: list[tuple[float, str]] = []  # (flight time, what happened)

    def _request(self, t_s: float, what: str) -> str | None:
        if self._asked_at is None or t_s - self._asked_at >= REQUEST_EVERY_S:
            self._asked_at = t_s
            return what
        return None

    def _enter(self, t_s: float, phase: str) -> None:
        self.phase = phase
        self._asked_at = None
        self.log.append((t_s, phase))

    def _toward(self, pos: np.ndarray, target: np.ndarray) -> np.ndarray:
        d = target[:2] - pos[:2]
        dist = float(np.hypot(*d))
        speed = min(self.cruise, APPROACH_GAIN * dist)
        vh = d / dist * speed if dist > 1e-6 else np.zeros(2)
        vz = float(np.clip(CLIMB_GAIN * (target[2] - pos[2]), -DESCENT_SPEED, CLIMB_SPEED))
        return np.array([vh[0], vh[1], vz])

    def _reached(self, pos: np.ndarray, target: np.ndarray) -> bool:
        return (
            math.hypot(*(target[:2] - pos[:2])) <= self.accept and abs(target[2] - pos[2]) <= VERTICAL_ACCEPT
        )

    def step(self, t_s: float, position: np.ndarray, armed: bool, mode: str) -> Setpoint:
        """The setpoint for a position message at flight time ``t_s`` (``position`` ENU m), given the flight
        controller's state (``armed``, ``mode``: PX4's mode name, e.g. OFFBOARD, AUTO.LAND)."""
        pos = np.asarray(position, dtype=float)
        hold = np.zeros(3)
        self.was_armed |= armed
        if self.phase == "arm":
            if armed:
                self._enter(t_s, "offboard")
            else:
                return Setpoint(hold, self.seq, self.phase, self._request(t_s, "arm"))
        if self.phase == "offboard":
            if mode == "OFFBOARD":
                self._enter(t_s, "takeoff")
            else:  # setpoints stream meanwhile: PX4 switches only while they do
                return Setpoint(hold, self.seq, self.phase, self._request(t_s, "offboard"))
        if self.phase == "takeoff":
            target = np.array([0.0, 0.0, self.altitude])
            if abs(pos[2] - self.altitude) <= VERTICAL_ACCEPT:
                self._enter(t_s, "corners")
            else:
                return Setpoint(self._toward(pos, target), self.seq, self.phase)
        if self.phase in ("corners", "return"):
            target = self.waypoints[self.seq]
            if self._reached(pos, target):
                self.seq += 1
                self.log.append((t_s, f"reached item {self.seq - 1}"))
                if self.seq == len(self.waypoints) - 1:
                    self.phase = "return"
                elif self.seq == len(self.waypoints):
                    self.seq -= 1
                    self._enter(t_s, "land")
            if self.phase != "land":
                return Setpoint(self._toward(pos, self.waypoints[self.seq]), self.seq, self.phase)
        if self.phase == "land":
            if self.was_armed and not armed:
                self._enter(t_s, "done")
            elif mode != "AUTO.LAND":
                return Setpoint(hold, self.seq, self.phase, self._request(t_s, "land"))
            return Setpoint(hold, self.seq, self.phase)
        return Setpoint(hold, self.seq, self.phase)

    @property
    def done(self) -> bool:
        return self.phase == "done"
