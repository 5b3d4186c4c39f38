"""Turn a simulated batch into per-flight tables (topic tables of both views, truth, labels)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.dataset import FlightRecord, flight_record, labelled_table
from scart_bench.generator.engine.simulate import BatchResult
from scart_bench.generator.params import STEP_US
from scart_bench.generator.telemetry.schedule import field_names
from scart_bench.generator.telemetry.timing import message_timing


def topic_table(steps: np.ndarray, values: np.ndarray, delivered: np.ndarray | None, fields, windows,
                last_step: int, timing: tuple[str, int, str] | None = None) -> pd.DataFrame:
    """One flight's table of one topic: Timestamp, labels, fields (undelivered rows dropped).

    ``timing``: (timing, flight seed, topic) to stamp the messages as :func:`message_timing`
    does (jitter, drops, late starts); None or "ideal" keeps the schedule's times."""
    ts_all = steps.astype(np.int64) * STEP_US
    keep = steps <= last_step
    if timing is not None:
        ts_all, kept = message_timing(timing[0], timing[1], timing[2], ts_all)
        keep = keep & kept
    if delivered is not None:
        keep = keep & delivered
    ts = ts_all[keep]
    order = np.argsort(ts, kind="stable")  # a late message comes after the ones stamped before it
    return labelled_table(ts[order], values[keep][order], list(fields), windows)


def flight_views(batch: BatchResult, i: int, windows=()) -> tuple[dict, dict]:
    """Navigator and simulator views of flight ``i`` as {topic: DataFrame}."""
    last = int(batch.exit_step[i])
    timing = getattr(batch, "timing", "ideal")
    nav, sim = {}, {}
    for topic, (steps, vals, _) in batch.simulator.items():
        fields = field_names(topic)
        sim[topic] = topic_table(steps, vals[i], None, fields, windows if topic != "truth" else (), last,
                                 (timing, batch.seeds[i], topic))
    for topic, (steps, vals, ok) in batch.navigator.items():
        if topic == "truth":
            continue
        nav[topic] = topic_table(steps, vals[i], ok[i], field_names(topic), windows, last,
                                 (timing, batch.seeds[i], topic))
    return nav, sim


def truth_table(batch: BatchResult, i: int) -> pd.DataFrame:
    """Flight ``i``'s truth table alone (what :func:`flight_views` puts in the simulator view)."""
    steps, vals, _ = batch.simulator["truth"]
    return topic_table(steps, vals[i], None, field_names("truth"), (), int(batch.exit_step[i]),
                       (getattr(batch, "timing", "ideal"), batch.seeds[i], "truth"))


def normal_record(batch: BatchResult, i: int, flight_id: str, split: str, config: dict) -> FlightRecord:
    """A normal (unattacked) flight ready for the dataset writer."""
    nav, sim = flight_views(batch, i)
    cfg = {**config, "seed": batch.seeds[i], "status": batch.status[i],
           "wind_mean_ned": batch.wind[i].tolist(), "waypoints_ned": batch.waypoints[i].tolist()}
    record = flight_record(flight_id, nav, sim, {"mode": "normal", "seed": batch.seeds[i], "split": split}, cfg,
                           end_us=(int(batch.exit_step[i]) + 1) * STEP_US)
    return with_uorb(record, getattr(batch, "uorb", False))


def with_uorb(record: FlightRecord, wanted: bool) -> FlightRecord:
    """``record`` with its uORB view (made from its simulator view, generator.telemetry.uorb) when ``wanted``."""
    if wanted:
        from scart_bench.generator.telemetry.uorb import uorb_view

        record.uorb = uorb_view(record.simulator)
    return record
