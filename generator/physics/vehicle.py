"""Rigid-body 6-DOF quadrotor (3DR Iris) with first-order motor lag, rotor drag and wind.

All arrays carry a leading flight axis. The state is stepped at a fixed rate with
semi-implicit Euler on the translational and rotational velocities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scart_bench.generator.params import GRAVITY, VehicleParams
from scart_bench.generator.physics.rotation import cross, quat_integrate, quat_to_rot, rotate, rotate_t


@dataclass
class VehicleState:
    """True state of a batch of vehicles."""

    pos: np.ndarray  # (N, 3) m, NED relative to home
    vel: np.ndarray  # (N, 3) m/s, NED
    quat: np.ndarray  # (N, 4) body (FRD) -> NED
    omega: np.ndarray  # (N, 3) rad/s, body rates
    rotor_speed: np.ndarray  # (N, 4) rad/s
    accel: np.ndarray  # (N, 3) m/s^2, NED acceleration of the last step
    on_ground: np.ndarray  # (N,) bool

    @classmethod
    def zeros(cls, n: int, yaw: np.ndarray | None = None) -> VehicleState:
        quat = np.zeros((n, 4))
        if yaw is None:
            quat[:, 0] = 1.0
        else:
            quat[:, 0] = np.cos(yaw / 2)
            quat[:, 3] = np.sin(yaw / 2)
        return cls(
            pos=np.zeros((n, 3)), vel=np.zeros((n, 3)), quat=quat, omega=np.zeros((n, 3)),
            rotor_speed=np.zeros((n, 4)), accel=np.zeros((n, 3)), on_ground=np.ones(n, dtype=bool),
        )


@dataclass
class Wind:
    """Per-flight mean wind plus Ornstein-Uhlenbeck gusts (NED, m/s)."""

    mean: np.ndarray  # (N, 3)
    gust: np.ndarray  # (N, 3)
    sigma: np.ndarray  # (N,) gust standard deviation
    tau: float  # s

    def step(self, noise: np.ndarray, dt: float) -> np.ndarray:
        """Advance the gusts with standard normals ``noise`` (N, 3); returns the wind (N, 3)."""
        a = np.exp(-dt / self.tau)
        noise = noise * np.array([1.0, 1.0, 0.3])
        self.gust = a * self.gust + np.sqrt(1 - a * a) * self.sigma[:, None] * noise
        return self.mean + self.gust


class Vehicle:
    """Quadrotor dynamics; ``step`` advances a VehicleState by one time step."""

    def __init__(self, params: VehicleParams):
        self.params = params
        self.inertia = np.array(params.inertia)
        self.alloc = params.allocation()
        self.alloc_inv = np.linalg.inv(self.alloc)

    def step(self, s: VehicleState, rotor_cmd: np.ndarray, wind: np.ndarray, dt: float,
             efficiency: np.ndarray | None = None, rocking: np.ndarray | None = None) -> np.ndarray:
        """Advance one step. ``rotor_cmd`` (N, 4) rad/s; returns the rotation matrices used. ``rocking`` (N, 3):
        an angular acceleration (rad/s^2, body) on top of the rotors' (:class:`Rocking`), none on the ground."""
        p = self.params
        up = rotor_cmd > s.rotor_speed
        tau = np.where(up, p.time_constant_up, p.time_constant_down)
        s.rotor_speed += (rotor_cmd - s.rotor_speed) * (dt / tau)
        thrusts = p.motor_constant * s.rotor_speed**2
        if efficiency is not None:
            thrusts = thrusts * efficiency
        wrench = thrusts @ self.alloc.T  # (N, 4): thrust, tau_x, tau_y, tau_z
        R = quat_to_rot(s.quat)
        v_air_b = rotate_t(R, s.vel - wind)
        drag_b = -p.rotor_drag_coefficient * s.rotor_speed.sum(axis=1)[:, None] * v_air_b
        drag_b[:, 2] = 0.0
        drag_b -= p.body_drag * np.abs(v_air_b) * v_air_b
        force_b = drag_b
        force_b[:, 2] -= wrench[:, 0]
        accel = rotate(R, force_b) / p.mass
        accel[:, 2] += GRAVITY
        # ground: the vehicle rests on it until the thrust lifts it off
        resting = s.on_ground & (accel[:, 2] >= 0)
        accel[resting] = 0.0
        s.vel += accel * dt
        s.pos += s.vel * dt
        touching = s.pos[:, 2] >= 0.0
        s.on_ground = touching
        if touching.any():
            s.pos[touching, 2] = 0.0
            s.vel[touching] = 0.0
        s.accel = accel
        J = self.inertia
        torque = wrench[:, 1:]
        w = s.omega
        gyro = cross(w, w * J)
        s.omega = w + (torque - gyro) / J * dt
        if rocking is not None:
            s.omega = s.omega + rocking * dt
        s.omega[touching] = 0.0
        s.quat = quat_integrate(s.quat, s.omega, dt)
        if touching.any():
            # resting on the ground: level, keep heading
            q = s.quat[touching]
            yaw = np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))
            s.quat[touching] = np.column_stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw),
                                                np.sin(yaw / 2)])
        return R


#: a flight's rocking stream of its seed (SeedSequence([seed, ROCKING_STREAM]))
ROCKING_STREAM = 0x70CC
_M32 = 0xFFFFFFFF
_SQRT3 = 1.7320508075688772


