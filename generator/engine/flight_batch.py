"""What a batch of flights is made of, shared by both engines of :func:`scart_bench.generator.engine.simulate.simulate`
(the compiled kernel in :mod:`scart_bench.generator.engine.compiled` and the numpy reference step): the flight
config, the initial conditions drawn from the seeds, the attack-layer hooks protocol, the recorded
result, and the sensor-instance fault helpers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from scart_bench.dataset.schema import SIM_RATE_HZ
from scart_bench.generator.flight_software.commander import ControlParams
from scart_bench.generator.flight_software.navigator import mission_table
from scart_bench.generator.flight_software.pilot import pilot_start
from scart_bench.generator.flight_software.startup import battery_start, startup_times
from scart_bench.generator.params import (
    BATTERY_OCV_SPAN_V,
    BATTERY_OCV_V,
    DT,
    ControllerParams,
    EstimatorParams,
    MissionParams,
    SensorParams,
    VehicleParams,
)
from scart_bench.generator.physics.disturbances import Disturbances
from scart_bench.generator.physics.sensors import Sensors, flight_vibration_levels
from scart_bench.generator.physics.vehicle import VehicleState, Wind, flow_start, rocking_start
from scart_bench.generator.telemetry.batch import BatchResult

STATUS = ("landed", "timeout", "crashed")

#: Which defaults a dataset's flights were made with (dataset.json ``flight_defaults``; a dataset
#: without it was made with 1). 1: instant start (arming at 1 s, GPS from boot), 1 s hover,
#: ideal timing, Gazebo GPS noise. 2: the PX4 start (ground phase, GPS fix and estimator origin
#: before arming), 5 s hover, yaw within MPC_YAWRAUTO_MAX, realistic timing, EKF2's output
#: predictor, PX4 SITL GPS noise, settling GPS accuracy and satellites, battery charge per flight.
#: 3: the flights are 2's, byte for byte; a --uorb dataset's uORB view is at a PX4 log's rates
#: (sensor_combined ~190 Hz, vehicle_attitude 20 Hz, vehicle_local_position 10 Hz, from the flight
#: controller's streams) and has the actuators (actuator_controls_0, actuator_outputs).
#: 4: the flights of 3 with the noise at hover calibrated on every axis (docs/realism.md): the
#: estimator's acceleration process noise 0.35 -> 0.2, gusts drawn up to 0.5 m/s (was 0.8), the
#: accelerometer's z axis 2.5x its x/y noise; a link loss lands the vehicle (COM_OBL_ACT Land).
#: 5: the tells of issue 47 fixed (docs/realism.md "Fixing the tells"): motor vibration on the
#: accelerometer whenever the motors turn, a smooth GPS slow error, take-off 3 s after arming with
#: the motors idling, a 9 s hover hold, the link's IMU and baro timing as the logs'.
FLIGHT_DEFAULTS = 5


def defaults_summary(cfg: FlightConfig) -> dict:
    """What dataset.json records of the defaults a dataset was made with."""
    return {"flight_defaults": FLIGHT_DEFAULTS, "timing": cfg.timing, "ground_phase": cfg.mission.ground_phase,
            "takeoff_hold_s": cfg.mission.takeoff_hold_s}
class AttackHooks(Protocol):
    """What the simulator calls at its injection points (implemented by the SCART layer)."""

    points: frozenset[str]

    def on_messages(self, point: str, step: int, t_us: int, messages: dict[str, np.ndarray]
                    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Return, per topic, the (possibly altered) values and the per-flight delivered mask."""

    def on_physics(self, step: int, t_us: int) -> Disturbances | dict:
        """Physical disturbances for this step (environment attacks, faults), or an empty dict."""

    def on_finish(self, step: int) -> None:
        """Called once after the last step (``step``): close open attack windows, flush a link."""
