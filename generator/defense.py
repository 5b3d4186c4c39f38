"""Defense in the loop: an online detector watches the navigator's stream and the flight controller responds.

:class:`DefenseHook` sits beside the SCART attack layer at the engines' injection points (it implements
:class:`~scart_bench.generator.engine.flight_batch.AttackHooks` and wraps the layer, or stands alone on a
normal flight). At the ``link`` and ``command`` points it hands what the navigator receives (telemetry after
the attack) and sends (its setpoint) to an :class:`AlarmSource` -- a plain object; the benchmark wires a
fitted detector and its calibrated threshold into one (``benchmark.defense.BatchMonitor``). After
``Response.alarms`` alarm rows on a flight, the mission computer raises the anomaly notice and the flight
controller takes the response at the next ``command`` point, as PX4 would:

- ``hold``, ``return``, ``land``: a COMMAND_LONG to the commander (DO_SET_MODE AUTO.LOITER,
  NAV_RETURN_TO_LAUNCH, NAV_LAND), accepted by its usual rules (generator.flight_software.commander);
- ``reject_gps``: for ``reject_s`` seconds the estimator no longer takes the GPS receiver's position, as EKF2
  does while its GPS position checks fail: at the ``sensor`` point the position it is fed is the flight
  controller's own estimate at the response carried on by the receiver's velocity (GPS velocity stays fused,
  through its innovation gate). Inertial-only dead reckoning is not an option here: this estimator's
  complementary attitude filter loses the horizontal position within seconds without aiding (as PX4 does
  after EKF2_NOAID_TOUT);
- ``reject_gps_then_return``: both: GPS position rejected (to the end of the flight by default), then return
  to launch on the estimate that the spoofed position no longer drags.

Alarms, responses and the end of a GPS rejection go into the flight's event log with their times. With no
alarm the hook changes nothing: a defended flight is byte-identical to the undefended one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.flight_software.commander import (
    COMMAND_FIELDS,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    PX4_MAIN_AUTO,
    PX4_SUB_LOITER,
)
from scart_bench.generator.geo import latlon_to_ned, ned_to_latlon

#: The responses the flight controller can take on the anomaly notice.
RESPONSES = ("hold", "return", "land", "reject_gps", "reject_gps_then_return")
#: The commander mode each response's COMMAND_LONG asks for (reject_gps alone sends none).
_MODE_OF = {"hold": "hold", "return": "return", "land": "land", "reject_gps_then_return": "return"}


@dataclass(frozen=True)
class Response:
    """What the flight controller does on the anomaly notice, and after how many alarm rows.

    ``reject_s``: how long GPS stays rejected by the reject responses (inf: to the end of the flight).
    """

    action: str = "return"
    alarms: int = 1
    reject_s: float = math.inf

    def __post_init__(self) -> None:
        if self.action not in RESPONSES:
            raise ValueError(f"response {self.action!r}: expected one of {', '.join(RESPONSES)}")
        if int(self.alarms) < 1:
            raise ValueError(f"response alarms: expected a whole number >= 1, got {self.alarms}")
        if not self.reject_s > 0:
            raise ValueError(f"response reject_s: expected > 0 s, got {self.reject_s}")

    @property
    def rejects_gps(self) -> bool:
        return self.action.startswith("reject_gps")


class AlarmSource(Protocol):
    """An online detector as the defense sees it: fed the navigator's messages, it says which flights alarmed."""

    def observe(
        self, point: str, t_us: int, messages: dict[str, tuple[np.ndarray, np.ndarray]]
    ) -> tuple[np.ndarray, int] | None:
        """Take one call's messages (values (N, fields), delivered (N,)); return (alarm rows per flight (N,),
        time of the last row they were decided on, us) when rows were scored, else None."""

    def finish(self) -> None:
        """The flights have ended."""


