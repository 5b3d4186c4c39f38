"""Defense runs: a detector from a finished run in the loop of simulation mode, and its defense table.

:class:`BatchMonitor` is the online detector of a defended batch (the
:class:`~scart_bench.generator.defense.AlarmSource` that :class:`~scart_bench.generator.defense.DefenseHook`
feeds): it rebuilds each flight's navigator-view ``most_frequent`` rows as
:class:`~scart_bench.benchmark.live.StreamMonitor` does (one row per base-topic message, complete once a later
message arrives, every other column holding its last delivered value), for every flight of the batch at once,
and scores them causally in blocks of ``block_rows`` rows: a block's rows are scored when its last row is
complete, so an alarm is known at that row's time. Rows count (may alarm) from ``burn_in_s`` after arming
until the flight disarms again, the run's own rule (benchmark.protocol.counted_rows).

:func:`defend` flies a grid's attacked flights and as many normal flights with the defense in the loop, each
beside its undefended twin (same seed), for every detector x response, and :func:`defense_table` sums them up:
missions saved, impact reduced, false aborts, time from onset to response, with intervals.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.intervals import BOOTSTRAP_SEED, N_BOOTSTRAP, wilson
from scart_bench.benchmark.live import ARMING_FIELDS
from scart_bench.benchmark.protocol import is_armed
from scart_bench.dataset.schema import TOPICS
from scart_bench.detectors.base import Detector

#: Rows scored at a time per flight (0.5 s of a 50 Hz base topic): the alarm time is the block's last row.
BLOCK_ROWS = 25


def _block_scored(detector) -> bool:
    """True when the detector's scores come from its prepared matrix (the base class's ``score`` and
    ``_transform``, no stream of its own): then a block is scored in one call on its trailing window."""
    cls = type(detector)
    return (
        cls.score is Detector.score
        and cls._transform is Detector._transform
        and cls.stream is Detector.stream
    )


class BatchMonitor:
    """A fitted detector and its row threshold scoring the navigator's stream of every flight of a batch.

    ``detector``: fitted (``columns_``); ``threshold``: the run's row threshold; ``n``: flights in the batch.
    After the flights end, ``scores`` holds each scored block's (t_us, scores (N, rows)).
    """

    def __init__(
        self, detector, threshold: float, n: int, burn_in_s: float = 0.0, block_rows: int = BLOCK_ROWS
    ):
        self.detector = detector
        self.threshold = float(threshold)
        self.n = int(n)
        self.burn_in_s = float(burn_in_s)
        self.block_rows = max(1, int(block_rows))
        self.columns = list(detector.columns_)
        index: dict[str, tuple[list[int], list[int]]] = {}
        for j, col in enumerate(self.columns):
            topic, _, fld = col.partition(".")
            if topic in TOPICS and fld in TOPICS[topic].field_names:
                js, ks = index.setdefault(topic, ([], []))
                js.append(j)
                ks.append(TOPICS[topic].field_names.index(fld))
        self._index = {t: (np.asarray(js), np.asarray(ks)) for t, (js, ks) in index.items()}
        rates = {t: TOPICS[t].rate_hz for t in index if TOPICS[t].direction == "telemetry"}
        self.base_topic = max(rates, key=rates.get) if rates else next(iter(index), "attitude")
        self.history = int(getattr(detector, "history_rows_", 0) or 500)
        self._last = np.full((self.n, len(self.columns)), np.nan)
        self._pending: int | None = None
        self._rows: list[np.ndarray] = []
        self._times: list[int] = []
        self.armed_us = np.full(self.n, -1, dtype=np.int64)
        self.ended_us = np.full(self.n, -1, dtype=np.int64)
        self._arming_seen = False
        self._first_us: int | None = None
        self._block = _block_scored(detector)
        self._buffer: np.ndarray | None = None  # (N, <= history, features) prepared rows, block mode
        self._streams = None if self._block else [detector.stream() for _ in range(self.n)]
        self.rows_scored = 0
        self.score_s = 0.0
        #: (row times (B,), scores (N, B)) of every block (-inf: a row not scored), kept for checks and figures
        self.blocks: list[tuple[np.ndarray, np.ndarray]] = []

    # -- AlarmSource ------------------------------------------------------------------------------
    def observe(self, point: str, t_us: int, messages: dict) -> tuple[np.ndarray, int] | None:
        got = None
        if self._first_us is None:
            self._first_us = int(t_us)
        if self._pending is not None and t_us > self._pending:
            got = self._emit()
        for topic, (vals, ok) in messages.items():
            ok = np.asarray(ok, dtype=bool)
            for k, name in ARMING_FIELDS.get(topic, ()):
                self._arming_seen = True
                on = is_armed(name, vals[:, k])
                self.armed_us[ok & on & (self.armed_us < 0)] = t_us
                self.ended_us[ok & ~on & (self.armed_us >= 0) & (self.ended_us < 0)] = t_us
            cols = self._index.get(topic)
            if cols is not None:
                rows = np.flatnonzero(ok)
                if rows.size == self.n:
                    self._last[:, cols[0]] = vals[:, cols[1]]
                elif rows.size:
                    self._last[np.ix_(rows, cols[0])] = vals[np.ix_(rows, cols[1])]
            if topic == self.base_topic:
                self._pending = int(t_us)
        return got

    def finish(self) -> None:
        if self._pending is not None:
            self._emit(flush=True)

    # -- rows and blocks ----------------------------------------------------------------------------
    def _emit(self, flush: bool = False) -> tuple[np.ndarray, int] | None:
        self._rows.append(self._last.copy())
        self._times.append(self._pending)
        self._pending = None
        if len(self._rows) < self.block_rows and not flush:
            return None
        rows, times = np.stack(self._rows, axis=1), np.asarray(self._times, dtype=np.int64)  # (N, B, C), (B,)
        self._rows, self._times = [], []
        return self._score_block(rows, times), int(times[-1])

    def counts(self, times: np.ndarray) -> np.ndarray:
        """(N, B) rows that may alarm: from ``burn_in_s`` after arming until the flight disarms again."""
        t = times[None, :]
        if self.burn_in_s <= 0:
            counted = np.ones((self.n, len(times)), dtype=bool)
        else:
            armed = self.armed_us if self._arming_seen else np.full(self.n, self._first_us or 0)
            counted = (armed[:, None] >= 0) & (t >= armed[:, None] + int(round(self.burn_in_s * 1e6)))
        return counted & ((self.ended_us[:, None] < 0) | (t < self.ended_us[:, None]))

    def _score_block(self, rows: np.ndarray, times: np.ndarray) -> np.ndarray:
        counted = self.counts(times)
        live = (self.ended_us < 0) | (self.ended_us > times[0])
        scores = np.full(counted.shape, -np.inf)
        t0 = time.perf_counter()
        if self._block:
            z = self._prepare(rows)
            window = z if self._buffer is None else np.concatenate([self._buffer, z], axis=1)
            for i in np.flatnonzero(counted.any(axis=1)):
                scores[i] = np.asarray(self.detector._score(window[i]), dtype=np.float64)[-rows.shape[1] :]
            self._buffer = window[:, -self.history :]
        else:
            for i in np.flatnonzero(live):
                stream = self._streams[i]
                scores[i] = [stream.update(r) for r in rows[i]]
        self.score_s += time.perf_counter() - t0
        self.blocks.append((times, scores))
        self.rows_scored += int(counted.sum())
        return ((scores > self.threshold) & counted).sum(axis=1)

    def _prepare(self, rows: np.ndarray) -> np.ndarray:
        """Raw rows (N, B, C) prepared as ``Detector._prepare_row`` prepares each: angles as sine and cosine,
        standardised, a missing value filled with the flight's previous prepared value (0 at the start)."""
        d = self.detector
        n, b, c = rows.shape
        flat = pd.DataFrame(rows.reshape(n * b, c), columns=self.columns)
        arr = Detector._raw_matrix(flat, self.columns)  # inf as missing, angles as sine and cosine
        z = ((arr - d.mean_) / d.scale_).reshape(n, b, -1)
        gap = np.isnan(z)
        if gap.any():
            prev = self._buffer[:, -1] if self._buffer is not None else np.zeros((self.n, z.shape[2]))
            for b in range(z.shape[1]):
                zb = z[:, b]
                zb[gap[:, b]] = prev[gap[:, b]]
                prev = zb
        return z


