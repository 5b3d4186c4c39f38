"""The SITL flight controller's MAVLink endpoint, with the SCART layer on its link.

::

    Plant (physics, sensors, estimator) --telemetry--> [SCART layer, point link] --> client(s)
                                                                  |
                                                                  v  (the view the client gets)
    Plant (controller) <-- [SCART layer, point command] <-- Commander (modes, mission, offboard)
                                                                  ^
    client(s) --COMMAND_LONG/INT, mission, params, offboard setpoints--'

Missions are :mod:`~scart_bench.generator.sitl.missions`' protocol; what is refused, and with which
answer, is :mod:`~scart_bench.generator.sitl.checks`'.

One UDP socket (``listen``) speaks MAVLink 2 as system 1, component 1 (MAV_AUTOPILOT_PX4,
MAV_TYPE_QUADROTOR). Telemetry goes to every address heard from (the last eight), and to
``remote`` if given (PX4's ``-o`` port); answers go to the sender. :meth:`SitlServer.serve`
paces the simulation by the wall clock (``speed`` x real time) or runs it as fast as it can
(``speed=None``, lockstep: the clock holds until a client is heard); :meth:`SitlServer.advance`
steps a given simulated time in the caller's thread, reading the socket between steps (the
step-exact lockstep of the tests).
"""

from __future__ import annotations

import selectors
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.mavlink import require_pymavlink
from scart_bench.generator.mavlink.codec import CODECS
from scart_bench.generator.params import DT, NAV_RATE_HZ
from scart_bench.generator.physics.disturbances import Disturbances
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.sitl.commander import (
    HOLD,
    LAND,
    MISSION,
    OFFBOARD,
    RTL,
    TAKEOFF,
    Commander,
    Params,
    custom_mode,
)
from scart_bench.generator.sitl.endpoint import SitlError, bind_udp
from scart_bench.generator.sitl.handlers import SYSTEM, ClientRequests
from scart_bench.generator.sitl.missions import MissionProtocol
from scart_bench.generator.sitl.plant import Plant, is_due

mavlink = require_pymavlink()

SITL_POINTS = ("link", "command", "sensor", "environment", "vehicle")
#: effects the sitl's plant does not model (the generator's sensor-instance failover)
UNSUPPORTED_EFFECTS = frozenset({"sensor_instance_loss"})
COMPONENT = 1
MAX_PEERS = 8
#: status messages besides the link topics, and their rates (Hz)
STATUS_RATES = {"HEARTBEAT": 1.0, "SYS_STATUS": 5.0, "EXTENDED_SYS_STATE": 5.0, "HOME_POSITION": 0.5,
                "MISSION_CURRENT": 1.0, "SYSTEM_TIME": 1.0}

R = mavlink  # short alias for the enums below
_SENSORS = (R.MAV_SYS_STATUS_SENSOR_3D_GYRO | R.MAV_SYS_STATUS_SENSOR_3D_ACCEL | R.MAV_SYS_STATUS_SENSOR_3D_MAG
            | R.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | R.MAV_SYS_STATUS_SENSOR_GPS
            | R.MAV_SYS_STATUS_AHRS | R.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)


@dataclass
class SitlStats:
    """Counters of a SITL run."""

    datagrams_in: int = 0
    messages_in: int = 0
    datagrams_out: int = 0
    commands: int = 0
    rejected: int = 0  # commands answered with anything but ACCEPTED
    offboard_setpoints: int = 0
    ignored_setpoints: int = 0  # offboard setpoints refused (infinite, off the planet, out of the height range)
    failsafes: int = 0
    errors: int = 0
    behind_s: float = 0.0  # simulated time flown while behind the asked pace

    def summary(self) -> str:
        return (f"{self.messages_in} messages in ({self.commands} commands, {self.rejected} not accepted, "
                f"{self.offboard_setpoints} offboard setpoints"
                + (f", {self.ignored_setpoints} refused" if self.ignored_setpoints else "")
                + f"), {self.datagrams_out} datagrams out, "
                f"{self.failsafes} failsafes, {self.errors} errors"
                + (f"; could not keep the asked pace for {self.behind_s:.1f} s of flight" if self.behind_s else ""))


