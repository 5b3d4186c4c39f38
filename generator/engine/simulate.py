"""Fly a batch of flights in the closed loop: the step pipeline and its recorder.

One step (250 Hz) is a fixed pipeline:
wind -> vehicle dynamics -> sensors [sensor hook] -> estimator -> telemetry [link hook] ->
navigator -> setpoint [command hook] -> controller -> land detector.
The hooks are where the SCART attack layer plugs in; with no layer they are skipped.
"""

from __future__ import annotations

import numpy as np

from scart_bench.dataset.schema import HOME_ALT, SIM_RATE_HZ, TELEMETRY_TOPICS, TOPICS, TRUTH_RATE_HZ
from scart_bench.generator.engine.flight_batch import (  # noqa: F401 (re-exported: the public names live on here)
    STATUS,
    AttackHooks,
    BatchResult,
    FlightConfig,
    Initial,
    alive,
    initial_conditions,
    instance_gps,
    instance_imu,
    instance_value,
    merge_results,
    vehicle_groups,
)
from scart_bench.generator.flight_software.commander import BatchCommander, exchange
from scart_bench.generator.flight_software.flight_controller import Controller, Estimator
from scart_bench.generator.flight_software.navigator import Navigator
from scart_bench.generator.flight_software.pilot import Pilot, pilot_on
from scart_bench.generator.geo import altitude_at, latlon_to_ned, ned_to_latlon
from scart_bench.generator.params import (  # noqa: F401 (re-exported)
    BATTERY_CAPACITY_AH,
    BATTERY_IDLE_W,
    BATTERY_NOISE_V,
    BATTERY_OCV_SPAN_V,
    BATTERY_OCV_V,
    BATTERY_POWER_K,
    BATTERY_R_OHM,
    BATTERY_STEP_S,
    CRASH_CHECK_STEPS,
    CRASH_GROUND_HOVERS,
    CRASH_TILT_RAD,
    DT,
    GRAVITY,
    NAV_RATE_HZ,
    STEP_US,
)
from scart_bench.generator.physics.disturbances import Disturbances
from scart_bench.generator.physics.noise import NOISE_DIM, NOISE_FIELDS, NoiseStream
from scart_bench.generator.physics.rotation import euler_from_quat
from scart_bench.generator.physics.sensors import logged_imu, thrust_scale, vibration_scale
from scart_bench.generator.physics.vehicle import FlowRocking, Rocking, Vehicle
from scart_bench.generator.telemetry.schedule import (
    SENSOR_TOPICS,
    UORB_STREAMS,
    FCSnapshot,
    compose,
    due_steps,
)
from scart_bench.generator.telemetry.timing import check_timing, check_timing_table


