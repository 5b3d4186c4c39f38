"""Labels of a flight: anomaly windows turned into per-row label columns, and the combined tables.

The labels: ``Is_Anomaly`` (1 inside any window), ``Anomaly_Ids`` (the active scenario ids, joined
by "+", empty outside windows) and ``Anomaly_Kind`` ("attack", "fault" or "attack+fault"). A
combined table aligns every topic of a view on one base topic's timestamps (:func:`combine`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd
import pyarrow as pa

from scart_bench.dataset.record import DatasetError
from scart_bench.dataset.tables import plain_columns

#: The label columns of every table, in order, after ``Timestamp``.
LABEL_COLUMNS = ("Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind")


#: The dtype pandas gives a column built from text: pandas 3's Arrow-backed "str" (earlier: object).
TEXT_DTYPE = pd.Series(np.array([""], dtype=object)).dtype


def text_array(values: np.ndarray):
    """An object array of strings as the column pandas makes of it (``pd.DataFrame({c: values})[c]``'s
    values, the same dtype and text), converted by Arrow in one call where pandas keeps text in Arrow:
    pandas' own inference costs ~0.7 ms a label column of 2,500 rows, a topic table has two."""
    if isinstance(TEXT_DTYPE, pd.StringDtype) and TEXT_DTYPE.storage == "pyarrow":
        return pd.arrays.ArrowStringArray(pa.array(values, type=pa.large_string()), dtype=TEXT_DTYPE)
    return values


def _label_data(timestamps: np.ndarray, windows: list) -> dict:
    """:func:`label_columns` with the text columns as pandas' text arrays (for building frames)."""
    labels = label_columns(timestamps, windows)
    return {k: text_array(v) if v.dtype == object else v for k, v in labels.items()}


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
    data = {"Timestamp": timestamps, **_label_data(timestamps, list(windows))}
    for j, name in enumerate(fields):
        data[name] = values[:, j]
    return pd.DataFrame(data)


def insert_labels(df: pd.DataFrame, timestamps: np.ndarray, windows: Iterable[tuple], at: int = 1) -> pd.DataFrame:
    """Put the label columns into ``df`` at position ``at`` (replacing any there were)."""
    labels = _label_data(timestamps, list(windows))
    keep = [c for c in df.columns if c not in LABEL_COLUMNS]
    if df.columns.is_unique and all(isinstance(c, str) for c in df.columns) and 0 <= at <= len(keep):
        # one constructor instead of a drop and three inserts (each copies the table)
        plain = plain_columns(df)  # plain number columns as their arrays: no Series per column
        data = {c: plain[c] if c in plain else df[c] for c in keep[:at]}
        data.update(labels)
        data.update({c: plain[c] if c in plain else df[c] for c in keep[at:]})
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


def label_patterns(timestamps: np.ndarray, windows: list[tuple]) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
    """The label columns of ``timestamps`` as a pattern index per row and the labels of each pattern
    (one row's :func:`label_columns`): rows inside the same windows share their labels, so a long
    table's text labels are a few strings taken by index (no Python string per row)."""
    ts = np.asarray(timestamps, dtype=np.int64)
    n = ts.shape[0]
    if n > 1 and not (ts[1:] >= ts[:-1]).all():  # out of order: a pattern per distinct set of windows
        codes = np.zeros(n, dtype=object if len(windows) > 62 else np.int64)
        for k, w in enumerate(windows):
            codes = codes + ((ts >= w[0]) & (ts < w[1])).astype(codes.dtype) * (1 << k)
        _, first, index = np.unique(codes, return_index=True, return_inverse=True)
        return index.reshape(-1), [label_columns(ts[i : i + 1], windows) for i in first]
    # in order: each window is a run of rows, so the labels change only where a window starts or ends
    cuts = np.searchsorted(ts, np.array([b for w in windows for b in (w[0], w[1])], dtype=np.int64), side="left")
    bounds = np.unique(np.concatenate([[0, n], cuts]))
    starts, lengths = bounds[:-1], np.diff(bounds)
    starts, lengths = starts[lengths > 0], lengths[lengths > 0]
    labels, seen, segment = [], {}, []
    for i in starts:
        key = tuple(bool(w[0] <= ts[i] < w[1]) for w in windows)
        if key not in seen:
            seen[key] = len(labels)
            labels.append(label_columns(ts[i : i + 1], windows))
        segment.append(seen[key])
    return np.repeat(np.asarray(segment, dtype=np.int64), lengths), labels


class SourceTopic:
    """A topic of an attacked copy that is its source recording's table as loaded, with the copy's
    labels: what ``insert_labels(table, table["Timestamp"], windows)`` gives, column for column, held
    without building it. A copy of an all-topic log holds a hundred such topics; the dataset writer
    stores their timestamps and labels and reads their fields from the source flight's file.

    ``cache`` (a dict shared by the copies of one source) keeps the columns' Arrow arrays."""

    def __init__(self, name: str, table: pd.DataFrame, windows: Iterable[tuple], cache: dict | None = None):
        self.name = name
        self.table = table
        self.windows = [tuple(w) for w in windows]
        self.cache = {} if cache is None else cache
        keep = [c for c in table.columns if c not in LABEL_COLUMNS]
        self.columns = [keep[0], *LABEL_COLUMNS, *keep[1:]]

    def __len__(self) -> int:
        return len(self.table)

    def __getitem__(self, column: str) -> pd.Series:
        """A column as the built table would hold it (the labels built on request)."""
        if column in LABEL_COLUMNS:
            return self.frame()[column]
        key = ("series", column)  # pandas copies a table's attrs on every column it hands out
        if key not in self.cache:
            self.cache[key] = self.table[column]
        return self.cache[key]

    @property
    def dtypes(self) -> list:
        """The columns' dtypes, in the order of :attr:`columns`."""
        if "dtypes" not in self.cache:
            d = self.table.dtypes
            self.cache["dtypes"] = {c: d[c] for c in self.table.columns if c not in LABEL_COLUMNS}
            self.cache["label_dtypes"] = insert_labels(self.table.iloc[:1], self.table["Timestamp"].iloc[:1]
                                                       .to_numpy(), []).dtypes[list(LABEL_COLUMNS)].tolist()
        known, labels = self.cache["dtypes"], dict(zip(LABEL_COLUMNS, self.cache["label_dtypes"]))
        return [labels[c] if c in labels else known[c] for c in self.columns]

    def frame(self) -> pd.DataFrame:
        """The table itself."""
        return insert_labels(self.table, self.table["Timestamp"].to_numpy(), self.windows)

    def label_arrays(self) -> dict[str, pa.Array]:
        """The three label columns as Arrow arrays (``Is_Anomaly`` int8, the others text)."""
        index, labels = label_patterns(self["Timestamp"].to_numpy(), self.windows)
        take = pa.array(index.astype(np.int32))
        out = {"Is_Anomaly": pa.array(np.array([p["Is_Anomaly"][0] for p in labels], dtype=np.int8)).take(take)}
        for c in LABEL_COLUMNS[1:]:
            out[c] = pa.array([str(p[c][0]) for p in labels], type=pa.string()).take(take)
        return out
