"""Live scoring: a fitted detector watching the navigator-side stream of a live link.

:class:`StreamMonitor` is a listener of the MAVLink proxy (``MavlinkProxy(listeners=[...])``);
:func:`monitor_from_run` fits it again from a finished benchmark run, with the run's parameters and
row threshold.

The monitor rebuilds, message by message, the rows of the navigator view's ``most_frequent``
table (one row per message of the base topic, every other topic holding its last value, as
:func:`scart_bench.dataset.combine` does): a row is complete once a message with a later timestamp
arrives, so the stream gives the same rows as the recorded flight. Each row is scored by calling
the detector on its trailing ``history_rows_`` rows (the rows that reproduce the last row's score;
detectors are causal) and an alarm is logged when the score exceeds the threshold, with the
scoring latency and, while an attack window is open, the delay since the attack started.

As in the benchmark's protocol (:mod:`scart_bench.benchmark.protocol`), with a ``burn_in_s`` rows before
arming and in the ``burn_in_s`` after it are scored but never alarm: arming is the first message whose ``armed``
field is set (the navigator's setpoint) or whose ``arming_state`` is 2; a stream that carries
neither field is armed at its first row.

The detector is duck-typed (``columns_``, ``score(DataFrame)``, optional ``history_rows_``).
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import ARMING_FIELD_NAMES, is_armed
from scart_bench.dataset.schema import TOPICS
from scart_bench.errors import RunError

#: topic -> (index, name) of its fields that say the vehicle is armed (looked up once, not per message)
ARMING_FIELDS = {name: fields for name, spec in TOPICS.items()
                 if (fields := [(k, f) for k, f in enumerate(spec.field_names) if f in ARMING_FIELD_NAMES])}
#: rows scored when a detector does not say how much history it needs (10 s at 50 Hz)
DEFAULT_HISTORY_ROWS = 500


@dataclass
class Alarm:
    """One row whose score exceeded the threshold."""

    t_us: int
    score: float
    latency_ms: float  # wall time to score the row
    delay_s: float | None  # since the start of the open attack window (None: no attack active)


class StreamMonitor:
    """Scores the navigator-side stream online with a fitted detector and a row threshold."""

    def __init__(self, detector, threshold: float, name: str = "detector",
                 log: Callable[[str], None] | None = None, burn_in_s: float = 0.0):
        self.detector = detector
        self.threshold = float(threshold)
        self.name = name
        self.burn_in_s = float(burn_in_s)
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        self.columns = list(detector.columns_)
        self.history = int(getattr(detector, "history_rows_", 0) or DEFAULT_HISTORY_ROWS)
        index: dict[str, list[tuple[int, int]]] = {}
        for j, col in enumerate(self.columns):
            topic, _, fld = col.partition(".")
            if topic in TOPICS and fld in TOPICS[topic].field_names:
                index.setdefault(topic, []).append((j, TOPICS[topic].field_names.index(fld)))
        self._index = index
        rates = {t: TOPICS[t].rate_hz for t in index if TOPICS[t].direction == "telemetry"}
        self.base_topic = max(rates, key=rates.get) if rates else next(iter(index), "attitude")
        self._last = np.full(len(self.columns), np.nan)
        self._seen = np.zeros(len(self.columns), dtype=bool)
        self._rows: deque[np.ndarray] = deque(maxlen=self.history)
        # the detector's own live scorer when it has one (incremental, same scores as batch)
        self._stream = detector.stream() if callable(getattr(detector, "stream", None)) else None
        self._pending: int | None = None  # timestamp of the base-topic row not yet complete
        self._layer = None
        self.scores: list[tuple[int, float]] = []
        self.alarms: list[Alarm] = []
        self.latency_ms: list[float] = []
        self._in_alarm = False
        self.armed_us: int | None = None  # when the stream armed (see the module docstring)
        self._first_us: int | None = None
        self._arming_seen = False  # a topic with an arming field has been seen

    def add_topics(self, fields: dict[str, tuple[str, ...]], rates: dict[str, float]) -> None:
        """Also read the detector's columns from these topics (``topic -> field names``, e.g. the MAVROS
        topics of the ROS node); the base topic is then the fastest of all the columns' topics."""
        for j, col in enumerate(self.columns):
            topic, _, fld = col.partition(".")
            if topic in fields and fld in fields[topic] and topic not in TOPICS:
                self._index.setdefault(topic, []).append((j, fields[topic].index(fld)))
        known = {t: TOPICS[t].rate_hz for t in self._index if t in TOPICS and TOPICS[t].direction == "telemetry"}
        known |= {t: rates[t] for t in self._index if t in rates}
        if known:
            self.base_topic = max(known, key=known.get)

    def _watch_arming(self, topic: str, t_us: int, values: np.ndarray) -> None:
        if self.armed_us is not None:
            return
        for k, name in ARMING_FIELDS.get(topic, ()):
            if k < len(values):
                self._arming_seen = True
                if is_armed(name, values[k]):
                    self.armed_us = int(t_us)

    def counts(self, t_us: int) -> bool:
        """Whether a row at ``t_us`` may alarm: at least ``burn_in_s`` after arming (every row when
        ``burn_in_s`` is 0, as :func:`~scart_bench.benchmark.protocol.counted_rows` counts them)."""
        if self.burn_in_s <= 0:
            return True
        armed = self.armed_us if self.armed_us is not None else (None if self._arming_seen else self._first_us)
        return armed is not None and t_us >= armed + 1e6 * self.burn_in_s

    def on_message(self, topic: str, t_us: int, values: np.ndarray, layer=None) -> None:
        """Take in one forwarded message (navigator view)."""
        self._layer = layer
        if self._first_us is None:
            self._first_us = int(t_us)
        self._watch_arming(topic, t_us, values)
        if self._pending is not None and t_us > self._pending:
            self._emit()
        cols = self._index.get(topic)
        if cols:
            for j, k in cols:
                self._last[j] = values[k]
                self._seen[j] = True
        if topic == self.base_topic:
            self._pending = t_us

    def flush(self) -> None:
        """Score the last row (at the end of the stream)."""
        if self._pending is not None:
            self._emit()

    def _emit(self) -> None:
        t_us = self._pending
        self._pending = None
        row = np.where(self._seen, self._last, np.nan)
        t0 = time.perf_counter()
        if self._stream is not None:
            score = float(self._stream.update(row))
        else:
            self._rows.append(row)
            frame = pd.DataFrame(np.vstack(self._rows), columns=self.columns)
            score = float(self.detector.score(frame)[-1])
        lat = (time.perf_counter() - t0) * 1e3
        self.latency_ms.append(lat)
        self.scores.append((t_us, score))
        if score > self.threshold and self.counts(t_us):
            delay = None
            if self._layer is not None:
                open_windows = [s for s, e in self._layer.windows(0, t_us + 1) if s <= t_us < e]
                if open_windows:
                    delay = (t_us - min(open_windows)) / 1e6
            self.alarms.append(Alarm(t_us, score, lat, delay))
            if not self._in_alarm:
                since = f", {delay:.2f} s after the attack started" if delay is not None else ", no attack active"
                self.log(f"ALARM {self.name}: t={t_us / 1e6:.2f} s score {score:.4g} > {self.threshold:.4g}"
                         f"{since}; scored in {lat:.2f} ms")
            self._in_alarm = True
        else:
            self._in_alarm = False

    def summary(self) -> str:
        if not self.scores:
            return f"{self.name}: no rows scored"
        lat = np.asarray(self.latency_ms)
        first = next((a for a in self.alarms if a.delay_s is not None), None)
        det = f"first alarm in an attack {first.delay_s:.2f} s after its start" if first else "no alarm during an attack"
        return (f"{self.name}: {len(self.scores)} rows scored, {len(self.alarms)} alarm rows; {det}; scoring "
                f"p50 {np.percentile(lat, 50):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms")


