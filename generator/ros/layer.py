"""The SCART layer on ROS messages, one at a time: what the node does to each message, without ROS.

A transport (ROS 1 now, ROS 2 later) turns a received message into its field values
(:mod:`scart_bench.generator.ros.topics`) and calls :meth:`RosLayer.on_message`: the values are
given to the same :class:`~scart_bench.generator.scart.layer.AttackLayer` as in simulation mode (a
batch of one flight, point ``link``), and the answer says whether to publish the message as
received, publish altered values, or publish nothing (dropped by the scenario). Both views are kept
for the recording: the simulator view is what the node received, the navigator view what it
published.

The layer's clock is the messages' header stamps, counted from the first one and never decreasing;
a message without a header (``std_msgs/Float64``) takes the last. Scenarios name topics by meaning
(``position``, ``gps.lat``, ``imu.zacc``) and resolve to the MAVROS topics the node carries.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import FlightRecord, append_flights, flight_record, insert_labels
from scart_bench.generator.modes import scenario_manifest
from scart_bench.generator.ros import RosError
from scart_bench.generator.ros.topics import MAVROS_TOPICS, RosTopic, topic_fields
from scart_bench.generator.scart.handling import HandlingStats
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import Scenario

#: The ``source_flight`` of a flight recorded by the SCART node.
SOURCE = "ros-node"
#: The injection point the node serves: the telemetry MAVROS hands the mission computer.
POINT = "link"


class StampClock:
    """Flight time (µs) from message header stamps: counted from the first stamp and never decreasing; a
    message without a stamp (None or 0, e.g. ``std_msgs/Float64``) takes the last time."""

    def __init__(self) -> None:
        self.first_stamp_us: int | None = None
        self.clock_us = 0

    def tick(self, stamp_us: int | None) -> int:
        if stamp_us:
            if self.first_stamp_us is None:
                self.first_stamp_us = int(stamp_us)
            self.clock_us = max(self.clock_us, int(stamp_us) - self.first_stamp_us)
        return self.clock_us


@dataclass
class NodeStats(HandlingStats):
    """Counters of the node and the time it took to run the layer on each message."""

    received: int = 0
    published: int = 0
    altered: int = 0
    dropped: int = 0  # by a scenario action
    errors: int = 0  # messages passed unchanged because the layer raised

    def summary(self) -> str:
        return (
            f"{self.received} messages received, {self.published} published ({self.altered} altered), "
            f"{self.dropped} dropped by the scenario, {self.errors} errors; layer p50 "
            f"{self.latency_ms(0.5):.3f} ms, p99 {self.latency_ms(0.99):.3f} ms"
        )


class RosLayer:
    """The SCART layer for one flight on MAVROS topics.

    ``scenarios``: the flight's scenarios (point ``link``); ``record``: keep both views for
    :meth:`record`; ``listeners``: objects with ``on_message(topic, t_us, values, layer)`` fed with every
    published message as the mission computer sees it (e.g. the live StreamMonitor); one that raises is
    counted and never changes what is published.
    """

    def __init__(
        self,
        scenarios: list[Scenario],
        seed: int = 0,
        record: bool = False,
        listeners: list | tuple = (),
        topics: dict[str, RosTopic] | None = None,
    ):
        self.topics = dict(topics or MAVROS_TOPICS)
        for sc in scenarios:
            if sc.injection_point != POINT:
                raise RosError(
                    f"scenario {sc.id!r} ({sc.source}): injection point {sc.injection_point!r}; the ROS "
                    f"node sits on the telemetry MAVROS publishes (point {POINT!r})"
                )
        self.scenarios = list(scenarios)
        self.seed = int(seed)
        self.fields = topic_fields(self.topics)
        self.layer = AttackLayer(
            [self.scenarios],
            [self.seed],
            fields=self.fields,
            rates={n: t.rate_hz for n, t in self.topics.items()},
        )
        #: the topics the scenarios use (listened, conditions, targets): only these go through the layer
        self.used = frozenset(t for t in self.layer.listened if t in self.topics)
        self.recording = bool(record)
        self.listeners = list(listeners)
        self.stats = NodeStats()
        self.views: dict[str, dict[str, tuple[list[int], list[np.ndarray]]]] = {
            "navigator": {},
            "simulator": {},
        }
        self.clock = StampClock()
        self.started_wall = time.time()
        self.log_errors: list[str] = []

    def needs_values(self, topic: str) -> bool:
        """Whether the transport must convert a message of ``topic`` to values (else: publish it as is)."""
        return topic in self.used or self.recording or bool(self.listeners)

    def tick(self, stamp_us: int | None) -> int:
        """The flight time (µs) of a message stamped ``stamp_us`` (None or 0: no stamp; the last time)."""
        return self.clock.tick(stamp_us)

    def on_message(
        self, topic: str, stamp_us: int | None, values: np.ndarray
    ) -> tuple[np.ndarray | None, bool]:
        """Run one message through the layer: (the values to publish, or None when they are unchanged; whether
        to publish at all). ``values`` are the message's fields in the order of its topic."""
        t0 = time.perf_counter_ns()
        st = self.stats
        st.received += 1
        t_us = self.tick(stamp_us)
        values = np.asarray(values, dtype=np.float64)
        new, ok = None, True
        if topic in self.used:
            try:
                res = self.layer.on_messages(POINT, 0, t_us, {topic: values[None, :]})
                vals, delivered = res[topic]
                ok = bool(delivered[0])
                if ok and not np.array_equal(vals[0], values, equal_nan=True):
                    new = vals[0]
            except Exception as exc:  # fail open: a bug in an action must not cut the mission computer off
                st.errors += 1
                if len(self.log_errors) < 5:
                    self.log_errors.append(f"{topic}: {type(exc).__name__}: {exc}")
                new, ok = None, True
        if self.recording:
            self._add("simulator", topic, t_us, values)
        if not ok:
            st.dropped += 1
        else:
            st.published += 1
            seen = values if new is None else new
            if new is not None:
                st.altered += 1
            if self.recording:
                self._add("navigator", topic, t_us, seen)
            for listener in self.listeners:
                try:
                    listener.on_message(topic, t_us, seen, self.layer)
                except Exception:  # a failing listener must not change what is published
                    st.errors += 1
        st.handle_ns.append(time.perf_counter_ns() - t0)
        return new, ok

    def _add(self, view: str, topic: str, t_us: int, values: np.ndarray) -> None:
        ts, vals = self.views[view].setdefault(topic, ([], []))
        ts.append(t_us)
        vals.append(values)

    # -- the recorded flight ----------------------------------------------------------------------
    @property
    def end_us(self) -> int:
        return self.clock.clock_us + 1

    def windows(self) -> list[tuple[int, int]]:
        """Attack windows so far (an open one is closed at the current clock)."""
        return self.layer.windows(0, self.end_us)

    def _table(self, topic: str, ts: list[int], vals: list[np.ndarray], windows) -> pd.DataFrame:
        t = np.asarray(ts, dtype=np.int64)
        names = list(self.fields[topic])
        df = pd.DataFrame(np.vstack(vals) if vals else np.zeros((0, len(names))), columns=names)
        df.insert(0, "Timestamp", t)
        return insert_labels(df, t, windows)

    def record(self, flight_id: str, extra_config: dict | None = None, split: str = "test") -> FlightRecord:
        """The flight seen so far as a :class:`scart_bench.dataset.FlightRecord`: both views, labels, events.
        With scenarios it is an attacked flight of mode ``simulation`` (closed loop), split ``test``; without,
        a normal flight of split ``split``."""
        end_us = self.end_us
        windows = self.layer.labelled_windows(0, end_us)
        views = {
            v: {t: self._table(t, *self.views[v][t], windows) for t in self.topics if t in self.views[v]}
            for v in ("navigator", "simulator")
        }
        if self.scenarios:
            manifest = scenario_manifest(self.scenarios, "simulation", self.seed, source=SOURCE)
        else:
            manifest = {
                "mode": "normal",
                "scenario_id": "",
                "action": "",
                "target": "",
                "injection_point": "",
                "params": "{}",
                "seed": self.seed,
                "split": split,
                "source_flight": SOURCE,
            }
        config = {
            **(extra_config or {}),
            "seed": self.seed,
            "mode": manifest["mode"],
            "source": SOURCE,
            "scenarios": [s.to_dict() for s in self.scenarios],
            "stats": self.stats.to_dict(),
            "topics": {t: self.topics[t].ros_name for t in sorted(views["simulator"])},
            "first_stamp_us": self.clock.first_stamp_us,
            "recorded_at": datetime.fromtimestamp(self.started_wall, UTC).isoformat(timespec="seconds"),
        }
        return flight_record(
            flight_id,
            views["navigator"],
            views["simulator"],
            manifest,
            config,
            windows,
            self.layer.event_log(0, end_us),
            end_us=end_us,
        )


def save_recording(record: FlightRecord, out: str | Path, fmt: str = "parquet") -> Path:
    """Write the flight into dataset ``out``: appended when ``out`` is a dataset, else a new one."""
    if not record.navigator:
        raise RosError(f"{out}: nothing was recorded (no message of a MAVROS topic reached the node)")
    return append_flights(Path(out), [record], fmt=fmt, info={"profile": "live", "source": SOURCE})
