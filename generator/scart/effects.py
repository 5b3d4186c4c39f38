"""Physical actions: environment attacks and reliability faults.

Message actions (generator.scart.actions) alter what passes an injection point. The actions here
change the world or the vehicle instead: they run at the ``environment`` and ``vehicle``
injection points and write into the step's ``Disturbances``, which the simulator applies to its
physics, sensors and battery. Nothing downstream is told: the flight controller sees the effects
only through its sensors, as it would in the air. Numeric parameters are per-flight arrays.
"""

from __future__ import annotations

import numpy as np

from scart_bench.generator.physics.disturbances import SENSOR_INSTANCES, Disturbances, Jammer, MagneticSource
from scart_bench.generator.scart.spec import Param

#: Full-charge voltage of the 4S battery; the maximum rotor speed scales with the voltage (KV * V).
BATTERY_FULL_V = 16.8


class Effect:
    """Base class; subclasses set ``name``, ``point``, ``spec`` and implement ``apply``."""

    name = "effect"
    point = "environment"
    spec: tuple[Param, ...] = ()
    random = False
    physical = True

    def __init__(self, params: dict):
        self.params = params
        self.fields: dict[str, tuple[int, ...]] = {}  # no message targets

    def lookback(self, topic: str, rate_hz: float) -> int:
        return 1

    def col(self, name: str) -> np.ndarray:
        return np.asarray(self.params[name], dtype=float).reshape(-1)

    def apply(self, ctx, active: np.ndarray, dist: Disturbances) -> None:
        """Write this step's effect for the group's flights that are ``active``."""
        raise NotImplementedError


def _elapsed_s(ctx) -> np.ndarray:
    return np.maximum(ctx.t_us - ctx.start_us, 0) / 1e6


def _horizontal(direction_deg: np.ndarray) -> np.ndarray:
    d = np.deg2rad(direction_deg)
    return np.column_stack([np.cos(d), np.sin(d), np.zeros_like(d)])


def _point3(value, where: str = "center") -> np.ndarray:
    v = np.asarray(value, dtype=float).reshape(-1)
    return np.array([v[0], v[1], v[2] if v.size > 2 else 0.0])


# -- environment ---------------------------------------------------------------------------------
class GpsJamming(Effect):
    """GPS jamming (RF): the C/N0 of every satellite drops; satellites and accuracy are lost and,
    below 4 satellites, the fix. Power falls with distance from ``center`` [north, east(, down)] when
    given (``js_db`` at ``reference_m``), else it is the same everywhere."""

    name = "gps_jamming"
    spec = (Param("js_db", float, required=True, minimum=-100.0, maximum=200.0,
                  help="jammer-to-signal ratio at the antenna, dB"),
            Param("center", list, None, help="[north_m, east_m(, down_m)] of the jammer (default: everywhere)",
                  item=float, min_items=2, max_items=3),
            Param("reference_m", float, 100.0, minimum=0.0, exclusive_min=True),
            Param("ramp_s", float, 0.0, minimum=0.0, help="seconds to reach full power"))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        if not rows.size:
            return
        js = self.col("js_db")[active]
        ramp = self.col("ramp_s")[active]
        t = _elapsed_s(ctx)[active]
        # ramping up from 40 dB below full power (a jammer switching on or approaching)
        frac = np.where(ramp > 0, np.clip(t / np.where(ramp > 0, ramp, 1.0), 0.0, 1.0), 1.0)
        js = js - 40.0 * (1.0 - frac)
        center = self.params["center"]
        if center is None:
            dist.jammers.append(Jammer(rows=rows, js_db=js))
        else:
            c = np.broadcast_to(_point3(center), (rows.size, 3))
            dist.jammers.append(Jammer(rows=rows, js_db=js, center_ned=c,
                                       reference_m=self.col("reference_m")[active]))


class GpsRfSpoof(Effect):
    """GPS spoofing at the RF level: the receiver locks on a spoofer's constellation, which starts on
    the true position and drags it off along ``direction_deg``, accelerating at ``accel`` to
    ``rate`` m/s (up to ``max_offset`` m). Position and velocity stay consistent; the spoofer shows
    ``satellites`` satellites with good accuracy. Every GPS receiver on the vehicle sees it."""

    name = "gps_rf_spoof"
    spec = (Param("rate", float, required=True, minimum=0.0, help="drag-off speed, m/s"),
            Param("direction_deg", float, 45.0, help="heading of the drag-off, 0 = north"),
            Param("accel", float, 0.1, minimum=0.0, exclusive_min=True, help="m/s^2 until ``rate``"),
            Param("max_offset", float, float("inf"), minimum=0.0, help="m", allow_inf=True),
            Param("satellites", int, 10, minimum=4, maximum=32))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        if not rows.size:
            return
        t = _elapsed_s(ctx)[active]
        rate, acc = self.col("rate")[active], self.col("accel")[active]
        t_ramp = rate / acc
        d = np.where(t < t_ramp, 0.5 * acc * t**2, 0.5 * acc * t_ramp**2 + rate * (t - t_ramp))
        v = np.where(t < t_ramp, acc * t, rate)
        cap = self.col("max_offset")[active]
        v = np.where(d >= cap, 0.0, v)
        d = np.minimum(d, cap)
        u = _horizontal(self.col("direction_deg")[active])
        dist.gps_offset[rows] += d[:, None] * u
        dist.gps_vel_offset[rows] += v[:, None] * u
        dist.gps_spoofed[rows] = True
        dist.gps_spoof_satellites[rows] = self.col("satellites")[active]


