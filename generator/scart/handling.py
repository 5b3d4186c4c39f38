"""Per-message handling times of a live man-in-the-middle (the MAVLink proxy, the ROS node)."""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np


@dataclass
class HandlingStats:
    """The time each message took to handle (ns), and the counters a subclass adds."""

    handle_ns: array = field(default_factory=lambda: array("q"))

    def latency_ms(self, q: float) -> float:
        """The ``q`` quantile (0..1) of the per-message handling time, in milliseconds (NaN before any)."""
        if not len(self.handle_ns):
            return float("nan")
        return float(np.quantile(np.frombuffer(self.handle_ns, dtype=np.int64), q)) / 1e6

    def to_dict(self) -> dict:
        """The counters, with the handling time's p50 and p99 instead of every sample."""
        d = {k: v for k, v in self.__dict__.items() if k != "handle_ns"}
        d["handle_p50_ms"] = self.latency_ms(0.5)
        d["handle_p99_ms"] = self.latency_ms(0.99)
        return d
