"""Message timing of a fleet's logs as the generator's timing table (``generate --like``, a profile's ``[timing]``).

Per log and logical topic (:data:`scart_bench.generator.like.fit.RATE_TOPICS`), :func:`interval_figures`
reads the message intervals the way the generator's timing (:func:`scart_bench.generator.telemetry.
timing.message_timing`) makes them: a zero-mean jitter of each message's time (the interval coefficient of
variation of the intervals near the period), dropped messages (an interval of about two periods or more)
and late ones (an interval of 1.25 periods or more followed by one of 0.75 or less). Logging gaps (2 s or
more) are left out. Over the fleet each figure is the median over the logs that measured it
(:func:`fleet_table`), written per generated link topic (:data:`LINK_TOPICS`), with the CV's spread
between the logs: a fleet's vehicles differ (the shared ArduCopter fleet's attitude CV runs from 0.002 to
0.027 between logs), and generated flights that all had the median would be told from them by that
alone (a classifier isolates a narrow band as well as a shifted one).

The CV is carried over as a CV, not as an absolute jitter: the generated topic keeps its own rate (the
dataset schema's: attitude at 50 Hz where an ArduCopter logs ATT at 10 Hz), and what a reader of the
flights sees of their timing (the window classifier of ``perf/realism_windows.py``: std / median of the
intervals) is the CV at the topic's own rate.
"""

from __future__ import annotations

import numpy as np

#: logical topic (generator.like.fit.RATE_TOPICS) -> the generated link topics that take its timing.
#: The magnetometer has no topic of its own (HIGHRES_IMU carries it); neither has the baro altitude
#: (HIGHRES_IMU's pressure_alt at the IMU's timing): the baro's figures go to SCALED_PRESSURE.
LINK_TOPICS = {
    "imu": ("highres_imu",),
    "attitude": ("attitude",),
    "local_position": ("local_position_ned", "global_position_int", "altitude"),
    "gps": ("gps_raw_int",),
    "baro": ("scaled_pressure",),
}
#: an interval this many periods long or more holds a dropped message (or a late one, see LATE_*)
DROP_PERIODS = 1.5
#: a late message: an interval of LATE_LONG periods or more followed by one of LATE_SHORT or less
LATE_LONG, LATE_SHORT = 1.25, 0.75
#: a logging gap (s): not the link's timing
GAP_S = 2.0
#: least intervals a figure is measured on
MIN_INTERVALS = 50
#: the widest spread of the CV between flights a fit writes
MAX_SPREAD = 10.0
#: logical topics fitted without a spread: the IMU's 50 Hz stream is read at 50 Hz (a reader's grid,
#: the window classifier's), and its wandering phase (generator.telemetry.timing.WANDERING) at a CV over
#: the fleet's repeats and skips samples on that grid, which the value features see: the fleet's ground
#: windows told such flights apart (flight AUC 0.92 over four classifier seeds with the IMU's spread,
#: 0.82 without it; docs/like.md)
NO_SPREAD = ("imu",)


def interval_figures(t_s: np.ndarray) -> tuple[float, float, float, float] | None:
    """(rate Hz, interval CV near the period, drop probability, late probability) of one topic's message
    times ``t_s`` (s, any order); None with fewer than :data:`MIN_INTERVALS` intervals.

    The CV is the std of the intervals within 0.75-1.25 periods over the period (the median interval);
    a drop is a missing message (an interval of ``k`` periods, ``k`` >= 2 rounded, holds ``k - 1``), a
    late message one that comes 0.25 period or more after its time and before the next; both per
    expected message."""
    t = np.sort(np.asarray(t_s, dtype=float))
    dt = np.diff(t)
    dt = dt[(dt > 0) & (dt < GAP_S)]
    if len(dt) < MIN_INTERVALS:
        return None
    period = float(np.median(dt))
    r = dt / period
    core = r[(r > LATE_SHORT) & (r < LATE_LONG)]
    cv = float(core.std()) if len(core) > 1 else 0.0
    late_at = np.flatnonzero((r[:-1] >= LATE_LONG) & (r[1:] <= LATE_SHORT))
    long = r >= DROP_PERIODS
    long[late_at] = False  # a late message's long interval is not a drop
    missing = float(np.sum(np.maximum(np.round(r[long]) - 1.0, 0.0)))
    expected = float(dt.sum() / period)
    return 1.0 / period, cv, missing / expected, len(late_at) / expected


def fleet_table(per_log: list[dict[str, tuple[float, float, float, float]]], n_logs: int,
                max_cv: float) -> dict[str, tuple[dict[str, float], str]]:
    """A profile's ``[timing]`` section from each log's :func:`interval_figures` per logical topic:
    generated topic -> ({cv, drop, late}, comment), each the median over the logs that measured it.
    A CV above ``max_cv`` (what the generator's timing can make) is capped, and the comment says so."""
    out = {}
    for logical, topics in LINK_TOPICS.items():
        figs = [m[logical] for m in per_log if logical in m]
        if not figs:
            continue
        hz, cv, drop, late = (float(np.median([f[k] for f in figs])) for k in range(4))
        capped = cv > max_cv
        spread = 1.0 if logical in NO_SPREAD else cv_spread([f[1] for f in figs])
        entry = {"cv": round(min(cv, max_cv), 4), "drop": round(drop, 5), "late": round(late, 5),
                 "spread": round(spread, 2)}
        what = (f"{logical} messages (median over {len(figs)} of {n_logs} logs, at their {hz:.3g} Hz): interval CV "
                f"near the period {cv:.3g}{f' (capped at {max_cv:g})' if capped else ''} (logs "
                f"{min(f[1] for f in figs):.2g}-{max(f[1] for f in figs):.2g}: spread {spread:.2f}), dropped "
                f"{100 * drop:.2g} %, late {100 * late:.2g} %")
        for topic in topics:
            out[topic] = (entry, what)
    return out


def cv_spread(cvs: list[float], most: float = MAX_SPREAD) -> float:
    """The ``spread`` k of a timing entry from the logs' CVs: log-uniform in [cv / k, cv * k] has the
    logs' standard deviation of log CV (k = exp(sqrt(3) std)); 1 with fewer than 2 logs, at most ``most``."""
    v = np.log([c for c in cvs if c > 0])
    if len(v) < 2:
        return 1.0
    return float(min(np.exp(np.sqrt(3.0) * v.std()), most))


def with_table(config, section: dict[str, tuple[dict[str, float], str]]):
    """``config`` (a FlightConfig) stamped with a ``[timing]`` section as :func:`fleet_table` gives it
    (its "realistic" timing with these entries); unchanged when the section is empty or timing is ideal."""
    import dataclasses

    from scart_bench.generator.telemetry.timing import TABLE_FIELDS, check_timing_table

    if not section or config.timing != "realistic":
        return config
    table = check_timing_table([(topic, *(entry[k] for k in TABLE_FIELDS)) for topic, (entry, _) in section.items()])
    return dataclasses.replace(config, timing_table=table)
