"""An attacked copy of a dataset's flight built at the cost of what the attack changed.

A log imported with all its topics holds a hundred or more topics (about 1,100 fields on the shared
ULogs); a grid attack changes a handful. :func:`copy_record` builds the same record as
:func:`scart_bench.generator.modes.csv_record` while the per-topic work (the clean reference view
with labels, the attack's effect) is done only on the topics the attack changed: an untouched topic
is the replayed table itself in both views. The dataset writer then stores only the changed fields
and reads the others from the source flight's file (scart_bench.dataset.write ``share_sources``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa

from scart_bench.dataset import LABEL_COLUMNS, FlightRecord, SourceTopic, flight_record, label_columns
from scart_bench.dataset.labels import TEXT_DTYPE  # the dtype of a label column (with_labels, labelled_table)
from scart_bench.generator.logs.orientation import recorded_view
from scart_bench.generator.modes import csv_record, passed_table


def _bits(x: np.ndarray) -> np.ndarray | None:
    """A numeric column as unsigned integers of its width (for a bit-for-bit comparison), or None."""
    if x.dtype.kind not in "biuf" or x.dtype.itemsize not in (1, 2, 4, 8):
        return None
    return np.ascontiguousarray(x).view(np.dtype(f"u{x.dtype.itemsize}"))


class _SourceColumns:
    """One source flight's topic tables as column arrays (taken from pandas once for all its copies)."""

    def __init__(self, source: dict[str, pd.DataFrame]):
        self.source = source
        self._topics: dict[str, tuple] = {}
        self._passes: dict[str, bool] = {}
        self._caches: dict[str, dict] = {}

    def passes_as_source(self, name: str, replayed: pd.DataFrame) -> bool:
        """Whether the table csv mode gives topic ``name`` when it passes ``replayed`` unchanged (its
        :func:`passed_table`, in the recording's own fields) is the source's table with the copy's labels,
        bit for bit (:func:`untouched`). The labels are made from the same timestamps and windows on
        both sides, so the answer does not depend on the windows: decided once for all the copies."""
        if name not in self._passes:
            table = recorded_view({name: passed_table(replayed)})[name]
            self._passes[name] = name in untouched({name: table}, self.source, ())
        return self._passes[name]

    def source_topic(self, name: str, windows) -> SourceTopic:
        """Topic ``name`` of a copy with ``windows``, held as the source's table."""
        return SourceTopic(name, self.source[name], windows, self._caches.setdefault(name, {}))

    def topic(self, name: str) -> tuple | None:
        """(non-label columns, their dtypes, their bits or None where not numeric) of topic ``name``."""
        if name not in self._topics:
            b = self.source.get(name)
            if b is None:
                self._topics[name] = None
            else:
                keep = [c for c in b.columns if c not in LABEL_COLUMNS]
                dtypes = b.dtypes
                bits = [_bits(b[c].to_numpy()) for c in keep]
                floats = None  # the fields after the first as one (rows x fields) array when all are float64
                if len(keep) > 1 and all(dtypes[c] == np.float64 for c in keep[1:]):
                    floats = np.column_stack([x.view(np.float64) for x in bits[1:]]).view(np.uint64)
                self._topics[name] = (keep, [dtypes[c] for c in keep], bits, floats)
        return self._topics[name]


def _same_columns(a: pd.DataFrame, keep: list[str], bits: list, floats: np.ndarray | None) -> bool:
    """Whether ``a`` (columns: ``keep[0]``, the labels, ``keep[1:]``) holds the source's fields bit for
    bit: all float64 fields (a log's usual case) taken from pandas in one block."""
    if not np.array_equal(_bits(a[keep[0]].to_numpy()), bits[0]):
        return False
    if floats is not None:
        return np.array_equal(a.iloc[:, 1 + len(LABEL_COLUMNS):].to_numpy(np.float64).view(np.uint64), floats)
    return all(np.array_equal(_bits(a[c].to_numpy()), x) for c, x in zip(keep[1:], bits[1:]))


def _same_text(column: pd.Series, expected: np.ndarray) -> bool:
    """Whether a text column holds ``expected`` (str objects) value for value, compared as Arrow arrays
    (no Python object per row) where the column is Arrow text, as a table built from str objects is."""
    arr = pa.array(column.array) if isinstance(column.dtype, pd.StringDtype) and column.dtype.storage == "pyarrow" \
        else None
    if isinstance(arr, pa.ChunkedArray):
        arr = arr.combine_chunks()
    if arr is None or not (pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type)):
        return bool(np.array_equal(column.to_numpy(dtype=object), expected))
    return arr.null_count == 0 and arr.equals(pa.array(expected, type=arr.type))


