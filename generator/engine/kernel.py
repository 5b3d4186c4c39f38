"""The compiled flight kernel: the closed loop of one flight as scalar code, parallel over flights.

The numpy pipeline in :mod:`generator.engine.simulate` (``simulate_reference``) is the reference; these
stages compute the same step, one flight at a time, on the named state row of
:mod:`generator.engine.kernel_layout`. ``run_steps`` flies every active flight of a batch through a block
of whole steps (no Python between steps); the per-stage entry points (``stage_*``) let the SCART
layer see and alter messages at its injection points. Noise is drawn in Python by the flights'
own numpy generators and passed in, so results do not depend on the batch a flight is flown in.
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np
from numba import njit, prange

from scart_bench.generator.engine import kernel_layout as L
from scart_bench.generator.engine.pcg_noise import fill_one
from scart_bench.generator.flight_software.startup import TAKEOFF_CLIMB
from scart_bench.generator.params import (
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
    GRAVITY,
    NAV_RATE_HZ,
)
from scart_bench.generator.physics.noise import (
    NZ_ACC,
    NZ_ACC_BIAS,
    NZ_BARO,
    NZ_BATTERY,
    NZ_GPS_BIAS,
    NZ_GPS_POS,
    NZ_GPS_VEL,
    NZ_GYRO,
    NZ_GYRO_BIAS,
    NZ_MAG,
    NZ_WIND,
)
from scart_bench.generator.physics.sensors import (
    EPH_SETTLE,
    EPH_SETTLE_TAU_S,
    HF_NORM,
    SATS_RAMP,
    VIB_AS_FLEET,
    VIBRATION_FULL_FROM,
)

_I = L.PARAM_INDEX
K_DT, K_MASS, K_JX, K_JY, K_JZ = _I["dt"], _I["mass"], _I["Jx"], _I["Jy"], _I["Jz"]
K_KF, K_MAXROT, K_TAU_UP, K_TAU_DOWN = _I["motor_constant"], _I["max_rot"], _I["tau_up"], _I["tau_down"]
K_ROTOR_DRAG, K_BODY_DRAG, K_ALLOC, K_ALLOC_INV = _I["rotor_drag"], _I["body_drag"], _I["alloc"], _I["alloc_inv"]
K_GUST_A, K_GUST_B = _I["gust_a"], _I["gust_b"]
K_A_AB, K_C_AB, K_A_GB, K_C_GB = _I["a_accel_bias"], _I["c_accel_bias"], _I["a_gyro_bias"], _I["c_gyro_bias"]
K_C_AN, K_C_GN, K_MAG_NOISE, K_MAG_FIELD = _I["c_accel_noise"], _I["c_gyro_noise"], _I["mag_noise"], _I["mag_field"]
K_ACC_VIB, K_INV_HOVER_ROT = _I["accel_vibration"], _I["inv_hover_rotor"]
K_TAKEOFF_AFTER_ARM, K_GYRO_VIB = _I["takeoff_after_arm"], _I["gyro_vibration"]
K_BARO_NOISE, K_HOME_ALT, K_GPS_A, K_GPS_BIAS_C = _I["baro_noise"], _I["home_alt"], _I["gps_a"], _I["gps_bias_c"]
K_ACC_LP, K_GYRO_LP, K_BARO_LP = _I["accel_lowpass"], _I["gyro_lowpass"], _I["baro_lowpass"]
K_IMU_OFFSET, K_BARO_DOWNWASH = _I["imu_offset"], _I["baro_downwash"]
K_BARO_WANDER, K_BARO_SPEED = _I["baro_wander"], _I["baro_speed"]
K_GPS_WHITE, K_GPS_VEL_NOISE, K_EPH0, K_EPV0 = _I["gps_white"], _I["gps_vel_noise"], _I["eph0"], _I["epv0"]
K_DELAY, K_ATT_ACC_GAIN, K_GYRO_BIAS_GAIN = _I["delay"], _I["att_accel_gain"], _I["gyro_bias_gain"]
K_ATT_MAG_GAIN, K_DECL, K_F, K_Q, K_GATE2 = _I["att_mag_gain"], _I["decl"], _I["kf_F"], _I["kf_Q"], _I["gate2"]
K_GPS_POS_R, K_GPS_VEL_R, K_BARO_R = _I["gps_pos_r"], _I["gps_vel_r"], _I["baro_r"]
K_RESET_TIMEOUT, K_MIN_SATS, K_MAX_EPH = _I["reset_timeout"], _I["gps_min_sats"], _I["gps_max_eph"]
K_VEL_P, K_VEL_I, K_VEL_XY_D = _I["vel_p"], _I["vel_i"], _I["vel_xy_d"]
K_ACC_HOR_DT, K_ACC_VERT_DT, K_TAN_TILT = _I["acc_hor_dt"], _I["acc_vert_dt"], _I["tan_tilt"]
K_ATT_P, K_RATE_MAX, K_RATE_P, K_RATE_I = _I["att_p"], _I["rate_max"], _I["rate_p"], _I["rate_i"]
K_THRUST_LO, K_THRUST_HI, K_MAX_THRUST = _I["thrust_lo"], _I["thrust_hi"], _I["max_thrust"]
K_LAND_DETECT, K_ARM_DELAY, K_TAKEOFF_HOLD = _I["land_detect_s"], _I["arm_delay"], _I["takeoff_hold"]
K_APPROACH, K_CLIMB, K_LAND_SPEED, K_ACCEPT = _I["approach_gain"], _I["climb_speed"], _I["land_speed"], _I["acceptance"]
K_LAT0, K_LON0, K_SIN_LAT0, K_COS_LAT0 = _I["lat0"], _I["lon0"], _I["sin_lat0"], _I["cos_lat0"]
K_HOVER, K_TAIL, K_YAW_STEP, K_OUT_DECAY = _I["hover"], _I["tail_steps"], _I["yaw_step_max"], _I["out_decay"]
K_PILOT = _I["pilot"]
K_PILOT_HP = _I["pilot_hp"]
K_FLOW = _I["rocking_flow"]

G = GRAVITY
PI = math.pi
TWO_PI = 2 * math.pi
EARTH_RADIUS = 6371000.0
SLP = 101325.0
INV_BARO_EXP = 1.0 / 5.25588
RAD2DEG = 180.0 / math.pi
NAV_DT = 1.0 / NAV_RATE_HZ
PH_IDLE, PH_TAKEOFF, PH_MISSION, PH_LAND = 0.0, 1.0, 2.0, 3.0

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}
#: The per-flight stages: compiled without reference counting. Their array arguments are views the
#: caller holds; counted, every call took and released a reference to each of them (about a hundred
#: atomic operations per flight-step, on counters that all threads share).
_HOT = {**_JIT, "_nrt": False, "forceinline": True}

# The workqueue layer's idle threads sleep; OpenMP's spin, which on a shared or small machine takes
# the CPU from the thread doing the work (a one-flight batch ran 4x slower). A layer chosen with
# NUMBA_THREADING_LAYER is kept.
if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"


# -- small algebra ----------------------------------------------------------------------------------
@njit(**_HOT)
def _rot(s, o):
    """Rotation matrix (row-major 9-tuple) of the quaternion at s[o:o+4]."""
    w, x, y, z = s[o], s[o + 1], s[o + 2], s[o + 3]
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


@njit(**_HOT)
def _quat_integrate(s, o, w0, w1, w2, dt):
    """Rotate the quaternion at s[o:o+4] by the body rate (w0, w1, w2) over dt (in place)."""
    angle = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) * dt
    half = 0.5 * angle
    k = (math.sin(half) / angle if angle > 1e-12 else 0.5) * dt
    bw, bx, by, bz = math.cos(half), w0 * k, w1 * k, w2 * k
    aw, ax, ay, az = s[o], s[o + 1], s[o + 2], s[o + 3]
    qw = aw * bw - ax * bx - ay * by - az * bz
    qx = aw * bx + ax * bw + ay * bz - az * by
    qy = aw * by - ax * bz + ay * bw + az * bx
    qz = aw * bz + ax * by - ay * bx + az * bw
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    s[o], s[o + 1], s[o + 2], s[o + 3] = qw / n, qx / n, qy / n, qz / n


@njit(**_HOT)
def _euler(s, o):
    w, x, y, z = s[o], s[o + 1], s[o + 2], s[o + 3]
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


@njit(**_HOT)
def _clip(x, lo, hi):
    return min(max(x, lo), hi)


@njit(**_HOT)
def _wrap_pi(a):
    return -((-a + PI) % TWO_PI - PI)


@njit(**_HOT)
def _latlon(p, x, y):
    """Local north/east (m) -> latitude/longitude (deg), as scart_bench.generator.geo.ned_to_latlon."""
    x = x / EARTH_RADIUS
    y = y / EARTH_RADIUS
    c = math.hypot(x, y)
    if c > 0:
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(_clip(cos_c * p[K_SIN_LAT0] + x * sin_c * p[K_COS_LAT0] / c, -1.0, 1.0))
        lon = p[K_LON0] + math.atan2(y * sin_c, c * p[K_COS_LAT0] * cos_c - x * p[K_SIN_LAT0] * sin_c)
    else:
        lat, lon = p[K_LAT0], p[K_LON0]
    return lat * RAD2DEG, lon * RAD2DEG


@njit(**_HOT)
def _altitude_at(pressure):
    return (1.0 - (pressure / SLP) ** INV_BARO_EXP) / 2.25577e-5


@njit(**_HOT)
def _kf_predict(s, o, p):
    """P = F P F^T + Q for the 3x3 covariance at s[o:o+9]."""
    f = K_F
    a00 = p[f] * s[o] + p[f + 1] * s[o + 3] + p[f + 2] * s[o + 6]
    a01 = p[f] * s[o + 1] + p[f + 1] * s[o + 4] + p[f + 2] * s[o + 7]
    a02 = p[f] * s[o + 2] + p[f + 1] * s[o + 5] + p[f + 2] * s[o + 8]
    a10 = p[f + 3] * s[o] + p[f + 4] * s[o + 3] + p[f + 5] * s[o + 6]
    a11 = p[f + 3] * s[o + 1] + p[f + 4] * s[o + 4] + p[f + 5] * s[o + 7]
    a12 = p[f + 3] * s[o + 2] + p[f + 4] * s[o + 5] + p[f + 5] * s[o + 8]
    a20 = p[f + 6] * s[o] + p[f + 7] * s[o + 3] + p[f + 8] * s[o + 6]
    a21 = p[f + 6] * s[o + 1] + p[f + 7] * s[o + 4] + p[f + 8] * s[o + 7]
    a22 = p[f + 6] * s[o + 2] + p[f + 7] * s[o + 5] + p[f + 8] * s[o + 8]
    rows = ((a00, a01, a02), (a10, a11, a12), (a20, a21, a22))
    for r in range(3):
        x0, x1, x2 = rows[r]
        for c in range(3):
            v = x0 * p[f + 3 * c] + x1 * p[f + 3 * c + 1] + x2 * p[f + 3 * c + 2]
            if r == c:
                v += p[K_Q + r]
            s[o + 3 * r + c] = v


# -- stages (one flight) ----------------------------------------------------------------------------
@njit(**_HOT)
def _rate_control(s, p):
    """Body-rate PI -> rotor speed commands (rad/s) through the mixer."""
    dt = p[K_DT]
    armed = s[L.ARMED]
    r0, r1, r2 = s[L.EST_RATES], s[L.EST_RATES + 1], s[L.EST_RATES + 2]
    J0, J1, J2 = p[K_JX], p[K_JY], p[K_JZ]
    e0 = s[L.RATE_SP] - r0
    e1 = s[L.RATE_SP + 1] - r1
    e2 = s[L.RATE_SP + 2] - r2
    s[L.RATE_INT] = _clip(s[L.RATE_INT] + e0 * dt * armed, -0.5, 0.5)
    s[L.RATE_INT + 1] = _clip(s[L.RATE_INT + 1] + e1 * dt * armed, -0.5, 0.5)
    s[L.RATE_INT + 2] = _clip(s[L.RATE_INT + 2] + e2 * dt * armed, -0.5, 0.5)
    t0 = J0 * (p[K_RATE_P] * e0 + p[K_RATE_I] * s[L.RATE_INT])
    t1 = J1 * (p[K_RATE_P + 1] * e1 + p[K_RATE_I + 1] * s[L.RATE_INT + 1])
    t2 = J2 * (p[K_RATE_P + 2] * e2 + p[K_RATE_I + 2] * s[L.RATE_INT + 2])
    rj0, rj1, rj2 = r0 * J0, r1 * J1, r2 * J2
    t0 += r1 * rj2 - r2 * rj1
    t1 += r2 * rj0 - r0 * rj2
    t2 += r0 * rj1 - r1 * rj0
    mt = p[K_MAX_THRUST]
    k = K_ALLOC_INV
    th = s[L.THRUST_SP]
    c0 = _mix(th, t0, t1, t2, p, k, mt, armed)
    c1 = _mix(th, t0, t1, t2, p, k + 4, mt, armed)
    c2 = _mix(th, t0, t1, t2, p, k + 8, mt, armed)
    c3 = _mix(th, t0, t1, t2, p, k + 12, mt, armed)
    return c0, c1, c2, c3


@njit(**_HOT)
def _mix(th, t0, t1, t2, p, k, mt, armed):
    v = _clip(th * p[k] + t0 * p[k + 1] + t1 * p[k + 2] + t2 * p[k + 3], 0.02 * mt, mt)
    return math.sqrt(v / p[K_KF]) if armed > 0.5 else 0.0


@njit(**_HOT)
def _motor(s, p, r, cmd, dt):
    w = s[L.ROTOR + r]
    tau = p[K_TAU_UP] if cmd > w else p[K_TAU_DOWN]
    w += (cmd - w) * (dt / tau)
    s[L.ROTOR + r] = w
    return w


@njit(**_HOT)
def _xorshift_normal(x):
    """Four xorshift32 uniforms from state ``x`` summed to a unit normal (the pilot's sticks and the rocking,
    as their numpy references draw it): the new state and the draw."""
    total = 0.0
    for _ in range(4):
        x ^= (x << 13) & 0xFFFFFFFF
        x ^= x >> 17
        x ^= (x << 5) & 0xFFFFFFFF
        total = total + x / 4294967296.0
    return x, (total - 2.0) * 1.7320508075688772


@njit(**_HOT)
def _rock(s, axis):
    """One axis of a vehicle's rocking, rad/s^2 (physics.vehicle.Rocking.step, the same lines): a normal
    of its own stream, times its level."""
    xr, n = _xorshift_normal(int(s[L.ROCK_RNG]))
    s[L.ROCK_RNG] = xr
    return s[L.ROCK_LEVEL + axis] * n


@njit(**_HOT)
def _flow(s, p, axis, gain):
    """One axis of a vehicle's rocking in forward flight, rad/s^2 (physics.vehicle.FlowRocking.step, the same lines):
    its low-passed unit drive advanced by a normal of its own stream, times its level and the speed's gain."""
    xr, n = _xorshift_normal(int(s[L.FLOW_RNG]))
    s[L.FLOW_RNG] = xr
    y = p[K_FLOW] * s[L.FLOW_Y + axis] + p[K_FLOW + 1] * n
    s[L.FLOW_Y + axis] = y
    return s[L.FLOW_LEVEL + axis] * gain * y


