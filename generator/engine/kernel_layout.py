"""Named layout of the compiled flight kernel's batch state: one float64 row per flight.

Every per-flight quantity of the closed loop (vehicle, wind, sensors, estimator, controller,
navigator, battery, flight status) has a fixed column range in ``BatchState.row``; the compiled
stages in :mod:`generator.engine.kernel` address them through these constants, and Python code reads
them through ``BatchState`` by name (``state["pos"]``). Booleans and counters are stored as 0.0/1.0
and small whole numbers (exact in float64).

The kernel is compiled with numba's on-disk cache, which is keyed on generator/engine/kernel.py alone and
bakes these constants in: after changing this file (or the NZ_* offsets in generator.physics.noise), touch
generator/engine/kernel.py (or delete generator/__pycache__/kernel.*.nb*) so that it is recompiled.
"""

from __future__ import annotations

# -- vehicle (true state) ------------------------------------------------------------------------
POS = 0  # 3, m NED
VEL = 3  # 3, m/s NED
QUAT = 6  # 4, body -> NED
OMEGA = 10  # 3, rad/s body
ROTOR = 13  # 4, rad/s
VACC = 17  # 3, m/s^2 NED acceleration of the last step
ON_GROUND = 20  # 1
# -- wind ----------------------------------------------------------------------------------------
GUST = 21  # 3
WIND_MEAN = 24  # 3
WIND_SIGMA = 27  # 1
# -- sensor errors -------------------------------------------------------------------------------
ACC_BIAS = 28  # 3
GYRO_BIAS = 31  # 3
BARO_OFFSET = 34  # 1, Pa
GPS_BIAS = 35  # 3, m
SATS_IN_VIEW = 38  # 1
SENSOR_TEMP = 39  # 1, degC
# -- latest sensor samples (as the estimator receives them) --------------------------------------
ACC = 40  # 3
GYRO = 43  # 3
MAG = 46  # 3
PRESSURE = 49  # 1
BARO_TEMP = 50  # 1
GPS_POS = 51  # 3, NED m
GPS_VEL = 54  # 3
GPS_EPH = 57
GPS_EPV = 58
GPS_SATS = 59
GPS_FIX = 60
# -- estimator -------------------------------------------------------------------------------------
EST_QUAT = 61  # 4
EST_GYRO_BIAS = 65  # 3
EST_X = 68  # 9: axis (N, E, D) x [pos, vel, accel bias], row-major
EST_RATES = 77  # 3
EST_ACC = 80  # 3
REJ_GPS_POS = 83
REJ_GPS_VEL = 84
REJ_BARO = 85
BARO_HOME = 86  # baro altitude of home (NaN until the first sample)
INERTIAL_ONLY_S = 87
SINCE_POS_FUSION_S = 88
GPS_RESETS = 89
P_H = 90  # 9, covariance of the horizontal axes
P_V = 99  # 9, covariance of the vertical axis
# -- controller ------------------------------------------------------------------------------------
ARMED = 108
VEL_INT = 109  # 3
RATE_INT = 112  # 3
THRUST_SP = 115
ATT_SP = 116  # 9, attitude setpoint (rotation matrix, row-major)
RATE_SP = 125  # 3
LAND_TIME = 128
DISARMED = 129  # disarmed after the flight
PREV_VEL_ERR = 130  # 3
CTRL_VEL_SP = 133  # 3, slew-limited velocity setpoint
SETPOINT_IN = 136  # 6, last setpoint received from the navigator
# -- navigator -------------------------------------------------------------------------------------
PHASE = 142
SEQ = 143
HOLD_UNTIL = 144
NAV_YAW_SP = 145
NAV_POS = 146  # 3, last received LOCAL_POSITION_NED
NAV_VEL = 149  # 3
NAV_YAW = 152  # last received ATTITUDE yaw
XT_INT = 153
CRUISE = 154
# -- battery, flight status, attitude used by the controller ---------------------------------------
BATTERY = 155  # 3: voltage, current, remaining
DONE = 158
EXIT_STEP = 159
STATUS = 160  # 0 timeout, 1 landed, 2 crashed
LANDED_AT = 161
R_CTRL = 162  # 9, estimated attitude the attitude controller uses this step
R_TRUE = 171  # 9, true attitude of this step's sensor samples (before the step's rotation)
LAST_FIX = 180  # 3, last fixed GPS position (reported while a jammed receiver has no fix)
LAST_FIX_SET = 183
# -- the flight's start on the ground (generator.flight_software.startup) --------------------------------------------
GPS_FIX_AT = 184  # s, the receiver's first fix
GPS_ORIGIN_AT = 185  # s, the estimator fuses GPS from then
ARM_AT = 186  # s, the navigator arms
# -- the estimator's output predictor ----------------------------------------------------------------
OUT_ERR = 187  # 6: per axis (N, E, D) [position, velocity] of the output minus the filter's state
# -- the mixer's output ------------------------------------------------------------------------------
MOTOR_CMD = 193  # 4, rad/s: the rotor speeds the rate controller's mixer commanded this step (before a rotor limit)
# -- the navigator's last mission item (generator.flight_software.navigator.mission_table) --------------
NAV_LAST = 197
# -- the GPS receiver's slow error: the Gauss-Markov drive its smooth error follows (physics.sensors) ----------
GPS_DRIVE = 198  # 3, m
# -- the controller's landed state: 1 once the take-off's climb was asked for (flight_controller.ControllerState)
TOOK_OFF = 201
# -- coloured sensor noise: the low-pass states (physics.sensors.lowpass_step; SensorParams.*_noise_cutoff_hz) -----------
IMU_LOWPASS = 202  # 12: [z0, z1] per channel, channels accelerometer x/y/z then gyro x/y/z (z0 at +2c, z1 at +2c+1)
BARO_LOWPASS = 214  # 2: z0, z1
WIDTH = 216

