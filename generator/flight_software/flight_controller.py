"""The flight controller (the paper's "Simulator" side): estimator, PX4-like cascade, land detector.

Estimator: a complementary attitude filter (gyro integration corrected by accelerometer tilt and
magnetometer heading) and an EKF2-like linear Kalman filter for position, velocity and
accelerometer bias per axis, fusing delayed GPS position/velocity and barometric height with
5-sigma innovation gates. Each flight has its own covariance: a measurement that is rejected or
never arrives (a jammed GPS, a lost sensor) does not shrink it, so it grows while the filter
coasts on inertial data, as EKF2's does.

Controller: velocity -> acceleration (PID) -> thrust vector and attitude -> body rates (P) ->
torques (PI) -> rotor thrusts through the Iris mixer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scart_bench.generator.flight_software.startup import TAKEOFF_CLIMB
from scart_bench.generator.params import GRAVITY, ControllerParams, EstimatorParams, VehicleParams
from scart_bench.generator.physics.rotation import (
    cross,
    euler_from_quat,
    quat_integrate,
    quat_to_rot,
    rotate,
    wrap_pi,
)


class AxisKF:
    """Kalman filter algebra of the per-axis model x = [position, velocity, accel bias].

    Covariances are (N, 3, 3), one per flight, kept in the EstimatorState.
    """

    P0 = np.diag([1.0, 0.25, 0.01])

    def __init__(self, dt: float, q_acc: float, q_bias: float):
        self.F = np.array([[1.0, dt, -0.5 * dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
        self.Q = np.diag([0.0, q_acc**2 * dt, q_bias**2 * dt])

    def init(self, n: int) -> np.ndarray:
        return np.repeat(self.P0[None], n, axis=0)

    def predict(self, P: np.ndarray) -> np.ndarray:
        return self.F @ P @ self.F.T + self.Q

    @staticmethod
    def gain(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gains (N, 3, m) and innovation variances (N, m)."""
        PHt = P @ H.T
        S = H @ PHt + R
        K = PHt @ np.linalg.inv(S)
        return K, np.diagonal(S, axis1=1, axis2=2).copy()

    @staticmethod
    def commit(P: np.ndarray, K: np.ndarray, H: np.ndarray, fused: np.ndarray) -> None:
        """Covariance update, only for the flights whose measurement was fused."""
        if not fused.any():
            return
        Pf, Kf = P[fused], K[fused]
        Pn = Pf - Kf @ (H @ Pf)
        P[fused] = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))


@dataclass
class EstimatorState:
    """Per-flight estimator state."""

    quat: np.ndarray  # (N, 4)
    gyro_bias: np.ndarray  # (N, 3)
    x: np.ndarray  # (N, 3, 3): axis (N, E, D) x [pos, vel, accel bias]
    history: np.ndarray  # (delay, N, 6) past pos/vel for delayed GPS fusion
    rates: np.ndarray  # (N, 3) bias-corrected body rates
    accel_ned: np.ndarray  # (N, 3) estimated acceleration
    gps_pos_rejected: np.ndarray  # (N,) count of rejected GPS position fusions
    gps_vel_rejected: np.ndarray
    baro_rejected: np.ndarray
    baro_offset: np.ndarray  # (N,) baro altitude of home (m AMSL), set at the first baro sample
    inertial_only_s: np.ndarray  # (N,) seconds since the last accepted horizontal aiding
    since_pos_fusion_s: np.ndarray  # (N,) seconds since the last accepted GPS position
    gps_resets: np.ndarray  # (N,) horizontal position resets to GPS
    P_h: np.ndarray | None = None  # (N, 3, 3) covariance of the horizontal axes (north and east alike)
    P_v: np.ndarray | None = None  # (N, 3, 3) covariance of the vertical axis
    R: np.ndarray | None = None  # (N, 3, 3) rotation of ``quat`` (None when stale)
    #: (N, 3, 2) output predictor: the output position / velocity per axis minus the filter's (the
    #: part of recent corrections not passed on yet); see :meth:`Estimator.output`
    out_err: np.ndarray | None = None


