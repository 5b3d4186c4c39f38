"""One simulated vehicle stepped at 250 Hz: the generator's physics, sensors, estimator and controller.

The step pipeline is :func:`scart_bench.generator.engine.simulate.simulate`'s for a batch of one flight, driven
from outside one step at a time: wind -> vehicle dynamics -> sensors -> estimator -> telemetry,
then (at 50 Hz) a velocity/yaw setpoint into the controller, then attitude control, battery and
the ground truth. Telemetry is composed with :func:`scart_bench.generator.telemetry.schedule.compose` at the rates of
``scart_bench.dataset.schema``, so a recorded flight has the schedule of the generated datasets.
"""

from __future__ import annotations

import numpy as np

from scart_bench.dataset.schema import HOME_ALT, TELEMETRY_TOPICS, TOPICS
from scart_bench.generator.flight_software.flight_controller import Controller, Estimator
from scart_bench.generator.geo import altitude_at, latlon_to_ned, ned_to_latlon
from scart_bench.generator.params import (
    BATTERY_CAPACITY_AH,
    BATTERY_IDLE_W,
    BATTERY_NOISE_V,
    BATTERY_OCV_SPAN_V,
    BATTERY_OCV_V,
    BATTERY_POWER_K,
    BATTERY_R_OHM,
    BATTERY_STEP_S,
    DT,
    GRAVITY,
    NAV_RATE_HZ,
    STEP_US,
    ControllerParams,
    EstimatorParams,
    MissionParams,
    SensorParams,
    VehicleParams,
)
from scart_bench.generator.physics.disturbances import Disturbances
from scart_bench.generator.physics.noise import NoiseStream
from scart_bench.generator.physics.rotation import euler_from_quat, quat_to_rot
from scart_bench.generator.physics.sensors import Sensors, thrust_scale, vibration_scale
from scart_bench.generator.physics.vehicle import Vehicle, VehicleState, Wind
from scart_bench.generator.telemetry.schedule import (  # is_due: re-exported for the sitl
    FCSnapshot,
    compose,
    is_due,
)