@njit(**_HOT)
def _vehicle(s, p, cmd, wx, wy, wz, x, env):
    """Advance the rigid body one step; returns the rotation matrix used (of the old attitude).

    With ``env`` the rotors' thrusts are scaled by the disturbances' motor efficiency (x).
    """
    dt = p[K_DT]
    flow_gain = 0.0
    if s[L.FLOW_RNG] != 0.0:  # the forward-flight rocking's gain at the speed before this step's
        flow_gain = min(max(math.sqrt(s[L.VEL] ** 2 + s[L.VEL + 1] ** 2) - p[K_FLOW + 3], 0.0) * p[K_FLOW + 2], 1.0)
    w0 = _motor(s, p, 0, cmd[0], dt)
    w1 = _motor(s, p, 1, cmd[1], dt)
    w2 = _motor(s, p, 2, cmd[2], dt)
    w3 = _motor(s, p, 3, cmd[3], dt)
    kf = p[K_KF]
    h0, h1, h2, h3 = kf * w0 ** 2, kf * w1 ** 2, kf * w2 ** 2, kf * w3 ** 2
    if env:
        e = L.X_EFFICIENCY
        h0, h1, h2, h3 = h0 * x[e], h1 * x[e + 1], h2 * x[e + 2], h3 * x[e + 3]
    rsum = w0 + w1 + w2 + w3
    A = K_ALLOC
    wr = (h0 * p[A] + h1 * p[A + 1] + h2 * p[A + 2] + h3 * p[A + 3],
          h0 * p[A + 4] + h1 * p[A + 5] + h2 * p[A + 6] + h3 * p[A + 7],
          h0 * p[A + 8] + h1 * p[A + 9] + h2 * p[A + 10] + h3 * p[A + 11],
          h0 * p[A + 12] + h1 * p[A + 13] + h2 * p[A + 14] + h3 * p[A + 15])
    R = _rot(s, L.QUAT)
    ax, ay, az = s[L.VEL] - wx, s[L.VEL + 1] - wy, s[L.VEL + 2] - wz
    vb0 = ax * R[0] + ay * R[3] + az * R[6]
    vb1 = ax * R[1] + ay * R[4] + az * R[7]
    vb2 = ax * R[2] + ay * R[5] + az * R[8]
    k = -p[K_ROTOR_DRAG] * rsum
    bd = p[K_BODY_DRAG]
    f0 = k * vb0 - bd * abs(vb0) * vb0
    f1 = k * vb1 - bd * abs(vb1) * vb1
    f2 = 0.0 - bd * abs(vb2) * vb2
    f2 -= wr[0]
    m = p[K_MASS]
    acc0 = (R[0] * f0 + R[1] * f1 + R[2] * f2) / m
    acc1 = (R[3] * f0 + R[4] * f1 + R[5] * f2) / m
    acc2 = (R[6] * f0 + R[7] * f1 + R[8] * f2) / m
    acc2 += G
    if s[L.ON_GROUND] > 0.5 and acc2 >= 0:
        acc0 = acc1 = acc2 = 0.0
    s[L.VEL] += acc0 * dt
    s[L.VEL + 1] += acc1 * dt
    s[L.VEL + 2] += acc2 * dt
    for a in range(3):
        s[L.POS + a] += s[L.VEL + a] * dt
    touching = s[L.POS + 2] >= 0.0
    s[L.ON_GROUND] = 1.0 if touching else 0.0
    if touching:
        s[L.POS + 2] = 0.0
        s[L.VEL], s[L.VEL + 1], s[L.VEL + 2] = 0.0, 0.0, 0.0
    s[L.VACC], s[L.VACC + 1], s[L.VACC + 2] = acc0, acc1, acc2
    J0, J1, J2 = p[K_JX], p[K_JY], p[K_JZ]
    w0, w1, w2 = s[L.OMEGA], s[L.OMEGA + 1], s[L.OMEGA + 2]
    wj0, wj1, wj2 = w0 * J0, w1 * J1, w2 * J2
    g0 = w1 * wj2 - w2 * wj1
    g1 = w2 * wj0 - w0 * wj2
    g2 = w0 * wj1 - w1 * wj0
    n0 = w0 + (wr[1] - g0) / J0 * dt
    n1 = w1 + (wr[2] - g1) / J1 * dt
    n2 = w2 + (wr[3] - g2) / J2 * dt
    if s[L.FLOW_RNG] != 0.0:  # ... and in forward flight (MissionParams.rocking_flow_levels; physics.vehicle.FlowRocking)
        r0 = r1 = 0.0
        r2 = 0.0
        if s[L.ROCK_RNG] != 0.0:
            r0, r1, r2 = _rock(s, 0), _rock(s, 1), _rock(s, 2)
        r0 = r0 + _flow(s, p, 0, flow_gain)
        r1 = r1 + _flow(s, p, 1, flow_gain)
        n0 = n0 + r0 * dt
        n1 = n1 + r1 * dt
        n2 = n2 + r2 * dt
    elif s[L.ROCK_RNG] != 0.0:  # each vehicle's rocking (MissionParams.rocking_levels; physics.vehicle.Rocking)
        n0 = n0 + _rock(s, 0) * dt
        n1 = n1 + _rock(s, 1) * dt
        n2 = n2 + _rock(s, 2) * dt
    if touching:
        n0 = n1 = n2 = 0.0
    s[L.OMEGA], s[L.OMEGA + 1], s[L.OMEGA + 2] = n0, n1, n2
    _quat_integrate(s, L.QUAT, n0, n1, n2, dt)
    if touching:
        q0, q1, q2, q3 = s[L.QUAT], s[L.QUAT + 1], s[L.QUAT + 2], s[L.QUAT + 3]
        yaw = math.atan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 ** 2 + q3 ** 2))
        s[L.QUAT], s[L.QUAT + 1], s[L.QUAT + 2], s[L.QUAT + 3] = math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)
    return R


