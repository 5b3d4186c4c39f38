"""A pilot in attitude mode: the stick a hand-flying pilot adds to what the flight controller flies.

Why: a fleet flown by hand (ArduCopter STABILIZE / ALT_HOLD / LOITER) rocks at 0.5-5 Hz: its roll and
pitch, gyro and accelerometer carry 30-70x the 0.5-5 Hz power of a flight that follows waypoints with
PX4's smooth position controller (docs/like.md), and neither wind nor sensor noise can stand for it.
Here the navigator's route stays the pilot's intention (the slow part, followed through the velocity
loop: the pilot's corrections), and the pilot's hand adds four sticks on top, each a smooth random
process: roll and pitch angle (rad, in the heading frame), a yaw offset (rad) and throttle (m/s^2 of
vertical acceleration). They enter the thrust vector before the tilt limit, so they are flown through
the attitude and rate controllers like any attitude setpoint.

Each stick is white noise through two first-order lags at ``pilot_stick_hz`` (a spectrum flat to that
corner, then falling at 40 dB/decade), scaled to unit standard deviation and then to the axis's
amplitude (``MissionParams.pilot_stick_deg``, ``pilot_yaw_deg``, ``pilot_throttle``), times a per-flight
factor (pilots and days differ) and an activity level: none below 1 m, full from 3 m, and
``pilot_hover_factor`` of it while the velocity setpoint is still (a pilot holding a hover moves the
stick less than one flying a leg). The noise is drawn once per setpoint (50 Hz, an RC frame rate) from
a 32-bit xorshift of the flight's own (its seed's ``PILOT_STREAM`` stream), in integer arithmetic, so
the compiled kernel (``generator.engine.kernel._pilot_stick``) and this numpy reference draw the same
values, and the flights' other noise streams are untouched: with every amplitude 0 (the default) the
flights are the ones without a pilot, byte for byte.
"""

from __future__ import annotations

import math

import numpy as np

from scart_bench.generator.params import GRAVITY, NAV_RATE_HZ, MissionParams

#: the pilot's own stream of a flight's seed (SeedSequence([seed, PILOT_STREAM]))
PILOT_STREAM = 0x9170
#: sticks: roll, pitch, yaw, throttle
AXES = 4
#: per flight, the stick amplitudes are scaled by exp(uniform(-SPREAD, SPREAD)) (0.61-1.65)
SPREAD = 0.5
#: the activity level's altitude ramp (m above home): none below ALT_OFF, full from ALT_FULL
ALT_OFF = 1.0
ALT_FULL = 3.0
#: m/s: a velocity setpoint this fast or faster is a leg (full stick), slower towards a hover (1 m/s: where the
#: window classifier's cruise begins; a hand-flown fleet's legs are slow, the shared one's median 1.6 m/s)
LEG_SPEED = 1.0
_M32 = 0xFFFFFFFF
_SQRT3 = math.sqrt(3.0)


def pilot_on(mission: MissionParams) -> bool:
    """Whether ``mission`` flies with the pilot (any stick amplitude above 0)."""
    return max(mission.pilot_stick_deg, mission.pilot_yaw_deg, mission.pilot_throttle) > 0.0


def pilot_start(seeds: list[int], mission: MissionParams) -> np.ndarray:
    """(N, 2) per flight: the stick's xorshift32 state (non-zero) and its amplitude factor (0: no pilot;
    ``pilot_share`` of the flights fly with one, drawn per flight)."""
    out = np.zeros((len(seeds), 2))
    for i, s in enumerate(seeds):
        g = np.random.default_rng(np.random.SeedSequence([int(s), PILOT_STREAM]))
        state = int(g.integers(1, 1 << 32))
        factor = math.exp(g.uniform(-SPREAD, SPREAD))
        flies = g.random() < mission.pilot_share
        out[i] = (state, factor if flies and pilot_on(mission) else 0.0)
    return out


def stick_lag(hz: float, rate_hz: float = NAV_RATE_HZ) -> tuple[float, float]:
    """(alpha, norm) of the stick's two first-order lags at ``hz`` sampled at ``rate_hz``: each lag is
    y <- alpha y + (1 - alpha) x; norm makes the second lag's output of unit-variance white input of unit
    variance (its variance is (1 - a)^4 (1 + a^2) / (1 - a^2)^3)."""
    a = math.exp(-2.0 * math.pi * hz / rate_hz)
    var = (1 - a) ** 4 * (1 + a * a) / (1 - a * a) ** 3
    return a, 1.0 / math.sqrt(var)