class _Recorder:
    """Preallocated, growing message arrays per topic: (N, n_messages, n_fields)."""

    def __init__(self, n: int, expected_steps: int):
        self.n = n
        self.capacity_steps = expected_steps
        self.values: dict[str, np.ndarray] = {}
        self.delivered: dict[str, np.ndarray] = {}
        self.steps: dict[str, list[int]] = {}

    def add(self, topic: str, step: int, values: np.ndarray, delivered: np.ndarray | None = None) -> None:
        arr = self.values.get(topic)
        count = len(self.steps.get(topic, ()))
        if arr is None:
            rate = values.shape[1]
            cap = max(8, int(self.capacity_steps * 0.2) + 8)
            arr = np.empty((self.n, cap, rate))
            self.values[topic] = arr
            self.delivered[topic] = np.ones((self.n, cap), dtype=bool)
            self.steps[topic] = []
        if count >= arr.shape[1]:
            grow = arr.shape[1]
            arr = np.concatenate([arr, np.empty((self.n, grow, arr.shape[2]))], axis=1)
            self.values[topic] = arr
            self.delivered[topic] = np.concatenate([self.delivered[topic], np.ones((self.n, grow), bool)], axis=1)
        arr[:, count, :] = values
        if delivered is not None:
            self.delivered[topic][:, count] = delivered
        self.steps[topic].append(step)

    def finish(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        out = {}
        for topic, steps in self.steps.items():
            k = len(steps)
            out[topic] = (np.asarray(steps, dtype=np.int64), self.values[topic][:, :k], self.delivered[topic][:, :k])
        return out






ENGINES = ("auto", "kernel", "numpy")


def simulate(seeds: list[int], config: FlightConfig | None = None, layer: AttackHooks | None = None,
             progress=None, engine: str = "auto") -> BatchResult:
    """Fly one flight per seed in a batch; same seeds and config give bit-identical results.

    ``engine``: "kernel" (the compiled flight kernel, generator.engine.kernel and generator.engine.compiled; what
    "auto" picks) or "numpy" (the reference step below, which the kernel is tested against).
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    cfg = config or FlightConfig()
    check_timing(cfg.timing)
    timing_table = check_timing_table(cfg.timing_table)
    if engine in ("auto", "kernel"):
        from scart_bench.generator.engine.compiled import simulate_kernel as fly
    else:
        fly = simulate_reference
    groups = vehicle_groups(seeds, cfg)  # one engine batch per airframe and payload (FlightConfig.airframes)
    if len(groups) == 1:
        result = fly(seeds, groups[0][0], layer, progress)
    elif layer is not None:
        raise ValueError("a batch with an attack layer flies one airframe and payload: fly the flights of "
                         "each of generator.engine.flight_batch.vehicle_groups as a batch of their own")
    else:
        parts = [fly([seeds[i] for i in idx], sub, None, None) for sub, idx in groups]
        result = merge_results(parts, [idx for _, idx in groups], seeds)
    result.timing = cfg.timing
    result.timing_table = timing_table
    result.uorb = cfg.uorb
    return result






def simulate_reference(seeds: list[int], config: FlightConfig | None = None, layer: AttackHooks | None = None,
                       progress=None) -> BatchResult:
    """The numpy reference step: the whole batch advanced one step at a time (all flights to the end)."""
    cfg = config or FlightConfig()
    init = initial_conditions(seeds, cfg)
    n = len(seeds)
    rngs, wind, yaw0, waypoints = init.rngs, init.wind, init.yaw0, init.waypoints
    wind_mean = wind.mean
    m = cfg.mission
    max_steps = init.max_steps
    vehicle = Vehicle(cfg.vehicle)
    sensors = init.sensors
    est = Estimator(cfg.estimator, DT, sensors.delay_steps, cfg.sensors.mag_field_ned)
    ctrl = Controller(cfg.controller, cfg.vehicle, DT)
    nav = Navigator(m, waypoints.copy(), init.cruise, init.start[:, 2],  # a copy: a mission tamper changes what it flies
                    init.table, init.last)
    vs = init.vehicle_state
    ss = init.sensor_state
    es = est.init_state(n, yaw0)
    cs = ctrl.init_state(n)
    ns = nav.init_state(n, yaw0)
    pilot = Pilot(m) if pilot_on(m) else None  # a pilot in attitude mode (MissionParams.pilot_*)
    pilot_state = pilot.init_state(init.pilot) if pilot is not None else None
    rocking = Rocking(init.rocking) if init.rocking is not None else None  # each vehicle's (MissionParams.rocking_levels)
    flow = (FlowRocking(init.flow, m.rocking_flow_hz, m.rocking_flow_full_m_s, m.rocking_flow_from_m_s, DT)  # ... in forward flight
            if init.flow is not None else None)
    noise = NoiseStream(rngs, NOISE_DIM)
    nz = NOISE_FIELDS

    sim_rec = _Recorder(n, max_steps // 2)
    nav_rec = _Recorder(n, max_steps // 2) if layer is not None else sim_rec
    points = layer.points if layer is not None else frozenset()
    commander = BatchCommander(cfg.control, n, np.zeros((n, 2)), m.land_speed) if "command" in points else None

    sched_len = max_steps + 1
    due = {t: due_steps(TOPICS[t].rate_hz, sched_len) for t in TOPICS}
    due_nav = due_steps(NAV_RATE_HZ, sched_len)
    due_truth = due_steps(TRUTH_RATE_HZ, sched_len)
    due_sens = {t: due_steps(r, sched_len) for t, (r, _) in SENSOR_TOPICS.items()}
    due_uorb = {t: due_steps(r, sched_len) for t, (r, _) in UORB_STREAMS.items()} if cfg.uorb else {}
    uorb_rec = _Recorder(n, max_steps // 2)
    gps_dt = 1.0 / cfg.sensors.gps_rate_hz

    done = np.zeros(n, dtype=bool)
    exit_step = np.full(n, -1, dtype=np.int64)
    status = np.array(["timeout"] * n, dtype=object)
    battery = init.battery.copy()
    origin_s = init.start[:, 1]
    vel_sp = np.zeros((n, 3))
    yaw_sp = yaw0.copy()
    setpoint_in = np.zeros((n, 6))
    accel = np.zeros((n, 3))
    gyro = np.zeros((n, 3))
    mag = np.zeros((n, 3))
    pressure = np.zeros(n)
    baro_temp = np.zeros(n)
    gps = None
    efficiency = None
    env: Disturbances | None = None
    max_rotor = cfg.vehicle.max_rot_velocity
    hover_thrust = cfg.vehicle.mass * GRAVITY
    hover_rotor = float(np.sqrt(hover_thrust / (4 * cfg.vehicle.motor_constant)))  # rad/s
    tail_steps = int(0.5 * SIM_RATE_HZ)
    landed_at = np.full(n, -1, dtype=np.int64)

    step = 0
    for step in range(max_steps):
        t_us = step * STEP_US
        t = step * DT
        w = noise.next()
        if layer is not None:
            phys = layer.on_physics(step, t_us)
            env = phys if isinstance(phys, Disturbances) else None
            efficiency = env.motor_efficiency if env is not None else phys.get("motor_efficiency")
        wind_now = wind.step(w[:, nz["wind"]], DT)
        rotor_cmd = ctrl.rate_control(cs, es.rates)
        motor_cmd = rotor_cmd  # what the mixer commanded, before a rotor limit (the uORB view's actuators)
        if env is not None:
            env.resolve(vs.pos)
            wind_now = wind_now + env.wind
            rotor_cmd = np.minimum(rotor_cmd, max_rotor * env.rotor_limit[:, None])
        rock = rocking.step() if rocking is not None else None
        if flow is not None:  # the forward-flight rocking at the speed before this step's (kernel._vehicle)
            rock = flow.step(vs.vel) if rock is None else rock + flow.step(vs.vel)
        R_true = vehicle.step(vs, rotor_cmd, wind_now, DT, efficiency, rock)
        sensors.push_truth(ss, step, vs.pos, vs.vel)

        # sensors -> estimator
        prev_imu = (accel, gyro)
        accel, gyro = sensors.imu(ss, vs.accel, vs.omega, R_true, w[:, nz["imu"]],
                                  vibration_scale(vs.rotor_speed, hover_rotor))
        if env is not None and env.sensor_lost:
            accel, gyro = instance_imu(env, accel, gyro, prev_imu)
        sens_msgs: dict[str, np.ndarray] = {}
        if "sensor" in points:
            sens_msgs["sensor_accel"] = accel
            sens_msgs["sensor_gyro"] = gyro
        if due_sens["sensor_mag"][step]:
            prev_mag = mag
            mag = sensors.mag(R_true, w[:, nz["mag"]], env.magnetic_field(vs.pos) if env is not None else None)
            if env is not None and env.sensor_lost:
                mag = instance_value(env, "mag", mag, prev_mag)
            if "sensor" in points:
                sens_msgs["sensor_mag"] = mag
        if due_sens["sensor_baro"][step]:
            prev_baro = pressure, baro_temp
            pressure, baro_temp = sensors.baro(ss, vs.pos, w[:, nz["baro"]], thrust_scale(vs.rotor_speed, hover_rotor))
            if env is not None and env.sensor_lost:
                pressure = instance_value(env, "baro", pressure, prev_baro[0], scale=-11.8)  # Pa per m up
                baro_temp = instance_value(env, "baro_temp", baro_temp, prev_baro[1])
            if "sensor" in points:
                sens_msgs["sensor_baro"] = np.column_stack([pressure, baro_temp])
        gps_due = due_sens["sensor_gps"][step]
        if gps_due:
            gps = sensors.gps(ss, step, w[:, nz["gps"]], gps_dt, env)
            if env is not None and env.sensor_lost:
                gps = instance_gps(env, gps)
            if "sensor" in points:
                lat, lon = ned_to_latlon(gps["pos"][:, 0], gps["pos"][:, 1])
                sens_msgs["sensor_gps"] = np.column_stack([
                    lat, lon, HOME_ALT - gps["pos"][:, 2], gps["vel"], gps["eph"], gps["epv"],
                    gps["satellites"], gps["fix_type"]])
        sens_ok: dict[str, np.ndarray] = {}
        if sens_msgs:
            altered = layer.on_messages("sensor", step, t_us, sens_msgs)
            for topic, (vals, ok) in altered.items():
                sens_ok[topic] = ok
                if topic == "sensor_accel":
                    accel = np.where(ok[:, None], vals, accel)
                elif topic == "sensor_gyro":
                    gyro = np.where(ok[:, None], vals, gyro)
                elif topic == "sensor_mag":
                    mag = vals
                elif topic == "sensor_baro":
                    pressure, baro_temp = vals[:, 0], vals[:, 1]
                elif topic == "sensor_gps":
                    x, y = latlon_to_ned(vals[:, 0], vals[:, 1])
                    gps = dict(gps)
                    gps["pos"] = np.column_stack([x, y, HOME_ALT - vals[:, 2]])
                    gps["vel"] = vals[:, 3:6].copy()
                    gps["eph"], gps["epv"] = vals[:, 6], vals[:, 7]
                    gps["satellites"], gps["fix_type"] = vals[:, 8], vals[:, 9]

        R_est = est.predict(es, step, accel, gyro, ~cs.armed)
        before_fusion = est.begin_fusion(es)
        if due_sens["sensor_mag"][step]:
            mag_ok = alive(env, "mag", sens_ok.get("sensor_mag"))
            if mag_ok is not None:
                _fuse_rows(est.fuse_mag, es, mag, mag_ok)
            else:
                est.fuse_mag(es, mag)
        if due_sens["sensor_baro"][step]:
            baro_alt = altitude_at(pressure)
            est.fuse_baro(es, baro_alt, alive(env, "baro", sens_ok.get("sensor_baro")))
        if gps_due:
            ep = cfg.estimator
            usable = (gps["fix_type"] >= 3) & (gps["satellites"] >= ep.gps_min_satellites) & (gps["eph"] <= ep.gps_max_eph)
            usable &= t >= origin_s  # EKF2 fuses GPS once its checks have passed (generator.flight_software.startup)
            if "sensor_gps" in sens_ok:
                usable = usable & sens_ok["sensor_gps"]
            est.fuse_gps(es, step, gps["pos"], gps["vel"], None if usable.all() else usable)
        est.end_fusion(es, before_fusion)
        out_pos, out_vel = est.output(es)
        log_acc, log_gyro = logged_imu(ss, accel, gyro)  # a rough vehicle's vibration (SensorParams.vibration_levels)
        for topic in (tp for tp, due_u in due_uorb.items() if due_u[step]):
            uorb_rec.add(topic, step, _uorb_stream(topic, log_acc, log_gyro, es.quat, out_pos, out_vel, motor_cmd,
                                                   cs, cfg.vehicle))

        # telemetry: flight controller -> link -> navigator
        due_now = [tp for tp in TELEMETRY_TOPICS if due[tp][step]]
        if due_now:
            snap = FCSnapshot(
                quat=es.quat, rates=es.rates, pos=out_pos, vel=out_vel, accel=log_acc, gyro=log_gyro,
                mag=mag, pressure=pressure, baro_temp=baro_temp, gps=gps if gps is not None else _no_gps(n),
                battery=battery, baro_home_alt=es.baro_offset,
            )
            msgs = {tp: compose(tp, snap) for tp in due_now}
            for tp, vals in msgs.items():
                sim_rec.add(tp, step, vals)
            if "link" in points:
                altered = layer.on_messages("link", step, t_us, msgs)
            else:
                altered = {tp: (vals, None) for tp, vals in msgs.items()}
            for tp, (vals, ok) in altered.items():
                if layer is not None:
                    nav_rec.add(tp, step, vals, ok)
                nav.receive(ns, tp, vals, np.ones(n, bool) if ok is None else ok, TOPICS[tp].field_names)

        # navigator -> command link -> flight controller
        if due_nav[step]:
            sp = nav.step(ns, t)
            sim_rec.add("setpoint", step, sp)
            if "command" in points:
                sp_vals, sp_ok, command, nav.wps = exchange(layer, step, t_us, sp, waypoints)
            else:
                sp_vals, sp_ok, command = sp, None, None
            if layer is not None:
                nav_rec.add("setpoint", step, sp_vals, sp_ok)
            ok = np.ones(n, bool) if sp_ok is None else sp_ok
            if commander is not None:
                sp_vals, ok, crashed = commander.step(t, sp_vals, ok, command, out_pos, out_vel,
                                                      setpoint_in[:, 3],
                                                      cs.armed, vs.vel[:, 2], vs.on_ground, done)
                status[crashed] = "crashed"
                cs.disarmed_after_flight |= crashed
                cs.armed &= ~crashed
            setpoint_in[ok] = sp_vals[ok]
            vel_sp = setpoint_in[:, 0:3]
            yaw_sp = setpoint_in[:, 3]
            arm_req = (setpoint_in[:, 5] > 0.5) & ~cs.disarmed_after_flight & ~done
            cs.armed = arm_req
            R_est = _rot(es)
            stick = None
            if pilot is not None:
                stick = pilot.step(pilot_state, -out_pos[:, 2], np.sqrt(cs.vel_sp[:, 0] ** 2 + cs.vel_sp[:, 1] ** 2))
            ctrl.velocity_control(cs, vel_sp, yaw_sp, out_vel, R_est, 1.0 / NAV_RATE_HZ, stick)
            ctrl.land_detector(cs, vel_sp, out_vel, 1.0 / NAV_RATE_HZ)
        ctrl.attitude_control(cs, R_est)

        # battery (4S, 5.1 Ah), at its own rate
        if due["battery_status"][step]:
            thrust = cfg.vehicle.motor_constant * vs.rotor_speed**2
            power = BATTERY_POWER_K * np.sum(np.maximum(thrust, 0.0) ** 1.5, axis=1) + BATTERY_IDLE_W
            ocv = BATTERY_OCV_V + BATTERY_OCV_SPAN_V * battery[:, 2]
            current = power / np.maximum(ocv, 1.0)
            battery[:, 2] = np.clip(battery[:, 2] - current * BATTERY_STEP_S / (BATTERY_CAPACITY_AH * 3600), 0.0, 1.0)
            battery[:, 0] = ocv - BATTERY_R_OHM * current + BATTERY_NOISE_V * w[:, nz["battery"]][:, 0]
            if env is not None:
                battery[:, 0] -= env.battery_sag_v
            battery[:, 1] = current

        if due_truth[step]:
            eul = euler_from_quat(vs.quat)
            sim_rec.add("truth", step, np.column_stack([vs.pos, vs.vel, eul, cs.armed, vs.on_ground]))

        # end of flight: landed and disarmed, or crashed
        eul_t = None
        if step % CRASH_CHECK_STEPS == 0:
            eul_t = euler_from_quat(vs.quat)
            crashed = ~done & ((np.abs(eul_t[:, 0]) > CRASH_TILT_RAD) | (np.abs(eul_t[:, 1]) > CRASH_TILT_RAD)) & ~vs.on_ground
            crashed |= ~done & vs.on_ground & (np.linalg.norm(vs.accel, axis=1) > CRASH_GROUND_HOVERS * hover_thrust)
            status[crashed] = "crashed"
            cs.disarmed_after_flight |= crashed
            cs.armed &= ~crashed
        newly = ~done & cs.disarmed_after_flight & (landed_at < 0)
        landed_at[newly] = step
        status[newly & (status == "timeout")] = "landed"
        finish = ~done & (landed_at >= 0) & (step >= landed_at + tail_steps)
        exit_step[finish] = step
        done |= finish
        if progress is not None and step % 250 == 0:
            progress(step, done)
        if done.all():
            break
    exit_step[exit_step < 0] = step
    if layer is not None:
        layer.on_finish(step)
    return BatchResult(
        seeds=[int(s) for s in seeds], simulator=sim_rec.finish(), navigator=nav_rec.finish(),
        exit_step=exit_step, status=list(status), waypoints=waypoints, wind=wind_mean,
        gps_rejections=np.column_stack([es.gps_pos_rejected, es.gps_vel_rejected, es.baro_rejected]),
        n_steps=step + 1, uorb_streams=uorb_rec.finish(),
    )


def _uorb_stream(topic: str, accel, gyro, quat, pos, vel, motor_cmd, cs, vp) -> np.ndarray:
    """One message of a uORB stream (generator.telemetry.schedule.UORB_STREAMS), after the estimator."""
    if topic == "sensor_combined":
        return np.column_stack([accel, gyro])
    if topic == "vehicle_attitude":
        return quat.copy()
    if topic == "vehicle_local_position":
        return np.column_stack([pos, vel])
    armed = cs.armed.astype(float)
    motors = (motor_cmd / vp.max_rot_velocity) ** 2  # thrust fractions: the rotor's thrust ~ speed^2
    return np.column_stack([motors, cs.thrust_sp / (4.0 * vp.max_thrust) * armed, armed])


def _rot(es):
    from scart_bench.generator.physics.rotation import quat_to_rot

    if es.R is None:
        es.R = quat_to_rot(es.quat)
    return es.R


def _no_gps(n: int) -> dict:
    return {"pos": np.zeros((n, 3)), "vel": np.zeros((n, 3)), "eph": np.full(n, 99.0), "epv": np.full(n, 99.0),
            "satellites": np.zeros(n), "fix_type": np.zeros(n)}










def _fuse_rows(fn, es, values, ok) -> None:
    """Fuse only where the message was delivered (dropped messages are not fused)."""
    before = es.x.copy(), es.quat.copy()
    fn(es, values)
    es.x[~ok] = before[0][~ok]
    es.quat[~ok] = before[1][~ok]