@njit(**_HOT)
def _physics(s, tbuf, p, step, w, k, x, env):
    """Wind, rate control and the vehicle's step (with ``env``: the disturbances in ``x``)."""
    bs = p[K_GUST_B] * s[L.WIND_SIGMA]
    ga = p[K_GUST_A]
    s[L.GUST] = ga * s[L.GUST] + bs * (w[k, NZ_WIND] * 1.0)
    s[L.GUST + 1] = ga * s[L.GUST + 1] + bs * (w[k, NZ_WIND + 1] * 1.0)
    s[L.GUST + 2] = ga * s[L.GUST + 2] + bs * (w[k, NZ_WIND + 2] * 0.3)
    c0, c1, c2, c3 = _rate_control(s, p)
    s[L.MOTOR_CMD], s[L.MOTOR_CMD + 1], s[L.MOTOR_CMD + 2], s[L.MOTOR_CMD + 3] = c0, c1, c2, c3
    wx = s[L.WIND_MEAN] + s[L.GUST]
    wy = s[L.WIND_MEAN + 1] + s[L.GUST + 1]
    wz = s[L.WIND_MEAN + 2] + s[L.GUST + 2]
    if env:
        wx, wy, wz = wx + x[L.X_WIND], wy + x[L.X_WIND + 1], wz + x[L.X_WIND + 2]
        lim = p[K_MAXROT] * x[L.X_ROTOR_LIMIT]
        c0, c1, c2, c3 = min(c0, lim), min(c1, lim), min(c2, lim), min(c3, lim)
    R = _vehicle(s, p, (c0, c1, c2, c3), wx, wy, wz, x, env)
    for j in range(9):
        s[L.R_TRUE + j] = R[j]
    slot = step % int(p[K_DELAY])
    for a in range(3):
        tbuf[slot, a] = s[L.POS + a]
        tbuf[slot, 3 + a] = s[L.VEL + a]


@njit(**_HOT)
def _sense(s, tbuf, p, step, w, k, due, x, env):
    """Wind, rate control, vehicle dynamics and the sensor samples due at this step."""
    _physics(s, tbuf, p, step, w, k, x, env)
    _sensors(s, tbuf, p, step, w, k, due, x, env)


@njit(**_HOT)
def _lowpass(s, z, p, c, x):
    """One sample of the coloured-noise low-pass with parameters p[c:c + 5] and state s[z], s[z + 1]
    (physics.sensors.lowpass_step, the same lines)."""
    y = p[c] * x + s[z]
    s[z] = p[c + 1] * x - p[c + 3] * y + s[z + 1]
    s[z + 1] = p[c + 2] * x - p[c + 4] * y
    return y


@njit(**_HOT)
def _baro_flow(s, p):
    """The baro's noise in forward flight, Pa per sample (physics.sensors.baro_flow, the same lines)."""
    v = math.sqrt(s[L.VEL] * s[L.VEL] + s[L.VEL + 1] * s[L.VEL + 1])
    return p[K_BARO_SPEED] * min(max((v - p[K_BARO_SPEED + 2]) * p[K_BARO_SPEED + 1], 0.0), 1.0)


@njit(**_HOT)
def _sensors(s, tbuf, p, step, w, k, due, x, env):
    """The sensor samples due at this step, of the true state after the step (attitude: R_TRUE)."""
    rt = L.R_TRUE
    R = (s[rt], s[rt + 1], s[rt + 2], s[rt + 3], s[rt + 4], s[rt + 5], s[rt + 6], s[rt + 7], s[rt + 8])
    delay = int(p[K_DELAY])
    # IMU: specific force and rates in the body frame, bias random walks
    a0, a1, a2 = s[L.VACC], s[L.VACC + 1], s[L.VACC + 2] - G
    fs = (a0 * R[0] + a1 * R[3] + a2 * R[6], a0 * R[1] + a1 * R[4] + a2 * R[7], a0 * R[2] + a1 * R[5] + a2 * R[8])
    if p[K_IMU_OFFSET + 3] != 0.0:  # the IMU's lever arm (SensorParams.imu_offset_m; physics.sensors.lever_arm)
        r0, r1, r2 = p[K_IMU_OFFSET], p[K_IMU_OFFSET + 1], p[K_IMU_OFFSET + 2]
        w0, w1, w2 = s[L.OMEGA], s[L.OMEGA + 1], s[L.OMEGA + 2]
        dt = p[K_DT]
        al0 = (w0 - s[L.PREV_OMEGA]) / dt
        al1 = (w1 - s[L.PREV_OMEGA + 1]) / dt
        al2 = (w2 - s[L.PREV_OMEGA + 2]) / dt
        s[L.PREV_OMEGA], s[L.PREV_OMEGA + 1], s[L.PREV_OMEGA + 2] = w0, w1, w2
        c0 = w1 * r2 - w2 * r1
        c1 = w2 * r0 - w0 * r2
        c2 = w0 * r1 - w1 * r0
        fs = (fs[0] + (al1 * r2 - al2 * r1 + (w1 * c2 - w2 * c1)),
              fs[1] + (al2 * r0 - al0 * r2 + (w2 * c0 - w0 * c2)),
              fs[2] + (al0 * r1 - al1 * r0 + (w0 * c1 - w1 * c0)))
    # motor vibration (white, or low-passed: SensorParams.*_noise_cutoff_hz), scaling with the rotors' mean speed
    # over the hover speed (physics.sensors)
    vib = (s[L.ROTOR] + s[L.ROTOR + 1] + s[L.ROTOR + 2] + s[L.ROTOR + 3]) / 4.0 * p[K_INV_HOVER_ROT]
    vib = max(min(vib / VIBRATION_FULL_FROM, 1.0), vib)
    for a in range(3):
        s[L.ACC_BIAS + a] = p[K_A_AB] * s[L.ACC_BIAS + a] + p[K_C_AB] * w[k, NZ_ACC_BIAS + a]
        s[L.GYRO_BIAS + a] = p[K_A_GB] * s[L.GYRO_BIAS + a] + p[K_C_GB] * w[k, NZ_GYRO_BIAS + a]
        # each vehicle's level (SensorParams.vibration_levels; 1 without): up to VIB_AS_FLEET as the fleet's, a rougher one's rest
        # at high frequency, the difference of this sample's draws and the last's (physics.sensors.Sensors.imu)
        la = s[L.VIB_LEVEL + a]
        wa = w[k, NZ_ACC + a]
        va = vib * min(la, VIB_AS_FLEET) * p[K_ACC_VIB + a]
        if p[K_ACC_LP + 5] != 0.0:  # coloured vibration, white sensor noise (SensorParams.accel_noise_cutoff_hz)
            na = p[K_C_AN + a] * wa + va * _lowpass(s, L.IMU_LOWPASS + 2 * a, p, K_ACC_LP, wa)
        else:
            na = math.sqrt(p[K_C_AN + a] * p[K_C_AN + a] + va * va) * wa
        if la > VIB_AS_FLEET:  # in the logged IMU only (_compose, _record_uorb)
            s[L.IMU_HF + a] = vib * math.sqrt(la * la - VIB_AS_FLEET * VIB_AS_FLEET) * p[K_ACC_VIB + a] * (
                (wa - s[L.PREV_DRAW + a]) * HF_NORM)
        s[L.PREV_DRAW + a] = wa
        s[L.ACC + a] = fs[a] + s[L.ACC_BIAS + a] + na
        lg = s[L.VIB_LEVEL + 3 + a]
        wg = w[k, NZ_GYRO + a]
        vg = vib * min(lg, VIB_AS_FLEET) * p[K_GYRO_VIB + a]
        if p[K_GYRO_LP + 5] != 0.0:
            ng = p[K_C_GN] * wg + vg * _lowpass(s, L.IMU_LOWPASS + 6 + 2 * a, p, K_GYRO_LP, wg)
        else:
            ng = math.sqrt(p[K_C_GN] * p[K_C_GN] + vg * vg) * wg
        if lg > VIB_AS_FLEET:
            s[L.IMU_HF + 3 + a] = vib * math.sqrt(lg * lg - VIB_AS_FLEET * VIB_AS_FLEET) * p[K_GYRO_VIB + a] * (
                (wg - s[L.PREV_DRAW + 3 + a]) * HF_NORM)
        s[L.PREV_DRAW + 3 + a] = wg
        s[L.GYRO + a] = s[L.OMEGA + a] + s[L.GYRO_BIAS + a] + ng
    if due[L.D_MAG, step]:
        m0, m1, m2 = p[K_MAG_FIELD], p[K_MAG_FIELD + 1], p[K_MAG_FIELD + 2]
        if env:
            m0, m1, m2 = m0 + x[L.X_MAG], m1 + x[L.X_MAG + 1], m2 + x[L.X_MAG + 2]
        s[L.MAG] = m0 * R[0] + m1 * R[3] + m2 * R[6] + p[K_MAG_NOISE] * w[k, NZ_MAG]
        s[L.MAG + 1] = m0 * R[1] + m1 * R[4] + m2 * R[7] + p[K_MAG_NOISE] * w[k, NZ_MAG + 1]
        s[L.MAG + 2] = m0 * R[2] + m1 * R[5] + m2 * R[8] + p[K_MAG_NOISE] * w[k, NZ_MAG + 2]
    if due[L.D_BARO, step]:
        alt = p[K_HOME_ALT] - s[L.POS + 2]
        wb = w[k, NZ_BARO]
        wander = 0.0
        if p[K_BARO_WANDER + 2] != 0.0:  # the slow error, on the same draw (physics.sensors.baro_wander_coefficients)
            s[L.BARO_WANDER] = p[K_BARO_WANDER] * s[L.BARO_WANDER] + p[K_BARO_WANDER + 1] * wb
            s[L.BARO_WANDER + 1] = p[K_BARO_WANDER] * s[L.BARO_WANDER + 1] + (1.0 - p[K_BARO_WANDER]) * s[L.BARO_WANDER]
            wander = s[L.BARO_WANDER + 1]
        if p[K_BARO_DOWNWASH] > 0.0:  # white sensor noise and the rotors' downwash (physics.sensors.Sensors.baro)
            ih = p[K_INV_HOVER_ROT]
            r0, r1, r2, r3 = s[L.ROTOR], s[L.ROTOR + 1], s[L.ROTOR + 2], s[L.ROTOR + 3]
            amp = p[K_BARO_DOWNWASH] * ((r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3) / 4.0 * (ih * ih))
            if p[K_BARO_SPEED] > 0.0:  # the noise in forward flight, in squares (physics.sensors.baro_flow)
                fl = _baro_flow(s, p)
                amp = math.sqrt(amp * amp + fl * fl)
            own = p[K_BARO_NOISE]
            if p[K_BARO_LP + 5] != 0.0:
                nb = own * wb + amp * _lowpass(s, L.BARO_LOWPASS, p, K_BARO_LP, wb)
            else:
                nb = math.sqrt(own * own + amp * amp) * wb
            s[L.PRESSURE] = SLP * (1.0 - 2.25577e-5 * alt) ** 5.25588 + s[L.BARO_OFFSET] + nb + wander
        else:
            if p[K_BARO_LP + 5] != 0.0:
                wb = _lowpass(s, L.BARO_LOWPASS, p, K_BARO_LP, wb)
            sigma = p[K_BARO_NOISE]
            if p[K_BARO_SPEED] > 0.0:
                fl = _baro_flow(s, p)
                sigma = math.sqrt(sigma * sigma + fl * fl)
            s[L.PRESSURE] = (SLP * (1.0 - 2.25577e-5 * alt) ** 5.25588 + s[L.BARO_OFFSET]
                             + sigma * wb + wander)
        s[L.BARO_TEMP] = s[L.SENSOR_TEMP] - 0.0065 * (-s[L.POS + 2]) + 0.05 * w[k, NZ_BARO + 1]
    if due[L.D_GPS, step]:
        old = (step + 1) % delay if step + 1 >= delay else 0
        sats = s[L.SATS_IN_VIEW]
        growth = 1.0
        if env:
            sats = x[L.X_GPS_SATS]
            growth = x[L.X_GPS_GROWTH]
        for a in range(3):
            # a smooth slow error: a first-order lag of a Gauss-Markov drive (physics.sensors.gps_error_coefficients)
            s[L.GPS_DRIVE + a] = p[K_GPS_A] * s[L.GPS_DRIVE + a] + p[K_GPS_BIAS_C + a] * w[k, NZ_GPS_BIAS + a]
            s[L.GPS_BIAS + a] = p[K_GPS_A] * s[L.GPS_BIAS + a] + (1.0 - p[K_GPS_A]) * s[L.GPS_DRIVE + a]
            white = p[K_GPS_WHITE + a] * w[k, NZ_GPS_POS + a]
            vel_noise = p[K_GPS_VEL_NOISE] * w[k, NZ_GPS_VEL + a]
            if env:
                white = white * growth
                vel_noise = vel_noise * growth
            s[L.GPS_POS + a] = tbuf[old, a] + s[L.GPS_BIAS + a] + white
            s[L.GPS_VEL + a] = tbuf[old, 3 + a] + vel_noise
        # the receiver's start (generator.physics.sensors.gps_quality): no fix, then satellites and accuracy settle
        after = max(step * p[K_DT] - s[L.GPS_FIX_AT], 0.0)
        sats = max(min(sats, s[L.SATS_IN_VIEW] - SATS_RAMP + math.floor(after)), 0.0)
        scale = 1.0 + EPH_SETTLE * math.exp(-after / EPH_SETTLE_TAU_S)
        s[L.GPS_EPH] = p[K_EPH0] * (12.0 / max(sats, 1.0)) * scale
        s[L.GPS_EPV] = p[K_EPV0] * (12.0 / max(sats, 1.0)) * scale
        s[L.GPS_SATS] = sats
        s[L.GPS_FIX] = 3.0
        if env:
            _gps_environment(s, x, sats, growth)
        if step * p[K_DT] < s[L.GPS_FIX_AT]:
            s[L.GPS_FIX] = 1.0
            s[L.GPS_EPH] = 99.99
            s[L.GPS_EPV] = 99.99


