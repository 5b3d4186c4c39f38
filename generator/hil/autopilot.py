"""The project's flight software flying an external simulator's vehicle, one sensor sample at a time.

The step is the built-in engine's (:func:`scart_bench.generator.engine.simulate.simulate_reference`)
for one flight, with the physics and sensors taken out: the simulator's samples come in, pass the
SCART layer's ``sensor`` point (a firmware attacker between the sensors and the estimator), feed
the estimator; its telemetry passes the ``link`` point to the navigator; the navigator's setpoint
passes the ``command`` point and drives the cascade, whose mixer output goes back as motor commands.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scart_bench.dataset.schema import HOME_ALT, TELEMETRY_TOPICS, TOPICS
from scart_bench.generator.flight_software.commander import exchange
from scart_bench.generator.flight_software.flight_controller import Controller, Estimator
from scart_bench.generator.flight_software.navigator import Navigator
from scart_bench.generator.geo import altitude_at, latlon_to_ned
from scart_bench.generator.hil.errors import HilError
from scart_bench.generator.hil.profiles import JMAVSIM, SimProfile
from scart_bench.generator.params import (
    BATTERY_CAPACITY_AH,
    BATTERY_IDLE_W,
    BATTERY_OCV_SPAN_V,
    BATTERY_OCV_V,
    BATTERY_POWER_K,
    BATTERY_R_OHM,
    BATTERY_STEP_S,
    DT,
    NAV_RATE_HZ,
    STEP_US,
    ControllerParams,
    EstimatorParams,
    MissionParams,
)
from scart_bench.generator.physics.rotation import quat_to_rot
from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS, FCSnapshot, compose, is_due

#: the points the bridge carries scenarios at
HIL_POINTS = ("sensor", "link", "command")
#: actions the bridge does not carry: a forged COMMAND_LONG needs the sitl's commander
UNCARRIED_ACTIONS = ("inject_command",)


@dataclass
class SensorSample:
    """One HIL_SENSOR: specific force (m/s^2) and rates (rad/s) in body FRD, field (gauss), pressure (Pa)."""

    t_us: int
    accel: np.ndarray
    gyro: np.ndarray
    mag: np.ndarray
    pressure: float
    temperature: float = 15.0


@dataclass
class GpsSample:
    """One HIL_GPS: position (deg, m AMSL), velocity NED (m/s), accuracy (m), satellites, fix type."""

    lat: float
    lon: float
    alt: float
    vel: np.ndarray
    eph: float
    epv: float
    satellites: float
    fix_type: float

    def row(self) -> np.ndarray:
        """The ``sensor_gps`` message (1, 10) of the SCART layer."""
        return np.array([[self.lat, self.lon, self.alt, *self.vel, self.eph, self.epv, self.satellites,
                          self.fix_type]])


@dataclass
class StartRule:
    """When the flight controller trusts its position and arms: GPS fused for ``origin_fixes``
    fixes sets the origin; the navigator arms ``arm_after_s`` later (PX4's pre-arm checks)."""

    origin_fixes: int = 10
    arm_after_s: float = 1.0


@dataclass
class Records:
    """What one flight leaves behind: per topic, the steps, rows and delivered flags before and
    after the layer (before: every message is delivered)."""

    before: dict[str, tuple[list[int], list[np.ndarray], list[bool]]] = field(default_factory=dict)
    after: dict[str, tuple[list[int], list[np.ndarray], list[bool]]] = field(default_factory=dict)

    @staticmethod
    def add(where: dict, topic: str, step: int, row: np.ndarray, delivered: bool = True) -> None:
        steps, rows, ok = where.setdefault(topic, ([], [], []))
        steps.append(step)
        rows.append(np.asarray(row, dtype=float).reshape(-1).copy())
        ok.append(bool(delivered))

    def table(self, topic: str, after: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(steps, rows) of ``topic`` as arrays (empty when never recorded)."""
        steps, rows, _ = (self.after if after else self.before).get(topic, ([], [], []))
        return np.asarray(steps, dtype=np.int64), (np.vstack(rows) if rows else np.zeros((0, 0)))

    def delivered(self, topic: str, after: bool = True) -> np.ndarray:
        return np.asarray((self.after if after else self.before).get(topic, ([], [], []))[2], dtype=bool)


class HilAutopilot:
    """Estimator, cascade and navigator for one flight of an external simulator's vehicle.

    ``waypoints`` (K, 3) NED and ``cruise`` (m/s): the navigator's mission; ``table`` (K, 6) and ``last``
    its items' leg speeds, holds and braking and its last item (a mission file's or a family's:
    :func:`~scart_bench.generator.flight_software.navigator.mission_table`), by default cruise on every leg.
    ``layer``: a SCART :class:`~scart_bench.generator.scart.layer.AttackLayer` for one flight (its
    scenarios at the ``sensor``, ``link`` and ``command`` points), or None for no layer. :meth:`step`
    takes one sensor sample (and the GPS fix that arrived since the last one) and returns the motor
    commands.
    """

    def __init__(self, waypoints: np.ndarray, cruise: float, profile: SimProfile = JMAVSIM, layer=None,
                 mission: MissionParams | None = None, estimator: EstimatorParams | None = None,
                 controller: ControllerParams | None = None, start: StartRule | None = None,
                 table: np.ndarray | None = None, last: int | None = None):
        self.profile = profile
        self.layer = layer
        self.points = layer.points if layer is not None else frozenset()
        bad = sorted(set(self.points) - set(HIL_POINTS))
        if bad or (layer is not None and layer.physical_groups):
            raise HilError(f"the simulator bridge runs scenarios at {', '.join(HIL_POINTS)}; "
                           f"not at {', '.join(bad) or 'environment/vehicle (the simulator owns the physics)'}")
        forged = [a.name for g in (layer.groups if layer is not None else []) for a in g.actions
                  if a.name in UNCARRIED_ACTIONS]
        if forged:
            raise HilError(f"action {forged[0]!r} is not carried by the simulator bridge (it forges a command "
                           "for the sitl's commander); run it in simulation mode")
        self.ep = estimator or EstimatorParams()
        self.start = start or StartRule()
        delay = max(1, int(round(profile.gps_delay_s / DT)) + 1)  # +1: a fix is used at the next sample
        self.est = Estimator(self.ep, DT, delay, profile.mag_field_ned)
        self.ctrl = Controller(controller or profile.controller, profile.vehicle, DT)
        wps = np.asarray(waypoints, dtype=float)[None]
        self.nav = Navigator(mission or MissionParams(), wps.copy(), np.array([float(cruise)]), np.array([np.inf]),
                             table=None if table is None else np.asarray(table, dtype=float)[None],
                             last=None if last is None else np.array([int(last)]))
        yaw0 = np.zeros(1)
        self.es = self.est.init_state(1, yaw0)
        self.cs = self.ctrl.init_state(1)
        self.ns = self.nav.init_state(1, yaw0)
        self.waypoints = wps[0]
        self.step_index = 0
        self.fused_fixes = 0
        self.origin_s: float | None = None
        self.gps = _no_gps()
        self.mag = np.zeros((1, 3))
        self.pressure = np.array([101325.0])
        self.baro_temp = np.array([15.0])
        self.battery = np.array([[16.8, 0.0, 1.0]])
        self.setpoint = np.zeros((1, 6))
        self.records = Records()
        #: at 50 Hz: step, x, y, z of the output position, the navigator's phase and mission item
        self.estimate: list[np.ndarray] = []
        self.controls = np.zeros(4)

    @property
    def armed(self) -> bool:
        return bool(self.cs.armed[0])

    @property
    def landed(self) -> bool:
        """The land detector disarmed the vehicle after its flight."""
        return bool(self.cs.disarmed_after_flight[0])

    @property
    def phase(self) -> int:
        return int(self.ns.phase[0])

    def sensor_messages(self, s: SensorSample, gps: GpsSample | None) -> dict[str, np.ndarray]:
        """The sensor topics due at this step from one sample (the magnetometer and baro at their
        rates, kept between), as the sensor point sees them; updates the held mag and baro."""
        k = self.step_index
        accel, gyro = np.asarray(s.accel, float).reshape(1, 3), np.asarray(s.gyro, float).reshape(1, 3)
        mag_due, baro_due = is_due(SENSOR_TOPICS["sensor_mag"][0], k), is_due(SENSOR_TOPICS["sensor_baro"][0], k)
        if mag_due:
            self.mag = np.asarray(s.mag, float).reshape(1, 3)
        if baro_due:
            self.pressure, self.baro_temp = np.array([float(s.pressure)]), np.array([float(s.temperature)])
        msgs = {"sensor_accel": accel, "sensor_gyro": gyro}
        if mag_due:
            msgs["sensor_mag"] = self.mag
        if baro_due:
            msgs["sensor_baro"] = np.column_stack([self.pressure, self.baro_temp])
        if gps is not None:
            msgs["sensor_gps"] = gps.row()
        return msgs

    def step(self, s: SensorSample, gps: GpsSample | None) -> np.ndarray:
        """One 4 ms step of the flight software; returns the four motor commands (0..1)."""
        k = self.step_index
        t, t_us = k * DT, k * STEP_US
        msgs = self.sensor_messages(s, gps)
        accel, gyro = msgs["sensor_accel"], msgs["sensor_gyro"]
        mag_due, baro_due = "sensor_mag" in msgs, "sensor_baro" in msgs
        for topic, vals in msgs.items():
            Records.add(self.records.before, topic, k, vals)
        ok = self._sensor_point(k, t_us, msgs) if "sensor" in self.points else {}
        for topic in msgs:
            Records.add(self.records.after, topic, k, msgs[topic], ok.get(topic, True))
        accel, gyro = ok.pop("_imu", (accel, gyro))
        self._estimate(k, t, accel, gyro, mag_due, baro_due, gps is not None, ok)
        self._telemetry(k, t_us, accel, gyro)
        if is_due(NAV_RATE_HZ, k):
            self._navigate(t)
        self.ctrl.attitude_control(self.cs, self._rot())
        rotor = self.ctrl.rate_control(self.cs, self.es.rates)
        self.controls = self.profile.controls(rotor[0])
        self._battery(k)
        if is_due(50.0, k):
            pos, _ = self.est.output(self.es)
            self.estimate.append(np.array([k, *pos[0], self.ns.phase[0], self.ns.seq[0]]))
        self.step_index += 1
        return self.controls

    # -- the pieces of a step ---------------------------------------------------------------------
    def _sensor_point(self, k: int, t_us: int, msgs: dict[str, np.ndarray]) -> dict:
        """Run the layer at the sensor point; take its values; per topic, delivered."""
        ok: dict = {}
        accel, gyro = msgs["sensor_accel"], msgs["sensor_gyro"]
        for topic, (vals, delivered) in self.layer.on_messages("sensor", k, t_us, msgs).items():
            ok[topic] = bool(delivered[0])
            if topic == "sensor_accel":
                accel = vals if ok[topic] else accel
            elif topic == "sensor_gyro":
                gyro = vals if ok[topic] else gyro
            elif topic == "sensor_mag":
                self.mag = vals
            elif topic == "sensor_baro":
                self.pressure, self.baro_temp = vals[:, 0], vals[:, 1]
            msgs[topic] = vals
        ok["_imu"] = (accel, gyro)
        return ok

    def _estimate(self, k: int, t: float, accel, gyro, mag_due: bool, baro_due: bool, gps_new: bool,
                  ok: dict) -> None:
        est, es, ep = self.est, self.es, self.ep
        self.accel, self.gyro = accel, gyro
        est.predict(es, k, accel, gyro, ~self.cs.armed)
        before = est.begin_fusion(es)
        if mag_due and ok.get("sensor_mag", True):
            est.fuse_mag(es, self.mag)
        if baro_due:
            est.fuse_baro(es, altitude_at(self.pressure), np.array([ok.get("sensor_baro", True)]))
        if gps_new:
            row = self._gps_row()
            x, y = latlon_to_ned(row[:, 0], row[:, 1])
            g = {"pos": np.column_stack([x, y, HOME_ALT - row[:, 2]]), "vel": row[:, 3:6].copy(),
                 "eph": row[:, 6], "epv": row[:, 7], "satellites": row[:, 8], "fix_type": row[:, 9]}
            self.gps = g
            usable = bool((g["fix_type"][0] >= 3) & (g["satellites"][0] >= ep.gps_min_satellites)
                          & (g["eph"][0] <= ep.gps_max_eph)) and ok.get("sensor_gps", True)
            if usable:
                self.fused_fixes += 1
                if self.origin_s is None and self.fused_fixes >= self.start.origin_fixes:
                    self.origin_s = t
                    self.nav.arm_s[:] = t + self.start.arm_after_s
            if self.origin_s is not None:
                est.fuse_gps(es, k, g["pos"], g["vel"], None if usable else np.array([False]))
        est.end_fusion(es, before)

    def _gps_row(self) -> np.ndarray:
        return self.records.after["sensor_gps"][1][-1].reshape(1, -1)

    def _telemetry(self, k: int, t_us: int, accel, gyro) -> None:
        due = [tp for tp in TELEMETRY_TOPICS if is_due(TOPICS[tp].rate_hz, k)]
        if not due:
            return
        pos, vel = self.est.output(self.es)
        snap = FCSnapshot(quat=self.es.quat, rates=self.es.rates, pos=pos, vel=vel, accel=accel, gyro=gyro,
                          mag=self.mag, pressure=self.pressure, baro_temp=self.baro_temp, gps=self.gps,
                          battery=self.battery, baro_home_alt=self.es.baro_offset)
        msgs = {tp: compose(tp, snap) for tp in due}
        for tp, vals in msgs.items():
            Records.add(self.records.before, tp, k, vals)
        if "link" in self.points:
            altered = self.layer.on_messages("link", k, t_us, msgs)
        else:
            altered = {tp: (vals, None) for tp, vals in msgs.items()}
        for tp, (vals, ok) in altered.items():
            delivered = np.ones(1, bool) if ok is None else ok
            Records.add(self.records.after, tp, k, vals, bool(delivered[0]))
            self.nav.receive(self.ns, tp, vals, delivered, TOPICS[tp].field_names)

    def _navigate(self, t: float) -> None:
        k = self.step_index
        sp = self.nav.step(self.ns, t)
        Records.add(self.records.before, "setpoint", k, sp)
        ok = True
        if "command" in self.points:
            vals, delivered, _, self.nav.wps = exchange(self.layer, k, k * STEP_US, sp, self.nav.wps)
            ok = bool(delivered[0])
            sp = vals if ok else self.setpoint
        Records.add(self.records.after, "setpoint", k, sp, ok)
        self.setpoint = sp
        cs = self.cs
        cs.armed = (sp[:, 5] > 0.5) & ~cs.disarmed_after_flight
        _, vel = self.est.output(self.es)
        self.ctrl.velocity_control(cs, sp[:, 0:3], sp[:, 3], vel, self._rot(), 1.0 / NAV_RATE_HZ)
        self.ctrl.land_detector(cs, sp[:, 0:3], vel, 1.0 / NAV_RATE_HZ)

    def _rot(self) -> np.ndarray:
        if self.es.R is None:
            self.es.R = quat_to_rot(self.es.quat)
        return self.es.R

    def _battery(self, k: int) -> None:
        """A 4S pack drained by the commanded thrust (the simulators here model no battery)."""
        if not is_due(TOPICS["battery_status"].rate_hz, k):
            return
        vp, b = self.profile.vehicle, self.battery
        thrust = self.controls * vp.max_thrust
        power = BATTERY_POWER_K * np.sum(np.maximum(thrust, 0.0) ** 1.5) + BATTERY_IDLE_W
        ocv = BATTERY_OCV_V + BATTERY_OCV_SPAN_V * b[0, 2]
        current = power / max(ocv, 1.0)
        b[0, 2] = np.clip(b[0, 2] - current * BATTERY_STEP_S / (BATTERY_CAPACITY_AH * 3600), 0.0, 1.0)
        b[0, 0] = ocv - BATTERY_R_OHM * current
        b[0, 1] = current


def _no_gps() -> dict:
    return {"pos": np.zeros((1, 3)), "vel": np.zeros((1, 3)), "eph": np.full(1, 99.0), "epv": np.full(1, 99.0),
            "satellites": np.zeros(1), "fix_type": np.zeros(1)}

