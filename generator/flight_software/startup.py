"""A PX4 flight's start on the ground: GPS fix, estimator alignment, arming; GPS quality as it settles.

A real PX4 vehicle does not take off at boot. Its GPS receiver needs seconds to a first 3-D fix
(RflyMAD SIL log: 4.6 s; the Gazebo SITL logs 8-12 s), EKF2 fuses GPS only after its checks have
passed for a while and then sets its origin (the global position starts: SIL log 8.9 s), and only
then do the pre-arm checks pass and the vehicle arm. Real logs spend 3.8-16 s on the ground.
After the fix, a receiver's satellites-used count climbs for a few seconds and its reported
accuracy (eph / epv) shrinks as it settles (CubeOrange log: eph 3.3 -> 2.5 m over 6 s).

Every time is drawn from the flight's seed only (one generator per flight and purpose), so a
flight's start is the same alone or in any batch. Both engines of the generator read the arrays
of :func:`startup_times`; the scalar formulas of :func:`gps_quality` are repeated in the kernel.
"""

from __future__ import annotations

import zlib

import numpy as np

#: receiver's first 3-D fix after boot, s (uniform; SIL log 4.6 s)
GPS_FIX_S = (3.0, 6.0)
#: EKF2 fuses GPS and sets its origin this long after the fix, s (SIL log: 8.9 - 4.6 = 4.3 s)
ORIGIN_AFTER_FIX_S = (3.0, 5.0)
#: the vehicle arms this long after the origin (pre-arm checks, the operator), s
ARM_AFTER_ORIGIN_S = (0.5, 3.0)
#: and takes off this long after arming, on the ground with its motors spinning at idle, s (was
#: 0.5; the shared logs from arming to lift-off: PX4 median 2.4 s, ArduCopter 5.8 s:
#: ``python -m perf.realism_tells``, "armed on the ground before take-off"; PX4's
#: COM_SPOOLUP_TIME is 1 s, the rest is the operator's or the mission's start)
TAKEOFF_AFTER_ARM_S = 3.0
#: upward velocity setpoint (m/s) that ends the controller's idle on the ground: the take-off's climb
TAKEOFF_CLIMB = 0.2
#: the old instant start's (``MissionParams(ground_phase=False)``), kept as it was
TAKEOFF_AFTER_ARM_INSTANT_S = 0.5


def takeoff_after_arm(ground_phase: bool) -> float:
    """Seconds from arming to the take-off of a flight with (or without) the ground phase."""
    return TAKEOFF_AFTER_ARM_S if ground_phase else TAKEOFF_AFTER_ARM_INSTANT_S
#: satellites used at the fix: this many fewer than the receiver settles on; one more per second
SATS_RAMP = 3.0
#: reported accuracy at the fix is (1 + EPH_SETTLE) times the settled one, decaying with EPH_SETTLE_TAU_S
EPH_SETTLE = 0.5
EPH_SETTLE_TAU_S = 6.0
#: remaining charge of the pack at boot (uniform): packs are not always freshly charged
BATTERY_REMAINING = (0.88, 1.0)


def _rng(seed: int, purpose: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(b"gps_fix"), zlib.crc32(purpose.encode())]))


def flight_start(seed: int) -> tuple[float, float, float]:
    """(GPS fix, estimator origin, arming) times of one flight in seconds after boot."""
    u = _rng(seed, "start").random(3)
    fix = GPS_FIX_S[0] + u[0] * (GPS_FIX_S[1] - GPS_FIX_S[0])
    origin = fix + ORIGIN_AFTER_FIX_S[0] + u[1] * (ORIGIN_AFTER_FIX_S[1] - ORIGIN_AFTER_FIX_S[0])
    arm = origin + ARM_AFTER_ORIGIN_S[0] + u[2] * (ARM_AFTER_ORIGIN_S[1] - ARM_AFTER_ORIGIN_S[0])
    return float(fix), float(origin), float(arm)


def startup_times(seeds, ground_phase: bool = True, arm_delay_s: float = 1.0) -> np.ndarray:
    """(N, 3) GPS fix, estimator origin and arming times (s) of the flights ``seeds``.

    ``ground_phase=False`` is the old instant start: GPS from boot, arming at ``arm_delay_s``.
    """
    if not ground_phase:
        out = np.zeros((len(seeds), 3))
        out[:, 2] = arm_delay_s
        return out
    return np.array([flight_start(s) for s in seeds], dtype=float).reshape(len(seeds), 3)


def battery_start(seeds) -> np.ndarray:
    """(N,) remaining charge (0-1) of each flight's pack at boot."""
    lo, hi = BATTERY_REMAINING
    return np.array([lo + (hi - lo) * _rng(s, "battery").random() for s in seeds], dtype=float)


def gps_quality(t: float, fix_s: np.ndarray, sats_settled: np.ndarray, sats_now: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(fixed, satellites used, accuracy scale) of the receivers at time ``t`` (s).

    ``sats_now``: the satellites the receiver could use now (fewer under jamming). Before its fix
    a receiver has no fix; from the fix its count climbs one a second from ``SATS_RAMP`` fewer than
    ``sats_settled``, and its eph / epv are (1 + ``EPH_SETTLE``) times the settled ones, shrinking.
    """
    since = t - np.asarray(fix_s, dtype=float)
    fixed = since >= 0.0
    after = np.maximum(since, 0.0)
    cap = np.asarray(sats_settled, dtype=float) - SATS_RAMP + np.floor(after)
    sats = np.maximum(np.minimum(np.asarray(sats_now, dtype=float), cap), 0.0)
    scale = 1.0 + EPH_SETTLE * np.exp(-after / EPH_SETTLE_TAU_S)
    return fixed, sats, scale
