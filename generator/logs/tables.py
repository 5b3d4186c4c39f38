"""What every log reader shares: name rules and the assembly of topic tables.

A reader turns its file into *raw topics*, ``{topic: (timestamps, {field: values}, notes)}`` with
timestamps in the file's own time base (int microseconds); :func:`finish_tables` moves time zero,
sorts, drops duplicate timestamps and makes the tables every reader returns (an int64
``Timestamp`` column, then float64 fields).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import DatasetError

logger = logging.getLogger(__name__)

#: A reader's output before assembly: topic -> (timestamps, fields, notes for the table's attrs).
RawTopics = dict[str, tuple[np.ndarray, dict[str, np.ndarray], dict]]


def sanitize_field_name(name: str) -> str:
    """A column name made of ``[A-Za-z0-9_]``: ``"accelerometer_m_s2[0]"`` -> ``"accelerometer_m_s2_0"``.

    Dots become underscores too (``"current.lat"`` -> ``"current_lat"``), because ``topic.field``
    is the separator of scart-bench's combined tables.
    """
    out = re.sub(r"[^A-Za-z0-9_]+", "_", str(name)).strip("_")
    return out or "field"


def sanitize_topic_name(name: str) -> str:
    """A topic name made of ``[a-z0-9_]`` (``"My Flight-3"`` -> ``"my_flight_3"``)."""
    out = re.sub(r"[^a-z0-9_]+", "_", str(name).lower()).strip("_")
    return out or "topic"


def unique_names(names: list[str]) -> list[str]:
    """Make sanitised names unique by appending ``_2``, ``_3`` ... to later duplicates."""
    seen: dict[str, int] = {}
    out = []
    for n in names:
        if n in seen:
            seen[n] += 1
            cand = f"{n}_{seen[n]}"
            while cand in seen:
                seen[n] += 1
                cand = f"{n}_{seen[n]}"
            n = cand
        seen.setdefault(n, 1)
        out.append(n)
    return out


# ----------------------------------------------------------------------------------------------
# common table assembly


def make_table(ts: np.ndarray, fields: dict[str, np.ndarray]) -> tuple[pd.DataFrame, int, str | None]:
    """Sort by time (stable), drop duplicate timestamps keeping the last; count them.

    Also returns the first field whose value differs between rows of one timestamp (None when the
    dropped rows only repeated the kept one): such rows are two different readings at one time.
    """
    ts = np.asarray(ts, dtype=np.int64)
    order = np.argsort(ts, kind="stable")
    ts = ts[order]
    keep = np.ones(ts.shape[0], dtype=bool)
    if ts.shape[0] > 1:
        keep[:-1] = ts[1:] != ts[:-1]
    n_dup = int(ts.shape[0] - keep.sum())
    cols: dict[str, np.ndarray] = {"Timestamp": ts[keep]}
    conflict = None
    for name, values in fields.items():
        v = np.asarray(values, dtype=np.float64)[order]
        if n_dup and conflict is None:
            same = (v[:-1] == v[1:]) | (np.isnan(v[:-1]) & np.isnan(v[1:]))
            if (~same & ~keep[:-1]).any():
                conflict = name
        cols[name] = v[keep]
    return pd.DataFrame(cols), n_dup, conflict


def finish_tables(raw: RawTopics, source: Path,
                  topics: list[str] | None = None, origin: int | None = None,
                  keep_last: bool = False) -> dict[str, pd.DataFrame]:
    """Build the topic tables (``topics`` only, if given) with time zero at ``origin``.

    ``origin`` defaults to the earliest timestamp over *all* topics of ``raw`` (before the
    selection, so time zero does not move with ``topics``). Messages before it (a ULog's latched
    topics, published before logging started) are put at 0: their value holds at the start.
    ``keep_last``: the input is a logger's record (ULog, DataFlash, tlog, bag), where two messages of a
    topic at one time are two writes and the last one stands; for a table (CSV, Parquet) two
    different rows at one time are an error in the file.
    Each table's ``attrs`` record ``source``, ``topic``, ``origin_us`` (the value in the file's
    own time base that became 0), ``duplicates_dropped`` and any format-specific notes.
    """
    raw = {k: v for k, v in raw.items() if len(v[0]) > 0}
    if not raw:
        raise DatasetError(f"{source}: the log is empty (no messages / data rows)")
    if origin is None:
        origin = int(min(int(np.min(ts)) for ts, _, _ in raw.values()))
    raw = select_topics(raw, topics, source)
    out: dict[str, pd.DataFrame] = {}
    for topic in raw:  # the loaders' order: sorted for ULogs and folders, column order for tables
        ts, fields, notes = raw[topic]
        table, n_dup, conflict = make_table(np.maximum(np.asarray(ts, dtype=np.int64) - origin, 0), fields)
        if conflict is not None and not keep_last:
            # a table of one's own: two different readings at one time is an error in the file, not
            # something to resolve silently (a logger's messages at one time, such as a ULog's latched
            # messages at time zero, are kept: last wins)
            raise DatasetError(f"{source}: topic {topic!r}: rows with the same timestamp hold different "
                               f"values (field {conflict!r}); expected one row per timestamp")
        if n_dup:
            logger.debug("%s: topic %s: dropped %d row(s) with a duplicate timestamp (kept the last)",
                         source, topic, n_dup)
        table.attrs.update({"source": str(source), "topic": topic, "origin_us": origin,
                            "duplicates_dropped": n_dup, **notes})
        out[topic] = table
    return out


def select_topics(tables: dict[str, tuple], topics: list[str] | None, source: Path) -> dict[str, tuple]:
    if topics is None:
        return tables
    missing = [t for t in topics if t not in tables]
    if missing:
        raise DatasetError(f"{source}: topic(s) {missing} not found; the file has: {sorted(tables)}")
    return {t: tables[t] for t in topics}