@njit(**_HOT)
def _gps_environment(s, x, sats, growth):
    """RF spoofing offsets and jamming: accuracy, and below 4 satellites no fix (the last fix held)."""
    for a in range(3):
        s[L.GPS_POS + a] = s[L.GPS_POS + a] + x[L.X_GPS_OFFSET + a]
        s[L.GPS_VEL + a] = s[L.GPS_VEL + a] + x[L.X_GPS_VEL_OFFSET + a]
    s[L.GPS_EPH] = s[L.GPS_EPH] * growth
    s[L.GPS_EPV] = s[L.GPS_EPV] * growth
    fixed = sats >= 4
    s[L.GPS_FIX] = 3.0 if fixed else 1.0
    if s[L.LAST_FIX_SET] < 0.5 or fixed:
        for a in range(3):
            s[L.LAST_FIX + a] = s[L.GPS_POS + a]
        s[L.LAST_FIX_SET] = 1.0
    if not fixed:
        for a in range(3):
            s[L.GPS_POS + a] = s[L.LAST_FIX + a]
            s[L.GPS_VEL + a] = 0.0
        s[L.GPS_EPH] = 99.99
        s[L.GPS_EPV] = 99.99


@njit(**_HOT)
def _propagate(s, a, an, on_ground, dt):
    """Inertial propagation of one axis with the NED acceleration ``an`` (before its bias)."""
    x = L.EST_X + 3 * a
    an = an - s[x + 2]
    if on_ground:
        an = 0.0
    s[L.EST_ACC + a] = an
    s[x] += s[x + 1] * dt + 0.5 * an * dt * dt
    s[x + 1] += an * dt


@njit(**_HOT)
def _predict(s, hist, p, step):
    """Attitude filter and the inertial propagation of the position/velocity filter."""
    dt = p[K_DT]
    R = _rot(s, L.EST_QUAT)
    a0, a1, a2 = s[L.ACC], s[L.ACC + 1], s[L.ACC + 2]
    norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    trust = 1.0 if abs(norm - G) < 0.15 * G else 0.0
    den = max(norm, 1e-6)
    md0, md1, md2 = -a0 / den, -a1 / den, -a2 / den
    ed0, ed1, ed2 = R[6], R[7], R[8]
    k = p[K_ATT_ACC_GAIN] * trust
    e0 = (md1 * ed2 - md2 * ed1) * k
    e1 = (md2 * ed0 - md0 * ed2) * k
    e2 = (md0 * ed1 - md1 * ed0) * k
    err = (e0, e1, e2)
    for a in range(3):
        s[L.EST_GYRO_BIAS + a] -= p[K_GYRO_BIAS_GAIN] * err[a] * dt
        s[L.EST_RATES + a] = s[L.GYRO + a] - s[L.EST_GYRO_BIAS + a]
    _quat_integrate(s, L.EST_QUAT, s[L.EST_RATES] + e0, s[L.EST_RATES + 1] + e1, s[L.EST_RATES + 2] + e2, dt)
    R = _rot(s, L.EST_QUAT)
    for j in range(9):
        s[L.R_CTRL + j] = R[j]
    on_ground = s[L.ARMED] < 0.5
    _propagate(s, 0, R[0] * a0 + R[1] * a1 + R[2] * a2, on_ground, dt)
    _propagate(s, 1, R[3] * a0 + R[4] * a1 + R[5] * a2, on_ground, dt)
    _propagate(s, 2, (R[6] * a0 + R[7] * a1 + R[8] * a2) + G, on_ground, dt)
    _kf_predict(s, L.P_H, p)
    _kf_predict(s, L.P_V, p)
    slot = step % int(p[K_DELAY])
    for a in range(3):
        hist[slot, a] = s[L.EST_X + 3 * a]
        hist[slot, 3 + a] = s[L.EST_X + 3 * a + 1]
    s[L.INERTIAL_ONLY_S] += dt
    for j in range(6):
        s[L.OUT_ERR + j] *= p[K_OUT_DECAY]
    s[L.SINCE_POS_FUSION_S] += dt


@njit(**_HOT)
def _fuse_mag(s, p):
    roll, pitch, yaw = _euler(s, L.EST_QUAT)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    m0, m1, m2 = s[L.MAG], s[L.MAG + 1], s[L.MAG + 2]
    mx = m0 * cp + m1 * sr * sp + m2 * cr * sp
    my = m1 * cr - m2 * sr
    yaw_mag = math.atan2(-my, mx) + p[K_DECL]
    err = _wrap_pi(yaw_mag - yaw)
    R = _rot(s, L.EST_QUAT)
    k = p[K_ATT_MAG_GAIN] * err
    _quat_integrate(s, L.EST_QUAT, R[6] * k, R[7] * k, R[8] * k, 0.01)


