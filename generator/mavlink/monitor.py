"""A fitted detector watching the navigator-side stream of a live link.

The monitor rebuilds, message by message, the rows of the navigator view's ``most_frequent``
table (one row per message of the base topic, every other topic holding its last value, as
:func:`scart_bench.generator.dataset.combine` does): a row is complete once a message with a later timestamp
arrives, so the stream gives the same rows as the recorded flight. Each row is scored by calling
the detector on its trailing ``history_rows_`` rows (the rows that reproduce the last row's score;
detectors are causal) and an alarm is logged when the score exceeds the threshold, with the
scoring latency and, while an attack window is open, the delay since the attack started.

The detector is duck-typed (``columns_``, ``score(DataFrame)``, optional ``history_rows_``): the
generator does not import the detector package; ``scart-bench proxy --detector`` builds it.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from scart_bench.generator.topics import TOPICS

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
                 log: Callable[[str], None] | None = None):
        self.detector = detector
        self.threshold = float(threshold)
        self.name = name
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
        self._pending: int | None = None  # timestamp of the base-topic row not yet complete
        self._layer = None
        self.scores: list[tuple[int, float]] = []
        self.alarms: list[Alarm] = []
        self.latency_ms: list[float] = []
        self._in_alarm = False

    def on_message(self, topic: str, t_us: int, values: np.ndarray, layer=None) -> None:
        """Take in one forwarded message (navigator view)."""
        self._layer = layer
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
        self._rows.append(row)
        t0 = time.perf_counter()
        frame = pd.DataFrame(np.vstack(self._rows), columns=self.columns)
        score = float(self.detector.score(frame)[-1])
        lat = (time.perf_counter() - t0) * 1e3
        self.latency_ms.append(lat)
        self.scores.append((t_us, score))
        if score > self.threshold:
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
