"""Fly a batch with the compiled flight kernel: named batch state, stages, recordings, the layer's hooks.

The batch is flown in blocks of steps. Within a block every active flight runs through whole steps
in compiled code (``kernel.run_steps``), in parallel over flights; Python is entered only at the
steps where the SCART layer must see or alter messages (its injection points: ``sensor`` every
step, ``link`` when telemetry is due, ``command`` when a setpoint is due). There the step runs as
named stages -- sense, estimate, telemetry, navigate, control -- with the layer between them.
A flight that has ended leaves the batch: it is no longer stepped, and its recordings after its
last step hold its last message (nothing reads them: a flight's tables end at its exit step). Noise is drawn per flight from its own generator, in blocks, so a flight flown
alone and the same flight inside any batch get identical bytes.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np

from scart_bench.dataset.schema import (
    HOME_ALT,
    HOME_LAT,
    HOME_LON,
    SIM_RATE_HZ,
    TELEMETRY_TOPICS,
    TOPICS,
    TRUTH_FIELDS,
    TRUTH_RATE_HZ,
)
from scart_bench.generator.engine import kernel as K
from scart_bench.generator.engine import kernel_layout as L
from scart_bench.generator.engine.flight_batch import alive, instance_gps, instance_imu, instance_value
from scart_bench.generator.engine.pcg_noise import fill_rows, fill_rows_parallel, pcg_states
from scart_bench.generator.flight_software.commander import BatchCommander, exchange
from scart_bench.generator.flight_software.flight_controller import AxisKF
from scart_bench.generator.flight_software.pilot import stick_highpass, stick_params
from scart_bench.generator.flight_software.startup import takeoff_after_arm
from scart_bench.generator.geo import latlon_to_ned, ned_to_latlon
from scart_bench.generator.params import DT, GRAVITY, NAV_RATE_HZ
from scart_bench.generator.physics.disturbances import Disturbances, gps_signal_quality
from scart_bench.generator.physics.noise import NOISE_DIM, fill_block
from scart_bench.generator.physics.sensors import (
    BARO_FLOW_FROM,
    baro_wander_coefficients,
    gps_error_coefficients,
    lowpass_coefficients,
)
from scart_bench.generator.physics.vehicle import flow_coefficients
from scart_bench.generator.telemetry.schedule import due_steps

if TYPE_CHECKING:
    from scart_bench.generator.engine.flight_batch import AttackHooks, BatchResult, FlightConfig

#: Steps per block: noise is drawn and finished flights leave the batch between blocks.
BLOCK_STEPS = 500
#: Flight-steps below which a stretch is flown in the calling thread (waking the workers costs more).
PARALLEL_MIN_STEPS = 2000
# numba's workqueue threading layer must not be entered from two threads at once: batches flown
# from several threads take turns for their parallel stretches.
_PARALLEL = threading.Lock()
_STATUS = ("timeout", "landed", "crashed")


class BatchState:
    """The closed-loop state of a batch: one named float64 row per flight plus the delay buffers."""

    def __init__(self, n: int, delay: int, waypoints: np.ndarray):
        self.row = np.zeros((n, L.WIDTH))
        self.truth_buffer = np.zeros((n, delay, 6))  # true pos/vel, for the GPS delay
        self.history = np.zeros((n, delay, 6))  # estimated pos/vel, for delayed GPS fusion
        #: (N, K, 6) the navigator's items: north, east, down, leg speed, hold s, braking m/s^2 (a mission tamper
        #: rewrites the first 3)
        self.waypoints = np.array(waypoints, dtype=float, order="C", copy=True)

    def __len__(self) -> int:
        return self.row.shape[0]

    def __getitem__(self, name: str) -> np.ndarray:
        """The named field as a view: (N,) for scalars, (N, k) otherwise."""
        start, width = L.FIELDS[name]
        return self.row[:, start] if width == 1 else self.row[:, start:start + width]

    def __setitem__(self, name: str, value) -> None:
        start, width = L.FIELDS[name]
        if width == 1:
            self.row[:, start] = value
        else:
            self.row[:, start:start + width] = value

    @property
    def done(self) -> np.ndarray:
        return self.row[:, L.DONE] > 0.5


def initial_state(init, est_P0: np.ndarray) -> BatchState:
    """The batch state at step 0 from the shared initial conditions (generator.engine.simulate.Initial)."""
    n = len(init.rngs)
    st = BatchState(n, init.sensors.delay_steps, init.table)
    vs, ss, yaw0 = init.vehicle_state, init.sensor_state, init.yaw0
    st["pos"], st["vel"], st["quat"] = vs.pos, vs.vel, vs.quat
    st["on_ground"] = vs.on_ground
    st["wind_mean"], st["wind_sigma"], st["gust"] = init.wind.mean, init.wind.sigma, init.wind.gust
    st["accel_bias"], st["gyro_bias"], st["baro_offset"] = ss.accel_bias, ss.gyro_bias, ss.baro_offset
    st["gps_bias"], st["satellites_in_view"], st["sensor_temperature"] = ss.gps_bias, ss.satellites, ss.temperature
    st["gps_drive"] = ss.gps_drive
    st["gps_eph"], st["gps_epv"] = 99.0, 99.0
    q = np.zeros((n, 4))
    q[:, 0], q[:, 3] = np.cos(yaw0 / 2), np.sin(yaw0 / 2)
    st["est_quat"] = q
    st["baro_home"] = np.nan
    st["P_h"] = est_P0.ravel()
    st["P_v"] = est_P0.ravel()
    st["att_sp"] = np.eye(3).ravel()
    st["nav_yaw_sp"], st["nav_yaw"] = yaw0, yaw0
    st["cruise"] = init.cruise
    st["nav_last"] = init.last
    st["battery"] = init.battery
    st["gps_fix_at"], st["gps_origin_at"], st["arm_at"] = init.start[:, 0], init.start[:, 1], init.start[:, 2]
    st["exit_step"] = -1.0
    st["landed_at"] = -1.0
    if init.pilot is not None:
        st["pilot_rng"], st["pilot_gain"] = init.pilot[:, 0], init.pilot[:, 1]
    st["vib_level"] = ss.vibration_level if ss.vibration_level is not None else 1.0
    if init.rocking is not None:
        st["rock_rng"], st["rock_level"] = init.rocking[:, 0], init.rocking[:, 1:4]
    if init.flow is not None:
        st["flow_rng"], st["flow_level"] = init.flow[:, 0], init.flow[:, 1:3]
    return st


def kernel_params(cfg: FlightConfig, delay: int) -> np.ndarray:
    """The kernel's parameter vector for a FlightConfig (derived constants computed as the reference does)."""
    vp, sp, ep, cp, mp = cfg.vehicle, cfg.sensors, cfg.estimator, cfg.controller, cfg.mission
    dt = 1.0 / SIM_RATE_HZ
    nav_dt = 1.0 / NAV_RATE_HZ
    alloc = vp.allocation()
    kf = AxisKF(dt, ep.accel_process_noise, ep.bias_process_noise)
    gust_a = np.exp(-dt / mp.gust_tau)
    gps_a, gps_bias_c = gps_error_coefficients(sp, 1.0 / sp.gps_rate_hz)
    max_total = 4 * vp.max_thrust
    lat0, lon0 = np.deg2rad(HOME_LAT), np.deg2rad(HOME_LON)
    values = {
        "dt": dt, "mass": vp.mass, "Jx": vp.inertia[0], "Jy": vp.inertia[1], "Jz": vp.inertia[2],
        "motor_constant": vp.motor_constant, "max_rot": vp.max_rot_velocity, "tau_up": vp.time_constant_up,
        "tau_down": vp.time_constant_down, "rotor_drag": vp.rotor_drag_coefficient, "body_drag": vp.body_drag,
        "alloc": alloc, "alloc_inv": np.linalg.inv(alloc), "gust_a": gust_a, "gust_b": np.sqrt(1 - gust_a * gust_a),
        "a_accel_bias": np.exp(-dt / sp.accel_bias_tau), "c_accel_bias": sp.accel_bias_random_walk * np.sqrt(dt),
        "a_gyro_bias": np.exp(-dt / sp.gyro_bias_tau), "c_gyro_bias": sp.gyro_bias_random_walk * np.sqrt(dt),
        "c_accel_noise": sp.accel_noise_density * np.sqrt(1 / dt) * np.array([1.0, 1.0, sp.accel_noise_z_factor]),
        "c_gyro_noise": sp.gyro_noise_density * np.sqrt(1 / dt),
        "mag_noise": sp.mag_noise, "mag_field": sp.mag_field_ned, "baro_noise": sp.baro_noise_pa, "home_alt": HOME_ALT,
        "gps_a": gps_a, "gps_bias_c": gps_bias_c,
        "gps_white": (sp.gps_noise_h, sp.gps_noise_h, sp.gps_noise_v), "gps_vel_noise": sp.gps_vel_noise,
        "eph0": np.hypot(sp.gps_noise_h, sp.gps_bias_h), "epv0": np.hypot(sp.gps_noise_v, sp.gps_bias_v),
        "delay": delay, "att_accel_gain": ep.att_accel_gain, "gyro_bias_gain": ep.gyro_bias_gain,
        "att_mag_gain": ep.att_mag_gain, "decl": np.arctan2(sp.mag_field_ned[1], sp.mag_field_ned[0]),
        "kf_F": kf.F, "kf_Q": np.diag(kf.Q), "gate2": ep.gate_sigma**2, "gps_pos_r": ep.gps_pos_noise**2,
        "gps_vel_r": ep.gps_vel_noise**2, "baro_r": ep.baro_noise**2, "reset_timeout": ep.reset_timeout_s,
        "gps_min_sats": ep.gps_min_satellites, "gps_max_eph": ep.gps_max_eph,
        "vel_p": (cp.vel_xy_p, cp.vel_xy_p, cp.vel_z_p), "vel_i": (cp.vel_xy_i, cp.vel_xy_i, cp.vel_z_i),
        "vel_xy_d": cp.vel_xy_d, "acc_hor_dt": cp.acc_hor * nav_dt, "acc_vert_dt": cp.acc_vert * nav_dt,
        "tan_tilt": np.tan(cp.tilt_max), "att_p": cp.att_p, "rate_max": cp.rate_limits(), "rate_p": cp.rate_p,
        "rate_i": cp.rate_i, "thrust_lo": cp.thrust_min * max_total, "thrust_hi": 0.95 * max_total,
        "max_thrust": vp.max_thrust, "land_detect_s": cp.land_detect_s, "arm_delay": mp.arm_delay_s,
        "takeoff_hold": mp.takeoff_hold_s, "approach_gain": mp.approach_gain, "climb_speed": mp.climb_speed,
        "land_speed": mp.land_speed, "acceptance": mp.acceptance_radius, "lat0": lat0, "lon0": lon0,
        "sin_lat0": np.sin(lat0), "cos_lat0": np.cos(lat0), "hover": vp.mass * GRAVITY,
        "tail_steps": int(0.5 * SIM_RATE_HZ), "yaw_step_max": mp.yaw_rate_max * nav_dt,
        "out_decay": 1.0 - dt / ep.output_tau_s,
        "accel_vibration": sp.accel_vibration,
        "inv_hover_rotor": 1.0 / float(np.sqrt(vp.mass * GRAVITY / (4 * vp.motor_constant))),
        "takeoff_after_arm": takeoff_after_arm(mp.ground_phase),
        "gyro_vibration": sp.gyro_vibration,
        "pilot": stick_params(mp),
        "pilot_hp": stick_highpass(mp),
        "accel_lowpass": _lowpass(sp.accel_noise_cutoff_hz, 1.0 / dt),
        "gyro_lowpass": _lowpass(sp.gyro_noise_cutoff_hz, 1.0 / dt),
        "baro_lowpass": _lowpass(sp.baro_noise_cutoff_hz, sp.baro_rate_hz),
        "imu_offset": np.r_[np.asarray(sp.imu_offset_m, dtype=float), float(any(sp.imu_offset_m))],
        "baro_downwash": sp.baro_downwash_pa,
        "baro_wander": np.r_[baro_wander_coefficients(sp), float(sp.baro_wander_pa > 0.0)],
        "rocking_flow": (*flow_coefficients(mp.rocking_flow_hz, dt), 1.0 / (mp.rocking_flow_full_m_s - mp.rocking_flow_from_m_s),
                         mp.rocking_flow_from_m_s),
        "baro_speed": (sp.baro_speed_pa, 1.0 / (sp.baro_speed_full_m_s - BARO_FLOW_FROM), BARO_FLOW_FROM),
    }
    return K.param_vector(values)