@njit(**_HOT)
def _commit(s, o, K0, K1, K2, row):
    """P = sym(P - K P[row, :]) for a scalar measurement of state ``row``."""
    h = o + 3 * row
    _commit2(s, o, K0, 0.0, K1, 0.0, K2, 0.0, s[h], s[h + 1], s[h + 2], 0.0, 0.0, 0.0)


@njit(**_HOT)
def _commit2(s, o, k00, k01, k10, k11, k20, k21, h00, h01, h02, h10, h11, h12):
    """P = sym(P - K (H P)) with K (3, 2) and H P (2, 3) given (a zero column/row for scalars)."""
    p00 = s[o] - (k00 * h00 + k01 * h10)
    p01 = s[o + 1] - (k00 * h01 + k01 * h11)
    p02 = s[o + 2] - (k00 * h02 + k01 * h12)
    p10 = s[o + 3] - (k10 * h00 + k11 * h10)
    p11 = s[o + 4] - (k10 * h01 + k11 * h11)
    p12 = s[o + 5] - (k10 * h02 + k11 * h12)
    p20 = s[o + 6] - (k20 * h00 + k21 * h10)
    p21 = s[o + 7] - (k20 * h01 + k21 * h11)
    p22 = s[o + 8] - (k20 * h02 + k21 * h12)
    s[o] = 0.5 * (p00 + p00)
    s[o + 1] = 0.5 * (p01 + p10)
    s[o + 2] = 0.5 * (p02 + p20)
    s[o + 3] = 0.5 * (p10 + p01)
    s[o + 4] = 0.5 * (p11 + p11)
    s[o + 5] = 0.5 * (p12 + p21)
    s[o + 6] = 0.5 * (p20 + p02)
    s[o + 7] = 0.5 * (p21 + p12)
    s[o + 8] = 0.5 * (p22 + p22)


@njit(**_HOT)
def _fuse_baro(s, p, ok):
    baro_alt = _altitude_at(s[L.PRESSURE])
    if math.isnan(s[L.BARO_HOME]) and ok:
        s[L.BARO_HOME] = baro_alt + s[L.EST_X + 6]
    meas = -(baro_alt - s[L.BARO_HOME])
    o = L.P_V
    S = s[o] + p[K_BARO_R]
    inv = 1.0 / S
    K0, K1, K2 = s[o] * inv, s[o + 3] * inv, s[o + 6] * inv
    innov = meas - s[L.EST_X + 6] if ok else 0.0
    gate = innov ** 2 <= p[K_GATE2] * S
    if ok and not gate:
        s[L.REJ_BARO] += 1.0
    if ok and gate:
        s[L.EST_X + 6] += K0 * innov
        s[L.EST_X + 7] += K1 * innov
        s[L.EST_X + 8] += K2 * innov
        _commit(s, o, K0, K1, K2, 0)


@njit(**_HOT)
def _fuse_gps(s, hist, p, step, usable):
    old = (step + 1) % int(p[K_DELAY])
    gate2 = p[K_GATE2]
    o = L.P_H
    # S = H P H^T + R for H = [[1, 0, 0], [0, 1, 0]]; K = P H^T S^-1
    s00, s01 = s[o] + p[K_GPS_POS_R], s[o + 1]
    s10, s11 = s[o + 3], s[o + 4] + p[K_GPS_VEL_R]
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    k00 = s[o] * i00 + s[o + 1] * i10
    k01 = s[o] * i01 + s[o + 1] * i11
    k10 = s[o + 3] * i00 + s[o + 4] * i10
    k11 = s[o + 3] * i01 + s[o + 4] * i11
    k20 = s[o + 6] * i00 + s[o + 7] * i10
    k21 = s[o + 6] * i01 + s[o + 7] * i11
    ip0 = s[L.GPS_POS] - hist[old, 0]
    ip1 = s[L.GPS_POS + 1] - hist[old, 1]
    iv0 = s[L.GPS_VEL] - hist[old, 3]
    iv1 = s[L.GPS_VEL + 1] - hist[old, 4]
    ivz = s[L.GPS_VEL + 2] - hist[old, 5]
    pos_gate = ip0 ** 2 + ip1 ** 2 <= gate2 * s00
    vel_gate = (iv0 ** 2 + iv1 ** 2) + ivz ** 2 <= gate2 * s11
    pos_ok = usable and pos_gate
    vel_ok = usable and vel_gate
    if usable and not pos_gate:
        s[L.REJ_GPS_POS] += 1.0
    if usable and not vel_gate:
        s[L.REJ_GPS_VEL] += 1.0
    if not pos_ok:
        ip0 = ip1 = 0.0
    if not vel_ok:
        iv0 = iv1 = ivz = 0.0
    if pos_ok or vel_ok:
        x = L.EST_X
        s[x] += ip0 * k00 + iv0 * k01
        s[x + 1] += ip0 * k10 + iv0 * k11
        s[x + 2] += ip0 * k20 + iv0 * k21
        s[x + 3] += ip1 * k00 + iv1 * k01
        s[x + 4] += ip1 * k10 + iv1 * k11
        s[x + 5] += ip1 * k20 + iv1 * k21
        _commit2(s, o, k00, k01, k10, k11, k20, k21, s[o], s[o + 1], s[o + 2], s[o + 3], s[o + 4], s[o + 5])
        s[L.INERTIAL_ONLY_S] = 0.0
    if pos_ok:
        s[L.SINCE_POS_FUSION_S] = 0.0
    rt = p[K_RESET_TIMEOUT]
    if usable and (s[L.SINCE_POS_FUSION_S] > 2 * rt or s[L.INERTIAL_ONLY_S] > rt):
        with_vel = s[L.INERTIAL_ONLY_S] > rt
        for a in range(2):
            s[L.EST_X + 3 * a] = s[L.GPS_POS + a]
            if with_vel:
                s[L.EST_X + 3 * a + 1] = s[L.GPS_VEL + a]
        s[L.SINCE_POS_FUSION_S] = 0.0
        s[L.INERTIAL_ONLY_S] = 0.0
        s[L.GPS_RESETS] += 1.0
        for k in range(3):
            s[o + k] = 0.0
            s[o + 3 * k] = 0.0
        s[o] = p[K_GPS_POS_R]
    # vertical velocity, H = [0, 1, 0]
    ov = L.P_V
    inv = 1.0 / (s[ov + 4] + p[K_GPS_VEL_R])
    K0, K1, K2 = s[ov + 1] * inv, s[ov + 4] * inv, s[ov + 7] * inv
    s[L.EST_X + 6] += ivz * K0
    s[L.EST_X + 7] += ivz * K1
    s[L.EST_X + 8] += ivz * K2
    if vel_ok:
        _commit(s, ov, K0, K1, K2, 1)


@njit(**_HOT)
def _estimate(s, hist, p, step, due, mag_ok, baro_ok, gps_ok):
    _predict(s, hist, p, step)
    x = L.EST_X
    p0, v0, p1, v1, p2, v2 = s[x], s[x + 1], s[x + 3], s[x + 4], s[x + 6], s[x + 7]
    if due[L.D_MAG, step] and mag_ok:
        _fuse_mag(s, p)
    if due[L.D_BARO, step]:
        _fuse_baro(s, p, baro_ok)
    if due[L.D_GPS, step]:
        usable = (s[L.GPS_FIX] >= 3 and s[L.GPS_SATS] >= p[K_MIN_SATS] and s[L.GPS_EPH] <= p[K_MAX_EPH]
                  and gps_ok and step * p[K_DT] >= s[L.GPS_ORIGIN_AT])
        _fuse_gps(s, hist, p, step, usable)
    # the output predictor takes this step's corrections in over output_tau_s (Estimator.end_fusion)
    o = L.OUT_ERR
    s[o] -= s[x] - p0
    s[o + 1] -= s[x + 1] - v0
    s[o + 2] -= s[x + 3] - p1
    s[o + 3] -= s[x + 4] - v1
    s[o + 4] -= s[x + 6] - p2
    s[o + 5] -= s[x + 7] - v2


@njit(**_HOT)
def _out(s, a, c):
    """The output predictor's position (c = 0) or velocity (c = 1) on axis ``a`` (Estimator.output)."""
    return s[L.EST_X + 3 * a + c] + s[L.OUT_ERR + 2 * a + c]


@njit(**_HOT)
def _compose(s, p, topic, out, m):
    """One telemetry message of the flight into ``out`` (field order of scart_bench.dataset.schema)."""
    if topic == L.D_ATT:
        r, pi, y = _euler(s, L.EST_QUAT)
        out[m, 0], out[m, 1], out[m, 2] = r, pi, y
        for a in range(3):
            out[m, 3 + a] = s[L.EST_RATES + a]
    elif topic == L.D_IMU:
        for a in range(3):  # the logged IMU: a rough vehicle's high-frequency vibration on top (0 without)
            out[m, a] = s[L.ACC + a] + s[L.IMU_HF + a]
            out[m, 3 + a] = s[L.GYRO + a] + s[L.IMU_HF + 3 + a]
            out[m, 6 + a] = s[L.MAG + a]
        out[m, 9] = s[L.PRESSURE] / 100.0
        out[m, 10] = _altitude_at(s[L.PRESSURE])
        out[m, 11] = s[L.BARO_TEMP]
    elif topic == L.D_GPI:
        lat, lon = _latlon(p, _out(s, 0, 0), _out(s, 1, 0))
        _, _, yaw = _euler(s, L.EST_QUAT)
        out[m, 0], out[m, 1] = lat, lon
        out[m, 2] = p[K_HOME_ALT] - _out(s, 2, 0)
        out[m, 3] = -_out(s, 2, 0)
        for a in range(3):
            out[m, 4 + a] = _out(s, a, 1)
        out[m, 7] = yaw % TWO_PI
    elif topic == L.D_LPN:
        for a in range(3):
            out[m, a] = _out(s, a, 0)
            out[m, 3 + a] = _out(s, a, 1)
    elif topic == L.D_GPSRAW:
        lat, lon = _latlon(p, s[L.GPS_POS], s[L.GPS_POS + 1])
        v0, v1, v2 = s[L.GPS_VEL], s[L.GPS_VEL + 1], s[L.GPS_VEL + 2]
        out[m, 0], out[m, 1] = lat, lon
        out[m, 2] = p[K_HOME_ALT] - s[L.GPS_POS + 2]
        out[m, 3], out[m, 4] = s[L.GPS_EPH], s[L.GPS_EPV]
        out[m, 5] = math.hypot(v0, v1)
        out[m, 6] = math.atan2(v1, v0) % TWO_PI
        out[m, 7], out[m, 8], out[m, 9] = v0, v1, v2
        out[m, 10], out[m, 11] = s[L.GPS_FIX], s[L.GPS_SATS]
    elif topic == L.D_PRESS:
        out[m, 0] = s[L.PRESSURE] / 100.0
        out[m, 1] = s[L.BARO_TEMP]
    elif topic == L.D_ALT:
        out[m, 0] = p[K_HOME_ALT] - _out(s, 2, 0)
        out[m, 1] = -_out(s, 2, 0)
        out[m, 2] = -_out(s, 2, 0)
    elif topic == L.D_BAT:
        for a in range(3):
            out[m, a] = s[L.BATTERY + a]


