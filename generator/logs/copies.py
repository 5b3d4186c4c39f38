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

from scart_bench.dataset import LABEL_COLUMNS, FlightRecord, flight_record, label_columns
from scart_bench.generator.modes import csv_record

#: The dtype pandas gives a label column built from text (as with_labels and labelled_table build them).
_TEXT_DTYPE = pd.Series(np.array([""], dtype=object)).dtype


def _same_values(a: pd.Series, b: pd.Series) -> bool:
    """Same dtype and the same bits (numeric columns only: anything else counts as changed)."""
    if a.dtype != b.dtype or len(a) != len(b):
        return False
    x, y = a.to_numpy(), b.to_numpy()
    if x.dtype.kind not in "biuf" or x.dtype != y.dtype:
        return False
    width = np.dtype(f"u{x.dtype.itemsize}")
    return bool(np.array_equal(np.ascontiguousarray(x).view(width), np.ascontiguousarray(y).view(width)))


def _same_fields(a: pd.DataFrame, b: pd.DataFrame, keep: list[str]) -> bool:
    """Whether ``a`` holds ``b``'s columns ``keep`` bit for bit in the same dtypes: all float64 fields
    (a log's usual case) compared in one array operation, others column by column."""
    da, db = a.dtypes, b.dtypes
    if any(da[c] != db[c] for c in keep):
        return False
    floats = [c for c in keep[1:] if db[c] == np.float64]
    if floats:
        x = a.iloc[:, [a.columns.get_loc(c) for c in floats]].to_numpy()
        y = b.iloc[:, [b.columns.get_loc(c) for c in floats]].to_numpy()
        if not np.array_equal(x.view(np.uint64), y.view(np.uint64)):
            return False
    return all(_same_values(a[c], b[c]) for c in keep if c not in floats)


def untouched(nav: dict[str, pd.DataFrame], source: dict[str, pd.DataFrame], windows) -> set[str]:
    """Topics whose replayed table is exactly the source table with the copy's labels (what
    ``with_labels(source, windows)`` gives, column for column, bit for bit, dtypes included)."""
    out = set()
    for topic, a in nav.items():
        b = source.get(topic)
        if b is None or len(a) != len(b) or not isinstance(a.index, pd.RangeIndex) or not a.index.equals(b.index):
            continue
        keep = [c for c in b.columns if c not in LABEL_COLUMNS]
        if not keep or list(a.columns) != [keep[0], *LABEL_COLUMNS, *keep[1:]] or "Timestamp" not in keep:
            continue
        if not _same_fields(a, b, keep):
            continue
        labels = label_columns(b["Timestamp"].to_numpy(), list(windows))
        flag = a["Is_Anomaly"].to_numpy()
        if flag.dtype != labels["Is_Anomaly"].dtype or not np.array_equal(flag, labels["Is_Anomaly"]):
            continue
        if any(a[c].dtype != _TEXT_DTYPE or not np.array_equal(a[c].to_numpy(dtype=object), labels[c])
               for c in LABEL_COLUMNS[1:]):
            continue
        out.add(topic)
    return out


def copy_record(flight_id: str, source: dict[str, pd.DataFrame], result: tuple, scenarios: list, seed: int,
                source_name: str, config: dict) -> FlightRecord:
    """The record ``csv_record(flight_id, source, result, scenarios, seed, source_name, config)`` gives
    (same views, tables, manifest row), with the reference view and the attack's effect computed on
    the changed topics only; an untouched topic's navigator table is also its simulator table."""
    nav, windows, events = result
    same = untouched(nav, source, windows)
    if not same or config.get("flight_config", {}).get("uorb"):  # a uORB view is made from the whole view
        return csv_record(flight_id, source, result, scenarios, seed, source_name, config)
    part = csv_record(flight_id, {t: df for t, df in source.items() if t not in same},
                      ({t: df for t, df in nav.items() if t not in same}, windows, events),
                      scenarios, seed, source_name, config)
    simulator = {t: nav[t] if t in same else part.simulator[t] for t in source}
    manifest = {k: v for k, v in part.manifest.items() if k != "duration_s"}  # of the whole flight, below
    record = flight_record(flight_id, dict(nav), simulator, manifest, part.config, part.windows, part.events)
    record.uorb = part.uorb
    return record