class Plant:
    """The vehicle and its flight controller's inner loops, for one flight (arrays of one row).

    ``seed`` draws the wind, the sensor errors and the noise as the generator does for one
    flight. :meth:`step` advances 4 ms and returns the telemetry due at that step;
    :meth:`control` takes the velocity/yaw setpoint at the navigator rate (50 Hz).
    """

    def __init__(self, seed: int = 0, vehicle: VehicleParams | None = None, sensors: SensorParams | None = None,
                 estimator: EstimatorParams | None = None, controller: ControllerParams | None = None,
                 mission: MissionParams | None = None):
        self.seed = int(seed)
        vp, sp = vehicle or VehicleParams(), sensors or SensorParams()
        ep, cp, mp = estimator or EstimatorParams(), controller or ControllerParams(), mission or MissionParams()
        self.vehicle_params = vp
        self.estimator_params = ep
        rngs = [np.random.default_rng(np.random.SeedSequence([self.seed, 0x5CA7, 0x5171]))]
        u = rngs[0].uniform(size=6)
        speed, direction = mp.wind_max * u[0], 2 * np.pi * u[1]
        self.wind = Wind(mean=np.array([[speed * np.cos(direction), speed * np.sin(direction), 0.0]]),
                         gust=np.zeros((1, 3)), sigma=np.array([mp.gust_sigma_max * u[2]]), tau=mp.gust_tau)
        yaw0 = np.array([(u[3] - 0.5) * 0.5])
        self.vehicle = Vehicle(vp)
        self.sensors = Sensors(sp, DT)
        self.est = Estimator(ep, DT, self.sensors.delay_steps, sp.mag_field_ned)
        self.ctrl = Controller(cp, vp, DT)
        self.vs = VehicleState.zeros(1, yaw0)
        self.ss = self.sensors.init_state(1, rngs)
        self.es = self.est.init_state(1, yaw0)
        self.cs = self.ctrl.init_state(1)
        self.noise = NoiseStream(rngs, 30)
        self.gps_dt = 1.0 / sp.gps_rate_hz
        self.step_index = 0
        self.battery = np.array([[16.8, 0.0, 1.0]])
        self.accel = np.zeros((1, 3))
        self.gyro = np.zeros((1, 3))
        self.mag = np.zeros((1, 3))
        self.pressure = np.zeros(1)
        self.baro_temp = np.zeros(1)
        self.gps: dict | None = None
        self.gps_fixes = 0
        self.R_est = quat_to_rot(self.es.quat)
        self._w = None
        self._env: Disturbances | None = None

    @property
    def t_us(self) -> int:
        """Time of the step about to run (µs since boot)."""
        return self.step_index * STEP_US

    @property
    def armed(self) -> bool:
        return bool(self.cs.armed[0])

    def set_armed(self, armed: bool) -> None:
        """Arm (integrators reset, the land detector's latch cleared) or disarm the motors."""
        cs = self.cs
        if armed and not cs.armed[0]:
            cs.disarmed_after_flight[:] = False
            cs.vel_int[:] = 0.0
            cs.rate_int[:] = 0.0
            cs.land_time[:] = 0.0
            cs.vel_sp[:] = 0.0
            cs.prev_vel_err[:] = 0.0
        cs.armed[:] = armed

    def landed_by_detector(self) -> bool:
        """The controller's land detector disarmed the vehicle (latched until the next arming)."""
        return bool(self.cs.disarmed_after_flight[0])

    def step(self, env: Disturbances | None = None, sensor_hook=None) -> dict[str, np.ndarray]:
        """Advance one step (physics, sensors, estimator); returns this step's telemetry (1, n_fields).

        ``env``: this step's physical disturbances from environment and vehicle scenarios (wind,
        magnetic sources, GPS jamming and RF spoofing, motor efficiency, battery sag), applied as
        :func:`scart_bench.generator.engine.simulate.simulate` applies them; sensor-instance loss is not modelled here.
        ``sensor_hook(messages) -> {topic: (values, delivered)}``: the ``sensor`` injection point,
        between the sensors and the estimator (topics of ``scart_bench.generator.telemetry.schedule.SENSOR_TOPICS``); an
        undelivered sample is not fused, as in simulation mode.
        """
        k = self.step_index
        w = self._w = self.noise.next()
        vs, ss, es, cs = self.vs, self.ss, self.es, self.cs
        self._env = env
        wind_now = self.wind.step(w[:, 26:29], DT)
        rotor_cmd = self.ctrl.rate_control(cs, es.rates)
        efficiency = None
        if env is not None:
            env.resolve(vs.pos)
            wind_now = wind_now + env.wind
            rotor_cmd = np.minimum(rotor_cmd, self.vehicle_params.max_rot_velocity * env.rotor_limit[:, None])
            efficiency = env.motor_efficiency
        R_true = self.vehicle.step(vs, rotor_cmd, wind_now, DT, efficiency)
        self.sensors.push_truth(ss, k, vs.pos, vs.vel)
        vp = self.vehicle_params
        hover_rotor = float(np.sqrt(vp.mass * GRAVITY / (4 * vp.motor_constant)))
        self.accel, self.gyro = self.sensors.imu(ss, vs.accel, vs.omega, R_true, w[:, 0:12],
                                                 vibration_scale(vs.rotor_speed, hover_rotor))
        mag_due = is_due(self.sensors.params.mag_rate_hz, k)
        baro_due = is_due(self.sensors.params.baro_rate_hz, k)
        gps_due = is_due(self.sensors.params.gps_rate_hz, k)
        if mag_due:
            self.mag = self.sensors.mag(R_true, w[:, 12:15], env.magnetic_field(vs.pos) if env is not None else None)
        if baro_due:
            self.pressure, self.baro_temp = self.sensors.baro(ss, vs.pos, w[:, 15:17], thrust_scale(vs.rotor_speed, hover_rotor))
        if gps_due:
            self.gps = self.sensors.gps(ss, k, w[:, 17:26], self.gps_dt, env)
        ok = self._sensor_point(sensor_hook, mag_due, baro_due, gps_due) if sensor_hook is not None else {}
        self.R_est = self.est.predict(es, k, self.accel, self.gyro, ~cs.armed)
        if mag_due and ok.get("sensor_mag", True):
            self.est.fuse_mag(es, self.mag)
        if baro_due:
            self.est.fuse_baro(es, altitude_at(self.pressure), np.array([ok.get("sensor_baro", True)]))
        if gps_due:
            g, ep = self.gps, self.estimator_params
            usable = (g["fix_type"] >= 3) & (g["satellites"] >= ep.gps_min_satellites) & (g["eph"] <= ep.gps_max_eph)
            usable = usable & ok.get("sensor_gps", True)
            self.est.fuse_gps(es, k, g["pos"], g["vel"], None if usable.all() else usable)
            self.gps_fixes += int(usable[0])
        due = [t for t in TELEMETRY_TOPICS if is_due(TOPICS[t].rate_hz, k)]
        if not due:
            return {}
        snap = FCSnapshot(quat=es.quat, rates=es.rates, pos=es.x[:, :, 0], vel=es.x[:, :, 1], accel=self.accel,
                          gyro=self.gyro, mag=self.mag, pressure=self.pressure, baro_temp=self.baro_temp,
                          gps=self.gps if self.gps is not None else _no_gps(), battery=self.battery,
                          baro_home_alt=es.baro_offset)
        return {t: compose(t, snap) for t in due}

    def _sensor_point(self, hook, mag_due: bool, baro_due: bool, gps_due: bool) -> dict[str, bool]:
        """Run the sensor samples of this step through ``hook``; take its values; per topic, delivered."""
        msgs = {"sensor_accel": self.accel, "sensor_gyro": self.gyro}
        if mag_due:
            msgs["sensor_mag"] = self.mag
        if baro_due:
            msgs["sensor_baro"] = np.column_stack([self.pressure, self.baro_temp])
        if gps_due:
            g = self.gps
            lat, lon = ned_to_latlon(g["pos"][:, 0], g["pos"][:, 1])
            msgs["sensor_gps"] = np.column_stack([lat, lon, HOME_ALT - g["pos"][:, 2], g["vel"], g["eph"], g["epv"],
                                                  g["satellites"], g["fix_type"]])
        ok: dict[str, bool] = {}
        for topic, (vals, delivered) in hook(msgs).items():
            ok[topic] = bool(delivered[0])
            if topic == "sensor_accel" and ok[topic]:
                self.accel = vals
            elif topic == "sensor_gyro" and ok[topic]:
                self.gyro = vals
            elif topic == "sensor_mag":
                self.mag = vals
            elif topic == "sensor_baro":
                self.pressure, self.baro_temp = vals[:, 0], vals[:, 1]
            elif topic == "sensor_gps":
                x, y = latlon_to_ned(vals[:, 0], vals[:, 1])
                self.gps = {**self.gps, "pos": np.column_stack([x, y, HOME_ALT - vals[:, 2]]),
                            "vel": vals[:, 3:6].copy(), "eph": vals[:, 6], "epv": vals[:, 7],
                            "satellites": vals[:, 8], "fix_type": vals[:, 9]}
        return ok

    def control(self, setpoint: np.ndarray | None) -> None:
        """Velocity control with the setpoint (1, 6) vx, vy, vz, yaw, seq, armed (None: keep the last)."""
        cs, es = self.cs, self.es
        if setpoint is not None:
            self._sp = setpoint
        sp = getattr(self, "_sp", None)
        if sp is None:
            sp = np.zeros((1, 6))
            sp[0, 3] = euler_from_quat(es.quat)[0, 2]
        cs.armed = (sp[:, 5] > 0.5) & ~cs.disarmed_after_flight
        self.R_est = quat_to_rot(es.quat)
        self.ctrl.velocity_control(cs, sp[:, 0:3], sp[:, 3], es.x[:, :, 1], self.R_est, 1.0 / NAV_RATE_HZ)
        self.ctrl.land_detector(cs, sp[:, 0:3], es.x[:, :, 1], 1.0 / NAV_RATE_HZ)

    def finish_step(self) -> np.ndarray | None:
        """Attitude control, battery; returns the truth row (1, 11) when due (50 Hz), else None."""
        k = self.step_index
        cs, vs = self.cs, self.vs
        self.ctrl.attitude_control(cs, self.R_est)
        if is_due(TOPICS["battery_status"].rate_hz, k):
            vp, b = self.vehicle_params, self.battery
            thrust = vp.motor_constant * vs.rotor_speed**2
            power = BATTERY_POWER_K * np.sum(np.maximum(thrust, 0.0) ** 1.5, axis=1) + BATTERY_IDLE_W
            ocv = BATTERY_OCV_V + BATTERY_OCV_SPAN_V * b[:, 2]
            current = power / np.maximum(ocv, 1.0)
            b[:, 2] = np.clip(b[:, 2] - current * BATTERY_STEP_S / (BATTERY_CAPACITY_AH * 3600), 0.0, 1.0)
            b[:, 0] = ocv - BATTERY_R_OHM * current + BATTERY_NOISE_V * self._w[:, 29]
            if self._env is not None:
                b[:, 0] -= self._env.battery_sag_v
            b[:, 1] = current
        truth = None
        if is_due(50.0, k):
            eul = euler_from_quat(vs.quat)
            truth = np.column_stack([vs.pos, vs.vel, eul, cs.armed, vs.on_ground]).astype(float)
        self.step_index += 1
        return truth

    # -- what the flight controller knows about itself --------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Estimated NED position (3,)."""
        return self.es.x[0, :, 0].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.es.x[0, :, 1].copy()

    @property
    def yaw(self) -> float:
        return float(euler_from_quat(self.es.quat)[0, 2])

    @property
    def position_valid(self) -> bool:
        """The estimator has fused GPS (PX4: global position valid), after 1 s of alignment."""
        return self.gps_fixes >= 5 and self.step_index * DT >= 1.0


def _no_gps() -> dict:
    return {"pos": np.zeros((1, 3)), "vel": np.zeros((1, 3)), "eph": np.full(1, 99.0), "epv": np.full(1, 99.0),
            "satellites": np.zeros(1), "fix_type": np.zeros(1)}
