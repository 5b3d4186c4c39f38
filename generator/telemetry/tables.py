"""Turn a simulated batch into per-flight tables (topic tables of both views, truth, labels)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.dataset import FlightRecord, flight_record, labelled_table
from scart_bench.generator.params import STEP_US
from scart_bench.generator.telemetry.batch import BatchResult
from scart_bench.generator.telemetry.schedule import field_names
from scart_bench.generator.telemetry.timing import message_timing


def topic_table(steps: np.ndarray, values: np.ndarray, delivered: np.ndarray | None, fields, windows,
                last_step: int, timing: tuple | None = None, rate_hz: float | None = None
                ) -> pd.DataFrame:
    """One flight's table of one topic: Timestamp, labels, fields (undelivered rows dropped).

    ``timing``: (timing, flight seed, topic[, timing table]) to stamp the messages as :func:`message_timing`
    does (jitter, drops, late starts; ``rate_hz``: the topic's, where it is not a schedule's);
    None or "ideal" keeps the schedule's times."""
    ts_all = steps.astype(np.int64) * STEP_US
    keep = steps <= last_step
    if timing is not None:
        ts_all, kept = message_timing(timing[0], timing[1], timing[2], ts_all, rate_hz, *timing[3:])
        keep = keep & kept
    if delivered is not None:
        keep = keep & delivered
    ts = ts_all[keep]
    order = np.argsort(ts, kind="stable")  # a late message comes after the ones stamped before it
    return labelled_table(ts[order], values[keep][order], list(fields), windows)


def flight_views(batch: BatchResult, i: int, windows=()) -> tuple[dict, dict]:
    """Navigator and simulator views of flight ``i`` as {topic: DataFrame}."""
    last = int(batch.exit_step[i])
    timing, table = getattr(batch, "timing", "ideal"), getattr(batch, "timing_table", ())
    nav, sim = {}, {}
    for topic, (steps, vals, _) in batch.simulator.items():
        fields = field_names(topic)
        sim[topic] = topic_table(steps, vals[i], None, fields, windows if topic != "truth" else (), last,
                                 (timing, batch.seeds[i], topic, table))
    for topic, (steps, vals, ok) in batch.navigator.items():
        if topic == "truth":
            continue
        nav[topic] = topic_table(steps, vals[i], ok[i], field_names(topic), windows, last,
                                 (timing, batch.seeds[i], topic, table))
    return nav, sim


def uorb_stream_tables(batch: BatchResult, i: int, windows=()) -> dict[str, pd.DataFrame]:
    """Flight ``i``'s rows of the uORB topics made of the flight controller's streams
    (``batch.uorb_streams``, recorded with FlightConfig.uorb), as {uORB topic: table of the stream's
    fields}: a topic on a slower clock of its own takes the stream's row due at each of its ticks
    (generator.telemetry.uorb.own_clock_rows, on the schedule's times), then each topic is stamped
    with the batch's timing under its own name, like the views. Empty when the batch has no streams."""
    from scart_bench.generator.telemetry.uorb import UORB_TOPICS, own_clock_rows

    streams = getattr(batch, "uorb_streams", {})
    last = int(batch.exit_step[i])
    timing, table = getattr(batch, "timing", "ideal"), getattr(batch, "timing_table", ())
    out = {}
    for name, topic in UORB_TOPICS.items():
        if topic.stream not in streams:
            continue
        steps, vals, _ = streams[topic.stream]
        vals = vals[i]
        if topic.rate_hz < topic.source_rate_hz(True):
            rows = own_clock_rows(steps * STEP_US, topic.rate_hz)
            steps, vals = steps[rows], vals[rows]
        out[name] = topic_table(steps, vals, None, field_names(topic.stream), windows, last,
                                (timing, batch.seeds[i], name, table), topic.rate_hz)
    return out


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
    wanted = getattr(batch, "uorb", False)
    return with_uorb(record, wanted, uorb_stream_tables(batch, i) if wanted else None)


def with_uorb(record: FlightRecord, wanted: bool, streams: dict[str, pd.DataFrame] | None = None) -> FlightRecord:
    """``record`` with its uORB view (generator.telemetry.uorb) when ``wanted``: made from the flight
    controller's ``streams`` (:func:`uorb_stream_tables`) where the flight has them, else from its
    simulator view (a csv-mode flight, a recording)."""
    if wanted:
        from scart_bench.generator.telemetry.uorb import uorb_view

        record.uorb = uorb_view(record.simulator, streams)
    return record