@dataclass
class DefenseEvent:
    """One entry of the defense's part of the event log."""

    flight: int
    timestamp_us: int
    event: str  # "alarm" (the N-th alarm row: the anomaly notice), "response", "gps_restored"
    detail: str


def response_command(action: str, target_system: int = 1, target_component: int = 1) -> np.ndarray | None:
    """The COMMAND_LONG (COMMAND_FIELDS order) that asks the commander for ``action``'s mode (None: no mode)."""
    mode = _MODE_OF.get(action)
    if mode is None:
        return None
    cmd = np.zeros(len(COMMAND_FIELDS))
    if mode == "hold":
        cmd[0], cmd[2], cmd[3] = MAV_CMD_DO_SET_MODE, PX4_MAIN_AUTO, PX4_SUB_LOITER
    else:
        cmd[0] = MAV_CMD_NAV_RETURN_TO_LAUNCH if mode == "return" else MAV_CMD_NAV_LAND
    cmd[8], cmd[9] = target_system, target_component
    return cmd


class DefenseHook:
    """The engines' hooks for a defended batch: the attack layer (or none) with a detector and a response.

    ``source``: the online detector (:class:`AlarmSource`); ``layer``: the SCART layer of the batch, called
    first at every point (the defense sees what the attack left); ``n``: flights in the batch.
    """

    def __init__(
        self, source: AlarmSource, response: Response, n: int, layer=None, target: tuple[int, int] = (1, 1)
    ):
        self.source = source
        self.response = response
        self.n = int(n)
        self.layer = layer
        own = {"link", "command"} | ({"sensor"} if response.rejects_gps else set())
        self.points = frozenset(own) | (layer.points if layer is not None else frozenset())
        self.command = response_command(response.action, *target)
        self.alarm_rows = np.zeros(self.n, dtype=np.int64)
        self.notice_us = np.full(self.n, -1, dtype=np.int64)  # the N-th alarm row's time (the anomaly notice)
        self.response_us = np.full(self.n, -1, dtype=np.int64)  # when the flight controller took the response
        self._pending = np.zeros(self.n, dtype=bool)
        self._reject_until_s = np.full(self.n, -math.inf)
        self._rejecting = np.zeros(self.n, dtype=bool)
        self._fc_pos = np.zeros((self.n, 2))  # the flight controller's own position estimate (north, east m)
        self._sub_pos = np.zeros((self.n, 2))  # the position fed in place of the receiver's while rejected
        self._sub_us = np.zeros(self.n, dtype=np.int64)
        self._gpi = TOPICS["global_position_int"].field_names.index("lat")
        self.events: list[DefenseEvent] = []

    # -- what the engines call ------------------------------------------------------------------
    @property
    def sensor_every_step(self) -> bool:
        """Whether the ``sensor`` point is needed at every step (the layer's sensor scenarios), or only at the
        GPS samples (the defense alone: the compiled engine then stays in compiled code between them)."""
        return self.layer is not None and "sensor" in self.layer.points

    @property
    def physical_groups(self) -> list:
        return getattr(self.layer, "physical_groups", []) if self.layer is not None else []

    def on_physics(self, step: int, t_us: int):
        return self.layer.on_physics(step, t_us) if self.layer is not None else {}

    def on_messages(
        self, point: str, step: int, t_us: int, messages: dict[str, np.ndarray]
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        inner = self.layer is not None and point in self.layer.points
        if point == "link" and self.response.rejects_gps and "global_position_int" in messages:
            gpi = messages["global_position_int"]  # before the attack: the flight controller's own estimate
            self._fc_pos[:] = np.column_stack(latlon_to_ned(gpi[:, self._gpi], gpi[:, self._gpi + 1]))
        if point == "sensor":
            out = self.layer.on_messages(point, step, t_us, messages) if inner else {}
            if self._rejecting.any():
                self._restore_gps(t_us)
                if "sensor_gps" in messages:
                    out = self._reject_gps(t_us, messages["sensor_gps"], out)
            return out
        if inner:
            out = self.layer.on_messages(point, step, t_us, messages)
        else:
            out = {t: (v, np.ones(self.n, dtype=bool)) for t, v in messages.items()}
        if point in ("link", "command"):
            got = self.source.observe(point, t_us, out)
            if got is not None:
                self._count(*got)
        if point == "command" and self._pending.any():
            out = self._respond(t_us, out)
        return out

    def on_finish(self, step: int) -> None:
        if self.layer is not None:
            self.layer.on_finish(step)
        self.source.finish()

    # -- the response -----------------------------------------------------------------------------
    def _count(self, alarms: np.ndarray, t_us: int) -> None:
        self.alarm_rows += np.asarray(alarms, dtype=np.int64)
        notice = (self.alarm_rows >= self.response.alarms) & (self.notice_us < 0)
        if notice.any():
            self.notice_us[notice] = t_us
            self._pending |= notice
            for i in np.flatnonzero(notice):
                self.events.append(
                    DefenseEvent(
                        int(i),
                        int(t_us),
                        "alarm",
                        f"anomaly notice after {int(self.alarm_rows[i])} alarm row(s)",
                    )
                )

    def _respond(self, t_us: int, out: dict) -> dict:
        rows = np.flatnonzero(self._pending)
        self._pending[rows] = False
        self.response_us[rows] = t_us
        if self.command is not None and "command_long" in out:
            vals, ok = out["command_long"]
            vals, ok = np.array(vals, dtype=float, copy=True), np.array(ok, dtype=bool, copy=True)
            vals[rows] = self.command
            ok[rows] = True
            out = {**out, "command_long": (vals, ok)}
        if self.response.rejects_gps:
            self._rejecting[rows] = True
            self._sub_pos[rows] = self._fc_pos[rows]
            self._sub_us[rows] = t_us
            self._reject_until_s[rows] = t_us / 1e6 + self.response.reject_s
        for i in rows:
            self.events.append(DefenseEvent(int(i), int(t_us), "response", self.response.action))
        return out

    def _reject_gps(self, t_us: int, raw: np.ndarray, out: dict) -> dict:
        """The GPS message with the rejected flights' position replaced (see the module docstring); the other
        flights get what the layer left them (the engine takes the message back only when it is returned)."""
        vals, ok = out.get("sensor_gps", (raw, np.ones(self.n, dtype=bool)))
        vals = np.array(vals, dtype=float, copy=True)
        rows = np.flatnonzero(self._rejecting)
        dt = (t_us - self._sub_us[rows]) / 1e6
        self._sub_pos[rows] += vals[rows, 3:5] * dt[:, None]  # carried on by the receiver's velocity (vn, ve)
        self._sub_us[rows] = t_us
        lat, lon = ned_to_latlon(self._sub_pos[rows, 0], self._sub_pos[rows, 1])
        vals[rows, 0], vals[rows, 1] = lat, lon
        return {**out, "sensor_gps": (vals, ok)}

    def _restore_gps(self, t_us: int) -> None:
        back = self._rejecting & (t_us / 1e6 >= self._reject_until_s)
        if back.any():
            self._rejecting[back] = False
            for i in np.flatnonzero(back):
                self.events.append(DefenseEvent(int(i), int(t_us), "gps_restored", "GPS fused again"))

    # -- the flight's records (the layer's, with the defense's events) ----------------------------
    def labelled_windows(self, flight: int, end_us: int) -> list:
        return self.layer.labelled_windows(flight, end_us) if self.layer is not None else []

    def windows(self, flight: int, end_us: int) -> list:
        return self.layer.windows(flight, end_us) if self.layer is not None else []

    def event_log(self, flight: int, end_us: int) -> list[dict]:
        """The attack event log of one flight with the defense's alarms and responses, in time order."""
        rows = self.layer.event_log(flight, end_us) if self.layer is not None else []
        rows = rows + [
            {"timestamp_us": e.timestamp_us, "event": e.event, "scenario_id": "defense", "detail": e.detail}
            for e in self.events
            if e.flight == flight and e.timestamp_us < end_us
        ]
        return sorted(rows, key=lambda r: r["timestamp_us"])


class LiveDefense:
    """The defense of one live flight (``scart-bench sitl``): a streaming monitor and the response.

    ``monitor``: duck-typed as the live ``benchmark.live.StreamMonitor`` is: ``on_message(topic, t_us, values,
    layer)`` takes each message the navigator receives and ``alarms`` lists the alarm rows so far. After
    ``response.alarms`` alarm rows the anomaly notice is raised (:attr:`pending`); the server then calls
    :meth:`respond` at its next navigator tick, switches the commander to :attr:`mode` and, for the reject
    responses, passes each GPS sample through :meth:`sensor_gps` (the position replaced as in
    :class:`DefenseHook`).
    """

    def __init__(self, monitor, response: Response):
        self.monitor = monitor
        self.response = response
        self.notice_us = -1
        self.response_us = -1
        self.events: list[DefenseEvent] = []
        self._rejecting = False
        self._reject_until_s = -math.inf
        self._sub_pos = np.zeros(2)
        self._sub_us = 0

    @property
    def mode(self) -> str | None:
        """The commander mode the response asks for ("hold", "return", "land"; None: reject_gps alone)."""
        return _MODE_OF.get(self.response.action)

    @property
    def pending(self) -> bool:
        """The anomaly notice is raised and the flight controller has not responded yet."""
        return self.notice_us >= 0 and self.response_us < 0

    @property
    def rejecting(self) -> bool:
        return self._rejecting

    def observe(self, topic: str, t_us: int, values: np.ndarray, layer=None) -> None:
        """One message as the navigator received it (after the attack)."""
        self.monitor.on_message(topic, t_us, values, layer)
        if self.notice_us < 0 and len(self.monitor.alarms) >= self.response.alarms:
            self.notice_us = int(t_us)
            self.events.append(
                DefenseEvent(0, int(t_us), "alarm", f"anomaly notice after {len(self.monitor.alarms)} alarm row(s)")
            )

    def respond(self, t_us: int, position_ne: np.ndarray) -> str | None:
        """Take the response now; ``position_ne``: the flight controller's own estimate (north, east m).
        Returns the commander mode to switch to (None: none)."""
        self.response_us = int(t_us)
        if self.response.rejects_gps:
            self._rejecting = True
            self._sub_pos = np.asarray(position_ne, dtype=float)[:2].copy()
            self._sub_us = int(t_us)
            self._reject_until_s = t_us / 1e6 + self.response.reject_s
        self.events.append(DefenseEvent(0, int(t_us), "response", self.response.action))
        return self.mode

    def sensor_gps(self, t_us: int, values: np.ndarray) -> np.ndarray:
        """The GPS sample (1, sensor_gps fields) the estimator is fed: while rejected, the position is the
        estimate at the response carried on by the receiver's velocity."""
        if not self._rejecting:
            return values
        if t_us / 1e6 >= self._reject_until_s:
            self._rejecting = False
            self.events.append(DefenseEvent(0, int(t_us), "gps_restored", "GPS fused again"))
            return values
        vals = np.array(values, dtype=float, copy=True)
        self._sub_pos += vals[0, 3:5] * (t_us - self._sub_us) / 1e6
        self._sub_us = int(t_us)
        lat, lon = ned_to_latlon(self._sub_pos[:1], self._sub_pos[1:2])
        vals[0, 0], vals[0, 1] = lat[0], lon[0]
        return vals

    def event_log(self, end_us: int) -> list[dict]:
        """The defense's events (alarm, response, gps_restored) as event-log rows."""
        return [
            {"timestamp_us": e.timestamp_us, "event": e.event, "scenario_id": "defense", "detail": e.detail}
            for e in self.events
            if e.timestamp_us < end_us
        ]