@njit(**_HOT)
def _receive(s, topic, vals, m):
    """The navigator takes in a (delivered) telemetry message."""
    if topic == L.D_LPN:
        for a in range(3):
            s[L.NAV_POS + a] = vals[m, a]
            s[L.NAV_VEL + a] = vals[m, 3 + a]
    elif topic == L.D_ATT:
        s[L.NAV_YAW] = vals[m, 2]


@njit(**_HOT)
def _navigate(s, wps, p, t, out, m):
    """The navigator's mission state machine: the setpoint message (vx, vy, vz, yaw, seq, armed).

    ``wps`` (K, 6): per item north, east, down, speed of the leg to it, hold at it (s), braking deceleration
    towards it (m/s^2; 0: none; negative: a fly-through item accepted within -braking m)."""
    k_last = int(s[L.NAV_LAST])
    armed = 1.0 if t >= s[L.ARM_AT] else 0.0
    if s[L.PHASE] == PH_IDLE and t >= s[L.ARM_AT] + p[K_TAKEOFF_AFTER_ARM]:
        s[L.PHASE] = PH_TAKEOFF
    phase = s[L.PHASE]
    seq = int(s[L.SEQ])
    ti = min(seq, k_last)
    d0 = wps[ti, 0] - s[L.NAV_POS]
    d1 = wps[ti, 1] - s[L.NAV_POS + 1]
    d2 = wps[ti, 2] - s[L.NAV_POS + 2]
    dist_h = math.hypot(d0, d1)
    flying = phase == PH_TAKEOFF or phase == PH_MISSION
    # a fly-through item (braking < 0: an orbit's points, a pilot's stick) is passed at its leg's speed
    speed = wps[ti, 3] if wps[ti, 5] < 0.0 else min(wps[ti, 3], p[K_APPROACH] * dist_h)
    if wps[ti, 5] > 0.0:  # a mission file's item: slow down so as to stop there
        speed = min(speed, math.sqrt(2.0 * wps[ti, 5] * dist_h))
    if phase == PH_TAKEOFF:
        speed = min(speed, 1.0)
    den = max(dist_h, 1e-6)
    dir0, dir1 = d0 / den, d1 / den
    vh0, vh1 = dir0 * speed, dir1 * speed
    pi_ = min(max(seq - 1, 0), k_last)
    leg0 = wps[ti, 0] - wps[pi_, 0]
    leg1 = wps[ti, 1] - wps[pi_, 1]
    leg_len = math.sqrt(leg0 * leg0 + leg1 * leg1)
    ll = max(leg_len, 1e-6)
    u0, u1 = leg0 / ll, leg1 / ll
    nrm0, nrm1 = -u1, u0
    xt = (s[L.NAV_POS] - wps[pi_, 0]) * nrm0 + (s[L.NAV_POS + 1] - wps[pi_, 1]) * nrm1
    on_leg = phase == PH_MISSION and leg_len > 1.0
    if on_leg:
        s[L.XT_INT] = _clip(s[L.XT_INT] + xt * NAV_DT * (1.0 if abs(xt) < 5.0 else 0.0), -10.0, 10.0)
    else:
        s[L.XT_INT] = 0.0
    side = _clip(-(0.8 * xt + 0.3 * s[L.XT_INT]), -0.7 * speed, 0.7 * speed)
    along = math.sqrt(max(speed ** 2 - side ** 2, 0.0))
    if on_leg:
        if wps[ti, 5] < 0.0:  # a fly-through leg: along the line itself (its end is passed, not aimed at)
            dir0, dir1 = u0, u1
        vh0 = along * dir0 + side * nrm0
        vh1 = along * dir1 + side * nrm1
    vz = _clip(1.0 * d2, -p[K_CLIMB], 1.5)
    if flying:
        out[m, 0], out[m, 1], out[m, 2] = vh0, vh1, vz
    else:
        out[m, 0], out[m, 1], out[m, 2] = 0.0, 0.0, 0.0
    if flying and dist_h > 3.0 and phase == PH_MISSION:  # turning no faster than MPC_YAWRAUTO_MAX
        turn_by = _clip(_wrap_pi(math.atan2(d1, d0) - s[L.NAV_YAW_SP]), -p[K_YAW_STEP], p[K_YAW_STEP])
        s[L.NAV_YAW_SP] = _wrap_pi(s[L.NAV_YAW_SP] + turn_by)
    near = dist_h < (-wps[ti, 5] if wps[ti, 5] < 0.0 else p[K_ACCEPT])
    if wps[ti, 5] < 0.0 and on_leg:  # a fly-through item is also passed once the vehicle is abreast of it
        near = near or (s[L.NAV_POS] - wps[pi_, 0]) * u0 + (s[L.NAV_POS + 1] - wps[pi_, 1]) * u1 >= leg_len
    reached = flying and near and abs(d2) < 0.5
    tk = reached and phase == PH_TAKEOFF
    if tk and s[L.HOLD_UNTIL] == 0:
        s[L.HOLD_UNTIL] = t + p[K_TAKEOFF_HOLD]
    go = tk and s[L.HOLD_UNTIL] > 0 and t >= s[L.HOLD_UNTIL]
    if go:
        s[L.PHASE] = PH_MISSION
        s[L.SEQ] += 1.0
        s[L.HOLD_UNTIL] = -1.0  # no hold begun at the next item
    adv = reached and s[L.PHASE] == PH_MISSION and not go
    if adv and wps[ti, 4] > 0.0:  # a hold time: stay from the item's arrival until it has passed
        if s[L.HOLD_UNTIL] < 0.0:
            s[L.HOLD_UNTIL] = t + wps[ti, 4]
        adv = t >= s[L.HOLD_UNTIL]
    last = adv and s[L.SEQ] >= k_last
    if adv and not last:
        s[L.SEQ] += 1.0
        s[L.HOLD_UNTIL] = -1.0
    if last:
        s[L.PHASE] = PH_LAND
    if s[L.PHASE] == PH_LAND:
        out[m, 0] = _clip(1.0 * (wps[k_last, 0] - s[L.NAV_POS]), -1.0, 1.0)
        out[m, 1] = _clip(1.0 * (wps[k_last, 1] - s[L.NAV_POS + 1]), -1.0, 1.0)
        out[m, 2] = 1.5 if -s[L.NAV_POS + 2] > 3.0 else p[K_LAND_SPEED]
    out[m, 3] = s[L.NAV_YAW_SP]
    out[m, 4] = s[L.SEQ]
    out[m, 5] = armed


@njit(**_HOT)
def _vel_axis(s, p, a, dv, armed, dt):
    """Slewed setpoint, error, derivative and PID acceleration of one axis."""
    s[L.CTRL_VEL_SP + a] = s[L.CTRL_VEL_SP + a] + dv if armed else 0.0
    err = s[L.CTRL_VEL_SP + a] - _out(s, a, 1)
    d_err = (err - s[L.PREV_VEL_ERR + a]) / dt
    s[L.PREV_VEL_ERR + a] = err
    acc = p[K_VEL_P + a] * err + p[K_VEL_I + a] * s[L.VEL_INT + a]
    if a < 2:
        acc += p[K_VEL_XY_D] * d_err
    return err, acc


@njit(**_HOT)
def _pilot_stick(s, p, lag_axis, level):
    """One stick of the pilot in attitude mode (generator.flight_software.pilot.Pilot.step, the same lines):
    four xorshift32 uniforms to a normal, through the two lags, scaled."""
    x, n = _xorshift_normal(int(s[L.PILOT_RNG]))
    s[L.PILOT_RNG] = x
    z = L.PILOT_LAG + 2 * lag_axis
    s[z] = p[K_PILOT + 4] * s[z] + p[K_PILOT + 5] * n
    s[z + 1] = p[K_PILOT + 4] * s[z + 1] + p[K_PILOT + 5] * s[z]
    if p[K_PILOT_HP + 3] != 0.0:  # band-pass: the lags' output minus its own slow lag
        h = L.PILOT_HP + lag_axis
        s[h] = p[K_PILOT_HP] * s[h] + p[K_PILOT_HP + 1] * s[z + 1]
        return p[K_PILOT + lag_axis] * p[K_PILOT_HP + 2] * (s[z + 1] - s[h]) * level
    return p[K_PILOT + lag_axis] * p[K_PILOT + 6] * s[z + 1] * level