# -- physical disturbances of one step (environment attacks, faults): one row per flight ------------
X_WIND = 0  # 3, m/s added to the wind
X_EFFICIENCY = 3  # 4, thrust multiplier per rotor
X_ROTOR_LIMIT = 7  # fraction of the maximum rotor speed available
X_MAG = 8  # 3, gauss of local magnetic disturbances (NED)
X_GPS_SATS = 11  # satellites the receiver tracks
X_GPS_GROWTH = 12  # noise growth under jamming
X_GPS_OFFSET = 13  # 3, m (RF spoofing)
X_GPS_VEL_OFFSET = 16  # 3, m/s
X_BATTERY_SAG = 19  # V
X_WIDTH = 20

#: name -> (first column, width), for BatchState's named access.
FIELDS: dict[str, tuple[int, int]] = {
    "pos": (POS, 3), "vel": (VEL, 3), "quat": (QUAT, 4), "omega": (OMEGA, 3), "rotor_speed": (ROTOR, 4),
    "accel_true": (VACC, 3), "on_ground": (ON_GROUND, 1), "gust": (GUST, 3), "wind_mean": (WIND_MEAN, 3),
    "wind_sigma": (WIND_SIGMA, 1), "accel_bias": (ACC_BIAS, 3), "gyro_bias": (GYRO_BIAS, 3),
    "baro_offset": (BARO_OFFSET, 1), "gps_bias": (GPS_BIAS, 3), "satellites_in_view": (SATS_IN_VIEW, 1),
    "sensor_temperature": (SENSOR_TEMP, 1), "accel": (ACC, 3), "gyro": (GYRO, 3), "mag": (MAG, 3),
    "pressure": (PRESSURE, 1), "baro_temp": (BARO_TEMP, 1), "gps_pos": (GPS_POS, 3), "gps_vel": (GPS_VEL, 3),
    "gps_eph": (GPS_EPH, 1), "gps_epv": (GPS_EPV, 1), "gps_satellites": (GPS_SATS, 1), "gps_fix": (GPS_FIX, 1),
    "est_quat": (EST_QUAT, 4), "est_gyro_bias": (EST_GYRO_BIAS, 3), "est_x": (EST_X, 9), "est_rates": (EST_RATES, 3),
    "est_accel": (EST_ACC, 3), "gps_pos_rejected": (REJ_GPS_POS, 1), "gps_vel_rejected": (REJ_GPS_VEL, 1),
    "baro_rejected": (REJ_BARO, 1), "baro_home": (BARO_HOME, 1), "inertial_only_s": (INERTIAL_ONLY_S, 1),
    "since_pos_fusion_s": (SINCE_POS_FUSION_S, 1), "gps_resets": (GPS_RESETS, 1), "P_h": (P_H, 9), "P_v": (P_V, 9),
    "armed": (ARMED, 1), "vel_int": (VEL_INT, 3), "rate_int": (RATE_INT, 3), "thrust_sp": (THRUST_SP, 1),
    "att_sp": (ATT_SP, 9), "rate_sp": (RATE_SP, 3), "land_time": (LAND_TIME, 1), "disarmed": (DISARMED, 1),
    "prev_vel_err": (PREV_VEL_ERR, 3), "ctrl_vel_sp": (CTRL_VEL_SP, 3), "setpoint_in": (SETPOINT_IN, 6),
    "phase": (PHASE, 1), "seq": (SEQ, 1), "hold_until": (HOLD_UNTIL, 1), "nav_yaw_sp": (NAV_YAW_SP, 1),
    "nav_pos": (NAV_POS, 3), "nav_vel": (NAV_VEL, 3), "nav_yaw": (NAV_YAW, 1), "xt_int": (XT_INT, 1),
    "cruise": (CRUISE, 1), "battery": (BATTERY, 3), "done": (DONE, 1), "exit_step": (EXIT_STEP, 1),
    "status": (STATUS, 1), "landed_at": (LANDED_AT, 1), "R_ctrl": (R_CTRL, 9), "R_true": (R_TRUE, 9),
    "last_fix": (LAST_FIX, 3), "last_fix_set": (LAST_FIX_SET, 1), "gps_fix_at": (GPS_FIX_AT, 1),
    "gps_origin_at": (GPS_ORIGIN_AT, 1), "arm_at": (ARM_AT, 1), "out_err": (OUT_ERR, 6),
    "motor_cmd": (MOTOR_CMD, 4), "nav_last": (NAV_LAST, 1),
    "gps_drive": (GPS_DRIVE, 3), "took_off": (TOOK_OFF, 1),
    "imu_lowpass": (IMU_LOWPASS, 12), "baro_lowpass": (BARO_LOWPASS, 2),
}