class Estimator:
    """Attitude and position estimation for a batch; see the module docstring."""

    def __init__(self, params: EstimatorParams, dt: float, gps_delay_steps: int,
                 mag_field_ned: tuple[float, float, float]):
        self.p = params
        self.dt = dt
        self.delay = gps_delay_steps
        self.decl = np.arctan2(mag_field_ned[1], mag_field_ned[0])
        self.kf = AxisKF(dt, params.accel_process_noise, params.bias_process_noise)
        self.out_decay = 1.0 - dt / params.output_tau_s

    def init_state(self, n: int, yaw: np.ndarray) -> EstimatorState:
        quat = np.zeros((n, 4))
        quat[:, 0] = np.cos(yaw / 2)
        quat[:, 3] = np.sin(yaw / 2)
        return EstimatorState(
            quat=quat, gyro_bias=np.zeros((n, 3)), x=np.zeros((n, 3, 3)),
            history=np.zeros((self.delay, n, 6)), rates=np.zeros((n, 3)), accel_ned=np.zeros((n, 3)),
            gps_pos_rejected=np.zeros(n, dtype=np.int64), gps_vel_rejected=np.zeros(n, dtype=np.int64),
            baro_rejected=np.zeros(n, dtype=np.int64), baro_offset=np.full(n, np.nan),
            inertial_only_s=np.zeros(n), since_pos_fusion_s=np.zeros(n), gps_resets=np.zeros(n, dtype=np.int64),
            P_h=self.kf.init(n), P_v=self.kf.init(n), out_err=np.zeros((n, 3, 2)),
        )

    def predict(self, s: EstimatorState, step: int, accel: np.ndarray, gyro: np.ndarray,
                on_ground: np.ndarray) -> np.ndarray:
        """Propagate with one IMU sample; returns the estimated rotation matrices."""
        p, dt = self.p, self.dt
        R = s.R if s.R is not None else quat_to_rot(s.quat)
        # tilt correction: measured "down" vs estimated "down" in the body frame
        norm = np.linalg.norm(accel, axis=1)
        trust = (np.abs(norm - GRAVITY) < 0.15 * GRAVITY).astype(float)
        meas_down = -accel / np.maximum(norm, 1e-6)[:, None]
        est_down = R[:, 2, :]  # R^T e3
        err = cross(meas_down, est_down) * (p.att_accel_gain * trust)[:, None]
        s.gyro_bias -= p.gyro_bias_gain * err * dt
        s.rates = gyro - s.gyro_bias
        s.quat = quat_integrate(s.quat, s.rates + err, dt)
        R = s.R = quat_to_rot(s.quat)
        # translation: accelerometer in NED minus the estimated bias
        a_ned = rotate(R, accel)
        a_ned[:, 2] += GRAVITY
        a_ned = a_ned - s.x[:, :, 2]
        a_ned[on_ground] = 0.0
        s.accel_ned = a_ned
        x = s.x
        x[:, :, 0] += x[:, :, 1] * dt + 0.5 * a_ned * dt * dt
        x[:, :, 1] += a_ned * dt
        s.P_h = self.kf.predict(s.P_h)
        s.P_v = self.kf.predict(s.P_v)
        slot = step % self.delay
        s.history[slot, :, :3] = x[:, :, 0]
        s.history[slot, :, 3:] = x[:, :, 1]
        s.inertial_only_s += dt
        s.since_pos_fusion_s += dt
        if s.out_err is not None:
            s.out_err *= self.out_decay
        return R

    @staticmethod
    def begin_fusion(s: EstimatorState) -> np.ndarray:
        """The filter's position and velocity before this step's fusions (for :meth:`end_fusion`)."""
        return s.x[:, :, :2].copy()

    @staticmethod
    def end_fusion(s: EstimatorState, before: np.ndarray) -> None:
        """Hold back this step's corrections from the output (it takes them in over output_tau_s)."""
        s.out_err -= s.x[:, :, :2] - before

    @staticmethod
    def output(s: EstimatorState) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) (N, 3) as the controllers and the telemetry see them: the filter's
        state with the latest corrections smoothed in (EKF2's output predictor)."""
        if s.out_err is None:
            return s.x[:, :, 0], s.x[:, :, 1]
        return s.x[:, :, 0] + s.out_err[:, :, 0], s.x[:, :, 1] + s.out_err[:, :, 1]

    def fuse_mag(self, s: EstimatorState, mag: np.ndarray) -> None:
        """Heading correction from the magnetometer (tilt-compensated)."""
        eul = euler_from_quat(s.quat)
        cr, sr = np.cos(eul[:, 0]), np.sin(eul[:, 0])
        cp, sp = np.cos(eul[:, 1]), np.sin(eul[:, 1])
        mx = mag[:, 0] * cp + mag[:, 1] * sr * sp + mag[:, 2] * cr * sp
        my = mag[:, 1] * cr - mag[:, 2] * sr
        yaw_mag = np.arctan2(-my, mx) + self.decl
        err = wrap_pi(yaw_mag - eul[:, 2])
        R = s.R if s.R is not None else quat_to_rot(s.quat)
        axis = R[:, 2, :]  # world down axis in body
        s.quat = quat_integrate(s.quat, axis * (self.p.att_mag_gain * err)[:, None], 0.01)
        s.R = None

    def fuse_baro(self, s: EstimatorState, baro_alt: np.ndarray, delivered: np.ndarray | None = None) -> None:
        """Height from the barometer (altitude AMSL), referenced to the first sample."""
        ok_in = np.ones(baro_alt.shape[0], dtype=bool) if delivered is None else delivered
        first = np.isnan(s.baro_offset) & ok_in
        s.baro_offset[first] = baro_alt[first] + s.x[first, 2, 0]
        meas = -(baro_alt - s.baro_offset)
        H = np.array([[1.0, 0.0, 0.0]])
        K, S = self.kf.gain(s.P_v, H, np.array([[self.p.baro_noise**2]]))
        innov = np.where(ok_in, meas - s.x[:, 2, 0], 0.0)
        gate = innov**2 <= self.p.gate_sigma**2 * S[:, 0]
        s.baro_rejected += ok_in & ~gate
        fused = ok_in & gate
        s.x[:, 2, :] += K[:, :, 0] * (innov * fused)[:, None]
        self.kf.commit(s.P_v, K, H, fused)

    def fuse_gps(self, s: EstimatorState, step: int, pos: np.ndarray, vel: np.ndarray,
                 usable: np.ndarray | None = None) -> None:
        """Delayed GPS position (horizontal) and velocity (3-D), with innovation gates.

        ``usable``: flights whose receiver has a fix good enough to fuse (default: all).
        """
        p = self.p
        n = pos.shape[0]
        usable = np.ones(n, dtype=bool) if usable is None else usable
        old = s.history[(step + 1) % self.delay]
        gate2 = p.gate_sigma**2
        # horizontal position and velocity (per axis [pos, vel] measurement)
        H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        Rm = np.diag([p.gps_pos_noise**2, p.gps_vel_noise**2])
        K, S = self.kf.gain(s.P_h, H, Rm)
        ip = pos[:, :2] - old[:, :2]
        iv = vel[:, :2] - old[:, 3:5]
        ivz = vel[:, 2] - old[:, 5]
        pos_gate = (ip**2).sum(axis=1) <= gate2 * S[:, 0]
        vel_gate = ((iv**2).sum(axis=1) + ivz**2) <= gate2 * S[:, 1]
        pos_ok = usable & pos_gate
        vel_ok = usable & vel_gate
        s.gps_pos_rejected += usable & ~pos_gate
        s.gps_vel_rejected += usable & ~vel_gate
        ip = ip * pos_ok[:, None]
        iv = iv * vel_ok[:, None]
        s.x[:, :2, :] += ip[:, :, None] * K[:, None, :, 0] + iv[:, :, None] * K[:, None, :, 1]
        self.kf.commit(s.P_h, K, H, pos_ok | vel_ok)
        s.inertial_only_s[pos_ok | vel_ok] = 0.0
        s.since_pos_fusion_s[pos_ok] = 0.0
        # EKF2: reset the horizontal position to GPS when it has not been fused for 2 x
        # EKF2_RESET_TIMEOUT_MAX (7 s), or when no horizontal aiding was fused for 7 s
        reset = usable & ((s.since_pos_fusion_s > 2 * p.reset_timeout_s) | (s.inertial_only_s > p.reset_timeout_s))
        if reset.any():
            s.x[reset, :2, 0] = pos[reset, :2]
            s.x[reset, :2, 1] = np.where((s.inertial_only_s[reset] > p.reset_timeout_s)[:, None],
                                         vel[reset, :2], s.x[reset, :2, 1])
            s.since_pos_fusion_s[reset] = 0.0
            s.inertial_only_s[reset] = 0.0
            s.gps_resets += reset
            P = s.P_h[reset]
            P[:, 0, :] = 0.0
            P[:, :, 0] = 0.0
            P[:, 0, 0] = p.gps_pos_noise**2
            s.P_h[reset] = P
        # vertical velocity
        Hv = np.array([[0.0, 1.0, 0.0]])
        Kv, _ = self.kf.gain(s.P_v, Hv, np.array([[p.gps_vel_noise**2]]))
        s.x[:, 2, :] += (ivz * vel_ok)[:, None] * Kv[:, :, 0]
        self.kf.commit(s.P_v, Kv, Hv, vel_ok)

    @staticmethod
    def position(s: EstimatorState) -> np.ndarray:
        return s.x[:, :, 0]

    @staticmethod
    def velocity(s: EstimatorState) -> np.ndarray:
        return s.x[:, :, 1]


@dataclass
class ControllerState:
    """Per-flight controller state."""

    armed: np.ndarray  # (N,) bool
    vel_int: np.ndarray  # (N, 3)
    rate_int: np.ndarray  # (N, 3)
    thrust_sp: np.ndarray  # (N,) collective thrust setpoint, N
    att_quat_sp: np.ndarray  # (N, 3, 3) attitude setpoint (rotation matrix)
    rate_sp: np.ndarray  # (N, 3)
    land_time: np.ndarray  # (N,) seconds of landed evidence
    disarmed_after_flight: np.ndarray  # (N,) bool
    prev_vel_err: np.ndarray  # (N, 3)
    vel_sp: np.ndarray  # (N, 3) slew-limited velocity setpoint in use
    #: (N,) bool: the take-off's climb was asked for since arming; before it, armed on the ground,
    #: the motors idle and the velocity integrators hold (PX4's landed state: no wind-up lifting it)
    took_off: np.ndarray | None = None


class Controller:
    """PX4-like multicopter cascade for a batch."""

    def __init__(self, params: ControllerParams, vehicle: VehicleParams, dt: float):
        self.p = params
        self.v = vehicle
        self.dt = dt
        self.alloc_inv = np.linalg.inv(vehicle.allocation())
        self.inertia = np.array(vehicle.inertia)
        self.max_total = 4 * vehicle.max_thrust

    def init_state(self, n: int) -> ControllerState:
        eye = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        return ControllerState(
            armed=np.zeros(n, dtype=bool), vel_int=np.zeros((n, 3)), rate_int=np.zeros((n, 3)),
            thrust_sp=np.zeros(n), att_quat_sp=eye, rate_sp=np.zeros((n, 3)), land_time=np.zeros(n),
            disarmed_after_flight=np.zeros(n, dtype=bool), prev_vel_err=np.zeros((n, 3)),
            vel_sp=np.zeros((n, 3)), took_off=np.zeros(n, dtype=bool),
        )

    def velocity_control(self, c: ControllerState, vel_sp: np.ndarray, yaw_sp: np.ndarray,
                         vel_est: np.ndarray, R_est: np.ndarray, dt: float, stick: np.ndarray | None = None) -> None:
        """Velocity setpoint -> thrust vector -> attitude setpoint and collective thrust. ``stick`` (N, 4): a
        pilot's roll, pitch, yaw offset (rad) and throttle (m/s^2, up) added on top (flight_software.pilot)."""
        p, m = self.p, self.v.mass
        c.took_off |= c.armed & (vel_sp[:, 2] < -TAKEOFF_CLIMB)
        idle = c.armed & ~c.took_off  # armed on the ground, before the take-off
        # PX4 smooths setpoints: limit the horizontal and vertical acceleration they ask for
        dv = vel_sp - c.vel_sp
        dvh = np.linalg.norm(dv[:, :2], axis=1)
        lim = p.acc_hor * dt
        dv[:, :2] *= np.where(dvh > lim, lim / np.maximum(dvh, 1e-9), 1.0)[:, None]
        dv[:, 2] = np.clip(dv[:, 2], -p.acc_vert * dt, p.acc_vert * dt)
        c.vel_sp = np.where(c.armed[:, None], c.vel_sp + dv, 0.0)
        vel_sp = c.vel_sp
        err = vel_sp - vel_est
        gains_p = np.array([p.vel_xy_p, p.vel_xy_p, p.vel_z_p])
        gains_i = np.array([p.vel_xy_i, p.vel_xy_i, p.vel_z_i])
        d_err = (err - c.prev_vel_err) / dt
        c.prev_vel_err = err
        acc = gains_p * err + gains_i * c.vel_int
        acc[:, :2] += p.vel_xy_d * d_err[:, :2]
        if stick is not None:  # the pilot's sticks in the heading frame, flown through the attitude controller
            a_fwd, a_right = -GRAVITY * stick[:, 1], GRAVITY * stick[:, 0]
            cy, sy = np.cos(yaw_sp), np.sin(yaw_sp)
            acc[:, 0] += cy * a_fwd - sy * a_right
            acc[:, 1] += sy * a_fwd + cy * a_right
            acc[:, 2] -= stick[:, 3]
            yaw_sp = yaw_sp + stick[:, 2]
        # limit tilt: horizontal acceleration within tan(tilt_max) of the vertical specific force
        lift = np.maximum(GRAVITY - acc[:, 2], 0.3 * GRAVITY)
        h = np.linalg.norm(acc[:, :2], axis=1)
        h_max = lift * np.tan(p.tilt_max)
        scale = np.where(h > h_max, h_max / np.maximum(h, 1e-9), 1.0)
        acc[:, :2] *= scale[:, None]
        saturated = scale < 1.0
        upd = err * dt
        upd[saturated, :2] = 0.0
        c.vel_int = np.clip(c.vel_int + upd * (c.armed & ~idle)[:, None], -3.0, 3.0)
        f = acc.copy()
        f[:, 2] -= GRAVITY  # desired specific force (points up: negative z)
        f[:, 2] = np.minimum(f[:, 2], -0.3 * GRAVITY)
        b3 = -f / np.linalg.norm(f, axis=1, keepdims=True)
        xc = np.column_stack([np.cos(yaw_sp), np.sin(yaw_sp), np.zeros_like(yaw_sp)])
        y = cross(b3, xc)
        y /= np.linalg.norm(y, axis=1, keepdims=True)
        x = cross(y, b3)
        c.att_quat_sp = np.stack([x, y, b3], axis=2)
        thrust = m * np.einsum("ni,ni->n", f, -R_est[:, :, 2])
        c.thrust_sp = np.where(idle, self.p.thrust_min * self.max_total,
                               np.clip(thrust, self.p.thrust_min * self.max_total, 0.95 * self.max_total))

    def attitude_control(self, c: ControllerState, R_est: np.ndarray) -> None:
        """Attitude error -> body-rate setpoint (geometric attitude error, PX4 P gains)."""
        Rd = c.att_quat_sp
        A = np.matmul(Rd.transpose(0, 2, 1), R_est)
        E = A - A.transpose(0, 2, 1)
        e = 0.5 * np.column_stack([E[:, 2, 1], E[:, 0, 2], E[:, 1, 0]])
        rate = -np.array(self.p.att_p) * e
        rmax = np.array(self.p.rate_limits())
        c.rate_sp = np.clip(rate, -rmax, rmax)

    def rate_control(self, c: ControllerState, rates: np.ndarray) -> np.ndarray:
        """Body-rate PI -> rotor speed commands (rad/s) through the mixer."""
        p, dt = self.p, self.dt
        err = c.rate_sp - rates
        c.rate_int = np.clip(c.rate_int + err * dt * c.armed[:, None], -0.5, 0.5)
        J = self.inertia
        torque = J * (np.array(p.rate_p) * err + np.array(p.rate_i) * c.rate_int)
        torque += cross(rates, rates * J)
        wrench = np.column_stack([c.thrust_sp, torque])
        thrusts = wrench @ self.alloc_inv.T
        thrusts = np.clip(thrusts, 0.02 * self.v.max_thrust, self.v.max_thrust)
        cmd = np.sqrt(thrusts / self.v.motor_constant)
        cmd[~c.armed] = 0.0
        return cmd

    def land_detector(self, c: ControllerState, vel_sp: np.ndarray, vel_est: np.ndarray, dt: float) -> None:
        """Disarm after ``land_detect_s`` of descent demand with no vertical motion and low thrust."""
        hover = self.v.mass * GRAVITY
        evidence = c.armed & (vel_sp[:, 2] > 0.1) & (np.abs(vel_est[:, 2]) < 0.25) & (c.thrust_sp < 0.7 * hover)
        c.land_time = np.where(evidence, c.land_time + dt, 0.0)
        landed = c.land_time >= self.p.land_detect_s
        c.disarmed_after_flight |= landed
        c.armed &= ~landed
        c.vel_int[landed] = 0.0