@dataclass
class FlightConfig:
    """Everything that defines a batch of flights besides the seeds."""

    vehicle: VehicleParams = field(default_factory=VehicleParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    mission: MissionParams = field(default_factory=MissionParams)
    #: the flight controller's commander: accepted commands, link-loss failsafe (generator.flight_software.commander)
    control: ControlParams = field(default_factory=ControlParams)
    #: how the written messages are stamped: "realistic" (jitter, drops, late topics) or "ideal"
    #: (periodic from t = 0); generator.telemetry.timing, applied after flying
    timing: str = "realistic"
    #: per topic (topic, cv, drop, late) in place of the "realistic" table's entry (generator.telemetry.timing.
    #: check_timing_table; a profile TOML's [timing], which generate --like fits); empty: that table as it is
    timing_table: tuple = ()
    #: also write the uORB view (PX4 topic names and units, generator.telemetry.uorb) of each flight; after flying
    uorb: bool = False
    #: airframes drawn per flight (generator.physics.airframes, a profile's ``airframes`` mix): sorted
    #: (name, weight) pairs summing to 1; empty: every flight flies ``vehicle`` and ``controller``
    airframes: tuple = ()


def _battery_init(remaining: np.ndarray) -> np.ndarray:
    """(N, 3) voltage, current, remaining of 4S packs at rest with the given charge (0-1)."""
    remaining = np.asarray(remaining, dtype=float)
    b = np.zeros((remaining.shape[0], 3))
    b[:, 0] = BATTERY_OCV_V + BATTERY_OCV_SPAN_V * remaining  # open-circuit voltage, as the battery model of both engines
    b[:, 2] = remaining
    return b
@dataclass
class Initial:
    """Per-flight initial conditions, drawn from the flights' own generators (shared by both engines)."""

    rngs: list[np.random.Generator]
    wind: Wind
    yaw0: np.ndarray
    waypoints: np.ndarray
    cruise: np.ndarray
    sensors: Sensors
    vehicle_state: VehicleState
    sensor_state: object
    max_steps: int
    #: (N, 3) s after boot: GPS fix, estimator origin (GPS fused from then), arming (generator.flight_software.startup)
    start: np.ndarray | None = None
    #: (N, 3) battery state at boot: voltage, current, remaining
    battery: np.ndarray | None = None
    #: (N, K, 6) the navigator's items (north, east, down, leg speed, hold s, braking) and (N,) each flight's last
    #: item (generator.flight_software.navigator.mission_table)
    table: np.ndarray | None = None
    last: np.ndarray | None = None
    #: (N, 2) the pilot's stick state and amplitude factor (generator.flight_software.pilot.pilot_start)
    pilot: np.ndarray | None = None
    #: (N, 4) each vehicle's rocking stream state and level (generator.physics.vehicle.rocking_start); None: none
    rocking: np.ndarray | None = None
    #: (N, 3) each vehicle's forward-flight rocking stream state and level (generator.physics.vehicle.flow_start)
    flow: np.ndarray | None = None
def initial_conditions(seeds: list[int], cfg: FlightConfig) -> Initial:
    """Draw the wind, start heading, mission jitter and sensor errors of each flight."""
    n = len(seeds)
    if n < 1:
        raise ValueError("simulate needs at least one seed")
    rngs = [np.random.default_rng(np.random.SeedSequence([int(s), 0x5CA7])) for s in seeds]
    m = cfg.mission
    u = np.array([g.uniform(size=6) for g in rngs])
    wind_speed = m.wind_max * u[:, 0]
    wind_dir = 2 * np.pi * u[:, 1]
    wind_mean = np.column_stack([wind_speed * np.cos(wind_dir), wind_speed * np.sin(wind_dir), np.zeros(n)])
    wind = Wind(mean=wind_mean, gust=np.zeros((n, 3)), sigma=m.gust_sigma_max * u[:, 2], tau=m.gust_tau)
    yaw0 = (u[:, 3] - 0.5) * 0.5
    waypoints, cruise, table, last = mission_table(m, seeds, rngs)
    max_s = m.max_duration_s
    if m.families and not m.missions:  # the longest of the drawn missions sets the batch's time limit
        from scart_bench.generator.flight_software.families import time_bound

        max_s = max(max_s, max(time_bound(table[i, :last[i] + 1], m.land_speed) for i in range(n)))
    sensors = Sensors(cfg.sensors, DT)
    vs = VehicleState.zeros(n, yaw0)
    ss = sensors.init_state(n, rngs)
    start = startup_times(seeds, m.ground_phase, m.arm_delay_s)
    ss.fix_at = start[:, 0].copy()
    ss.vibration_level = flight_vibration_levels(cfg.sensors.vibration_levels, seeds)
    battery = _battery_init(battery_start(seeds))
    return Initial(rngs, wind, yaw0, waypoints, cruise, sensors, vs, ss, int(max_s * SIM_RATE_HZ),
                   start, battery, table, last, pilot_start(seeds, m), rocking_start(seeds, m.rocking_levels),
                   flow_start(seeds, m.rocking_flow_levels))
def alive(env: Disturbances | None, sensor: str, delivered: np.ndarray | None) -> np.ndarray | None:
    """Flights whose ``sensor`` sample reaches the estimator (None: all of them)."""
    lost = env.lost(sensor) if env is not None else None
    if lost is None:
        return delivered
    return ~lost if delivered is None else delivered & ~lost
def instance_value(env: Disturbances, sensor: str, value: np.ndarray, previous: np.ndarray,
                    scale: float = 1.0) -> np.ndarray:
    """A sensor whose primary instance is lost: the secondary's reading (its own offset), or the
    last reading frozen when there is no failover."""
    name = "baro" if sensor == "baro_temp" else sensor
    lost = env.sensor_lost.get(name)
    if lost is None or not lost.any():
        return value
    fail = env.sensor_failover.get(name, np.zeros_like(lost))
    out = np.array(value, dtype=float, copy=True)
    offset = env.sensor_offset.get(name)
    if sensor != "baro_temp" and offset is not None:
        sec = lost & fail
        if out.ndim == 1:
            out[sec] += scale * offset[sec]
        else:
            out[sec, 0] += scale * offset[sec]  # the secondary instance's calibration differs on x
    frozen = lost & ~fail
    out[frozen] = np.asarray(previous)[frozen]
    return out
def instance_imu(env: Disturbances, accel: np.ndarray, gyro: np.ndarray, prev) -> tuple[np.ndarray, np.ndarray]:
    pa, pg = prev
    return instance_value(env, "accel", accel, pa), instance_value(env, "gyro", gyro, pg)
def instance_gps(env: Disturbances, gps: dict) -> dict:
    """The GPS receiver lost: a secondary receiver's fix (offset north), or no GPS at all."""
    lost = env.sensor_lost.get("gps")
    if lost is None or not lost.any():
        return gps
    fail = env.sensor_failover.get("gps", np.zeros_like(lost))
    gps = {k: np.array(v, copy=True) for k, v in gps.items()}
    offset = env.sensor_offset.get("gps")
    if offset is not None:
        gps["pos"][lost & fail, 0] += offset[lost & fail]
    gone = lost & ~fail
    gps["fix_type"][gone] = 0.0  # MAVLink GPS_FIX_TYPE_NO_GPS
    gps["satellites"][gone] = 0.0
    gps["eph"][gone], gps["epv"][gone] = 99.99, 99.99
    gps["vel"][gone] = 0.0
    return gps


def flight_vehicles(seeds: list[int], cfg: FlightConfig) -> list[tuple[str, float]]:
    """Per flight, the airframe it flies (``""``: the config's own vehicle) and its payload (a fraction of
    the airframe's mass, drawn with its mission family: generator.flight_software.families; carried only
    with an airframe mix, so that a config without one flies one vehicle), both drawn from its seed."""
    from scart_bench.generator.physics.airframes import airframe_for_seed

    names = [airframe_for_seed(cfg.airframes, s) if cfg.airframes else "" for s in seeds]
    m = cfg.mission
    if cfg.airframes and m.families and not m.missions:
        from scart_bench.generator.flight_software.families import draw_mission

        return [(name, draw_mission(s, m).payload) for name, s in zip(names, seeds)]
    return [(name, 0.0) for name in names]


def vehicle_groups(seeds: list[int], cfg: FlightConfig) -> list[tuple[FlightConfig, np.ndarray]]:
    """The batch split by vehicle: per airframe and payload, the config that flies it (its vehicle and
    controller, no mix left) and the positions of its flights in ``seeds``. The engines take one vehicle
    a batch (the compiled kernel's parameter vector); a flight's result does not depend on its batch
    mates, so flying the groups apart gives every flight the bytes it has alone. Without a mix: one
    group, ``cfg`` itself."""
    import dataclasses

    from scart_bench.generator.physics.airframes import airframe

    drawn = flight_vehicles(seeds, cfg)
    if not cfg.airframes and all(p == 0.0 for _, p in drawn):
        return [(cfg, np.arange(len(seeds)))]
    groups = []
    for key in sorted(set(drawn)):
        name, payload = key
        vehicle, controller = airframe(name) if name else (cfg.vehicle, cfg.controller)
        vehicle = dataclasses.replace(vehicle, mass=vehicle.mass * (1.0 + payload))
        sub = dataclasses.replace(cfg, vehicle=vehicle, controller=controller, airframes=())
        groups.append((sub, np.array([i for i, d in enumerate(drawn) if d == key], dtype=np.int64)))
    return groups


def _pad_messages(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], where: list[np.ndarray], n: int):
    """One topic's (steps, values, delivered) of the groups as one batch's: the longest schedule, a
    shorter group's flights holding their last message (as a finished flight does in a batch)."""
    steps = max((p[0] for p in parts), key=len)
    vals = np.empty((n, len(steps), parts[0][1].shape[2]))
    ok = np.ones((n, len(steps)), dtype=bool)
    for (st, v, d), idx in zip(parts, where):
        k = len(st)
        vals[idx, :k] = v
        vals[idx, k:] = v[:, k - 1:k] if k else 0.0
        ok[idx, :k] = d
    return steps, vals, ok