# -- schedules: rows of the due / message-index tables ---------------------------------------------
#: Telemetry topics in scart_bench.dataset.schema.TELEMETRY_TOPICS order, then the setpoint, truth and sensors,
#: then the flight controller's streams recorded for the uORB view (generator.telemetry.schedule.UORB_STREAMS;
#: never due unless FlightConfig.uorb).
SCHEDULE = ("attitude", "highres_imu", "global_position_int", "local_position_ned", "gps_raw_int",
            "scaled_pressure", "altitude", "battery_status", "setpoint", "truth", "sensor_mag", "sensor_baro",
            "sensor_gps", "sensor_combined", "vehicle_attitude", "vehicle_local_position", "actuator_controls_0")
D_ATT, D_IMU, D_GPI, D_LPN, D_GPSRAW, D_PRESS, D_ALT, D_BAT, D_SETPOINT, D_TRUTH, D_MAG, D_BARO, D_GPS = range(13)
D_U_IMU, D_U_ATT, D_U_LPOS, D_U_ACT = range(13, 17)
N_TELEMETRY = 8
N_UORB = 4

# -- the parameter vector ---------------------------------------------------------------------------
PARAMS = (
    "dt", "mass", "Jx", "Jy", "Jz", "motor_constant", "max_rot", "tau_up", "tau_down", "rotor_drag", "body_drag",
    "alloc", "alloc_inv", "gust_a", "gust_b", "a_accel_bias", "c_accel_bias", "a_gyro_bias", "c_gyro_bias",
    "c_accel_noise", "c_gyro_noise", "mag_noise", "mag_field", "baro_noise", "home_alt", "gps_a", "gps_bias_c",
    "gps_white", "gps_vel_noise", "eph0", "epv0", "delay", "att_accel_gain", "gyro_bias_gain", "att_mag_gain",
    "decl", "kf_F", "kf_Q", "gate2", "gps_pos_r", "gps_vel_r", "baro_r", "reset_timeout", "gps_min_sats",
    "gps_max_eph", "vel_p", "vel_i", "vel_xy_d", "acc_hor_dt", "acc_vert_dt", "tan_tilt", "att_p", "rate_max",
    "rate_p", "rate_i", "thrust_lo", "thrust_hi", "max_thrust", "land_detect_s", "arm_delay", "takeoff_hold",
    "approach_gain", "climb_speed", "land_speed", "acceptance", "lat0", "lon0", "sin_lat0", "cos_lat0",
    "hover", "tail_steps", "yaw_step_max", "out_decay", "accel_vibration", "inv_hover_rotor",
    "takeoff_after_arm", "gyro_vibration", "accel_lowpass", "gyro_lowpass", "baro_lowpass",
)
_SIZES = {"accel_lowpass": 6, "gyro_lowpass": 6, "baro_lowpass": 6, "alloc": 16, "alloc_inv": 16, "c_accel_noise": 3, "accel_vibration": 3, "gyro_vibration": 3, "mag_field": 3, "gps_bias_c": 3, "gps_white": 3, "kf_F": 9, "kf_Q": 3,
          "vel_p": 3, "vel_i": 3, "att_p": 3, "rate_max": 3, "rate_p": 3, "rate_i": 3}
PARAM_INDEX: dict[str, int] = {}
_k = 0
for _name in PARAMS:
    PARAM_INDEX[_name] = _k
    _k += _SIZES.get(_name, 1)
N_PARAMS = _k

# -- the pilot in attitude mode (generator.flight_software.pilot; MissionParams.pilot_*): after every column above ------
PILOT_RNG = WIDTH  # the sticks' xorshift32 state (an integer below 2^32)
PILOT_GAIN = WIDTH + 1  # this flight's stick amplitude factor (0: flown without the pilot)
PILOT_LAG = WIDTH + 2  # 8: the two lags' states per stick (roll, pitch, yaw, throttle)
WIDTH = PILOT_LAG + 8
FIELDS.update({"pilot_rng": (PILOT_RNG, 1), "pilot_gain": (PILOT_GAIN, 1), "pilot_lag": (PILOT_LAG, 8)})
#: the pilot's parameters (pilot.stick_params): amplitudes (4), alpha, 1 - alpha, norm, hover factor, on
PARAMS += ("pilot",)
PARAM_INDEX["pilot"] = N_PARAMS
N_PARAMS += 9