# -- replay: the notices a batch's flown stream gives, without the detector in the loop -----------------
class ScheduledAlarms:
    """An :class:`~scart_bench.generator.defense.AlarmSource` that replays known notices: flight ``i`` gets its
    ``alarms`` alarm rows at the first call after ``notice_us[i]`` (-1: never), as :class:`BatchMonitor` reports a
    block's alarms at the first call after the block's last row."""

    def __init__(self, notice_us: np.ndarray, alarms: int):
        self.notice_us = np.asarray(notice_us, dtype=np.int64)
        self.alarms = int(alarms)
        self._sent = self.notice_us < 0

    def observe(self, point: str, t_us: int, messages: dict) -> tuple[np.ndarray, int] | None:
        due = ~self._sent & (t_us > self.notice_us)
        if not due.any():
            return None
        self._sent |= due
        return np.where(due, self.alarms, 0), int(self.notice_us[due].max())

    def finish(self) -> None:
        pass


@dataclass
class Notices:
    """What the online monitor would have decided on a flown batch: per flight, the time of the block that raised
    the anomaly notice (-1: none), the alarm rows up to it (or in the whole flight), and the scoring wall time."""

    notice_us: np.ndarray
    alarm_rows: np.ndarray
    score_s: float
    rows: int


def stream_rows(batch, monitor: BatchMonitor) -> tuple[np.ndarray, np.ndarray]:
    """The rows ``monitor`` builds from ``batch``'s navigator view in the loop: (row times (R,) us, rows (N, R, C)):
    one row per base-topic message, every column the last delivered value at or before it (NaN before any)."""
    from scart_bench.generator.params import STEP_US

    steps = np.asarray(batch.navigator[monitor.base_topic][0], dtype=np.int64)
    rows = np.full((len(batch), len(steps), len(monitor.columns)), np.nan)
    for topic, (js, ks) in monitor._index.items():
        if topic not in batch.navigator:
            continue
        t_steps, vals, ok = batch.navigator[topic]
        m = np.searchsorted(t_steps, steps, side="right") - 1  # the topic's last message at or before each row
        last_ok = np.maximum.accumulate(np.where(ok, np.arange(ok.shape[1]), -1), axis=1)  # (N, M)
        idx = np.where(m[None, :] >= 0, last_ok[:, np.maximum(m, 0)], -1)  # (N, R)
        got = np.take_along_axis(vals[:, :, ks], np.maximum(idx, 0)[:, :, None], axis=1)  # (N, R, len(ks))
        got[idx < 0] = np.nan
        rows[:, :, js] = got
    return steps * STEP_US, rows