@njit(**_HOT)
def _velocity_control(s, p):
    """Velocity setpoint -> thrust vector -> attitude setpoint and collective thrust (50 Hz)."""
    dt = NAV_DT
    armed = s[L.ARMED] > 0.5
    if armed and s[L.SETPOINT_IN + 2] < -TAKEOFF_CLIMB:
        s[L.TOOK_OFF] = 1.0
    idle = armed and s[L.TOOK_OFF] < 0.5  # armed on the ground before the take-off: motors at idle
    roll_stick, pitch_stick, yaw_stick, throttle = 0.0, 0.0, 0.0, 0.0
    if p[K_PILOT + 8] != 0.0:  # the pilot's sticks (MissionParams.pilot_*), at the slewed setpoint of the last tick
        alt = -_out(s, 2, 0)
        vsp = math.sqrt(s[L.CTRL_VEL_SP] ** 2 + s[L.CTRL_VEL_SP + 1] ** 2)
        level = _clip((alt - 1.0) / 2.0, 0.0, 1.0)
        level = level * (p[K_PILOT + 7] + (1.0 - p[K_PILOT + 7]) * min(vsp / 1.0, 1.0)) * s[L.PILOT_GAIN]
        roll_stick = _pilot_stick(s, p, 0, level)
        pitch_stick = _pilot_stick(s, p, 1, level)
        yaw_stick = _pilot_stick(s, p, 2, level)
        throttle = _pilot_stick(s, p, 3, level)
    dv0 = s[L.SETPOINT_IN] - s[L.CTRL_VEL_SP]
    dv1 = s[L.SETPOINT_IN + 1] - s[L.CTRL_VEL_SP + 1]
    dv2 = s[L.SETPOINT_IN + 2] - s[L.CTRL_VEL_SP + 2]
    dvh = math.sqrt(dv0 * dv0 + dv1 * dv1)
    lim = p[K_ACC_HOR_DT]
    if dvh > lim:
        f = lim / max(dvh, 1e-9)
        dv0 *= f
        dv1 *= f
    dv2 = _clip(dv2, -p[K_ACC_VERT_DT], p[K_ACC_VERT_DT])
    err0, acc0 = _vel_axis(s, p, 0, dv0, armed, dt)
    err1, acc1 = _vel_axis(s, p, 1, dv1, armed, dt)
    err2, acc2 = _vel_axis(s, p, 2, dv2, armed, dt)
    if p[K_PILOT + 8] != 0.0:
        a_fwd, a_right = -G * pitch_stick, G * roll_stick
        cy, sy = math.cos(s[L.SETPOINT_IN + 3]), math.sin(s[L.SETPOINT_IN + 3])
        acc0 += cy * a_fwd - sy * a_right
        acc1 += sy * a_fwd + cy * a_right
        acc2 -= throttle
    lift = max(G - acc2, 0.3 * G)
    h = math.sqrt(acc0 * acc0 + acc1 * acc1)
    h_max = lift * p[K_TAN_TILT]
    sc = h_max / max(h, 1e-9) if h > h_max else 1.0
    acc0 *= sc
    acc1 *= sc
    saturated = sc < 1.0
    arm = 1.0 if armed and not idle else 0.0
    u0 = 0.0 if saturated else err0 * dt
    u1 = 0.0 if saturated else err1 * dt
    s[L.VEL_INT] = _clip(s[L.VEL_INT] + u0 * arm, -3.0, 3.0)
    s[L.VEL_INT + 1] = _clip(s[L.VEL_INT + 1] + u1 * arm, -3.0, 3.0)
    s[L.VEL_INT + 2] = _clip(s[L.VEL_INT + 2] + err2 * dt * arm, -3.0, 3.0)
    f0, f1 = acc0, acc1
    f2 = min(acc2 - G, -0.3 * G)
    fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    b0, b1, b2 = -f0 / fn, -f1 / fn, -f2 / fn
    yaw = s[L.SETPOINT_IN + 3] + yaw_stick
    x0, x1, x2 = math.cos(yaw), math.sin(yaw), 0.0
    y0 = b1 * x2 - b2 * x1
    y1 = b2 * x0 - b0 * x2
    y2 = b0 * x1 - b1 * x0
    yn = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    y0, y1, y2 = y0 / yn, y1 / yn, y2 / yn
    c0 = y1 * b2 - y2 * b1
    c1 = y2 * b0 - y0 * b2
    c2 = y0 * b1 - y1 * b0
    a = L.ATT_SP
    s[a], s[a + 1], s[a + 2], s[a + 3], s[a + 4], s[a + 5], s[a + 6], s[a + 7], s[a + 8] = (
        c0, y0, b0, c1, y1, b1, c2, y2, b2)
    r = L.R_CTRL
    thrust = p[K_MASS] * (f0 * -s[r + 2] + f1 * -s[r + 5] + f2 * -s[r + 8])
    s[L.THRUST_SP] = p[K_THRUST_LO] if idle else _clip(thrust, p[K_THRUST_LO], p[K_THRUST_HI])


@njit(**_HOT)
def _land_detector(s, p):
    evidence = (s[L.ARMED] > 0.5 and s[L.SETPOINT_IN + 2] > 0.1 and abs(_out(s, 2, 1)) < 0.25
                and s[L.THRUST_SP] < 0.7 * p[K_HOVER])
    s[L.LAND_TIME] = s[L.LAND_TIME] + NAV_DT if evidence else 0.0
    if s[L.LAND_TIME] >= p[K_LAND_DETECT]:
        s[L.DISARMED] = 1.0
        s[L.ARMED] = 0.0
        s[L.VEL_INT], s[L.VEL_INT + 1], s[L.VEL_INT + 2] = 0.0, 0.0, 0.0


@njit(**_HOT)
def _attitude_control(s, p):
    e0 = 0.5 * (_ata(s, 2, 1) - _ata(s, 1, 2))
    e1 = 0.5 * (_ata(s, 0, 2) - _ata(s, 2, 0))
    e2 = 0.5 * (_ata(s, 1, 0) - _ata(s, 0, 1))
    s[L.RATE_SP] = _clip(-p[K_ATT_P] * e0, -p[K_RATE_MAX], p[K_RATE_MAX])
    s[L.RATE_SP + 1] = _clip(-p[K_ATT_P + 1] * e1, -p[K_RATE_MAX + 1], p[K_RATE_MAX + 1])
    s[L.RATE_SP + 2] = _clip(-p[K_ATT_P + 2] * e2, -p[K_RATE_MAX + 2], p[K_RATE_MAX + 2])


@njit(**_HOT)
def _ata(s, r, c):
    """(Rd^T R)[r, c] of the attitude setpoint Rd and the estimated attitude R."""
    d, e = L.ATT_SP, L.R_CTRL
    return s[d + r] * s[e + c] + s[d + 3 + r] * s[e + 3 + c] + s[d + 6 + r] * s[e + 6 + c]


@njit(**_HOT)
def _control(s, p, step, due, sp, m_sp, sp_ok, w, k, rec_truth, m_truth, x, env):
    """Setpoint in, controllers, battery, truth, end of flight (after the navigator)."""
    if due[L.D_SETPOINT, step]:
        if sp_ok:
            for c in range(6):
                s[L.SETPOINT_IN + c] = sp[m_sp, c]
        arm = s[L.SETPOINT_IN + 5] > 0.5 and s[L.DISARMED] < 0.5 and s[L.DONE] < 0.5
        s[L.ARMED] = 1.0 if arm else 0.0
        R = _rot(s, L.EST_QUAT)
        for j in range(9):
            s[L.R_CTRL + j] = R[j]
        _velocity_control(s, p)
        _land_detector(s, p)
    _attitude_control(s, p)
    if due[L.D_BAT, step]:
        power = 0.0
        for r in range(4):
            th = p[K_KF] * s[L.ROTOR + r] ** 2
            power += max(th, 0.0) ** 1.5
        power = BATTERY_POWER_K * power + BATTERY_IDLE_W
        ocv = BATTERY_OCV_V + BATTERY_OCV_SPAN_V * s[L.BATTERY + 2]
        current = power / max(ocv, 1.0)
        s[L.BATTERY + 2] = _clip(s[L.BATTERY + 2] - current * BATTERY_STEP_S / (BATTERY_CAPACITY_AH * 3600), 0.0, 1.0)
        s[L.BATTERY] = ocv - BATTERY_R_OHM * current + BATTERY_NOISE_V * w[k, NZ_BATTERY]
        if env:
            s[L.BATTERY] -= x[L.X_BATTERY_SAG]
        s[L.BATTERY + 1] = current
    if due[L.D_TRUTH, step]:
        roll, pitch, yaw = _euler(s, L.QUAT)
        for a in range(3):
            rec_truth[m_truth, a] = s[L.POS + a]
            rec_truth[m_truth, 3 + a] = s[L.VEL + a]
        rec_truth[m_truth, 6], rec_truth[m_truth, 7], rec_truth[m_truth, 8] = roll, pitch, yaw
        rec_truth[m_truth, 9] = s[L.ARMED]
        rec_truth[m_truth, 10] = s[L.ON_GROUND]
    # end of flight: landed and disarmed, or crashed
    if step % CRASH_CHECK_STEPS == 0 and s[L.DONE] < 0.5:
        roll, pitch, _ = _euler(s, L.QUAT)
        ground = s[L.ON_GROUND] > 0.5
        crashed = (abs(roll) > CRASH_TILT_RAD or abs(pitch) > CRASH_TILT_RAD) and not ground
        a0, a1, a2 = s[L.VACC], s[L.VACC + 1], s[L.VACC + 2]
        crashed = crashed or (ground and math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) > CRASH_GROUND_HOVERS * p[K_HOVER])
        if crashed:
            s[L.STATUS] = 2.0
            s[L.DISARMED] = 1.0
            s[L.ARMED] = 0.0
    if s[L.DONE] < 0.5 and s[L.DISARMED] > 0.5 and s[L.LANDED_AT] < 0:
        s[L.LANDED_AT] = step
        if s[L.STATUS] == 0.0:
            s[L.STATUS] = 1.0
    if s[L.DONE] < 0.5 and s[L.LANDED_AT] >= 0 and step >= s[L.LANDED_AT] + p[K_TAIL]:
        s[L.EXIT_STEP] = step
        s[L.DONE] = 1.0