# -- the IMU's lever arm (SensorParams.imu_offset_m; physics.sensors.lever_arm): after every column above ------------
PREV_OMEGA = WIDTH  # 3, rad/s body: the body rates at the last IMU sample (the angular acceleration's difference)
WIDTH = PREV_OMEGA + 3
FIELDS.update({"prev_omega": (PREV_OMEGA, 3)})
#: imu_offset: r (3, m body) and on (1: an offset is set); baro_downwash: Pa per sample at hover thrust (0: off)
PARAMS += ("imu_offset", "baro_downwash")
PARAM_INDEX["imu_offset"] = N_PARAMS
PARAM_INDEX["baro_downwash"] = N_PARAMS + 4
N_PARAMS += 5

# -- the pilot's band-pass (MissionParams.pilot_stick_highpass_hz; flight_software.pilot.stick_highpass) --------------
PILOT_HP = WIDTH  # 4: the high-pass's slow lag per stick (roll, pitch, yaw, throttle)
WIDTH = PILOT_HP + 4
FIELDS.update({"pilot_hp": (PILOT_HP, 4)})
#: alpha, 1 - alpha, the band-pass's norm, on
PARAMS += ("pilot_hp",)
PARAM_INDEX["pilot_hp"] = N_PARAMS
N_PARAMS += 4

# -- each vehicle's vibration (SensorParams.vibration_levels; physics.sensors.flight_vibration_levels) ----------------
VIB_LEVEL = WIDTH  # 6: this flight's accelerometer x/y/z, gyro x/y/z multiples of the vibration (1 without levels)
PREV_DRAW = WIDTH + 6  # 6: the IMU's noise draws of the last sample (accelerometer x/y/z, gyro x/y/z)
IMU_HF = WIDTH + 12  # 6: a rough vehicle's high-frequency vibration of the last sample, in the logged IMU only
WIDTH = IMU_HF + 6
FIELDS.update({"vib_level": (VIB_LEVEL, 6), "prev_draw": (PREV_DRAW, 6), "imu_hf": (IMU_HF, 6)})

# -- each vehicle's rocking (MissionParams.rocking_levels; physics.vehicle.Rocking) ------------------------------------
ROCK_RNG = WIDTH  # the rocking's xorshift32 state (an integer below 2^32)
ROCK_LEVEL = WIDTH + 1  # 3: rad/s^2 per step, roll/pitch/yaw (0: no rocking)
WIDTH = ROCK_LEVEL + 3
FIELDS.update({"rock_rng": (ROCK_RNG, 1), "rock_level": (ROCK_LEVEL, 3)})

# -- each vehicle's rocking in forward flight (MissionParams.rocking_flow_levels; physics.vehicle.FlowRocking) ----------
FLOW_RNG = WIDTH  # its xorshift32 state (0: none)
FLOW_LEVEL = WIDTH + 1  # 2: rad/s^2 at full speed, roll/pitch
FLOW_Y = WIDTH + 3  # 2: the low-passed unit drive, roll/pitch
WIDTH = FLOW_Y + 2
FIELDS.update({"flow_rng": (FLOW_RNG, 1), "flow_level": (FLOW_LEVEL, 2), "flow_y": (FLOW_Y, 2)})
#: a, b (the low-pass per step, physics.vehicle.flow_coefficients), 1 / (the speed of the full rocking - the speed it
#: starts from), the speed it starts from
PARAMS += ("rocking_flow",)
PARAM_INDEX["rocking_flow"] = N_PARAMS
N_PARAMS += 4


# -- the baro's slow error (SensorParams.baro_wander_pa; physics.sensors.baro_wander_coefficients) ---------------------
BARO_WANDER = WIDTH  # 2, Pa: the wander's drive and the wander
WIDTH = BARO_WANDER + 2
FIELDS.update({"baro_wander": (BARO_WANDER, 2)})
#: a (the decay per baro sample), c (the drive's gain, Pa), on
PARAMS += ("baro_wander",)
PARAM_INDEX["baro_wander"] = N_PARAMS
N_PARAMS += 3
#: baro_speed: Pa per sample at full speed (0: off), 1 / (the speed of the full noise - the speed it starts from), the
#: speed it starts from (physics.sensors.BARO_FLOW_FROM)
PARAMS += ("baro_speed",)
PARAM_INDEX["baro_speed"] = N_PARAMS
N_PARAMS += 3