class WindGust(Effect):
    """A wind gust: ``speed`` m/s toward ``direction_deg`` (and ``vertical`` m/s up), rising as
    1 - cos over ``rise_s`` and holding while the scenario is active."""

    name = "wind_gust"
    spec = (Param("speed", float, required=True, minimum=0.0, maximum=100.0, help="m/s"),
            Param("direction_deg", float, 0.0, help="the gust blows toward this heading, 0 = north"),
            Param("vertical", float, 0.0, minimum=-50.0, maximum=50.0, help="m/s, positive up"),
            Param("rise_s", float, 2.0, minimum=0.0))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        if not rows.size:
            return
        t = _elapsed_s(ctx)[active]
        rise = self.col("rise_s")[active]
        shape = np.where(rise > 0, 0.5 * (1 - np.cos(np.pi * np.clip(t / np.where(rise > 0, rise, 1.0), 0, 1))), 1.0)
        gust = _horizontal(self.col("direction_deg")[active]) * self.col("speed")[active][:, None]
        gust[:, 2] = -self.col("vertical")[active]
        dist.wind[rows] += shape[:, None] * gust


class MagInterference(Effect):
    """Magnetic interference near a location: a field of ``strength`` gauss at ``reference_m`` from
    ``center`` [north, east(, down)], falling as 1/r^3 (a dipole's far field), along ``direction``
    (NED). The magnetometer sees it at the vehicle's true position."""

    name = "mag_interference"
    spec = (Param("center", list, required=True, help="[north_m, east_m(, down_m)]", item=float, min_items=2,
                  max_items=3),
            Param("strength", float, required=True, minimum=-100.0, maximum=100.0, help="gauss at reference_m"),
            Param("reference_m", float, 5.0, minimum=0.0, exclusive_min=True),
            Param("direction", list, [1.0, 0.0, 0.0], help="[north, east, down] of the disturbing field",
                  item=float, min_items=3, max_items=3))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        if not rows.size:
            return
        k = rows.size
        direction = _point3(self.params["direction"])
        norm = np.linalg.norm(direction)
        direction = direction / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
        dist.magnetic.append(MagneticSource(
            rows=rows, center_ned=np.broadcast_to(_point3(self.params["center"]), (k, 3)),
            strength=self.col("strength")[active], reference_m=self.col("reference_m")[active],
            direction_ned=np.broadcast_to(direction, (k, 3))))


# -- vehicle (reliability faults) ------------------------------------------------------------------
_MOTOR = Param("motor", int, required=True, minimum=1, maximum=4, help="rotor 1-4 (PX4 quad-x order)")


class MotorEfficiency(Effect):
    """A motor (or propeller) losing thrust: rotor ``motor`` gives ``efficiency`` of its thrust."""

    name = "motor_efficiency"
    point = "vehicle"
    spec = (_MOTOR, Param("efficiency", float, required=True, minimum=0.0, maximum=1.0))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        motor = np.asarray(self.params["motor"]).reshape(-1)[active] - 1
        dist.motor_efficiency[rows, motor] *= self.col("efficiency")[active]


class MotorFailure(Effect):
    """A motor failure: rotor ``motor`` gives no thrust."""

    name = "motor_failure"
    point = "vehicle"
    spec = (_MOTOR,)

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        motor = np.asarray(self.params["motor"]).reshape(-1)[active] - 1
        dist.motor_efficiency[rows, motor] = 0.0


class BatterySag(Effect):
    """Battery voltage sag: ``volts`` off the terminal voltage (reaching it over ``ramp_s``); the
    motors' maximum speed falls with the voltage."""

    name = "battery_sag"
    point = "vehicle"
    spec = (Param("volts", float, required=True, minimum=0.0, maximum=BATTERY_FULL_V),
            Param("ramp_s", float, 0.0, minimum=0.0))

    def apply(self, ctx, active, dist):
        rows = ctx.rows[active]
        ramp = self.col("ramp_s")[active]
        t = _elapsed_s(ctx)[active]
        frac = np.where(ramp > 0, np.clip(t / np.where(ramp > 0, ramp, 1.0), 0.0, 1.0), 1.0)
        sag = self.col("volts")[active] * frac
        dist.battery_sag_v[rows] += sag
        dist.rotor_limit[rows] = np.minimum(dist.rotor_limit[rows], np.clip(1.0 - sag / BATTERY_FULL_V, 0.0, 1.0))


class SensorInstanceLoss(Effect):
    """Loss of a sensor instance. With ``failover`` the flight controller switches to a redundant
    instance whose calibration differs by ``offset`` (m/s^2, rad/s, gauss, m of altitude, m north of
    GPS); without, the sensor's data stops (its last reading stays in the telemetry)."""

    name = "sensor_instance_loss"
    point = "vehicle"
    spec = (Param("sensor", str, required=True, choices=SENSOR_INSTANCES),
            Param("failover", bool, True), Param("offset", float, 0.0))

    def apply(self, ctx, active, dist):
        name = self.params["sensor"]
        n = dist.wind.shape[0]
        lost = dist.sensor_lost.setdefault(name, np.zeros(n, dtype=bool))
        fail = dist.sensor_failover.setdefault(name, np.zeros(n, dtype=bool))
        off = dist.sensor_offset.setdefault(name, np.zeros(n))
        rows = ctx.rows[active]
        lost[rows] = True
        fail[rows] = bool(self.params["failover"])
        off[rows] = self.col("offset")[active]


EFFECTS: dict[str, type[Effect]] = {
    e.name: e for e in (GpsJamming, GpsRfSpoof, WindGust, MagInterference, MotorEfficiency, MotorFailure,
                        BatterySag, SensorInstanceLoss)
}
#: Injection points whose scenarios act on the physics, not on messages.
PHYSICAL_POINTS = ("environment", "vehicle")
