"""Message timing as a real PX4 link shows it: jitter, dropped and late messages, late-starting sensors.

The flight itself is flown on the ideal schedule (every topic periodic from t = 0, which the
closed loop and the attack layer see); this module changes only *when the written messages are
stamped* and *which of them are written*, as the telemetry rows become tables
(:func:`scart_bench.generator.telemetry.tables.topic_table`). It applies the same timing to the navigator
and the simulator view of a flight, so the two still line up row for row.

``FlightConfig.timing``:

- ``"realistic"`` (the default): per topic (:data:`REALISTIC`), every message's timestamp moves by a zero-mean
  offset (normal, clipped at +-0.45 period) sized so that the interval coefficient of variation is
  that of the RflyMAD SIL log (``perf/realism.py``: jitter CV); a message is dropped, or written
  late (0.5-0.9 period after its time), with the topic's probabilities (from the CubeOrange
  hardware log; the SIL log has neither); the GPS topics start when the receiver has its fix and
  the global position when the estimator has its origin, at the flight's own times
  (:func:`generator.flight_software.startup.flight_start`, the times the closed loop flies by: SIL log 4.6 s and
  8.9 s). The truth and the setpoint are not messages of the link: unchanged;
- ``"ideal"``: nothing changes (every topic periodic from t = 0; GPS messages before the fix are
  written, with fix type 1 "no fix").

``FlightConfig.timing_table`` (a profile TOML's ``[timing]`` section, which ``generate --like`` fills
from a fleet's logs): per topic, ``(topic, cv, drop, late, spread)`` in place of that topic's
:data:`REALISTIC` entry, under ``"realistic"`` timing only; empty (the default) is :data:`REALISTIC` as
it is, byte for byte. ``spread`` > 1 varies the CV between flights as a fleet's vehicles differ: each
flight's CV is ``cv * spread ** (2 q - 1)`` (log-uniform in [cv / spread, cv * spread]), with one
quantile ``q`` per flight for every topic (a vehicle with a rough clock is rough on every topic). The
rates stay the schedule's (the dataset schema's, one per topic for every flight).

Everything is drawn from the flight's seed and the topic's name only (one generator per flight,
topic and purpose, each used in one call), so a flight's timing is the same in any batch and on
every run.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from scart_bench.generator.flight_software import startup

TIMINGS = ("ideal", "realistic")

#: per link topic: (interval coefficient of variation, drop probability, late probability).
#: The CV is the RflyMAD SIL log's (altitude as the attitude), but for the 50 Hz IMU stream: 0.05,
#: as the 14 ArduCopter logs' 50 Hz IMU (0.01-0.07, median 0.046); the SIL log's 0.386 is its
#: logger's 4/8 ms steps of a 250 Hz clock, which on a 50 Hz stream repeated a sample in one
#: resampled tick of three (lag-1 autocorrelation 0.3 of white noise: perf.realism_tells). Drops and late messages are the
#: CubeOrange hardware log's (the SIL log has none): 0.8 % of the local position's intervals are
#: a missed message, 0.08 % of the IMU's, and 4.4 % of the local position's are 1.25-1.75
#: periods long (a late message); the GPS and battery topics lose none. The baro loses none
#: either and its CV is 0.02: the RflyMAD SIL log's is 0.025, the 14 ArduCopter logs' BARO at
#: 10 Hz 0.016 (``python -m perf.realism_tells``; the CubeOrange's drops made it 6x theirs).
REALISTIC = {
    "highres_imu": (0.05, 0.0008, 0.0), "attitude": (0.092, 0.0008, 0.0), "altitude": (0.092, 0.0008, 0.0),
    "local_position_ned": (0.059, 0.008, 0.044), "global_position_int": (0.112, 0.0, 0.0),
    "gps_raw_int": (0.018, 0.0, 0.0), "scaled_pressure": (0.02, 0.0, 0.0), "battery_status": (0.071, 0.0, 0.0),
}
#: per uORB stream (generator.telemetry.schedule.UORB_STREAMS, written to the uORB view) as the RflyMAD
#: SIL log's logger writes it: the IMU's 200 Hz rows (4 and 8 ms apart) lose 5 % of their rows
#: (the log: 187 Hz, interval CV 0.386; here ~190 Hz, ~0.40), the slower topics jitter as the log's
#: (their own step-clock pattern, 48/52 ms at 20 Hz, adds to it: vehicle_attitude 0.092,
#: vehicle_local_position 0.059, actuator_controls_0 0.067, actuator_outputs 0.055 in the log).
REALISTIC.update({
    "sensor_combined": (0.05, 0.05, 0.0), "vehicle_attitude": (0.085, 0.0, 0.0),
    "vehicle_local_position": (0.059, 0.0, 0.0), "actuator_controls_0": (0.055, 0.0, 0.0),
    "actuator_outputs": (0.055, 0.0, 0.0),
})
#: link topics whose timestamps' offset wanders (AR(1) with this correlation from one message to
#: the next) instead of being drawn afresh per message, at the same interval CV. A stream sampled
#: by the clock of a sensor it is as fast as keeps its phase for a while: with independent offsets,
#: a 50 Hz stream read back at 50 Hz (the latest message at each tick) repeated a sample at one tick
#: in three, which turned the accelerometer's white noise into lag-1 autocorrelation 0.3
#: (``perf.realism_tells``; the ArduCopter logs' 50 Hz IMU: -0.1 on the ground).
WANDERING = {"highres_imu": 0.95}
GPS_FIX_S = startup.GPS_FIX_S
GLOBAL_AFTER_FIX_S = startup.ORIGIN_AFTER_FIX_S
GPS_TOPICS = ("gps_raw_int", "global_position_int")
_CLIP = 0.45


#: the largest interval CV an entry may ask for: the offsets are clipped at +-0.45 period, beyond which
#: the written CV no longer follows the asked one
MAX_CV = 0.3
#: the fields of a timing table's entry, after its topic
TABLE_FIELDS = ("cv", "drop", "late", "spread")
#: a field's allowed range
TABLE_RANGE = {"cv": (0.0, MAX_CV), "drop": (0.0, 1.0), "late": (0.0, 1.0), "spread": (1.0, 10.0)}


def check_timing(timing: str) -> str:
    if timing not in TIMINGS:
        raise ValueError(f"timing must be one of {', '.join(TIMINGS)}, got {timing!r}")
    return timing


def check_timing_table(table) -> tuple[tuple[str, float, float, float, float], ...]:
    """A timing table (``FlightConfig.timing_table``) as sorted ``(topic, cv, drop, late, spread)`` tuples,
    or ValueError naming the topic and what was expected: a topic of :data:`REALISTIC` once, each field
    in its :data:`TABLE_RANGE` (``cv`` at most MAX_CV), ``drop + late <= 1``; ``spread`` may be left out (1)."""
    out = {}
    for entry in table or ():
        if not isinstance(entry, (tuple, list)) or len(entry) not in (4, 5):
            raise ValueError(f"timing table entry {entry!r}: expected (topic, cv, drop, late[, spread])")
        topic, *values = entry
        values = [*values, 1.0][:4]
        if topic not in REALISTIC:
            raise ValueError(f"timing table topic {topic!r}: expected one of {', '.join(sorted(REALISTIC))}")
        if topic in out:
            raise ValueError(f"timing table topic {topic!r}: given twice")
        for name, v in zip(TABLE_FIELDS, values, strict=True):
            lo, hi = TABLE_RANGE[name]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ValueError(f"timing table {topic}.{name}: expected a number in [{lo:g}, {hi:g}], got {v!r}")
        if values[1] + values[2] > 1.0:
            raise ValueError(f"timing table {topic}: drop + late must be at most 1, got {values[1] + values[2]:g}")
        out[topic] = (topic, *(float(v) for v in values))
    return tuple(out[t] for t in sorted(out))


def _rng(seed: int, key: str, purpose: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(key.encode()), purpose]))


def fix_times_us(seed: int) -> dict[str, int]:
    """When the GPS topics of a flight start (µs): the fix, then the global position (the
    estimator's origin), as the flight's ground phase has them (generator.flight_software.startup)."""
    fix, glob, _ = startup.flight_start(seed)
    return {"gps_raw_int": int(round(fix * 1e6)), "global_position_int": int(round(glob * 1e6))}


def message_timing(timing: str, seed: int, topic: str, ts_us: np.ndarray, rate_hz: float | None = None,
                   table: tuple = ()) -> tuple[np.ndarray, np.ndarray]:
    """(stamped timestamps µs, kept) of a topic's messages at their ideal times ``ts_us`` (every
    message the flight's schedule holds, in order). ``kept`` is False for a dropped message or
    one before its sensor is ready. The stamped times may not be sorted (a late message).
    ``rate_hz``: the topic's nominal rate, by default its schedule's (a link topic or uORB stream).
    ``table``: the flight's timing table (``FlightConfig.timing_table``, checked): its entry for
    ``topic`` replaces the :data:`REALISTIC` one."""
    ts = np.asarray(ts_us, dtype=np.int64)
    n = ts.size
    if check_timing(timing) == "ideal" or topic not in REALISTIC or n < 2:
        return ts, np.ones(n, bool)
    from scart_bench.dataset.schema import TOPICS
    from scart_bench.generator.telemetry.schedule import UORB_STREAMS

    if rate_hz is None:
        rate_hz = TOPICS[topic].rate_hz if topic in TOPICS else UORB_STREAMS[topic][0]
    rate = rate_hz
    period = 1e6 / rate  # nominal: the schedule's own intervals vary on the step clock
    entry = next((e[1:] for e in table if e[0] == topic), None)
    if entry is None:
        cv, drop_p, late_p = REALISTIC[topic]
    else:
        cv, drop_p, late_p, spread = entry
        if spread > 1.0:  # this flight's place in the fleet: one quantile for all its topics
            q = _rng(seed, "timing_spread", 3).random()
            cv = min(cv * spread ** (2.0 * q - 1.0), MAX_CV)
    z = _rng(seed, topic, 1).standard_normal(n)
    rho = WANDERING.get(topic)
    if rho is None:
        offset = np.clip(z * cv * period / math.sqrt(2.0), -_CLIP * period, _CLIP * period)
    else:  # the phase wanders: consecutive messages share most of their offset (AR(1), unit variance)
        from scipy.signal import lfilter

        phase = lfilter([math.sqrt(1.0 - rho * rho)], [1.0, -rho], z)
        phase += rho ** np.arange(n) * (z[0] - phase[0])  # start from the stationary state
        offset = np.clip(phase * cv * period / math.sqrt(2.0 * (1.0 - rho)), -_CLIP * period, _CLIP * period)
    u = _rng(seed, topic, 2).random((n, 2))  # drop/late draw, late amount
    late = (u[:, 0] >= drop_p) & (u[:, 0] < drop_p + late_p)
    offset = np.where(late, (0.5 + 0.4 * u[:, 1]) * period, offset)
    kept = u[:, 0] >= drop_p
    if topic in GPS_TOPICS:
        kept &= ts >= fix_times_us(seed)[topic]
    return np.maximum(ts + np.round(offset).astype(np.int64), 0), kept