def _lowpass(cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """The kernel's low-pass parameters: (b0, b1, b2, a1, a2, on) of physics.sensors.lowpass_coefficients, on = 0
    for white noise (the draws as they are)."""
    c = lowpass_coefficients(cutoff_hz, rate_hz)
    return np.zeros(6) if c is None else np.r_[c, 1.0]


def schedules(max_steps: int, uorb: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Due table (rows of kernel_layout.SCHEDULE x steps) and each due step's message index.

    The uORB streams' rows are due only with ``uorb`` (FlightConfig.uorb): else nothing is recorded."""
    from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS, UORB_STREAMS

    rates = {t: TOPICS[t].rate_hz for t in TOPICS}
    rates["setpoint"] = 50.0  # the navigator's rate
    rates["truth"] = TRUTH_RATE_HZ
    rates.update({t: r for t, (r, _) in SENSOR_TOPICS.items()})
    rates.update({t: r for t, (r, _) in UORB_STREAMS.items()})
    due = np.stack([due_steps(rates[name], max_steps + 1) for name in L.SCHEDULE])
    if not uorb:
        due[L.D_U_IMU:L.D_U_IMU + L.N_UORB] = False
    index = np.maximum(np.cumsum(due, axis=1) - 1, 0).astype(np.int64)
    return due, index


class _NoiseDrawer:
    """Each block's per-flight noise, drawn just before the block flies, on the kernel's own threads.

    Without the layer's hooks, the kernel draws each flight's block itself, in the thread that flies
    it, right before flying it, so the values are still in cache (``fused``). With hooks, which read
    the block's noise between stretches, the whole block is drawn first, in one parallel region
    (``draw``). Either way each flight's normals come from its own generator in order, so the values a
    flight gets do not depend on the block size, the batch or the threads. (Drawing in background
    threads while the block flew put two more threads on the cores the kernel's threads use: on 2
    cores two kernel threads kept only 1.7 of them busy, and the one-thread line took 1.2.)
    """

    def __init__(self, rngs: list[np.random.Generator], steps: int):
        self.rngs = rngs
        # each flight's PCG64 stepped in compiled code (the same values as numpy, ~3x faster); the
        # Generators themselves are not advanced, nothing reads them after the initial conditions
        self.states = pcg_states(rngs)
        # one buffer for every block: fresh arrays every block cost as much in page faults and
        # zeroing (120 MB a block at 1,000 flights) as drawing the normals
        self.buffer = np.empty((len(rngs), steps, NOISE_DIM))

    def fused(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(noise buffer for ``rows``, PCG64 states): for the kernel to draw each flight's block
        itself, in the thread that flies it (``run_steps``' ``draw``); only when ``states`` is not None."""
        return self.buffer[:len(rows)], self.states

    def draw(self, rows: np.ndarray, steps: int) -> np.ndarray:
        """(len(rows), steps or more, dim): flight ``rows[j]``'s next ``steps`` normals in row j."""
        out = self.buffer[:len(rows)]
        if self.states is None:
            fill_block(self.rngs, rows, out[:, :steps])
        elif len(rows) * steps < PARALLEL_MIN_STEPS:
            fill_rows(self.states, rows, out[:, :steps])
        else:
            with _PARALLEL:
                fill_rows_parallel(self.states, rows, out[:, :steps])
        return out


class _Recordings:
    """Message arrays of the telemetry topics, the setpoint and the truth, time-major: (messages, N, fields).

    Sized for the longest possible flight but touched only up to the batch's last step: time-major,
    the untouched tail stays virtual memory (flight-major, transparent huge pages made it resident).
    """

    def __init__(self, n: int, due: np.ndarray, max_steps: int):
        from scart_bench.generator.telemetry.schedule import UORB_STREAMS

        counts = due[:, :max_steps].sum(axis=1)
        width = [len(TOPICS[t].fields) for t in TELEMETRY_TOPICS] + [6, len(TRUTH_FIELDS)]
        self.names = list(TELEMETRY_TOPICS) + ["setpoint", "truth"]
        self.arrays = [np.empty((int(counts[k]), n, width[k])) for k in range(len(self.names))]
        #: the uORB streams (no rows unless they are due: FlightConfig.uorb)
        self.uorb_names = list(L.SCHEDULE[L.D_U_IMU:L.D_U_IMU + L.N_UORB])
        self.uorb = [np.empty((int(counts[L.D_U_IMU + k]), n, len(UORB_STREAMS[name][1])))
                     for k, name in enumerate(self.uorb_names)]

    def telemetry(self) -> list[np.ndarray]:
        return self.arrays[:L.N_TELEMETRY]


def simulate_kernel(seeds: list[int], cfg: FlightConfig, layer: AttackHooks | None = None,
                    progress=None) -> BatchResult:
    """simulate() with the compiled kernel; see the module docstring."""
    from scart_bench.generator.engine.flight_batch import BatchResult, initial_conditions

    init = initial_conditions(seeds, cfg)
    n = len(seeds)
    max_steps = init.max_steps
    st = initial_state(init, AxisKF.P0)
    p = kernel_params(cfg, init.sensors.delay_steps)
    due, index = schedules(max_steps, cfg.uorb)
    rec = _Recordings(n, due, max_steps)
    tele, rec_sp, rec_truth = rec.telemetry(), rec.arrays[L.N_TELEMETRY], rec.arrays[L.N_TELEMETRY + 1]
    points = layer.points if layer is not None else frozenset()
    physical = bool(getattr(layer, "physical_groups", None))
    hooks = _Hooks(layer, points, st, rec, due, index, n) if points or physical else None
    if hooks is not None and "command" in points:
        hooks.commander = BatchCommander(cfg.control, n, np.zeros((n, 2)), cfg.mission.land_speed)
        hooks.mission = init.waypoints
    active = np.arange(n, dtype=np.int64)
    drawer = _NoiseDrawer(init.rngs, min(BLOCK_STEPS, max_steps))
    no_draw = np.zeros((0, 4), dtype=np.uint64)
    s0 = 0
    while active.size and s0 < max_steps:
        s1 = min(s0 + BLOCK_STEPS, max_steps)
        if hooks is None and drawer.states is not None:
            # one stretch for the whole block: each flight draws its noise in the thread that flies it
            noise, states = drawer.fused(active)
            _fly(len(active) * (s1 - s0), st.row, st.truth_buffer, st.history, st.waypoints, p, active, s0, s1,
                 noise, 0, due, index, *tele, rec_sp, rec_truth, *rec.uorb, states, s1 - s0)
        else:  # the layer's hooks read the block's noise between stretches: draw it all first
            noise = drawer.draw(active, s1 - s0)
            k = s0
            for h in (hooks.steps(s0, s1) if hooks else ()):
                if h > k:
                    _fly(len(active) * (h - k), st.row, st.truth_buffer, st.history, st.waypoints, p, active, k, h,
                         noise, k - s0, due, index, *tele, rec_sp, rec_truth, *rec.uorb, no_draw, 0)
                hooks.step(p, h, active, noise[:, h - s0].copy())
                k = h + 1
            if k < s1:
                _fly(len(active) * (s1 - k), st.row, st.truth_buffer, st.history, st.waypoints, p, active, k, s1,
                     noise, k - s0, due, index, *tele, rec_sp, rec_truth, *rec.uorb, no_draw, 0)
        active = active[~st.done[active]]
        if progress is not None:
            progress(s1 - 1, st.done.copy())
        s0 = s1
    exit_step = st["exit_step"].astype(np.int64)
    exit_step[exit_step < 0] = max_steps - 1
    n_steps = int(exit_step.max()) + 1
    simulator = _finish(rec.names, rec.arrays, due, n_steps, exit_step)
    if hooks is not None:
        seen = _finish(rec.names[:-1], [hooks.nav[t] for t in rec.names[:-1]], due, n_steps, exit_step,
                       [hooks.nav_ok[t] for t in rec.names[:-1]])
        # topics the layer did not see reach the navigator unchanged
        navigator = {name: seen.get(name, simulator[name]) for name in rec.names[:-1]}
        layer.on_finish(n_steps - 1)
    else:
        navigator = simulator
        if layer is not None:
            layer.on_finish(n_steps - 1)
    uorb = _finish(rec.uorb_names, rec.uorb, due, n_steps, exit_step) if cfg.uorb else {}
    status = [_STATUS[int(c)] for c in st["status"]]
    rej = np.column_stack([st["gps_pos_rejected"], st["gps_vel_rejected"], st["baro_rejected"]]).astype(np.int64)
    return BatchResult(seeds=[int(s) for s in seeds], simulator=simulator, navigator=navigator, exit_step=exit_step,
                       status=status, waypoints=init.waypoints, wind=init.wind.mean, gps_rejections=rej,
                       n_steps=n_steps, uorb_streams=uorb)


def _fly(work: int, *args) -> None:
    """Whole steps of the active flights: in parallel when there is enough work, else in this thread."""
    if work < PARALLEL_MIN_STEPS:
        K.run_steps_serial(*args)
        return
    with _PARALLEL:
        K.run_steps(*args)


def _finish(names, arrays, due, n_steps, exit_step, delivered=None) -> dict:
    """(steps, values, delivered) per topic up to the batch's last step; after a flight's end its last message."""
    out = {}
    row = {name: k for k, name in enumerate(L.SCHEDULE)}
    for j, name in enumerate(names):
        arr = arrays[j]
        if arr is None:
            continue
        steps = np.flatnonzero(due[row[name], :n_steps]).astype(np.int64)
        vals = arr[:len(steps)].transpose(1, 0, 2)  # (N, messages, fields), as BatchResult documents
        for i in np.flatnonzero(exit_step < n_steps - 1):
            last = np.searchsorted(steps, exit_step[i], side="right")
            vals[i, last:] = vals[i, last - 1]  # the flight has ended: its last message, held
        ok = np.ones(vals.shape[:2], dtype=bool) if delivered is None else delivered[j][:len(steps)].T
        out[name] = (steps, vals, ok)
    return out


class _Hooks:
    """The steps where the SCART layer sees messages, flown as stages with the layer between them."""

    def __init__(self, layer, points, st: BatchState, rec: _Recordings, due, index, n: int):
        self.layer, self.points, self.st, self.rec = layer, points, st, rec
        self.due, self.index, self.n = due, index, n
        self.all_rows = np.arange(n, dtype=np.int64)
        need = np.zeros(due.shape[1], dtype=bool)
        # environment attacks and faults act on the physics: the layer is asked at every step
        self.physical = bool(getattr(layer, "physical_groups", None))
        self.X = np.zeros((n, L.X_WIDTH))
        if self.physical or ("sensor" in points and getattr(layer, "sensor_every_step", True)):
            need[:] = True
        elif "sensor" in points:  # a layer that only takes GPS samples (e.g. a defense rejecting GPS)
            need |= due[L.D_GPS]
        if "link" in points:
            need |= due[:L.N_TELEMETRY].any(axis=0)
        if "command" in points:
            need |= due[L.D_SETPOINT]
        self.need = need
        self.commander = None  # the flight controller's commander, when the command point is hooked
        self.mission: np.ndarray | None = None  # the mission as sent (N, K, 3)
        self.nav: dict[str, np.ndarray | None] = {}
        self.nav_ok: dict[str, np.ndarray | None] = {}
        for k, name in enumerate(rec.names[:-1]):
            seen = "link" in points if k < L.N_TELEMETRY else "command" in points
            arr = rec.arrays[k]
            self.nav[name] = np.empty_like(arr) if seen else None
            self.nav_ok[name] = np.ones(arr.shape[:2], dtype=bool) if seen else None

    def steps(self, s0: int, s1: int) -> np.ndarray:
        return s0 + np.flatnonzero(self.need[s0:s1])

    def step(self, p: np.ndarray, h: int, active: np.ndarray, noise: np.ndarray) -> None:
        """One step as stages, the layer at its points (``noise``: (len(active), dim), this step's)."""
        st, due, index, layer = self.st, self.due, self.index, self.layer
        live = ~st.done[active]
        rows = active[live]
        w = np.ascontiguousarray(noise[live])
        t_us = h * int(round(1e6 / SIM_RATE_HZ))
        n = self.n
        env = None
        if self.physical:
            phys = layer.on_physics(h, t_us)
            env = phys if isinstance(phys, Disturbances) else None
        if env is not None:
            self._physics_and_sensors(env, p, h, rows, w)
        else:
            K.stage_sense(st.row, st.truth_buffer, p, rows, h, w, due)
        delivered: dict[str, np.ndarray | None] = {}
        if "sensor" in self.points:
            self._sensor_hook(h, t_us, delivered)
        ok = {}
        for sensor in ("mag", "baro", "gps"):
            d = delivered.get(sensor)
            if env is not None and sensor != "gps":
                d = alive(env, sensor, d)
            ok[sensor] = np.ones(n, bool) if d is None else np.asarray(d, dtype=bool)
        K.stage_estimate(st.row, st.history, p, rows, h, due, ok["mag"], ok["baro"], ok["gps"])
        K.stage_record_uorb(st.row, p, rows, h, due, index, *self.rec.uorb)
        tele = self.rec.telemetry()
        due_now = [k for k in range(L.N_TELEMETRY) if due[k, h]]
        if due_now:
            if "link" in self.points:
                K.stage_telemetry(st.row, p, self.all_rows, h, due, index, *tele, False)
                msgs = {TELEMETRY_TOPICS[k]: tele[k][index[k, h]].copy() for k in due_now}
                altered = layer.on_messages("link", h, t_us, msgs)
                for name, (vals, delivered) in altered.items():
                    k = TELEMETRY_TOPICS.index(name)
                    vals = np.ascontiguousarray(vals, dtype=float)
                    self.nav[name][index[k, h]] = vals
                    self.nav_ok[name][index[k, h]] = delivered
                    K.receive_rows(st.row, rows, k, vals, np.asarray(delivered, dtype=bool))
            else:
                K.stage_telemetry(st.row, p, rows, h, due, index, *tele, True)
        sp = np.zeros((n, 6))
        sp_ok = np.ones(n, dtype=bool)
        if due[L.D_SETPOINT, h]:
            m = index[L.D_SETPOINT, h]
            rec_sp = self.rec.arrays[L.N_TELEMETRY]
            if "command" in self.points:
                K.stage_navigate(st.row, st.waypoints, p, self.all_rows, h, sp)
                rec_sp[m] = sp
                vals, sp_ok, command, st.waypoints[:, :, :3] = exchange(layer, h, t_us, sp.copy(), self.mission)
                self.nav["setpoint"][m] = vals
                self.nav_ok["setpoint"][m] = sp_ok
                est = st["est_x"].reshape(n, 3, 3)[:, :, :2] + st["out_err"].reshape(n, 3, 2)  # the output
                vals, sp_ok, crashed = self.commander.step(h * DT, vals, sp_ok, command, est[:, :, 0], est[:, :, 1],
                                                           st["setpoint_in"][:, 3].copy(), st["armed"] > 0.5,
                                                           st["vel"][:, 2].copy(), st["on_ground"] > 0.5, st.done)
                st["status"][crashed] = 2.0
                st["disarmed"][crashed] = 1.0
                st["armed"][crashed] = 0.0
                sp = np.ascontiguousarray(vals, dtype=float)
                sp_ok = np.asarray(sp_ok, dtype=bool)
            else:
                K.stage_navigate(st.row, st.waypoints, p, rows, h, sp)
                rec_sp[m] = sp
        K.stage_control(st.row, p, rows, h, sp, sp_ok, w, due, index, self.rec.arrays[L.N_TELEMETRY + 1], self.X,
                        env is not None)

    def _physics_and_sensors(self, env: Disturbances, p: np.ndarray, h: int, rows: np.ndarray, w: np.ndarray) -> None:
        """The sense stage under environment attacks and faults, as the reference step applies them."""
        st, due, X = self.st, self.due, self.X
        env.resolve(st["pos"])  # jamming level at the positions before the step
        X[:, L.X_WIND:L.X_WIND + 3] = env.wind
        X[:, L.X_EFFICIENCY:L.X_EFFICIENCY + 4] = env.motor_efficiency
        X[:, L.X_ROTOR_LIMIT] = env.rotor_limit
        X[:, L.X_BATTERY_SAG] = env.battery_sag_v
        X[:, L.X_GPS_OFFSET:L.X_GPS_OFFSET + 3] = env.gps_offset
        X[:, L.X_GPS_VEL_OFFSET:L.X_GPS_VEL_OFFSET + 3] = env.gps_vel_offset
        prev = {name: st[name].copy() for name in ("accel", "gyro", "mag", "pressure", "baro_temp")}
        K.stage_physics(st.row, st.truth_buffer, p, rows, h, w, X)
        field = env.magnetic_field(st["pos"])  # at the positions after the step
        X[:, L.X_MAG:L.X_MAG + 3] = 0.0 if field is None else field
        if due[L.D_GPS, h]:
            sats = np.where(env.gps_spoofed, env.gps_spoof_satellites, st["satellites_in_view"])
            X[:, L.X_GPS_SATS], X[:, L.X_GPS_GROWTH] = gps_signal_quality(sats, env.gps_js_db)
        K.stage_sensors(st.row, st.truth_buffer, p, rows, h, w, due, X)
        if not env.sensor_lost:
            return
        # a lost sensor instance: the secondary's readings, or the last one frozen
        st["accel"], st["gyro"] = instance_imu(env, st["accel"].copy(), st["gyro"].copy(),
                                                (prev["accel"], prev["gyro"]))
        if due[L.D_MAG, h]:
            st["mag"] = instance_value(env, "mag", st["mag"].copy(), prev["mag"])
        if due[L.D_BARO, h]:
            st["pressure"] = instance_value(env, "baro", st["pressure"].copy(), prev["pressure"], scale=-11.8)
            st["baro_temp"] = instance_value(env, "baro_temp", st["baro_temp"].copy(), prev["baro_temp"])
        if due[L.D_GPS, h]:
            gps = {"pos": st["gps_pos"].copy(), "vel": st["gps_vel"].copy(), "eph": st["gps_eph"].copy(),
                   "epv": st["gps_epv"].copy(), "satellites": st["gps_satellites"].copy(),
                   "fix_type": st["gps_fix"].copy()}
            gps = instance_gps(env, gps)
            st["gps_pos"], st["gps_vel"], st["gps_eph"], st["gps_epv"] = gps["pos"], gps["vel"], gps["eph"], gps["epv"]
            st["gps_satellites"], st["gps_fix"] = gps["satellites"], gps["fix_type"]

    def _sensor_hook(self, h: int, t_us: int, ok: dict) -> None:
        """The sensor messages through the layer; ``ok`` gets the delivered masks of mag, baro, gps."""
        st, due = self.st, self.due
        msgs = {"sensor_accel": st["accel"].copy(), "sensor_gyro": st["gyro"].copy()}
        if due[L.D_MAG, h]:
            msgs["sensor_mag"] = st["mag"].copy()
        if due[L.D_BARO, h]:
            msgs["sensor_baro"] = np.column_stack([st["pressure"], st["baro_temp"]])
        if due[L.D_GPS, h]:
            pos = st["gps_pos"]
            lat, lon = ned_to_latlon(pos[:, 0], pos[:, 1])
            msgs["sensor_gps"] = np.column_stack([lat, lon, HOME_ALT - pos[:, 2], st["gps_vel"], st["gps_eph"],
                                                  st["gps_epv"], st["gps_satellites"], st["gps_fix"]])
        altered = self.layer.on_messages("sensor", h, t_us, msgs)
        for topic, (vals, delivered) in altered.items():
            delivered = np.asarray(delivered, dtype=bool)
            if topic == "sensor_accel":
                st["accel"] = np.where(delivered[:, None], vals, st["accel"])
            elif topic == "sensor_gyro":
                st["gyro"] = np.where(delivered[:, None], vals, st["gyro"])
            elif topic == "sensor_mag":
                st["mag"] = vals
                ok["mag"] = delivered
            elif topic == "sensor_baro":
                st["pressure"], st["baro_temp"] = vals[:, 0], vals[:, 1]
                ok["baro"] = delivered
            elif topic == "sensor_gps":
                x, y = latlon_to_ned(vals[:, 0], vals[:, 1])
                st["gps_pos"] = np.column_stack([x, y, HOME_ALT - vals[:, 2]])
                st["gps_vel"] = vals[:, 3:6]
                st["gps_eph"], st["gps_epv"] = vals[:, 6], vals[:, 7]
                st["gps_satellites"], st["gps_fix"] = vals[:, 8], vals[:, 9]
                ok["gps"] = delivered