def monitor_from_run(run: str | Path, name: str, plugins: list[str] | None = None,
                     log: Callable[[str], None] | None = None, command: str = "proxy") -> StreamMonitor:
    """A StreamMonitor for detector ``name`` of benchmark run ``run``: refitted on the run's training
    flights with the job's saved parameters, row threshold calibrated on its saved validation scores
    (``command``: the command its log lines name).

    The run folder is read as data: the detector is resolved by name among the built-ins, installed
    plugins and the ``plugins`` given now (``--plugin``), never from a file the run folder names.
    """
    from scart_bench.benchmark.protocol import Protocol, counted_rows
    from scart_bench.benchmark.store import RunStore
    from scart_bench.dataset import open_dataset
    from scart_bench.detectors import registry
    from scart_bench.detectors.base import DetectorError

    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    store = RunStore(run)
    if not store.exists():
        raise RunError(f"--run {run}: not a benchmark run folder (no config.json)")
    config = store.read_config()
    status = store.read_status(name)
    if not status or status.get("status") != "OK":
        done = [d for d in store.job_names() if (store.read_status(d) or {}).get("status") == "OK"]
        raise RunError(f"--detector {name!r}: run {run} has no finished (OK) job for it; "
                       f"finished: {', '.join(done) or '(none)'}")
    params = (store.read_params(name) or {}).get("params", {})
    for spec in plugins or []:
        registry.load_plugin(spec)
    if name not in registry.available():
        raise RunError(f"--detector {name!r}: not a built-in or installed detector; the run folder's record of "
                       "where it came from is not executed: load it with --plugin module:Class or file.py:Class")
    if config.get("train_dataset"):
        raise RunError(f"--run {run}: a transfer run (--train-dataset) fits its detectors on columns matched by "
                       "meaning, which a live stream does not carry; give a run on one dataset")
    if (config.get("columns") or {}).get("by") == "meaning":
        raise RunError(f"--run {run}: its flights were read by meaning (their logged columns differ), which a live "
                       "stream does not carry; give a run read as logged (run --columns logged)")
    flights = store.read_flights()
    train = flights.loc[flights["role"] == "train", "flight_id"].astype(str).tolist()
    validation = flights.loc[flights["role"] == "validation", "flight_id"].astype(str).tolist()
    dataset = config.get("dataset", {}).get("path")
    if not dataset or not Path(dataset).exists():
        raise RunError(f"--run {run}: its dataset {dataset!r} is gone; the detector cannot be fitted again")
    ds = open_dataset(dataset)
    try:
        det = registry.make(name, **params)
    except (TypeError, DetectorError) as exc:
        raise RunError(f"--run {run}: the saved parameters of {name} do not fit the detector installed now "
                       f"({exc})") from exc
    log(f"{command}: fitting {name} on the {len(train)} training flights of run {run} ...")
    t0 = time.perf_counter()
    rule = (config.get("identity") or {}).get("features") or {}
    det.fit([ds.flight(fid) for fid in train], features=rule.get("include") or None, exclude=rule.get("exclude") or None)
    scores = store.read_scores(name)
    missing = [fid for fid in validation if fid not in scores]
    if missing:
        raise RunError(f"--run {run}: detector {name} has no saved scores for validation flight {missing[0]}")
    protocol = Protocol.from_dict(config["protocol"])
    # the run's own operating point: its validation flights without their burn-in after arming
    truth = store.read_truth() if protocol.burn_in_s else {}
    armed = flights.set_index("flight_id")["armed_us"] if "armed_us" in flights.columns else {}
    counted = {fid: counted_rows(truth[fid][0], armed.get(fid), protocol.burn_in_s)
               for fid in validation if fid in truth}
    _, row_threshold = protocol.thresholds({fid: np.asarray(scores[fid]) for fid in validation}, counted)
    log(f"{command}: {name} fitted in {time.perf_counter() - t0:.1f} s; row threshold {row_threshold:.4g} "
        f"({protocol.row_rule.describe()}); no alarm before {protocol.burn_in_s:g} s after arming")
    return StreamMonitor(det, row_threshold, name=name, log=log, burn_in_s=protocol.burn_in_s)
