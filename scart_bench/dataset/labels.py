"""Labels of a flight: anomaly windows turned into per-row label columns, and the combined tables.

The labels: ``Is_Anomaly`` (1 inside any window), ``Anomaly_Ids`` (the active scenario ids, joined
by "+", empty outside windows) and ``Anomaly_Kind`` ("attack", "fault" or "attack+fault"). A
combined table aligns every topic of a view on one base topic's timestamps (:func:`combine`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from scart_bench.dataset.record import DatasetError

#: The label columns of every table, in order, after ``Timestamp``.
LABEL_COLUMNS = ("Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind")


def label_rows(timestamps: np.ndarray, windows: Iterable[tuple]) -> np.ndarray:
    """``Is_Anomaly`` for the given timestamps: 1 inside any ``[start, end)`` window."""
    ts = np.asarray(timestamps, dtype=np.int64)
    out = np.zeros(ts.shape[0], dtype=np.int8)
    for w in windows:
        out[(ts >= w[0]) & (ts < w[1])] = 1
    return out


def label_columns(timestamps: np.ndarray, windows: Iterable[tuple]) -> dict[str, np.ndarray]:
    """The three label columns for the given timestamps.

    ``windows`` are ``(start, end)`` or ``(start, end, scenario_id, kind)``; a plain window counts
    as an attack with no id.
    """
    ts = np.asarray(timestamps, dtype=np.int64)
    n = ts.shape[0]
    flag = np.zeros(n, dtype=np.int8)
    ids = np.full(n, "", dtype=object)
    kinds = np.full(n, "", dtype=object)
    for w in windows:
        m = (ts >= w[0]) & (ts < w[1])
        if not m.any():
            continue
        flag[m] = 1
        sid = str(w[2]) if len(w) > 2 else ""
        kind = str(w[3]) if len(w) > 3 else "attack"
        if sid:
            ids[m] = [sid if not old else old if sid in old.split("+") else f"{old}+{sid}" for old in ids[m]]
        kinds[m] = [kind if not old else old if kind in old.split("+") else "+".join(sorted({*old.split("+"), kind}))
                    for old in kinds[m]]
    return {"Is_Anomaly": flag, "Anomaly_Ids": ids, "Anomaly_Kind": kinds}


def labelled_table(timestamps: np.ndarray, values: np.ndarray, fields, windows: Iterable[tuple]) -> pd.DataFrame:
    """A topic table built in one go: ``Timestamp``, the label columns, then ``fields`` (the
    columns of the 2-D ``values``). The same table as inserting the labels into a frame of the
    fields, without pandas' per-insert copies."""
    data = {"Timestamp": timestamps, **label_columns(timestamps, list(windows))}
    for j, name in enumerate(fields):
        data[name] = values[:, j]
    return pd.DataFrame(data)


def insert_labels(df: pd.DataFrame, timestamps: np.ndarray, windows: Iterable[tuple], at: int = 1) -> pd.DataFrame:
    """Put the label columns into ``df`` at position ``at`` (replacing any there were)."""
    labels = label_columns(timestamps, list(windows))
    keep = [c for c in df.columns if c not in LABEL_COLUMNS]
    if df.columns.is_unique and all(isinstance(c, str) for c in df.columns) and 0 <= at <= len(keep):
        # one constructor instead of a drop and three inserts (each copies the table)
        data = {c: df[c] for c in keep[:at]}
        data.update(labels)
        data.update({c: df[c] for c in keep[at:]})
        return pd.DataFrame(data, index=df.index)
    df = df.drop(columns=[c for c in LABEL_COLUMNS if c in df.columns])
    for k, (name, col) in enumerate(labels.items()):
        df.insert(at + k, name, col)
    return df


def combine(topics: dict[str, pd.DataFrame], windows, base_topic: str | None = None,
            tables: tuple[str, ...] = ("all_sensors", "most_frequent")) -> dict[str, pd.DataFrame]:
    """The two combined tables of one view (or only those named in ``tables``).

    ``all_sensors``: every timestamp of every topic; a topic's columns are NaN where it has no
    message. ``most_frequent``: resampled on the timestamps of the most frequently sampled topic
    (or ``base_topic``), each topic holding its last value received at or before the row. A topic's
    repeated timestamp keeps its last message. (Array code: it runs for every flight read.)
    """
    frames = []
    for name, df in topics.items():  # a table, or a dict of column arrays
        cols = [c for c in df.keys() if c != "Timestamp" and c not in LABEL_COLUMNS]
        ts = np.asarray(df["Timestamp"], dtype=np.int64)
        order = np.argsort(ts, kind="stable")
        ts_sorted = ts[order]
        last = np.ones(len(ts_sorted), dtype=bool)
        last[:-1] = ts_sorted[1:] != ts_sorted[:-1]
        rows = order[last]
        frames.append((name, ts_sorted[last], [(f"{name}.{c}", np.asarray(df[c])[rows]) for c in cols]))
    if not frames:
        raise DatasetError("cannot combine a flight with no topics")
    indexes = {}
    if "all_sensors" in tables:
        indexes["all_sensors"] = np.unique(np.concatenate([ts for _, ts, _ in frames]))
    if "most_frequent" in tables:
        if base_topic is None:
            base_topic = _base_topic([(name, ts) for name, ts, _ in frames])
        indexes["most_frequent"] = next(ts for name, ts, _ in frames if name == base_topic)
    out = {}
    for key, index in indexes.items():
        data: dict[str, np.ndarray] = {"Index": np.arange(len(index), dtype=np.int64), "Timestamp": index,
                                       **label_columns(index, windows)}
        for _, ts, columns in frames:
            if key == "all_sensors":
                at = np.searchsorted(index, ts)
                pick, valid = np.full(len(index), -1), np.zeros(len(index), dtype=bool)
                pick[at], valid[at] = np.arange(len(ts)), True
            else:
                pick = np.searchsorted(ts, index, side="right") - 1
                valid = pick >= 0
            for name, values in columns:
                data[name] = _take(values, pick, valid)
        out[key] = pd.DataFrame(data)
    return out


def _take(values: np.ndarray, pick: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``values[pick]`` with NaN where not ``valid`` (ints become float64, as pandas' reindex does)."""
    if valid.all():
        return values[pick]
    if values.dtype.kind in "iub":
        values = values.astype(np.float64)
    out = values[np.where(valid, pick, 0)] if len(values) else np.empty(len(pick), dtype=values.dtype)
    if values.dtype.kind == "f":
        out[~valid] = np.nan
    else:
        out = out.astype(object)
        out[~valid] = np.nan
    return out


def _base_topic(frames: list[tuple[str, np.ndarray]]) -> str:
    """The most frequently sampled topic (distinct timestamps; the first on a tie)."""
    return max(frames, key=lambda item: len(item[1]))[0]
