"""History: the messages each listener has received, per topic and per flight.

Every message that passes the layer is appended (before any action alters it). A ring buffer
keeps as many messages as the scenarios look back (Duplicate k, Delayed d, AvgSensors n), plus
the count and timestamps of messages received so far. All flights of a batch receive a topic's
messages at the same timestamps, so counts and times are shared by the batch.
"""

from __future__ import annotations

import numpy as np


class TopicHistory:
    """Ring buffer of one topic's last ``depth`` messages for a batch of flights."""

    def __init__(self, n_flights: int, n_fields: int, depth: int):
        self.depth = max(1, int(depth))
        self.values = np.full((self.depth, n_flights, n_fields), np.nan)
        self.times = np.full(self.depth, -1, dtype=np.int64)
        self.count = 0  # messages received so far

    def append(self, t_us: int, values: np.ndarray) -> None:
        slot = self.count % self.depth
        self.values[slot] = values
        self.times[slot] = t_us
        self.count += 1

    def latest(self) -> np.ndarray:
        """(N, F) last message (NaN before the first)."""
        if self.count == 0:
            return self.values[0] * np.nan
        return self.values[(self.count - 1) % self.depth]

    def back(self, k: int | np.ndarray) -> np.ndarray:
        """(N, F) the message ``k`` messages before the latest (k=0: latest), clamped to the oldest kept."""
        k = np.minimum(np.asarray(k, dtype=np.int64), min(self.count, self.depth) - 1)
        k = np.maximum(k, 0)
        slots = (self.count - 1 - k) % self.depth
        if slots.ndim == 0:
            return self.values[int(slots)]
        return self.values[slots, np.arange(slots.shape[0])]

    def mean_last(self, n: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(R, F) mean of the last ``n`` (R,) messages of the flights ``rows`` (default: all)."""
        avail = min(self.count, self.depth)
        n = np.clip(np.asarray(n, dtype=np.int64), 1, max(avail, 1))
        m = int(n.max())
        slots = (self.count - 1 - np.arange(m)) % self.depth  # newest first
        block = self.values[slots] if rows is None else self.values[slots[:, None], rows[None, :]]
        use = np.arange(m)[:, None] < n[None, :]  # (m, R)
        total = np.where(use[:, :, None], block, 0.0).sum(axis=0)
        return total / n[:, None]

    def at_time(self, t_us: np.ndarray) -> np.ndarray:
        """(N, F) the latest message received at or before ``t_us`` (per flight)."""
        avail = min(self.count, self.depth)
        order = [(self.count - 1 - k) % self.depth for k in range(avail)]  # newest first
        times = self.times[order]
        t_us = np.asarray(t_us, dtype=np.int64)
        # index of the newest message with time <= t (clamp to the oldest kept)
        ok = times[None, :] <= t_us[:, None]
        first = np.where(ok.any(axis=1), ok.argmax(axis=1), avail - 1)
        slots = np.asarray(order)[first]
        return self.values[slots, np.arange(t_us.shape[0])]


class History:
    """Histories of every listened topic (created lazily with the depth the scenarios need)."""

    def __init__(self, n_flights: int, depths: dict[str, int] | None = None):
        self.n = n_flights
        self.depths = dict(depths or {})
        self.topics: dict[str, TopicHistory] = {}

    def append(self, topic: str, t_us: int, values: np.ndarray) -> None:
        h = self.topics.get(topic)
        if h is None:
            h = TopicHistory(self.n, values.shape[1], self.depths.get(topic, 1) + 1)
            self.topics[topic] = h
        h.append(t_us, values)

    def get(self, topic: str) -> TopicHistory | None:
        return self.topics.get(topic)

    def count(self, topic: str) -> int:
        h = self.topics.get(topic)
        return 0 if h is None else h.count
