"""A PX4 flight's start on the ground: GPS fix, estimator alignment, arming; GPS quality as it settles.

A real PX4 vehicle does not take off at boot. Its GPS receiver needs seconds to a first 3-D fix
(RflyMAD SIL log: 4.6 s; the Gazebo SITL logs 8-12 s), EKF2 fuses GPS only after its checks have
passed for a while and then sets its origin (the global position starts: SIL log 8.9 s), and only
then do the pre-arm checks pass and the vehicle arm. Real logs spend 3.8-16 s on the ground.
After the fix, a receiver's satellites-used count climbs for a few seconds and its reported
accuracy (eph / epv) shrinks as it settles (CubeOrange log: eph 3.3 -> 2.5 m over 6 s).

Every time is drawn from the flight's seed only (one generator per flight and purpose), so a
flight's start is the same alone or in any batch. Both engines of the generator read the arrays
of :func:`startup_times`. The receiver's settling after its fix (``gps_quality``) lives with the
sensors (generator.physics.sensors), which read it; its scalar formulas are repeated in the kernel.
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