def check_scenarios(scenarios: list[Scenario], points: tuple[str, ...] = SITL_POINTS, physics: str = "") -> None:
    """Refuse, in one line, a scenario the sitl does not carry (``points``: its plant's; ``physics``: its name)."""
    for sc in scenarios:
        if sc.injection_point not in points:
            known = sc.injection_point in SITL_POINTS
            raise SitlError(f"scenario {sc.id!r} ({sc.source}): " + (
                f"injection point {sc.injection_point!r} needs the built-in physics; with --physics {physics} the "
                if known else f"unknown injection point {sc.injection_point!r}; the ")
                + f"sitl runs scenarios at {', '.join(points)}")
        bad = [name for name, _ in sc.actions if name in UNSUPPORTED_EFFECTS]
        if bad:
            raise SitlError(f"scenario {sc.id!r} ({sc.source}): action {bad[0]!r} is not modelled by the sitl "
                            "(no sensor-instance failover); use it in simulation mode")
        forged = [name for name, _ in sc.actions if name in ("inject_command", "mission_tamper")]
        if forged:
            raise SitlError(f"scenario {sc.id!r} ({sc.source}): action {forged[0]!r} is not carried inside the sitl; "
                            "run it in simulation mode, or forge the command on the link with scart-bench proxy")


class SitlServer(ClientRequests):
    """One simulated PX4-like vehicle behind a MAVLink UDP endpoint, with ``scenarios`` on its link.

    ``scenarios`` run at the points link, command, sensor, environment and vehicle (one flight,
    ``seed``); ``record`` keeps both views and the truth for :meth:`record`. ``sock``: a socket
    already bound to ``listen`` (:func:`~scart_bench.generator.sitl.endpoint.bind_udp`, done before a
    slow start-up so that early datagrams wait in it); the server owns and closes it. ``plant``: the
    vehicle (default the built-in :class:`~scart_bench.generator.sitl.plant.Plant` of ``seed``; a started
    :class:`~scart_bench.generator.sitl.jmavsim_plant.JmavsimPlant` flies jMAVSim; its ``points`` limit the
    scenarios); the caller closes a plant it gave.
    """

    def __init__(self, listen: tuple[str, int] = ("127.0.0.1", 0), scenarios: list[Scenario] | None = None,
                 seed: int = 0, remote: tuple[str, int] | None = None, record: bool = False,
                 log: Callable[[str], None] | None = None, sock=None, defense=None, plant=None):
        self.scenarios = list(scenarios or [])
        self.defense = defense  # a generator.defense.LiveDefense: a detector on the navigator's view, and a response
        check_scenarios(self.scenarios, getattr(plant, "points", SITL_POINTS), getattr(plant, "name", ""))
        self.sock = sock if sock is not None else bind_udp(listen)
        self.seed = int(seed)
        self.plant = plant if plant is not None else Plant(self.seed)
        self.params = Params()
        self.commander = Commander(self.plant, self.params)
        self.layer = AttackLayer([self.scenarios], [self.seed], rates={t: v.rate_hz for t, v in TOPICS.items()}) \
            if self.scenarios else None
        self.points = self.layer.points if self.layer is not None else frozenset()
        self.recording = bool(record)
        self.journal = None  # a generator.sitl.journal.Journal: the recording written as it flies
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        self.stats = SitlStats()
        self.listen = listen
        self.remote = remote
        self.peers: dict[tuple, float] = {}
        self.mav = mavlink.MAVLink(None, srcSystem=SYSTEM, srcComponent=COMPONENT)
        self.mav.robust_parsing = True
        self.missions = MissionProtocol(self.commander, self._reply, self._outbox_now)
        self._handlers = {**self.missions.handlers(), **{name[4:].upper(): getattr(self, name)
                                                         for name in dir(self) if name.startswith("_on_")}}
        self.views: dict[str, dict[str, tuple[list[int], list[np.ndarray]]]] = {"navigator": {}, "simulator": {}}
        self.started_wall = time.time()
        self.boot_wall = time.monotonic()
        self._pending: list[bytes] = []
        self._error_logged = 0
        if self.plant.step_index == 0:
            self.commander.set_home(np.zeros(3))
            self.commander.outbox.clear()

    @property
    def address(self) -> tuple[str, int]:
        """The bound address (the real port when 0 was asked for)."""
        return self.sock.getsockname()[:2]

    @property
    def time_s(self) -> float:
        """Simulated time since boot."""
        return self.plant.step_index * DT

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> SitlServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- running ----------------------------------------------------------------------------------
    def advance(self, seconds: float) -> None:
        """Run ``seconds`` of simulated time now, handling the client's datagrams between steps."""
        end = self.plant.step_index + int(round(seconds / DT))
        while self.plant.step_index < end:
            self.poll()
            self.step()
        self.poll()

    def serve(self, stop, speed: float | None = 1.0, duration_s: float | None = None) -> SitlStats:
        """Run until ``stop`` (a threading.Event) is set or ``duration_s`` of simulated time have passed.

        ``speed``: simulated seconds per wall second; None runs as fast as it can, holding the
        clock until a client has been heard from.
        """
        sel = selectors.DefaultSelector()
        sel.register(self.sock, selectors.EVENT_READ)
        wall0, sim0 = time.monotonic(), self.time_s
        try:
            while not stop.is_set():
                if duration_s is not None and self.time_s >= duration_s:
                    break
                self.poll()
                if speed is None and not self.peers and self.remote is None:
                    sel.select(0.05)
                    if hasattr(self.plant, "idle"):  # an external simulator waits with the clock
                        self.plant.idle()
                    continue
                self.step()
                if speed is None:
                    continue
                while True:
                    delay = wall0 + (self.time_s - sim0) / speed - time.monotonic()
                    if delay <= 0:
                        break
                    if sel.select(delay):
                        self.poll()
                if delay < -0.25:  # fell behind: go on from now rather than run in a burst
                    self.stats.behind_s += self.time_s - sim0
                    wall0, sim0 = time.monotonic(), self.time_s
        finally:
            sel.close()
        return self.stats

    # -- one step ---------------------------------------------------------------------------------
    def step(self) -> None:
        """One 4 ms step: physics, telemetry through the layer, navigation, control, status messages."""
        plant, cmd = self.plant, self.commander
        k, t_us = plant.step_index, plant.t_us
        frames: list[bytes] = []
        env = None
        if self.layer is not None and self.layer.physical_groups:
            phys = self.layer.on_physics(k, t_us)
            env = phys if isinstance(phys, Disturbances) else None
        hook = None
        defense = self.defense
        if "sensor" in self.points or (defense is not None and defense.rejecting):
            def hook(sensor_msgs):
                out = self.layer.on_messages("sensor", k, t_us, sensor_msgs) if "sensor" in self.points else {}
                if defense is not None and defense.rejecting and "sensor_gps" in sensor_msgs:
                    vals, ok = out.get("sensor_gps", (sensor_msgs["sensor_gps"], np.ones(1, dtype=bool)))
                    out = {**out, "sensor_gps": (defense.sensor_gps(t_us, vals), ok)}
                return out
        msgs = plant.step(env, hook)
        if msgs:
            if "link" in self.points:
                altered = self.layer.on_messages("link", k, t_us, msgs)
            else:
                altered = {t: (v, None) for t, v in msgs.items()}
            for topic, (vals, ok) in altered.items():
                self._keep("simulator", topic, t_us, msgs[topic][0])
                if ok is not None and not ok[0]:
                    continue
                row = vals[0]
                cmd.perceive(topic, row)
                if defense is not None:
                    defense.observe(topic, t_us, row, self.layer)
                self._keep("navigator", topic, t_us, row)
                frames.append(self._pack(CODECS[topic].new_message(row, t_us)))
        if is_due(NAV_RATE_HZ, k):
            if defense is not None and defense.pending:
                self._respond(t_us)
            sp = cmd.tick(k * DT)[None, :]
            self._keep("simulator", "setpoint", t_us, sp[0])
            ok = True
            if "command" in self.points:
                sp, delivered = self.layer.on_messages("command", k, t_us, {"setpoint": sp})["setpoint"]
                ok = bool(delivered[0])
            if ok:
                self._keep("navigator", "setpoint", t_us, sp[0])
            plant.control(sp if ok else None)
        truth = plant.finish_step()
        if truth is not None:
            self._keep("simulator", "truth", t_us, truth[0])
        for name, rate in STATUS_RATES.items():
            if is_due(rate, k):
                frames.append(self._status(name, t_us))
        frames.extend(self._outbox(t_us))
        self.missions.tick()
        if self.journal is not None and self.journal.due(k, DT):
            self.journal.flush(self)
        if frames:
            self._broadcast(b"".join(frames))

    def _respond(self, t_us: int) -> None:
        """The anomaly notice reached the flight controller: it takes the defense's response (a mode change under
        the commander's usual rules, GPS rejected at the sensor point), says so and logs it."""
        defense, cmd = self.defense, self.commander
        mode = defense.respond(t_us, self.plant.position)
        name = getattr(defense.monitor, "name", "detector")
        why = ""
        if mode is not None:
            ok, why = cmd.set_mode({"hold": HOLD, "return": RTL, "land": LAND}[mode])
            why = "" if ok else f" (refused: {why})"
        self.log(f"sitl: t={self.time_s:.2f} s: anomaly notice from {name} "
                 f"({len(defense.monitor.alarms)} alarm row(s)): {defense.response.action}{why}")
        cmd.say(f"Anomaly notice: {defense.response.action}", severity=2)

    def _keep(self, view: str, topic: str, t_us: int, values: np.ndarray) -> None:
        if self.recording:
            ts, vals = self.views[view].setdefault(topic, ([], []))
            ts.append(t_us)
            vals.append(np.array(values, dtype=np.float64))

    # -- sending ----------------------------------------------------------------------------------
    def _pack(self, msg) -> bytes:
        return msg.pack(self.mav)

    def _targets(self) -> list:
        out = list(self.peers)
        if self.remote is not None and self.remote not in out:
            out.append(self.remote)
        return out

    def _broadcast(self, data: bytes) -> None:
        for addr in self._targets():
            self._sendto(data, addr)

    def _sendto(self, data: bytes, addr) -> None:
        try:
            self.sock.sendto(data, addr)
            self.stats.datagrams_out += 1
        except OSError:  # the peer is gone: UDP semantics
            pass

    def _reply(self, msg, addr) -> None:
        self._sendto(self._pack(msg), addr)

    def heartbeat(self):
        cmd = self.commander
        base = R.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if cmd.armed:
            base |= R.MAV_MODE_FLAG_SAFETY_ARMED
        if cmd.mode in (HOLD, MISSION, RTL, LAND, TAKEOFF, OFFBOARD):
            base |= R.MAV_MODE_FLAG_AUTO_ENABLED | R.MAV_MODE_FLAG_GUIDED_ENABLED | R.MAV_MODE_FLAG_STABILIZE_ENABLED
        else:
            base |= R.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | R.MAV_MODE_FLAG_STABILIZE_ENABLED
        state = R.MAV_STATE_ACTIVE if cmd.armed else R.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(R.MAV_TYPE_QUADROTOR, R.MAV_AUTOPILOT_PX4, base,
                                                 custom_mode(cmd.mode), state, 3)

    def _status(self, name: str, t_us: int) -> bytes:
        cmd, plant = self.commander, self.plant
        if name == "HEARTBEAT":
            msg = self.heartbeat()
        elif name == "SYS_STATUS":
            ok = plant.position_valid
            health = _SENSORS if ok else _SENSORS & ~R.MAV_SYS_STATUS_SENSOR_GPS
            if ok and not cmd.armed:
                health |= R.MAV_SYS_STATUS_PREARM_CHECK
            b = plant.battery[0]
            msg = mavlink.MAVLink_sys_status_message(
                _SENSORS | R.MAV_SYS_STATUS_PREARM_CHECK, _SENSORS | R.MAV_SYS_STATUS_PREARM_CHECK, health, 250,
                int(b[0] * 1000), int(b[1] * 100), int(round(b[2] * 100)), 0, 0, 0, 0, 0, 0)
        elif name == "EXTENDED_SYS_STATE":
            msg = mavlink.MAVLink_extended_sys_state_message(R.MAV_VTOL_STATE_UNDEFINED, cmd.landed_state())
        elif name == "HOME_POSITION":
            msg = self._home(t_us)
        elif name == "MISSION_CURRENT":
            msg = self._mission_current()
        else:
            msg = mavlink.MAVLink_system_time_message(0, int(t_us // 1000) & 0xFFFFFFFF)
        return self._pack(msg)

    def _home(self, t_us: int):
        lat, lon, alt = self.commander.home_global()
        h = self.commander.home
        return mavlink.MAVLink_home_position_message(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)), float(h[0]), float(h[1]),
            float(h[2]), [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(t_us))

    def _mission_current(self):
        cmd = self.commander
        total = len(cmd.mission)
        return mavlink.MAVLink_mission_current_message(cmd.seq if total else 0, total, cmd.mission_state,
                                                       1 if cmd.mode == MISSION else 0)

    def _outbox(self, t_us: int) -> list[bytes]:
        out = []
        cmd = self.commander
        for item in cmd.outbox:
            kind = item[0]
            if kind == "statustext":
                out.append(self._pack(mavlink.MAVLink_statustext_message(item[1], item[2][:50].encode(), 0, 0)))
                self.log(f"sitl: t={self.time_s:.2f} s: {item[2]}")
            elif kind == "reached":
                out.append(self._pack(mavlink.MAVLink_mission_item_reached_message(item[1])))
            elif kind == "current":
                out.append(self._pack(self._mission_current()))
            elif kind == "home":
                out.append(self._pack(self._home(t_us)))
            elif kind == "mode":
                out.append(self._pack(self.heartbeat()))
            elif kind == "failsafe":
                self.stats.failsafes += 1
        cmd.outbox.clear()
        return out

    # -- receiving --------------------------------------------------------------------------------
    def poll(self) -> None:
        """Handle every datagram waiting on the socket."""
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionError:
                continue
            self.stats.datagrams_in += 1
            if addr not in self.peers:
                self.peers[addr] = time.monotonic()
                if len(self.peers) > MAX_PEERS:
                    del self.peers[next(iter(self.peers))]
            for msg in _frames(data):
                self.stats.messages_in += 1
                try:
                    self.handle(msg, addr)
                except Exception as exc:  # a malformed request must not stop the vehicle
                    self.stats.errors += 1
                    if self._error_logged < 5:
                        self._error_logged += 1
                        self.log(f"sitl: error handling {msg.get_type()} ({type(exc).__name__}: {exc})")
            if self.commander.outbox:
                frames = self._outbox(self.plant.t_us)
                if frames:
                    self._broadcast(b"".join(frames))

    def windows(self) -> list[tuple[int, int]]:
        if self.layer is None:
            return []
        return self.layer.windows(0, self.plant.t_us + 1)

    def record(self, flight_id: str, extra_config: dict | None = None, split: str = "test"):
        """The flight so far as a :class:`scart_bench.dataset.FlightRecord` (both views, truth, labels)."""
        from scart_bench.generator.sitl.record import sitl_record

        return sitl_record(self, flight_id, extra_config or {}, split)


def _frames(data: bytes) -> list:
    """The messages of one datagram. A UDP datagram carries whole frames, so each gets a parser of its
    own: a frame cut short (a noisy or hostile sender) never swallows the frames of the next datagram."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    try:
        return parser.parse_buffer(data) or []
    except mavlink.MAVError:
        return []