def xorshift_normal(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(next states, one draw each) of per-flight 32-bit xorshift streams: four uniforms summed, centred and
    scaled to unit variance (the kernel's ``_xorshift_normal``, the same lines)."""
    total = np.zeros(len(x))
    for _ in range(4):
        x = x ^ ((x << 13) & _M32)
        x = x ^ (x >> 17)
        x = x ^ ((x << 5) & _M32)
        total = total + x / 4294967296.0
    return x, (total - 2.0) * _SQRT3


def stream_start(seeds, levels, stream: int) -> np.ndarray | None:
    """(N, 1 + len(level)) per flight: its own xorshift32 stream's start (from SeedSequence([seed, stream])) and
    the level of the flight with seed s, ``levels[s mod len(levels)]``; None for no levels."""
    if not levels:
        return None
    out = np.zeros((len(seeds), 1 + len(levels[0])))
    for i, s in enumerate(seeds):
        g = np.random.default_rng(np.random.SeedSequence([int(s), stream]))
        out[i, 0] = int(g.integers(1, 1 << 32))
        out[i, 1:] = levels[int(s) % len(levels)]
    return out


class Rocking:
    """Each vehicle's rocking (MissionParams.rocking_levels): per step a white angular acceleration of the flight's
    level, from a 32-bit xorshift of its own per flight (four uniforms summed, as the pilot's sticks), so that the
    flights' other draws stay as they are. The compiled kernel has the same lines (kernel._vehicle)."""

    def __init__(self, start: np.ndarray):
        self.state = start[:, 0].astype(np.int64)  # (N,) xorshift32 states, non-zero
        self.level = np.array(start[:, 1:4], dtype=float)  # (N, 3) rad/s^2 per step

    def step(self) -> np.ndarray:
        """(N, 3) this step's angular acceleration, rad/s^2."""
        x = self.state
        out = np.zeros(self.level.shape)
        for a in range(3):
            x, n = xorshift_normal(x)
            out[:, a] = self.level[:, a] * n
        self.state = x
        return out


def rocking_start(seeds, levels) -> np.ndarray | None:
    """(N, 4) per flight: its rocking stream's xorshift32 state and its (roll, pitch, yaw) level, the flight with seed
    s taking ``levels[s mod len(levels)]`` (MissionParams.rocking_levels); None for no levels."""
    return stream_start(seeds, levels, ROCKING_STREAM)


#: a flight's forward-flight rocking stream of its seed (SeedSequence([seed, FLOW_STREAM]))
FLOW_STREAM = 0xF10C


def flow_coefficients(hz: float, dt: float) -> tuple[float, float]:
    """(a, b) of the forward-flight rocking's first-order low-pass at ``hz`` per step ``dt``: y' = a y + b n keeps
    a unit normal drive n at unit variance (b = sqrt(1 - a^2))."""
    a = math.exp(-2.0 * math.pi * hz * dt)
    return a, math.sqrt(1.0 - a * a)


class FlowRocking:
    """Each vehicle's rocking in forward flight (MissionParams.rocking_flow_levels): per step an angular acceleration
    (roll, pitch) that is a unit Gauss-Markov process low-passed at ``rocking_flow_hz``, times the flight's level and
    a gain growing linearly with its true horizontal speed from ``rocking_flow_from_m_s`` (0) to ``rocking_flow_full_m_s``
    (1): the rotors' disturbed inflow and the
    frame's response in forward flight, which a hovering vehicle does not have. Its own 32-bit xorshift stream (four
    uniforms summed, as the rocking's), so the flights' other draws stay as they are. The compiled kernel has the
    same lines (kernel._flow)."""

    def __init__(self, start: np.ndarray, hz: float, full_m_s: float, from_m_s: float, dt: float):
        self.state = start[:, 0].astype(np.int64)  # (N,) xorshift32 states, non-zero
        self.level = np.array(start[:, 1:3], dtype=float)  # (N, 2) rad/s^2 at full speed, roll/pitch
        self.y = np.zeros(self.level.shape)  # (N, 2) the low-passed unit drive
        self.a, self.b = flow_coefficients(hz, dt)
        self.inv_span, self.start = 1.0 / (full_m_s - from_m_s), from_m_s

    def step(self, vel: np.ndarray) -> np.ndarray:
        """(N, 3) this step's angular acceleration (rad/s^2; yaw 0) at true velocity ``vel`` (N, 3, NED)."""
        x = self.state
        out = np.zeros((len(x), 3))
        gain = np.minimum(np.maximum(np.sqrt(vel[:, 0] ** 2 + vel[:, 1] ** 2) - self.start, 0.0) * self.inv_span, 1.0)
        for a in range(2):
            x, n = xorshift_normal(x)
            self.y[:, a] = self.a * self.y[:, a] + self.b * n
            out[:, a] = self.level[:, a] * gain * self.y[:, a]
        self.state = x
        return out


def flow_start(seeds, levels) -> np.ndarray | None:
    """(N, 3) per flight: its forward-flight rocking stream's xorshift32 state and its (roll, pitch) level, the
    flight with seed s taking ``levels[s mod len(levels)]`` (MissionParams.rocking_flow_levels); None for none."""
    return stream_start(seeds, levels, FLOW_STREAM)