def merge_results(parts: list[BatchResult], where: list[np.ndarray], seeds: list[int]) -> BatchResult:
    """The groups' results (:func:`vehicle_groups`) as one batch's, flights in ``seeds`` order."""
    n = len(seeds)

    def topics(get) -> dict:
        names = get(parts[0]).keys()
        return {t: _pad_messages([get(p)[t] for p in parts], where, n) for t in names}

    def rows(get, dtype=float) -> np.ndarray:
        first = np.asarray(get(parts[0]))
        out = np.zeros((n,) + first.shape[1:], dtype=dtype)
        for p, idx in zip(parts, where):
            out[idx] = get(p)
        return out

    simulator = topics(lambda p: p.simulator)
    same = all(p.navigator is p.simulator for p in parts)
    navigator = simulator if same else topics(lambda p: p.navigator)
    k = max(p.waypoints.shape[1] for p in parts)
    waypoints = np.zeros((n, k, 3))
    for p, idx in zip(parts, where):
        w = p.waypoints
        waypoints[idx] = np.concatenate([w, np.repeat(w[:, -1:], k - w.shape[1], axis=1)], axis=1)
    status = [""] * n
    for p, idx in zip(parts, where):
        for j, i in enumerate(idx):
            status[i] = p.status[j]
    return BatchResult(
        seeds=[int(s) for s in seeds], simulator=simulator, navigator=navigator,
        exit_step=rows(lambda p: p.exit_step, np.int64), status=status, waypoints=waypoints,
        wind=rows(lambda p: p.wind), gps_rejections=rows(lambda p: p.gps_rejections, np.int64),
        n_steps=max(p.n_steps for p in parts), timing=parts[0].timing, uorb=parts[0].uorb,
        uorb_streams=topics(lambda p: p.uorb_streams) if parts[0].uorb_streams else {})


