"""Physical and tuning parameters as plain data with units, apart from the dynamics code.

Vehicle values are the 3DR Iris of PX4 SITL (Gazebo classic ``iris.sdf``); sensor values are the
Gazebo-classic plugin defaults PX4 ships; controller gains follow PX4 multicopter defaults
(MPC_*, MC_*) translated to physical units.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import SIM_RATE_HZ

GRAVITY = 9.80665  # m/s^2

#: The one clock of every engine (numpy reference step, compiled kernel, sitl plant): the simulation step
#: in seconds and microseconds, and the rate at which the navigator sends setpoints.
DT = 1.0 / SIM_RATE_HZ
STEP_US = int(round(1e6 * DT))
NAV_RATE_HZ = 50.0

#: The battery model of every engine (a 4S pack, 5.1 Ah): open-circuit voltage BATTERY_OCV_V +
#: BATTERY_OCV_SPAN_V * remaining, drawn power BATTERY_POWER_K * sum(thrust^1.5) + BATTERY_IDLE_W, voltage
#: sag BATTERY_R_OHM * current plus BATTERY_NOISE_V of noise; updated every BATTERY_STEP_S.
BATTERY_OCV_V = 12.8
BATTERY_OCV_SPAN_V = 4.0
BATTERY_CAPACITY_AH = 5.1
BATTERY_POWER_K = 6.4
BATTERY_IDLE_W = 2.0
BATTERY_R_OHM = 0.05
BATTERY_NOISE_V = 0.01
BATTERY_STEP_S = 0.5
#: A crash, as every engine checks it every CRASH_CHECK_STEPS steps: roll or pitch beyond CRASH_TILT_RAD in
#: the air, or on the ground an acceleration above CRASH_GROUND_HOVERS times the hover thrust.
CRASH_TILT_RAD = 1.3
CRASH_GROUND_HOVERS = 3
CRASH_CHECK_STEPS = 25


@dataclass(frozen=True)
class VehicleParams:
    """3DR Iris quadrotor (PX4 SITL)."""

    mass: float = 1.5  # kg
    inertia: tuple[float, float, float] = (0.029125, 0.029125, 0.055225)  # kg m^2, body x/y/z
    # rotor positions in the FRD body frame (m) and spin (+1: reaction torque yaws the body +z)
    rotor_x: tuple[float, ...] = (0.13, -0.13, 0.13, -0.13)
    rotor_y: tuple[float, ...] = (0.22, -0.20, -0.22, 0.20)
    rotor_spin: tuple[float, ...] = (1.0, 1.0, -1.0, -1.0)
    motor_constant: float = 5.84e-06  # N / (rad/s)^2
    moment_constant: float = 0.06  # m (yaw torque = moment_constant * thrust)
    max_rot_velocity: float = 1100.0  # rad/s
    time_constant_up: float = 0.0125  # s
    time_constant_down: float = 0.025  # s
    rotor_drag_coefficient: float = 8.06428e-05  # N s / (m rad) per rotor
    body_drag: float = 0.05  # N s^2/m^2, quadratic drag of the airframe

    @property
    def max_thrust(self) -> float:
        """Thrust of one rotor at full speed (N)."""
        return self.motor_constant * self.max_rot_velocity**2

    def allocation(self) -> np.ndarray:
        """Matrix A with [thrust, tau_x, tau_y, tau_z] = A @ rotor_thrusts (FRD body)."""
        x = np.array(self.rotor_x)
        y = np.array(self.rotor_y)
        s = np.array(self.rotor_spin)
        return np.vstack([np.ones(4), -y, x, s * self.moment_constant])


@dataclass(frozen=True)
class SensorParams:
    """PX4 Gazebo-classic sensor plugin defaults (noise densities turned into per-sample sigmas),
    with the accelerometer's white noise calibrated against real PX4 logs (docs/realism.md).

    The accelerometer density stands for the output of PX4's accelerometer low-pass filter
    (IMU_ACCEL_CUTOFF), which the generator does not model: Gazebo's raw 0.004 m/s^2/sqrt(Hz) gave
    hover noise 2.1-2.2x (x/y) the RflyMAD SIL log's; 0.00126 gives 1.0-1.4x, the rest being wind
    gusts (``python -m perf.realism``). The gyro's Gazebo density already gives 1.1x at hover.
    """

    imu_rate_hz: float = 250.0
    accel_noise_density: float = 0.00126  # m/s^2/sqrt(Hz): 0.020 m/s^2 per 250 Hz sample (Gazebo: 0.004)
    #: the z axis's white sensor noise relative to x/y (1: the motors' vibration, stronger along the
    #: thrust axis, is ``accel_vibration``'s; defaults 4 had 2.5 here standing in for it)
    accel_noise_z_factor: float = 1.0
    #: motor vibration on the accelerometer at hover rotor speed, white, m/s^2 per sample, x/y/z;
    #: none with the motors stopped, as much armed at idle on the ground, more above hover speed
    #: (physics.sensors.vibration_scale). With the sensor's own 0.020 it gives the RflyMAD SIL log's white noise at hover
    #: (0.035 / 0.031 / 0.069 at 50 Hz; perf.realism_tells, docs/realism.md "Fixing the tells")
    accel_vibration: tuple[float, float, float] = (0.029, 0.024, 0.066)
    #: m/s^3/sqrt(Hz); Gazebo's 0.006 drifted the bias by ~0.02 m/s^2 in 10 s on the ground (lag-1
    #: autocorrelation 0.3 at 50 Hz there; the PX4 logs' ground windows: 0.0, perf.realism_tells)
    accel_bias_random_walk: float = 0.0006
    accel_bias_tau: float = 300.0  # s
    gyro_noise_density: float = 0.00018665  # rad/s/sqrt(Hz)
    gyro_bias_random_walk: float = 3.8785e-05  # rad/s^2/sqrt(Hz)
    #: motor vibration on the gyro at hover rotor speed, white, rad/s per sample, x/y/z, scaling as
    #: ``accel_vibration``: none by default (the gyro's white noise alone is 1.3x the SIL log's at
    #: hover); real airframes shake theirs (the ArduCopter fleet: 8x), which a fitted profile sets
    gyro_vibration: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_tau: float = 1000.0  # s
    #: coloured IMU vibration: cutoff (Hz) of a second-order Butterworth low-pass of ``accel_vibration`` /
    #: ``gyro_vibration`` at the IMU rate, their per-sample sigma kept (physics.sensors.lowpass_coefficients); the
    #: sensor's own noise stays white. 0: white, as drawn (the default). A frame shakes and rocks at low
    #: frequencies: the ArduCopter fleet's gyro differences at hover have lag-1 autocorrelation 0.7-0.9 at 50 Hz
    #: (white noise -0.5), on the ground, motors running, -0.2 to -0.5; ``generate --like`` fits these (docs/like.md)
    accel_noise_cutoff_hz: float = 0.0
    gyro_noise_cutoff_hz: float = 0.0
    #: where the IMU sits relative to the centre of gravity, m, body frame (FRD): the accelerometer reads the
    #: specific force there, alpha x r + omega x (omega x r) on top of the centre's (physics.sensors). (0, 0, 0):
    #: at the centre (the default). Half the ArduCopter fleet's logs show it: their 0.5-5 Hz acc_y follows the
    #: roll acceleration with 2-12 cm; ``generate --like`` fits it (docs/like.md "The IMU's lever arm")
    imu_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the vehicles' vibration per flight: accelerometer x/y/z and gyro x/y/z multiples of ``accel_vibration`` /
    #: ``gyro_vibration`` (above 2, the rest is high-frequency: physics.sensors.Sensors.imu); the flight with seed s
    #: shakes as ``vibration_levels[s mod len]`` (the same rule as ``MissionParams.missions``: ``generate --like``
    #: writes one per recovered mission, in the missions' order, so that each flight shakes as the vehicle whose log
    #: its mission came from). (): 1 for every flight (the default). The ArduCopter fleet's vehicles differ by
    #: 10-1000x in IMU vibration power (docs/like.md "Each vehicle's vibration")
    vibration_levels: tuple[tuple[float, float, float, float, float, float], ...] = ()
    mag_rate_hz: float = 100.0
    mag_noise: float = 0.0015  # gauss, 1 sigma per sample: the shared SITL logs 0.0009-0.0023 (Gazebo: 0.004)
    # Earth field at the PX4 SITL home (Zurich), NED, gauss
    mag_field_ned: tuple[float, float, float] = (0.2158, 0.0099, 0.4250)
    baro_rate_hz: float = 50.0
    baro_noise_pa: float = 1.0  # Pa RMS
    #: the same low-pass of the baro's pressure noise at ``baro_rate_hz`` (0: white, the default)
    baro_noise_cutoff_hz: float = 0.0
    #: the rotors' downwash on the baro, Pa per sample at hover thrust, scaling with the rotors' thrust over the
    #: hover's (physics.sensors.thrust_scale: ~0.15 at idle on the ground, none with the motors stopped); with it
    #: ``baro_noise_pa`` is the sensor's own noise (white) and ``baro_noise_cutoff_hz`` colours the downwash only.
    #: 0: off (the default). The ArduCopter fleet's baro on the ground is quieter and whiter than at hover
    #: (sample-to-sample x0.5, 0.5-5 Hz power x0.25); ``generate --like`` fits it (docs/like.md)
    baro_downwash_pa: float = 0.0
    #: the baro's slow error, Pa (stationary sigma): a first-order Gauss-Markov wander of time constant
    #: ``baro_wander_tau_s`` on top of its noise, driven by the same draws (physics.sensors.baro_wander_coefficients).
    #: 0: off (the default). The ArduCopter fleet's baro at still hover wanders 2-4x more than the estimator's
    #: altitude (detrended 10 s windows: 0.19 m against 0.06 m); ``generate --like`` fits it (docs/like.md)
    baro_wander_pa: float = 0.0
    baro_wander_tau_s: float = 2.0
    #: the baro's noise in forward flight, Pa per sample at and above ``baro_speed_full_m_s`` of true horizontal speed,
    #: growing with the speed from none at 1 m/s and adding in squares to the downwash's (coloured as it is: the same
    #: draws; physics.sensors.baro_flow). 0: off (the default). The ArduCopter fleet's baro at 2-3 m/s moves 3x as much from sample to sample as
    #: at hover and 25x in 0.5-2 Hz, the same at 16 m/s (the rotors' wake swept back over the body); ``generate
    #: --like`` fits it (docs/like.md)
    baro_speed_pa: float = 0.0
    baro_speed_full_m_s: float = 2.0  # above 1 m/s, where it starts (physics.sensors.BARO_FLOW_FROM)
    baro_drift_pa: float = 0.6  # Pa, 1 sigma of the slowly varying offset
    gps_rate_hz: float = 10.0
    gps_delay_s: float = 0.112  # s, 28 simulation steps (PX4 SITL: 110-120 ms)
    # GPS position errors: the "simulator" level of GPS_ACCURACY (see there for "real_receiver");
    # the receiver reports eph = hypot(noise_h, bias_h) and epv = hypot(noise_v, bias_v) at 12 satellites
    # (PX4 SITL's GPS, as the RflyMAD SIL log shows it at hover: 0.03 m white on top of a slow error)
    gps_noise_h: float = 0.03  # m, white, per axis
    gps_noise_v: float = 0.05  # m, white
    gps_bias_h: float = 0.2985  # m, 1 sigma of the correlated (Gauss-Markov) error: eph 0.30 m
    gps_bias_v: float = 0.469  # m: epv 0.47 m
    gps_bias_tau: float = 60.0  # s
    gps_vel_noise: float = 0.025  # m/s, white per axis (the RflyMAD SIL log at hover: 0.024-0.025 m/s)


@dataclass(frozen=True)
class ControllerParams:
    """PX4-like cascade: velocity -> acceleration -> attitude -> rate -> motors."""

    vel_xy_p: float = 1.8  # MPC_XY_VEL_P_ACC, 1/s
    vel_xy_i: float = 0.4  # MPC_XY_VEL_I_ACC, 1/s^2
    vel_xy_d: float = 0.2  # MPC_XY_VEL_D_ACC
    vel_z_p: float = 4.0  # MPC_Z_VEL_P_ACC
    vel_z_i: float = 2.0  # MPC_Z_VEL_I_ACC
    acc_hor: float = 3.0  # MPC_ACC_HOR, m/s^2: slew limit of the horizontal velocity setpoint
    acc_vert: float = 3.0  # MPC_ACC_UP_MAX / MPC_ACC_DOWN_MAX, m/s^2
    tilt_max: float = np.deg2rad(35.0)  # MPC_TILTMAX_AIR (rad)
    att_p: tuple[float, float, float] = (6.5, 6.5, 2.8)  # MC_ROLL_P, MC_PITCH_P, MC_YAW_P
    rate_max: tuple[float, float, float] = (np.deg2rad(220), np.deg2rad(220), np.deg2rad(200))
    #: MPC_YAWRAUTO_MAX (rad/s): every flight here is flown in an auto mode, whose yaw rate PX4 limits
    yaw_rate_auto: float = float(np.deg2rad(45.0))
    rate_p: tuple[float, float, float] = (18.0, 18.0, 8.0)  # 1/s, in physical units
    rate_i: tuple[float, float, float] = (4.0, 4.0, 2.0)
    thrust_min: float = 0.08  # of the maximum collective thrust

    def rate_limits(self) -> tuple[float, float, float]:
        """Body-rate setpoint limits (rad/s): MC_*RATE_MAX, the yaw at most MPC_YAWRAUTO_MAX."""
        return (self.rate_max[0], self.rate_max[1], min(self.rate_max[2], self.yaw_rate_auto))
    land_detect_s: float = 0.6  # seconds of "landed" evidence before disarming


@dataclass(frozen=True)
class EstimatorParams:
    """EKF2-like position/velocity filter and complementary attitude filter."""

    reset_timeout_s: float = 7.0  # EKF2_RESET_TIMEOUT_MAX, s
    gate_sigma: float = 5.0  # EKF2_GPS_P_GATE / EKF2_GPS_V_GATE / EKF2_BARO_GATE
    #: m/s^2/sqrt(Hz), includes model error (EKF2_ACC_NOISE is 0.35 per sample; this filter's input
    #: is the IMU at 250 Hz through a complementary attitude filter: 0.2 keeps its estimate within
    #: ~1 m of the truth with gyro x/y at hover within 1.5x the SIL log's, docs/realism.md)
    accel_process_noise: float = 0.2
    bias_process_noise: float = 0.003  # m/s^3/sqrt(Hz)
    gps_pos_noise: float = 0.5  # m, assumed measurement sigma (EKF2_GPS_P_NOISE)
    gps_vel_noise: float = 0.3  # m/s (EKF2_GPS_V_NOISE)
    baro_noise: float = 0.3  # m (EKF2_BARO_NOISE)
    gps_min_satellites: int = 6  # EKF2_REQ_NSATS: fewer satellites and GPS is not fused
    gps_max_eph: float = 3.0  # m, EKF2_REQ_EPH: a worse horizontal accuracy and GPS is not fused
    #: EKF2_TAU_VEL / EKF2_TAU_POS (s): PX4's output predictor passes a fusion's correction on to the
    #: position and velocity the controllers and the telemetry use over this time constant, so that
    #: a GPS or baro update does not jolt the vehicle (the EKF's own state jumps at each fusion)
    output_tau_s: float = 0.25
    att_accel_gain: float = 0.2  # 1/s, tilt correction from the accelerometer
    att_mag_gain: float = 0.3  # 1/s, heading correction from the magnetometer
    gyro_bias_gain: float = 0.002


@dataclass(frozen=True)
class MissionParams:
    """The default mission: take off, fly the square through its four corners, return, land."""

    altitude: float = 10.0  # m above home
    side: float = 30.0  # m
    # square of side 30 m, offset from home so that "return" is a leg of its own (N, E in m)
    corners: tuple[tuple[float, float], ...] = ((10.0, 10.0), (40.0, 10.0), (40.0, 40.0), (10.0, 40.0))
    cruise_speed: float = 5.0  # m/s (MPC_XY_CRUISE)
    climb_speed: float = 2.5  # m/s
    land_speed: float = 0.7  # m/s (MPC_LAND_SPEED), below 3 m; 1.5 m/s above
    acceptance_radius: float = 0.8  # m, perceived
    approach_gain: float = 1.0  # 1/s, speed = gain * distance near a waypoint
    #: a PX4 start (generator.flight_software.startup): wait on the ground for the GPS fix and the estimator's
    #: origin, then arm (3.8-16 s on the ground as in real logs); False: GPS from boot, arm at arm_delay_s
    ground_phase: bool = True
    arm_delay_s: float = 1.0  # s, arming time when there is no ground phase
    #: s of hover at the take-off point before the mission's first leg (was 5 s: from lift-off to the
    #: first leg the shared logs take 14 s (ArduCopter) and 20 s (RflyMAD), 5 s gave 10 s; 9 s gives
    #: 14 s: ``python -m perf.realism_tells``, docs/realism.md "Fixing the tells")
    takeoff_hold_s: float = 9.0
    yaw_rate_max: float = float(np.deg2rad(45.0))  # MPC_YAWRAUTO_MAX, rad/s: the navigator turns no faster
    max_duration_s: float = 150.0
    jitter_m: float = 0.3  # per-flight jitter of waypoints
    jitter_speed: float = 0.4  # m/s, per-flight jitter of the cruise speed
    wind_max: float = 5.0  # m/s, mean wind drawn uniformly in [0, wind_max]
    gust_sigma_max: float = 0.5  # m/s, gust standard deviation drawn in [0, gust_sigma_max]
    gust_tau: float = 2.0  # s
    #: missions read from files (generator.flight_software.mission_files.MissionFile; ``generate --missions``): flight ``i``
    #: flies file ``seed mod len(missions)`` as written instead of the square (empty: the square)
    missions: tuple = ()
    #: mission families drawn per flight (generator.flight_software.families, a profile's ``missions`` mix):
    #: sorted (family, weight) pairs summing to 1; empty: every flight flies the square (or ``missions``)
    families: tuple = ()
    #: s, with ``families``: the range of each flight's planned mission duration (drawn log-uniform)
    duration_range: tuple[float, float] = (60.0, 180.0)
    #: a pilot in attitude mode (generator.flight_software.pilot): stick standard deviation of roll and pitch (deg)
    #: on a leg, added to the navigator's route through the attitude controller; 0: none (the default). A
    #: hand-flown fleet (ArduCopter STABILIZE / ALT_HOLD / LOITER) rocks at 0.5-5 Hz; ``generate --like`` fits these
    pilot_stick_deg: float = 0.0
    #: Hz, corner of the sticks' spectrum (two first-order lags: flat below it, -40 dB/decade above)
    pilot_stick_hz: float = 1.5
    #: Hz, a first-order high-pass of the sticks (a band-pass with ``pilot_stick_hz``): a hand's corrections come
    #: and go, where two lags alone leave power below 0.5 Hz (the fleet's roll 0.3x the generated there); 0: none
    pilot_stick_highpass_hz: float = 0.0
    #: yaw stick standard deviation (deg of heading) and throttle stick (fraction of g of vertical acceleration)
    pilot_yaw_deg: float = 0.0
    pilot_throttle: float = 0.0
    #: the sticks' amplitude while the velocity setpoint is still, relative to a leg's (1 m/s or faster)
    pilot_hover_factor: float = 0.5
    #: share of the flights flown with the pilot (drawn per flight from its seed)
    pilot_share: float = 1.0
    #: each vehicle's rocking: the standard deviation (rad/s^2 per 250 Hz step, roll/pitch/yaw) of a white angular
    #: acceleration on the airborne body (a loose frame, turbulence; physics.vehicle.Rocking), per flight: the flight
    #: with seed s rocks as ``rocking_levels[s mod len]`` (``generate --like``: one per recovered mission, in the
    #: missions' order, fitted to its log's gyro). (): none (the default). The ArduCopter fleet's rough vehicles'
    #: gyro differences in cruise are 2.5x the generated ones (docs/like.md "Each vehicle's rocking")
    rocking_levels: tuple[tuple[float, float, float], ...] = ()
    #: each vehicle's rocking in forward flight: the standard deviation (rad/s^2, roll/pitch) of an angular acceleration
    #: low-passed at ``rocking_flow_hz``, at ``rocking_flow_full_m_s`` of true horizontal speed or faster (linear in the
    #: speed from ``rocking_flow_from_m_s``: none below it), per flight as ``rocking_levels``
    #: (physics.vehicle.FlowRocking). (): none (the default). The ArduCopter fleet's hand-flown vehicles rock at 1-5 Hz in forward flight, 3-30x more than at rest
    #: (docs/like.md "Rocking in forward flight")
    rocking_flow_levels: tuple[tuple[float, float], ...] = ()
    rocking_flow_hz: float = 1.0  # Hz, the forward-flight rocking's first-order low-pass
    rocking_flow_full_m_s: float = 3.0  # m/s, the speed of the full forward-flight rocking
    rocking_flow_from_m_s: float = 0.5  # m/s, the speed it starts from


#: GPS accuracy levels, a profile's ``gps_accuracy``: the receiver's position errors (SensorParams)
#: and what the flight controller accepts (EstimatorParams). The receiver reports
#: eph = hypot(gps_noise_h, gps_bias_h) and epv = hypot(gps_noise_v, gps_bias_v) at 12 satellites
#: (scaled by 12 / satellites, 8-16 in view).
#:
#: - ``simulator``: PX4 SITL's GPS (eph/epv ~0.3/0.5 m, as the RflyMAD and Gazebo SITL logs report).
#: - ``real_receiver``: what real receivers report (eph/epv ~2.8/5.9 m, the CubeOrange log), with
#:   errors to match: a correlated horizontal error of 2.75 m (1 sigma, 60 s time constant), so the
#:   estimate, and the path flown, wander by metres as with a real GPS. GPS height is not fused, so
#:   the vertical error only shows in the reported altitude. EKF2_REQ_EPH (3 m) is checked by PX4
#:   before the first fix is used; the generator checks it on every message, so this level raises
#:   it to 5 m, or a receiver with fewer than 12 satellites would never be fused.
GPS_ACCURACY: dict[str, dict[str, dict[str, float]]] = {
    "simulator": {"sensors": {}, "estimator": {}},
    "real_receiver": {
        "sensors": {"gps_noise_h": 0.5, "gps_bias_h": 2.75, "gps_noise_v": 1.0, "gps_bias_v": 5.8},
        "estimator": {"gps_max_eph": 5.0},
    },
}


def with_gps_accuracy(config, level: str):
    """``config`` (a FlightConfig, or anything with ``sensors`` and ``estimator``) at GPS accuracy ``level``."""
    if level not in GPS_ACCURACY:
        raise ValueError(f"GPS accuracy {level!r}: expected one of {', '.join(GPS_ACCURACY)}")
    spec = GPS_ACCURACY[level]
    return dataclasses.replace(config, sensors=dataclasses.replace(config.sensors, **spec["sensors"]),
                               estimator=dataclasses.replace(config.estimator, **spec["estimator"]))


#: Sensor noise profiles, a profile's ``sensor_profile``: the magnetometer and barometer noise, where
#: the shared real logs disagree (docs/realism.md). The IMU is calibrated on the RflyMAD SIL log's
#: hover in both (the other logs are bench logs, on the ground).
#:
#: - ``gazebo``: PX4's Gazebo-classic SITL and real hardware: baro altitude noise ~0.08 m at hover
#:   (the Gazebo SITL logs 0.09-0.11 m, the CubeOrange 0.12 m on the ground), magnetometer 0.0015
#:   gauss (the Gazebo SITL logs 0.0012-0.0023).
#: - ``rflymad``: RflySim's SIL, as the RflyMAD log shows it at hover: a 3x quieter barometer
#:   (0.027 m) and magnetometer (0.0007-0.0012 gauss).
SENSOR_PROFILES: dict[str, dict[str, float]] = {
    "gazebo": {},
    "rflymad": {"baro_noise_pa": 0.3, "mag_noise": 0.0009},
}


def with_sensor_profile(config, name: str):
    """``config`` (a FlightConfig, or anything with ``sensors``) with the sensor noise profile ``name``."""
    if name not in SENSOR_PROFILES:
        raise ValueError(f"sensor profile {name!r}: expected one of {', '.join(SENSOR_PROFILES)}")
    return dataclasses.replace(config, sensors=dataclasses.replace(config.sensors, **SENSOR_PROFILES[name]))