#: The source flight whose columns were taken last: the copies of one source come one after the other.
_last: list[_SourceColumns] = []


def _columns_of(source: dict[str, pd.DataFrame]) -> _SourceColumns:
    if not _last or _last[0].source is not source:
        _last[:] = [_SourceColumns(source)]
    return _last[0]


def untouched(nav: dict[str, pd.DataFrame], source: dict[str, pd.DataFrame], windows) -> set[str]:
    """Topics whose replayed table is exactly the source table with the copy's labels (what
    ``with_labels(source, windows)`` gives, column for column, bit for bit, dtypes included)."""
    cols = _columns_of(source)
    out = set()
    for topic, a in nav.items():
        if isinstance(a, SourceTopic):  # held as the source's table (copy_record decided it)
            out.add(topic)
            continue
        b = source.get(topic)
        if b is None or len(a) != len(b) or not isinstance(a.index, pd.RangeIndex) or not a.index.equals(b.index):
            continue
        keep, dtypes, bits, floats = cols.topic(topic)
        if not keep or list(a.columns) != [keep[0], *LABEL_COLUMNS, *keep[1:]] or "Timestamp" not in keep:
            continue
        da = a.dtypes.tolist()  # in the order of the columns checked above: keep[0], the labels, keep[1:]
        if da[:1] + da[1 + len(LABEL_COLUMNS):] != dtypes or any(x is None for x in bits):
            continue
        if not _same_columns(a, keep, bits, floats):
            continue
        labels = label_columns(a["Timestamp"].to_numpy(), list(windows))
        flag = a["Is_Anomaly"].to_numpy()
        if flag.dtype != labels["Is_Anomaly"].dtype or not np.array_equal(flag, labels["Is_Anomaly"]):
            continue
        if any(d != TEXT_DTYPE for d in da[2:1 + len(LABEL_COLUMNS)]) or \
                any(not _same_text(a[c], labels[c]) for c in LABEL_COLUMNS[1:]):
            continue
        out.add(topic)
    return out


def copy_record(flight_id: str, source: dict[str, pd.DataFrame], result: tuple, scenarios: list, seed: int,
                source_name: str, config: dict, replayed: dict[str, pd.DataFrame] | None = None) -> FlightRecord:
    """The record ``csv_record(flight_id, source, result, scenarios, seed, source_name, config)`` gives
    (same views, tables, manifest row), with the reference view and the attack's effect computed on
    the changed topics only; an untouched topic's navigator table is also its simulator table.

    ``result`` may leave the topics csv mode passed unchanged as None (csv_mode ``leave_passed``;
    ``replayed``: the tables it replayed): each is then held as the source's table with the copy's
    labels (:class:`SourceTopic`, not built) where that is what csv mode would have given, and
    built as csv mode builds it otherwise."""
    nav, windows, events = result
    if any(df is None for df in nav.values()):
        if replayed is None:
            raise ValueError("copy_record: a result with topics left out (None) needs the replayed tables")
        cols = _columns_of(source)
        nav = {t: df if df is not None else cols.source_topic(t, windows) if cols.passes_as_source(t, replayed[t])
               else recorded_view({t: passed_table(replayed[t], windows)})[t] for t, df in nav.items()}
    uorb = config.get("flight_config", {}).get("uorb")
    same = untouched(nav, source, windows)
    if not same or uorb:  # a uORB view is made from the whole view
        nav = {t: df.frame() if isinstance(df, SourceTopic) else df for t, df in nav.items()}
        return csv_record(flight_id, source, (nav, windows, events), scenarios, seed, source_name, config)
    part = csv_record(flight_id, {t: df for t, df in source.items() if t not in same},
                      ({t: df for t, df in nav.items() if t not in same}, windows, events),
                      scenarios, seed, source_name, config)
    simulator = {t: nav[t] if t in same else part.simulator[t] for t in source}
    manifest = {k: v for k, v in part.manifest.items() if k != "duration_s"}  # of the whole flight, below
    record = flight_record(flight_id, dict(nav), simulator, manifest, part.config, part.windows, part.events)
    record.uorb = part.uorb
    # the writer compares each of these with the stored source once for all the copies of the source
    record.same_as_source = {t: source[t] for t in same}
    return record