def _arming(batch, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(armed_us, ended_us) as :class:`BatchMonitor` sees them in the loop (the navigator's setpoints)."""
    from scart_bench.generator.params import STEP_US

    armed_us, ended_us = np.full(n, -1, dtype=np.int64), np.full(n, -1, dtype=np.int64)
    for topic, fields in ARMING_FIELDS.items():
        if topic not in batch.navigator:
            continue
        t_steps, vals, ok = batch.navigator[topic]
        t = np.asarray(t_steps, dtype=np.int64) * STEP_US
        for k, name in fields:
            on = is_armed(name, vals[:, :, k]) & ok
            off = ~is_armed(name, vals[:, :, k]) & ok
            for i in range(n):
                a = np.flatnonzero(on[i])
                if a.size and armed_us[i] < 0:
                    armed_us[i] = t[a[0]]
                    e = np.flatnonzero(off[i, a[0] + 1 :])
                    if e.size:
                        ended_us[i] = t[a[0] + 1 + e[0]]
    return armed_us, ended_us


def replay_notices(
    batch, detector: DefendedDetector, alarms: int, block_rows: int = BLOCK_ROWS, chunk_blocks: int = 40
) -> Notices:
    """The notices :class:`BatchMonitor` would raise in the loop of ``batch`` (flown without a response): the same
    rows, row rule and blocks, scored per flight on its counted rows and the detector's trailing history before
    them, ``chunk_blocks`` blocks at a time up to the notice (causal detectors: the same scores, to rounding).

    A flight flown with :class:`ScheduledAlarms` and the response is the flight the monitor would have defended
    (its stream is the same up to the response), without the detector in the loop."""
    n = len(batch)
    mon = detector.monitor(n, block_rows)
    times, rows = stream_rows(batch, mon)
    mon.armed_us, mon.ended_us = _arming(batch, n)
    mon._arming_seen = any(t in batch.navigator for t in ARMING_FIELDS)
    mon._first_us = int(times[0]) if len(times) else 0
    counted = mon.counts(times)
    notice = np.full(n, -1, dtype=np.int64)
    alarm_rows = np.zeros(n, dtype=np.int64)
    t0 = time.perf_counter()
    b = mon.block_rows
    full = (len(times) // b) * b  # the last, partial block is scored at the end of the batch: no response
    history = max(int(getattr(mon.detector, "history_rows_", 0) or 500), 1)
    for i in np.flatnonzero(counted[:, :full].any(axis=1)):
        rows_i = np.flatnonzero(counted[i, :full])
        first, last = rows_i[0] // b, rows_i[-1] // b + 1  # blocks with counted rows
        total = 0
        for k0 in range(first, last, chunk_blocks):  # in chunks: an alarmed flight stops at its notice
            k1 = min(k0 + chunk_blocks, last)
            lo = max(k0 * b - history, 0)  # the detector's trailing history before the chunk
            frame = pd.DataFrame(rows[i, lo : k1 * b], columns=mon.columns)
            scores = np.asarray(mon.detector.score(frame), dtype=np.float64)[k0 * b - lo :]
            hits = (scores > mon.threshold) & counted[i, k0 * b : k1 * b]
            per_block = total + np.cumsum(hits.reshape(-1, b).sum(axis=1))
            k = np.flatnonzero(per_block >= alarms)
            if k.size:
                notice[i] = times[(k0 + k[0] + 1) * b - 1]
                total = int(per_block[k[0]])
                break
            total = int(per_block[-1])
        alarm_rows[i] = total
    return Notices(notice, alarm_rows, time.perf_counter() - t0, int(counted[:, :full].sum()))


# -- can it keep up with the link? -------------------------------------------------------------------
#: Wall time spent measuring a detector's streaming rate (after its history is filled).
RATE_BUDGET_S = 0.5


def link_rate_hz(detector) -> tuple[str, float]:
    """The base topic of the detector's rows and its link rate (rows the detector must score per second)."""
    base = BatchMonitor(detector, math.inf, 1).base_topic
    return base, float(TOPICS[base].rate_hz) if base in TOPICS else 50.0


def streaming_rate(detector, block_rows: int | None = None, seed: int = 0) -> float:
    """Rows per second one flight's online monitor scores with ``detector``, history full (rows of noise).

    ``block_rows``: scored in blocks, as :class:`BatchMonitor` scores them in simulation mode; None: row by row
    through the detector's own stream, as the live monitor (``benchmark.live.StreamMonitor``) does.
    """
    from scart_bench.detectors.base import TrailingStream

    rng = np.random.default_rng(seed)
    columns = list(detector.columns_)
    history = int(getattr(detector, "history_rows_", 0) or 500)
    done = spent = 0.0
    if block_rows is None:
        stream = detector.stream()
        warm = rng.standard_normal((history, len(columns)))
        if isinstance(stream, TrailingStream) and stream._prepared:  # fill the window without scoring it
            last = None
            for row in warm:
                last = detector._prepare_row(row, last)
                stream._rows.append(last)
            stream._last = last
        else:
            for row in warm:
                stream.update(row)
        while spent < RATE_BUDGET_S or done < 3:
            row = rng.standard_normal(len(columns))
            t0 = time.perf_counter()
            stream.update(row)
            spent += time.perf_counter() - t0
            done += 1
        return done / spent
    mon = BatchMonitor(detector, math.inf, 1, block_rows=block_rows)
    t = np.arange(history, dtype=np.int64)
    mon._score_block(rng.standard_normal((1, history, len(columns))), t)
    while spent < RATE_BUDGET_S or done < 3 * block_rows:
        rows = rng.standard_normal((1, block_rows, len(columns)))
        t0 = time.perf_counter()
        mon._score_block(rows, t[-1] + 1 + np.arange(block_rows))
        spent += time.perf_counter() - t0
        done += block_rows
    return done / spent


def require_link_rate(name: str, detector, block_rows: int | None = None, where: str = "the loop") -> float:
    """The detector's streaming rate (:func:`streaming_rate`); RunError in one line when it is below the rate of
    the link it must keep up with (its base topic's)."""
    from scart_bench.errors import RunError

    topic, need = link_rate_hz(detector)
    rate = streaming_rate(detector, block_rows)
    if rate < need:
        how = "row by row" if block_rows is None else f"in blocks of {block_rows} rows"
        raise RunError(
            f"--detector {name}: scores {rate:.1f} rows/s {how}, below the link's {need:g} rows/s "
            f"({topic} at {need:g} Hz); refused for {where}"
        )
    return rate


# -- the experiment ---------------------------------------------------------------------------------
@dataclass
class DefendedDetector:
    """A detector ready for the loop: fitted, with the run's row threshold and burn-in."""

    name: str
    detector: object
    threshold: float
    burn_in_s: float = 0.0

    def monitor(self, n: int, block_rows: int = BLOCK_ROWS) -> BatchMonitor:
        return BatchMonitor(self.detector, self.threshold, n, self.burn_in_s, block_rows)


def from_run(
    run, name: str, plugins: list[str] | None = None, log: Callable[[str], None] | None = None
) -> DefendedDetector:
    """Detector ``name`` of a finished run, refitted with its parameters and its calibrated row threshold
    (:func:`scart_bench.benchmark.live.monitor_from_run`)."""
    from scart_bench.benchmark.live import monitor_from_run

    m = monitor_from_run(run, name, plugins=plugins, log=log, command="defend")
    return DefendedDetector(name, m.detector, m.threshold, m.burn_in_s)


@dataclass
class DefenseRun:
    """Per-flight outcomes of a defense run (``flights``) and how long the flying took."""

    flights: pd.DataFrame
    wall_s: dict[str, float] = field(default_factory=dict)
    #: one example attacked flight's paths (detector, response, seed, path in normal/undefended/defended, x, y):
    #: the first one the defense saved, else the first one it responded to
    paths: pd.DataFrame = field(default_factory=pd.DataFrame)


def _truth_xy(batch, i: int) -> tuple[pd.DataFrame, np.ndarray]:
    from scart_bench.generator.telemetry.tables import truth_table

    t = truth_table(batch, i)
    return t, t[["x", "y"]].to_numpy(np.float64)


def defend(
    detectors: list[DefendedDetector],
    responses: list,
    configs: list,
    seeds: list[int],
    normal_seeds: list[int],
    flight_config=None,
    batch_size: int = 64,
    block_rows: int = BLOCK_ROWS,
    far_m: float | None = None,
    say: Callable[[str], None] = lambda msg: None,
) -> DefenseRun:
    """Fly ``configs`` (one list of scenarios per attacked flight, seed ``seeds[i]``) and the normal
    ``normal_seeds`` undefended and with every detector x response (generator.defense.Response) in the loop.

    One row per (detector, response, flight): its undefended and defended impact against the normal twin
    (generator.impact), whether the response was taken and when. ``far_m``: how far from the planned landing
    (the twin's) a flight may end and still complete its mission (default generator.impact.MISSION_TOLERANCE_M).
    """
    import dataclasses

    from scart_bench.generator.defense import DefenseHook
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.impact import MISSION_TOLERANCE_M, impact
    from scart_bench.generator.params import STEP_US
    from scart_bench.generator.scart.layer import AttackLayer

    far_m = MISSION_TOLERANCE_M if far_m is None else float(far_m)
    if flight_config is not None and flight_config.airframes:  # a layer's batch flies one vehicle: no airframe mix
        flight_config = dataclasses.replace(flight_config, airframes=())
    rows: list[dict] = []
    example: tuple[bool, pd.DataFrame] | None = None
    wall = {"undefended_s": 0.0, "defended_s": 0.0, "scoring_s": 0.0}
    jobs = [
        ("attacked", configs[k : k + batch_size], seeds[k : k + batch_size])
        for k in range(0, len(configs), batch_size)
    ]
    jobs += [
        ("normal", None, normal_seeds[k : k + batch_size]) for k in range(0, len(normal_seeds), batch_size)
    ]
    for kind, cfgs, sds in jobs:
        n = len(sds)
        t0 = time.perf_counter()
        twin = simulate(sds, flight_config)
        if cfgs is not None:
            layer = AttackLayer(cfgs, sds, rates=_rates())
            und = simulate(sds, flight_config, layer=layer)
        else:
            layer, und = None, twin
        wall["undefended_s"] += time.perf_counter() - t0
        base = []
        notices_of: dict[tuple[str, int], Notices] = {}  # the notices depend on the detector and alarms only
        for i in range(n):
            twin_truth, twin_xy = _truth_xy(twin, i)
            und_truth, und_xy = (twin_truth, twin_xy) if und is twin else _truth_xy(und, i)
            imp = impact(und_truth, twin_truth, und.status[i])
            plan = twin_xy[-1]
            base.append(
                {
                    "twin_truth": twin_truth,
                    "plan": plan,
                    "twin_end_us": (int(twin.exit_step[i]) + 1) * STEP_US,
                    "twin_xy": twin_xy,
                    "und_xy": und_xy,
                    "und": imp,
                    "und_status": und.status[i],
                    "und_off_m": float(np.hypot(*(und_xy[-1] - plan))),
                }
            )
        for det in detectors:
            for resp in responses:
                t0 = time.perf_counter()
                if (det.name, resp.alarms) not in notices_of:
                    notices_of[det.name, resp.alarms] = replay_notices(und, det, resp.alarms, block_rows)
                notices = notices_of[det.name, resp.alarms]
                wall["scoring_s"] += time.perf_counter() - t0
                hit = np.flatnonzero(notices.notice_us >= 0)
                hook, dfd, at = None, und, {}
                if hit.size:  # only the flights the detector alarmed on fly again, with the response
                    inner = AttackLayer([cfgs[i] for i in hit], [sds[i] for i in hit], rates=_rates()) \
                        if cfgs is not None else None
                    hook = DefenseHook(ScheduledAlarms(notices.notice_us[hit], resp.alarms), resp, len(hit), inner)
                    t0 = time.perf_counter()
                    dfd = simulate([sds[i] for i in hit], flight_config, layer=hook)
                    wall["defended_s"] += time.perf_counter() - t0
                    at = {int(i): j for j, i in enumerate(hit)}
                for i in range(n):
                    b = base[i]
                    j = at.get(i)
                    if j is None:  # never alarmed: the defended flight is the undefended one
                        d_imp, d_status, d_off, d_xy = b["und"], b["und_status"], b["und_off_m"], b["und_xy"]
                        end_us = (int(und.exit_step[i]) + 1) * STEP_US
                        notice_us = response_us = -1
                    else:
                        d_truth, d_xy = _truth_xy(dfd, j)
                        d_imp = impact(d_truth, b["twin_truth"], dfd.status[j])
                        d_status, d_off = dfd.status[j], float(np.hypot(*(d_xy[-1] - b["plan"])))
                        end_us = (int(dfd.exit_step[j]) + 1) * STEP_US
                        notice_us, response_us = int(hook.notice_us[j]), int(hook.response_us[j])
                    rows.append(
                        {
                            "detector": det.name,
                            "response": resp.action,
                            "alarms": resp.alarms,
                            "kind": kind,
                            "seed": sds[i],
                            "scenario_id": "+".join(s.id for s in cfgs[i]) if cfgs is not None else "",
                            "undefended_status": b["und_status"],
                            "defended_status": d_status,
                            "undefended_max_dev_m": b["und"]["impact_max_dev_m"],
                            "defended_max_dev_m": d_imp["impact_max_dev_m"],
                            "undefended_off_plan_m": b["und_off_m"],
                            "defended_off_plan_m": d_off,
                            "onset_us": _onset(layer, i, end_us),
                            "notice_us": notice_us,
                            "response_us": response_us,
                            "twin_end_us": b["twin_end_us"],
                            "alarm_rows": int(notices.alarm_rows[i]),
                        }
                    )
                    saved = (
                        b["und_status"] == "crashed" or b["und_off_m"] > far_m
                    ) and d_status == "landed" and d_off <= far_m
                    if kind == "attacked" and response_us >= 0 and (example is None or (saved and not example[0])):
                        example = (saved, _example_paths(det.name, resp.action, sds[i], b, d_xy))
        say(f"defend: {kind} flights {len(rows)} rows so far")
    flights = pd.DataFrame(rows)
    if len(flights):
        flights["far_m"] = far_m
    return DefenseRun(flights, wall, example[1] if example is not None else pd.DataFrame())


def _example_paths(detector: str, response: str, seed: int, base: dict, defended_xy: np.ndarray) -> pd.DataFrame:
    """The normal twin's, undefended and defended true paths (north x, east y, m) of one flight, at 10 Hz."""
    parts = []
    for name, xy in (("normal", base["twin_xy"]), ("undefended", base["und_xy"]), ("defended", defended_xy)):
        xy = xy[::5]
        parts.append(pd.DataFrame({"detector": detector, "response": response, "seed": seed, "path": name,
                                   "x": xy[:, 0], "y": xy[:, 1]}))
    return pd.concat(parts, ignore_index=True)


def _rates() -> dict[str, float]:
    """Message rates of the built-in topics, as simulation mode gives the attack layer."""
    from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS

    rates = {t: v.rate_hz for t, v in TOPICS.items()}
    rates.update({t: r for t, (r, _) in SENSOR_TOPICS.items()})
    return rates


def _onset(layer, i: int, end_us: int) -> int:
    """The first attack window's start on flight ``i`` (-1: none)."""
    if layer is None:
        return -1
    w = layer.labelled_windows(i, end_us)
    return int(w[0][0]) if w else -1


def _median_ci(values: np.ndarray, seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float]:
    """Median and its 95 % percentile-bootstrap interval (NaN when empty)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan, math.nan
    rng = np.random.default_rng(seed)
    boot = np.median(v[rng.integers(0, v.size, size=(N_BOOTSTRAP, v.size))], axis=1)
    return float(np.median(v)), float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))


def _rate(k: int, n: int) -> dict:
    lo, hi = wilson(k, n)
    return {"k": int(k), "n": int(n), "rate": k / n if n else math.nan, "low": lo, "high": hi}


def outcomes(flights: pd.DataFrame) -> pd.DataFrame:
    """Per-flight verdicts: endangered (undefended crashed or ended off its planned landing), saved (endangered,
    and the defended flight landed within ``far_m`` of it), responded, false abort (a normal flight whose
    response came before its twin's end), response delay after the attack's onset (s)."""
    f = flights.copy()
    far = f["far_m"]
    f["endangered"] = (f["kind"] == "attacked") & (
        (f["undefended_status"] == "crashed") | (f["undefended_off_plan_m"] > far)
    )
    f["saved"] = f["endangered"] & (f["defended_status"] == "landed") & (f["defended_off_plan_m"] <= far)
    f["safe_landing"] = f["defended_status"] == "landed"
    f["responded"] = f["response_us"] >= 0
    f["false_abort"] = (f["kind"] == "normal") & f["responded"] & (f["response_us"] < f["twin_end_us"])
    after = f["responded"] & (f["onset_us"] >= 0) & (f["response_us"] >= f["onset_us"])
    f["response_delay_s"] = np.where(after, (f["response_us"] - f["onset_us"]) / 1e6, np.nan)
    f["early_response"] = (f["kind"] == "attacked") & f["responded"] & (f["onset_us"] >= 0) & ~after
    return f


def defense_table(flights: pd.DataFrame) -> pd.DataFrame:
    """One row per detector x response: missions saved, impact reduced, false aborts, time to response."""
    f = outcomes(flights)
    out = []
    for (det, resp), g in f.groupby(["detector", "response"], sort=False):
        a, nrm = g[g["kind"] == "attacked"], g[g["kind"] == "normal"]
        saved = _rate(int(a["saved"].sum()), int(a["endangered"].sum()))
        fa = _rate(int(nrm["false_abort"].sum()), len(nrm))
        responded = _rate(int((a["responded"] & ~a["early_response"]).sum()), len(a))
        und = _median_ci(a["undefended_max_dev_m"])
        dfd = _median_ci(a["defended_max_dev_m"])
        delay = _median_ci(a["response_delay_s"])
        out.append(
            {
                "detector": det,
                "response": resp,
                "alarms": int(g["alarms"].iloc[0]),
                "attacked": len(a),
                "endangered": saved["n"],
                "missions_saved": saved["k"],
                "saved_rate": saved["rate"],
                "saved_low": saved["low"],
                "saved_high": saved["high"],
                "undefended_max_dev_m": und[0],
                "undefended_max_dev_low": und[1],
                "undefended_max_dev_high": und[2],
                "defended_max_dev_m": dfd[0],
                "defended_max_dev_low": dfd[1],
                "defended_max_dev_high": dfd[2],
                "impact_reduced_m": und[0] - dfd[0],
                "responded_after_onset": responded["k"],
                "responded_rate": responded["rate"],
                "early_responses": int(a["early_response"].sum()),
                "response_delay_s": delay[0],
                "response_delay_low": delay[1],
                "response_delay_high": delay[2],
                "normal": fa["n"],
                "false_aborts": fa["k"],
                "false_abort_rate": fa["rate"],
                "false_abort_low": fa["low"],
                "false_abort_high": fa["high"],
            }
        )
    return pd.DataFrame(out)


def table_markdown(table: pd.DataFrame) -> str:
    """The defense table as Markdown: rates with their 95 % intervals, medians with bootstrap intervals."""

    def rate(k, n, lo, hi):
        return f"{k}/{n} ({lo:.0%}-{hi:.0%})" if n else "-"

    def med(v, lo, hi, unit):
        return f"{v:.1f} {unit} ({lo:.1f}-{hi:.1f})" if np.isfinite(v) else "-"

    lines = [
        "| detector | response | missions saved | max deviation undefended | defended | false aborts "
        "| onset -> response |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in table.itertuples():
        lines.append(
            f"| {r.detector} | {r.response} (x{r.alarms}) "
            f"| {rate(r.missions_saved, r.endangered, r.saved_low, r.saved_high)} "
            f"| {med(r.undefended_max_dev_m, r.undefended_max_dev_low, r.undefended_max_dev_high, 'm')} "
            f"| {med(r.defended_max_dev_m, r.defended_max_dev_low, r.defended_max_dev_high, 'm')} "
            f"| {rate(r.false_aborts, r.normal, r.false_abort_low, r.false_abort_high)} "
            f"| {med(r.response_delay_s, r.response_delay_low, r.response_delay_high, 's')} |"
        )
    lines.append("")
    lines.append(
        "Missions saved: attacked flights whose undefended twin crashed or ended off its planned landing, "
        "landed within the tolerance by the defended flight (Wilson 95 % interval). Max deviation: median "
        "largest distance from the normal twin's path (bootstrap 95 % interval). False aborts: normal "
        "flights whose response came before the flight's end. Onset -> response: median delay on "
        "attacked flights responded to after the onset."
    )
    return "\n".join(lines) + "\n"


def write_defense(run: DefenseRun, out: Path, header: str) -> str:
    """Write ``out``/defense.csv (the table), defense_flights.csv (per flight, with the verdicts), defense_paths.csv
    (the example flight, when there is one) and defense.md (``header`` and the table); returns the table's Markdown.
    Each file is written whole (a temporary file renamed)."""
    from scart_bench.benchmark.store import atomic_write_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = defense_table(run.flights)
    text = table_markdown(table)
    atomic_write_text(out / "defense.csv", table.to_csv(index=False))
    atomic_write_text(out / "defense_flights.csv", outcomes(run.flights).to_csv(index=False))
    if len(run.paths):
        atomic_write_text(out / "defense_paths.csv", run.paths.to_csv(index=False))
    atomic_write_text(out / "defense.md", f"# Defense table\n\n{header}\n\n" + text)
    for path in out.glob("defense*"):
        os.chmod(path, 0o644)  # a table is meant to be shared (the temporary file was private)
    return text