@njit(**_HOT)
def _telemetry(s, p, step, due, mi, r0, r1, r2, r3, r4, r5, r6, r7, receive):
    """Compose the telemetry due at this step into the recordings; the navigator takes it in."""
    if due[L.D_ATT, step]:
        _compose(s, p, L.D_ATT, r0, mi[L.D_ATT, step])
    if due[L.D_IMU, step]:
        _compose(s, p, L.D_IMU, r1, mi[L.D_IMU, step])
    if due[L.D_GPI, step]:
        _compose(s, p, L.D_GPI, r2, mi[L.D_GPI, step])
    if due[L.D_LPN, step]:
        _compose(s, p, L.D_LPN, r3, mi[L.D_LPN, step])
    if due[L.D_GPSRAW, step]:
        _compose(s, p, L.D_GPSRAW, r4, mi[L.D_GPSRAW, step])
    if due[L.D_PRESS, step]:
        _compose(s, p, L.D_PRESS, r5, mi[L.D_PRESS, step])
    if due[L.D_ALT, step]:
        _compose(s, p, L.D_ALT, r6, mi[L.D_ALT, step])
    if due[L.D_BAT, step]:
        _compose(s, p, L.D_BAT, r7, mi[L.D_BAT, step])
    if receive:
        if due[L.D_ATT, step]:
            _receive(s, L.D_ATT, r0, mi[L.D_ATT, step])
        if due[L.D_LPN, step]:
            _receive(s, L.D_LPN, r3, mi[L.D_LPN, step])


@njit(**_HOT)
def _record_uorb(s, p, step, due, mi, u0, u1, u2, u3):
    """The flight controller's streams due at this step, after the estimator (generator.telemetry.schedule.
    UORB_STREAMS): the IMU sample it received, its attitude, its output position and velocity, the mixer."""
    if due[L.D_U_IMU, step]:
        m = mi[L.D_U_IMU, step]
        for a in range(3):
            u0[m, a] = s[L.ACC + a] + s[L.IMU_HF + a]
            u0[m, 3 + a] = s[L.GYRO + a] + s[L.IMU_HF + 3 + a]
    if due[L.D_U_ATT, step]:
        m = mi[L.D_U_ATT, step]
        for c in range(4):
            u1[m, c] = s[L.EST_QUAT + c]
    if due[L.D_U_LPOS, step]:
        m = mi[L.D_U_LPOS, step]
        for a in range(3):
            u2[m, a] = _out(s, a, 0)
            u2[m, 3 + a] = _out(s, a, 1)
    if due[L.D_U_ACT, step]:
        m = mi[L.D_U_ACT, step]
        armed = s[L.ARMED]
        for r in range(4):
            u3[m, r] = (s[L.MOTOR_CMD + r] / p[K_MAXROT]) ** 2
        u3[m, 4] = s[L.THRUST_SP] / (4.0 * p[K_MAX_THRUST]) * armed
        u3[m, 5] = armed


@njit(**_HOT)
def _step(s, tbuf, hist, wps, p, step, w, k, due, mi, r0, r1, r2, r3, r4, r5, r6, r7, rec_sp, rec_truth, x,
          u0, u1, u2, u3):
    """One whole step of one flight with no attack layer (noise: w[k])."""
    _sense(s, tbuf, p, step, w, k, due, x, False)
    _estimate(s, hist, p, step, due, True, True, True)
    _record_uorb(s, p, step, due, mi, u0, u1, u2, u3)
    _telemetry(s, p, step, due, mi, r0, r1, r2, r3, r4, r5, r6, r7, True)
    m_sp = mi[L.D_SETPOINT, step]
    if due[L.D_SETPOINT, step]:
        _navigate(s, wps, p, step * p[K_DT], rec_sp, m_sp)
    _control(s, p, step, due, rec_sp, m_sp, True, w, k, rec_truth, mi[L.D_TRUTH, step], x, False)


# -- batch entry points ------------------------------------------------------------------------------
@njit(**_JIT)
def _fly(S, tbuf, hist, wps, p, i, nz, s0, s1, k0, due, mi, r0, r1, r2, r3, r4, r5, r6, r7, rec_sp, rec_truth,
         u0, u1, u2, u3):
    """Flight ``i`` through steps [s0, s1) (noise of step s: nz[k0 + s - s0]); stops when it ends."""
    s = S[i]
    tb, hs, wp = tbuf[i], hist[i], wps[i]
    x = np.zeros(L.X_WIDTH)  # no physical disturbances in whole steps
    q0, q1, q2, q3, q4, q5, q6, q7 = r0[:, i], r1[:, i], r2[:, i], r3[:, i], r4[:, i], r5[:, i], r6[:, i], r7[:, i]
    rsp, rtr = rec_sp[:, i], rec_truth[:, i]
    v0, v1, v2, v3 = u0[:, i], u1[:, i], u2[:, i], u3[:, i]
    for step in range(s0, s1):
        if s[L.DONE] > 0.5:
            break
        _step(s, tb, hs, wp, p, step, nz, k0 + step - s0, due, mi, q0, q1, q2, q3, q4, q5, q6, q7, rsp, rtr, x,
              v0, v1, v2, v3)


@njit(parallel=True, **_JIT)
def run_steps(S, tbuf, hist, wps, p, rows, s0, s1, noise, k0, due, mi, r0, r1, r2, r3, r4, r5, r6, r7,
              rec_sp, rec_truth, u0, u1, u2, u3, states, draw):
    """Fly flights ``rows`` through steps [s0, s1), in parallel; a flight that finishes stops.

    noise: (flights, block, dim); step ``s`` of flight ``rows[j]`` uses noise[j, k0 + s - s0].
    u0..u3: the uORB streams' recordings (no rows when the flights are flown without the uORB view).
    draw > 0: first draw each flight's next ``draw`` steps of noise into its rows of ``noise`` from
    its PCG64 state in ``states`` (pcg_noise), in the thread that flies it, while they are in cache.
    """
    for j in prange(rows.shape[0]):
        if draw > 0:
            fill_one(states, rows[j], noise[j, :draw])
        _fly(S, tbuf, hist, wps, p, rows[j], noise[j], s0, s1, k0, due, mi, r0, r1, r2, r3, r4, r5, r6, r7,
             rec_sp, rec_truth, u0, u1, u2, u3)


@njit(**_JIT)
def run_steps_serial(S, tbuf, hist, wps, p, rows, s0, s1, noise, k0, due, mi, r0, r1, r2, r3, r4, r5, r6,
                     r7, rec_sp, rec_truth, u0, u1, u2, u3, states, draw):
    """run_steps in the calling thread: for a few steps between the layer's hooks, where starting
    the worker threads would cost more than the steps."""
    for j in range(rows.shape[0]):
        if draw > 0:
            fill_one(states, rows[j], noise[j, :draw])
        _fly(S, tbuf, hist, wps, p, rows[j], noise[j], s0, s1, k0, due, mi, r0, r1, r2, r3, r4, r5, r6, r7,
             rec_sp, rec_truth, u0, u1, u2, u3)


# Stages of one step, for the steps where the SCART layer sees messages. They run in the calling
# thread: the work per call is a single step of the batch.
@njit(**_JIT)
def stage_sense(S, tbuf, p, rows, step, noise, due):
    """Wind, dynamics and sensor samples of one step (noise: (rows, dim))."""
    x = np.zeros(L.X_WIDTH)
    for j in range(rows.shape[0]):
        i = rows[j]
        _sense(S[i], tbuf[i], p, step, noise, j, due, x, False)


@njit(**_HOT)
def stage_physics(S, tbuf, p, rows, step, noise, X):
    """Wind, rate control and dynamics under the physical disturbances X (N, X_WIDTH)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _physics(S[i], tbuf[i], p, step, noise, j, X[i], True)


@njit(**_HOT)
def stage_sensors(S, tbuf, p, rows, step, noise, due, X):
    """The sensor samples due, under the physical disturbances X (magnetic field, GPS signals)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _sensors(S[i], tbuf[i], p, step, noise, j, due, X[i], True)


@njit(**_HOT)
def stage_estimate(S, hist, p, rows, step, due, mag_ok, baro_ok, gps_ok):
    """The estimator's step; ``*_ok`` (N,): the sample reached it (undelivered samples are not fused)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _estimate(S[i], hist[i], p, step, due, mag_ok[i], baro_ok[i], gps_ok[i])


@njit(**_HOT)
def stage_record_uorb(S, p, rows, step, due, mi, u0, u1, u2, u3):
    """Record the uORB streams due at this step (for ``rows``), after the estimator's stage."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _record_uorb(S[i], p, step, due, mi, u0[:, i], u1[:, i], u2[:, i], u3[:, i])


@njit(**_HOT)
def stage_telemetry(S, p, rows, step, due, mi, r0, r1, r2, r3, r4, r5, r6, r7, receive):
    """Compose the telemetry due (for ``rows``); with ``receive`` the navigator takes it in unchanged."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _telemetry(S[i], p, step, due, mi, r0[:, i], r1[:, i], r2[:, i], r3[:, i], r4[:, i], r5[:, i], r6[:, i], r7[:, i],
                   receive)


@njit(**_HOT)
def stage_navigate(S, wps, p, rows, step, out):
    """The navigator's setpoint for ``rows`` into ``out`` (N, 6)."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _navigate(S[i], wps[i], p, step * p[K_DT], out, i)


@njit(**_HOT)
def stage_control(S, p, rows, step, sp, sp_ok, noise, due, mi, rec_truth, X, env):
    """Controllers and the rest of the step; ``sp`` (N, 6) / ``sp_ok`` (N,): the setpoint delivered;
    with ``env`` the battery sags by X's (N, X_WIDTH) battery column."""
    for j in range(rows.shape[0]):
        i = rows[j]
        _control(S[i], p, step, due, sp, i, sp_ok[i], noise, j, rec_truth[:, i], mi[L.D_TRUTH, step], X[i], env)


@njit(**_HOT)
def receive_rows(S, rows, topic, vals, ok):
    """The navigator takes in a (possibly altered) telemetry message where it was delivered."""
    for j in range(rows.shape[0]):
        i = rows[j]
        if ok[i]:
            _receive(S[i], topic, vals, i)


def param_vector(values: dict) -> np.ndarray:
    """The kernel's parameter vector from named values (see generator.engine.kernel_layout.PARAMS)."""
    p = np.zeros(L.N_PARAMS)
    for name, k in L.PARAM_INDEX.items():
        v = np.ravel(np.asarray(values[name], dtype=float))
        p[k:k + v.size] = v
    return p