def flight_summaries(seeds: list[int], cfg: FlightConfig) -> list[dict]:
    """Per flight, what it flies (dataset per-flight metadata, so results can be broken down by it):
    mission family, airframe, mass with payload, planned altitude, speed, duration and path length,
    mean wind and gust strength, battery charge at boot; all redrawn from the seeds as the engines draw them."""
    m = cfg.mission
    u = np.array([np.random.default_rng(np.random.SeedSequence([int(s), 0x5CA7])).uniform(size=6) for s in seeds])
    battery = battery_start(seeds)
    out = []
    for i, ((name, payload), s) in enumerate(zip(flight_vehicles(seeds, cfg), seeds)):
        if m.families and not m.missions:
            from scart_bench.generator.flight_software.families import draw_mission

            row = draw_mission(s, m).summary()
        else:
            row = {"family": "mission_file" if m.missions else "square"}
        mass = cfg.vehicle.mass
        if name:
            from scart_bench.generator.physics.airframes import airframe

            mass = airframe(name)[0].mass
        row.update({"airframe": name or "default", "mass_kg": round(mass * (1.0 + payload), 4),
                    "wind_ms": round(float(m.wind_max * u[i, 0]), 3),
                    "gust_sigma_ms": round(float(m.gust_sigma_max * u[i, 2]), 3),
                    "battery_start": round(float(battery[i]), 4)})
        out.append(row)
    return out