def stick_params(mission: MissionParams) -> np.ndarray:
    """The kernel's pilot parameters: amplitudes (roll, pitch, yaw rad; throttle m/s^2), then alpha,
    1 - alpha, norm, hover factor and on (1/0)."""
    a, norm = stick_lag(mission.pilot_stick_hz)
    amp = math.radians(mission.pilot_stick_deg)
    return np.array([amp, amp, math.radians(mission.pilot_yaw_deg), mission.pilot_throttle * GRAVITY,
                     a, 1.0 - a, norm, mission.pilot_hover_factor, 1.0 if pilot_on(mission) else 0.0])


def stick_highpass(mission: MissionParams, rate_hz: float = NAV_RATE_HZ) -> np.ndarray:
    """The kernel's parameters of the sticks' high-pass (``MissionParams.pilot_stick_highpass_hz``): alpha,
    1 - alpha, the norm of the band-pass (two lags, then the lags' output minus its own lag at the high-pass
    corner: unit-variance white input gives unit variance) and on (1/0; 0: the two lags' :func:`stick_lag` norm)."""
    hz = mission.pilot_stick_highpass_hz
    if not hz > 0.0:
        return np.zeros(4)
    from scipy import signal

    a, _ = stick_lag(mission.pilot_stick_hz, rate_hz)
    ah = math.exp(-2.0 * math.pi * hz / rate_hz)
    n = int(40 * rate_hz / min(hz, mission.pilot_stick_hz)) + 200
    y = signal.lfilter([1 - a], [1, -a], signal.lfilter([1 - a], [1, -a], np.r_[1.0, np.zeros(n)]))
    h = y - signal.lfilter([1 - ah], [1, -ah], y)
    return np.array([ah, 1.0 - ah, 1.0 / float(np.sqrt(np.dot(h, h))), 1.0])


def xorshift32(x: np.ndarray) -> np.ndarray:
    """The next state of 32-bit xorshift (13, 17, 5) generators held in int64 (exact: below 2^45)."""
    x = x ^ ((x << 13) & _M32)
    x = x ^ (x >> 17)
    return x ^ ((x << 5) & _M32)


class Pilot:
    """The numpy reference of the sticks for a batch (the compiled kernel has the same lines)."""

    def __init__(self, mission: MissionParams):
        self.m = mission
        self.p = stick_params(mission)
        self.hp = stick_highpass(mission)

    def init_state(self, start: np.ndarray) -> np.ndarray:
        """(N, 2 + 3 * AXES): xorshift state, amplitude factor, the lags' states, the high-pass's (zero)."""
        st = np.zeros((start.shape[0], 2 + 3 * AXES))
        st[:, :2] = start
        return st

    def step(self, st: np.ndarray, altitude: np.ndarray, speed_sp: np.ndarray) -> np.ndarray:
        """The sticks (N, 4) at this setpoint: roll, pitch, yaw offset (rad), throttle (m/s^2, up);
        ``altitude`` (m above home) and ``speed_sp`` (horizontal velocity setpoint, m/s) set the level."""
        p = self.p
        x = st[:, 0].astype(np.int64)
        out = np.zeros((st.shape[0], AXES))
        level = np.clip((altitude - ALT_OFF) / (ALT_FULL - ALT_OFF), 0.0, 1.0)
        level = level * (p[7] + (1.0 - p[7]) * np.minimum(speed_sp / LEG_SPEED, 1.0)) * st[:, 1]
        for a in range(AXES):
            total = np.zeros(st.shape[0])
            for _ in range(4):
                x = xorshift32(x)
                total = total + x / 4294967296.0
            n = (total - 2.0) * _SQRT3
            st[:, 2 + 2 * a] = p[4] * st[:, 2 + 2 * a] + p[5] * n
            st[:, 3 + 2 * a] = p[4] * st[:, 3 + 2 * a] + p[5] * st[:, 2 + 2 * a]
            if self.hp[3] != 0.0:  # band-pass: the lags' output minus its own slow lag
                h = 2 + 2 * AXES + a
                st[:, h] = self.hp[0] * st[:, h] + self.hp[1] * st[:, 3 + 2 * a]
                out[:, a] = p[a] * self.hp[2] * (st[:, 3 + 2 * a] - st[:, h]) * level
            else:
                out[:, a] = p[a] * p[6] * st[:, 3 + 2 * a] * level
        st[:, 0] = x
        return out
