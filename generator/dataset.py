"""Reading and writing datasets: the compact layout (default) and the paper's layout.

```
<dataset>/manifest.(parquet|csv)     one row per flight; written last: a dataset is complete
                                     exactly when its manifest exists
<dataset>/dataset.json               format, layout, profile, seed, versions
<dataset>/flights/<id>/raw/          config.json (scenario, mission, seed, versions), events.csv
compact layout (Parquet; generator.compact):
<dataset>/flights/<id>/<view>.parquet  navigator.parquet, simulator.parquet: every topic of the view
                                     in one file; the combined tables are made from it on reading
paper layout (the paper's files; CSV or Parquet):
<dataset>/flights/<id>/sensors/      navigator/<topic>.<ext> and simulator/<topic>.<ext>
<dataset>/flights/<id>/combined/     navigator_all_sensors, navigator_most_frequent,
                                     simulator_all_sensors, simulator_most_frequent
```
Readers read both layouts (each flight's own); the tables read back are the same, except that the
compact layout's float32 fields come back as float64 holding their float32 values.
Topic tables have columns ``Timestamp`` (integer microseconds from the start of the run), the
labels and the topic's fields. Combined tables start with ``Index``, ``Timestamp``, the labels and
then one ``topic.field`` column per field of every topic. The labels: ``Is_Anomaly`` (1 inside
any window), ``Anomaly_Ids`` (the active scenario ids, joined by "+", empty outside windows) and
``Anomaly_Kind`` ("attack", "fault" or "attack+fault"; empty outside windows).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.errors import ScartBenchError
from scart_bench.generator import compact
from scart_bench.locks import FolderLock
from scart_bench.names import check_id, inside

FORMATS = ("parquet", "csv")
#: "compact": one Parquet file per view per flight (the default for Parquet); "paper": the paper's
#: per-topic and combined files (CSV, or Parquet on request)
LAYOUTS = ("compact", "paper")
VIEWS = ("navigator", "simulator")
#: Views with per-topic tables (``sensors/<view>/``); ``uorb`` only for flights generated with it.
TOPIC_VIEWS = (*VIEWS, "uorb")
TABLES = ("most_frequent", "all_sensors")
MANIFEST_COLUMNS = (
    "flight_id", "mode", "scenario_id", "action", "target", "injection_point", "params", "seed",
    "split", "rows", "duration_s", "attack_start_us", "attack_end_us", "source_flight", "kind",
    "effect_rows", "effect_fields", "no_effect", "detectability",
    "impact_max_dev_m", "impact_final_dev_m", "impact_mission_completed", "impact_landing_dist_m",
    "impact_crashed", "checksum",
)
#: Simulator-view topics that are the vehicle's true state, not link messages (kept out of the
#: combined tables): the flight's own and, for a simulation-mode attacked flight, its twin's.
TRUTH_TOPICS = ("truth", "twin_truth")


class DatasetError(ScartBenchError):
    """A dataset folder or file is missing, incomplete or malformed."""


@dataclass
class FlightRecord:
    """One flight as produced by the generator or the attack layer, before it is written.

    ``navigator`` and ``simulator`` map topic name -> table (``Timestamp``, ``Is_Anomaly``,
    fields). ``windows`` are the attack windows ``[start_us, end_us)`` in which an action was
    active; ``events`` is the attack event log (one dict per event). ``uorb``: the flight's uORB
    view (generator.uorb; topic -> table like the other views), written as a third view when given.
    """

    flight_id: str
    navigator: dict[str, pd.DataFrame]
    simulator: dict[str, pd.DataFrame]
    manifest: dict
    config: dict
    windows: list[tuple] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    uorb: dict[str, pd.DataFrame] | None = None


#: Manifest values of a flight that does not set them (a normal flight, no attack).
MANIFEST_DEFAULTS = {
    "mode": "normal", "scenario_id": "", "action": "", "target": "", "injection_point": "", "params": "{}",
    "seed": 0, "split": "test", "source_flight": "", "kind": "",
}


def flight_record(flight_id: str, navigator: dict[str, pd.DataFrame], simulator: dict[str, pd.DataFrame],
                  manifest: dict, config: dict, windows: Iterable[tuple] = (), events: Iterable[dict] = (),
                  end_us: int | None = None) -> FlightRecord:
    """The one way a flight record is built (generator, attack layer, import, proxy recording).

    ``manifest`` holds what differs from :data:`MANIFEST_DEFAULTS` (mode, split, seed, the
    attack fields...); ``duration_s`` is ``end_us`` / 1e6, where ``end_us`` (the end of the
    flight, exclusive) defaults to one microsecond after the last timestamp of any table.
    """
    if end_us is None:
        last = [int(df["Timestamp"].iloc[-1]) for view in (navigator, simulator) for df in view.values() if len(df)]
        end_us = max(last) + 1 if last else 0
    row = {**MANIFEST_DEFAULTS, **manifest, "duration_s": int(end_us) / 1e6}
    return FlightRecord(flight_id=str(flight_id), navigator=navigator, simulator=simulator, manifest=row,
                        config=config, windows=list(windows), events=list(events))


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


def combine(topics: dict[str, pd.DataFrame], windows, base_topic: str | None = None) -> dict[str, pd.DataFrame]:
    """The two combined tables of one view.

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
    union = np.unique(np.concatenate([ts for _, ts, _ in frames]))
    if base_topic is None:
        base_topic = _base_topic([(name, ts) for name, ts, _ in frames])
    base = next(ts for name, ts, _ in frames if name == base_topic)
    out = {}
    for key, index in (("all_sensors", union), ("most_frequent", base)):
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


def _write_table(df: pd.DataFrame, path: Path, fmt: str) -> None:
    if fmt == "parquet":
        df.to_parquet(path.with_suffix(".parquet"), index=False, compression="zstd")
    else:
        df.to_csv(path.with_suffix(".csv"), index=False, float_format=None)


def _read_table(path: Path, columns: list[str] | None = None) -> pd.DataFrame:
    for suffix in (".parquet", ".csv"):
        p = path.with_suffix(suffix)
        if p.exists():
            if suffix == ".parquet":
                return pd.read_parquet(p, columns=columns)
            df = _read_csv_exact(p, columns)
            for c in ("Anomaly_Ids", "Anomaly_Kind"):  # CSV has no empty string: it reads back as NaN
                if c in df.columns:
                    df[c] = df[c].astype(object).where(df[c].notna(), "")
            return df
    raise DatasetError(f"{path}.(parquet|csv): no such table")


def _read_csv_exact(path: Path, columns: list[str] | None) -> pd.DataFrame:
    """Floats exactly as written (pandas 3 deprecates ``float_precision``; newer ones drop it)."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            return pd.read_csv(path, usecols=columns, float_precision="round_trip")
    except TypeError:
        return pd.read_csv(path, usecols=columns)


def check_output_dir(out: Path, overwrite: bool = False) -> None:
    """Refuse an output folder that holds something other than a dataset, or is unwritable."""
    out = Path(out)
    recover(out)
    if out.exists():
        if not out.is_dir():
            raise DatasetError(f"{out}: exists and is not a folder")
        entries = [p.name for p in out.iterdir()]
        if entries and not is_dataset(out):
            raise DatasetError(f"{out}: exists, is not empty and is not a scart-bench dataset (no manifest); "
                               "choose a new folder")
        if entries and not overwrite:
            raise DatasetError(f"{out}: a dataset is already there; pass --overwrite to replace it")
    parent = out if out.exists() else out.parent
    while not parent.exists():
        parent = parent.parent
    try:  # a real write: os.access says yes to root even where nothing can be written
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as exc:
        raise DatasetError(f"{out}: folder {parent} is not writable ({exc.strerror})") from exc


def exit_with_parent(parent: int, period_s: float = 0.5) -> None:
    """In a worker process: end it as soon as its parent is gone (SIGKILL or SIGTERM of the command
    leaves no writer behind). Started as the worker pool's initializer."""
    import threading
    import time

    def watch() -> None:
        while True:
            time.sleep(period_s)
            if os.getppid() != parent:
                os._exit(3)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def dataset_lock(out: str | Path) -> FolderLock:
    """The lock every writer of the dataset at ``out`` holds (a hidden file beside it, so that it also
    covers a dataset being built in a sibling folder): a second writer is refused (LockHeld, exit 2)."""
    out = Path(out)
    return FolderLock(out.parent / f".{out.name}.lock", str(out))


def recover(out: str | Path) -> None:
    """Finish what a killed writer left beside ``out``: its partial folder is removed and, when it
    was killed between its two renames (the old dataset moved aside, the new one not yet in place),
    the old dataset is moved back. Does nothing while another process holds the dataset's lock."""
    from scart_bench.locks import LockHeld

    out = Path(out)
    partial, old = out.parent / f".{out.name}.partial", out.parent / f".{out.name}.old"
    if not (partial.exists() or old.exists()) or not out.parent.is_dir():
        return
    try:
        lock = dataset_lock(out).acquire()
    except (LockHeld, OSError):
        return
    try:
        shutil.rmtree(partial, ignore_errors=True)
        if old.exists():
            if not out.exists() and is_dataset(old):
                os.replace(old, out)
            else:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        lock.release()


@contextmanager
def replacing(out: str | Path) -> Iterator[Path]:
    """Build a dataset in a hidden sibling folder and move it to ``out`` only once complete.

    Yields the folder to write into. Until the new dataset is complete, the old one at ``out`` (if
    any) is untouched: an error (a full disk) or an interrupt leaves it as it was and removes the
    partial folder. Holds :func:`dataset_lock` throughout.
    """
    out = Path(out)
    recover(out)
    with dataset_lock(out):
        partial = out.parent / f".{out.name}.partial"
        old = out.parent / f".{out.name}.old"
        shutil.rmtree(partial, ignore_errors=True)
        try:
            yield partial
            if out.exists():
                shutil.rmtree(old, ignore_errors=True)
                os.replace(out, old)  # two renames: the new dataset appears whole, the old goes after
            os.replace(partial, out)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(partial, ignore_errors=True)


def is_dataset(path: Path) -> bool:
    path = Path(path)
    return (path / "manifest.parquet").exists() or (path / "manifest.csv").exists()


class DatasetWriter:
    """Writes flights one by one and the manifest last (call ``close`` to complete).

    The only writer of manifests. A new dataset: a writer that is not closed leaves no
    manifest, so the folder never looks complete. ``append=True`` adds flights to the dataset
    at ``out`` (a new one if there is none): its format is kept, a flight id already there is
    refused before anything is written, and the manifest is replaced atomically at ``close``,
    so the dataset is complete before and after; ``abort`` removes the flights it wrote.
    """

    def __init__(self, out: str | Path, fmt: str = "parquet", info: dict | None = None,
                 overwrite: bool = False, workers: int = 0, append: bool = False, layout: str | None = None):
        if fmt not in FORMATS:
            raise DatasetError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
        self.out = Path(out)
        self.fmt = fmt
        self.layout = check_layout(fmt, layout)
        self.info = dict(info or {})
        self.existing: pd.DataFrame | None = None
        self.written: list[str] = []
        self._lock = dataset_lock(self.out).acquire() if append else None
        if append and is_dataset(self.out):
            ds = open_dataset(self.out)
            self.existing = ds.manifest
            self.fmt = ds.info.get("format", "csv" if (self.out / "manifest.csv").exists() else "parquet")
            self.layout = ds.info.get("layout", "paper")  # datasets from before the compact layout
            self.info = {**ds.info, **{k: v for k, v in self.info.items() if k not in ds.info}}
        else:
            check_output_dir(self.out, overwrite=overwrite)
            if self.out.exists() and any(self.out.iterdir()):
                for name in ("manifest.parquet", "manifest.csv"):
                    (self.out / name).unlink(missing_ok=True)
                shutil.rmtree(self.out / "flights", ignore_errors=True)
        (self.out / "flights").mkdir(parents=True, exist_ok=True)
        self.ids: set[str] = set() if self.existing is None else set(self.existing["flight_id"].astype(str))
        self.rows: list[dict] = []
        self.workers = int(workers)
        self._pending: list = []
        self._pool = None
        if self.workers > 0:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=exit_with_parent, initargs=(os.getpid(),))

    def write(self, record: FlightRecord) -> None:
        """Write one flight's raw, sensors and combined folders (in a worker process if any)."""
        check_id(record.flight_id, "flight id")  # before any path is made from it
        if record.flight_id in self.ids:
            raise DatasetError(f"{self.out}: a flight {record.flight_id!r} is already in the dataset; "
                               "flight ids must be unique")
        self.ids.add(record.flight_id)
        self.written.append(record.flight_id)
        if self.existing is not None:  # a folder left by an append that never finished
            shutil.rmtree(inside(self.out / "flights", record.flight_id), ignore_errors=True)
        if self._pool is None:
            self.rows.append(write_flight(self.out, self.fmt, record, self.layout))
            return
        while len(self._pending) >= 2 * self.workers:  # bound the records held in memory
            self.rows.append(self._pending.pop(0).result())
        self._pending.append(self._pool.submit(write_flight, self.out, self.fmt, record, self.layout))

    def add_written(self, rows: list[dict]) -> None:
        """Take the manifest rows of flights written into this dataset by another process (after
        the flights written through this writer, in order)."""
        ids = [str(r["flight_id"]) for r in rows]
        taken = sorted(set(ids) & self.ids)
        if taken or len(set(ids)) != len(ids):
            raise DatasetError(f"{self.out}: flight ids written twice: {', '.join(taken[:5]) or 'within the rows'}")
        while self._pending:
            self.rows.append(self._pending.pop(0).result())
        self.ids.update(ids)
        self.written.extend(ids)
        self.rows.extend(rows)

    def abort(self) -> None:
        """Stop without writing a manifest: a new dataset stays incomplete; an appended-to dataset
        keeps its manifest and loses the flights this writer wrote."""
        if self._pool is not None:
            for f in self._pending:
                f.cancel()
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            self._pending = []
        if self.existing is not None:
            for fid in self.written:
                shutil.rmtree(inside(self.out / "flights", fid), ignore_errors=True)
        self._release()

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def close(self) -> Path:
        """Write dataset.json and, last, the manifest. Returns the manifest path."""
        if self._pool is not None:
            try:
                self.rows.extend(f.result() for f in self._pending)
            finally:
                self._pending = []
                self._pool.shutdown()
                self._pool = None
        (self.out / "dataset.json").write_text(json.dumps({**self.info, "format": self.fmt, "layout": self.layout}, indent=2,
                                                          sort_keys=True, default=json_default))
        manifest = pd.DataFrame(self.rows, columns=list(MANIFEST_COLUMNS))
        if self.existing is not None:
            old = self.existing.reindex(columns=list(MANIFEST_COLUMNS))
            manifest = pd.concat([old, manifest], ignore_index=True) if len(manifest) else old
        for col in ("attack_start_us", "attack_end_us"):
            manifest[col] = pd.to_numeric(manifest[col]).astype("Int64")
        for col in ("effect_rows", "effect_fields"):
            manifest[col] = pd.to_numeric(manifest[col], errors="coerce").astype("Int64")
        manifest["no_effect"] = manifest["no_effect"].astype(object).where(manifest["no_effect"].notna(), False)
        manifest["no_effect"] = manifest["no_effect"].astype(bool)
        manifest["detectability"] = pd.to_numeric(manifest["detectability"], errors="coerce").astype(np.float64)
        for col in ("impact_max_dev_m", "impact_final_dev_m", "impact_landing_dist_m"):
            manifest[col] = pd.to_numeric(manifest[col], errors="coerce").astype(np.float64)
        for col in ("impact_mission_completed", "impact_crashed"):
            manifest[col] = manifest[col].astype("boolean")
        final = self.out / f"manifest.{self.fmt}"
        tmp = self.out / f".manifest.tmp.{self.fmt}"
        try:
            if self.fmt == "parquet":
                manifest.to_parquet(tmp, index=False)
            else:
                manifest.to_csv(tmp, index=False)
            os.replace(tmp, final)
        finally:
            tmp.unlink(missing_ok=True)
            self._release()
        return final


def check_layout(fmt: str, layout: str | None) -> str:
    """The layout to write: ``layout``, or compact for Parquet and the paper's for CSV."""
    if layout is None:
        return "compact" if fmt == "parquet" else "paper"
    if layout not in LAYOUTS:
        raise DatasetError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    if layout == "compact" and fmt != "parquet":
        raise DatasetError("layout 'compact' is Parquet only; use --layout paper for CSV files")
    return layout


def _views(record: FlightRecord) -> list[tuple[str, dict[str, pd.DataFrame]]]:
    views = [("navigator", record.navigator), ("simulator", record.simulator)]
    if record.uorb is not None:
        views.append(("uorb", record.uorb))
    return views


def write_flight(out: Path, fmt: str, record: FlightRecord, layout: str = "paper") -> dict:
    """Write one flight (raw folder plus its views, in ``layout``); returns its manifest row."""
    if not any(k not in TRUTH_TOPICS for k in record.navigator):
        raise DatasetError(f"flight {record.flight_id!r}: cannot combine a flight with no topics")
    root = inside(out / "flights", check_id(record.flight_id, "flight id"))
    (root / "raw").mkdir(parents=True, exist_ok=True)
    (root / "raw" / "config.json").write_text(json.dumps(record.config, indent=2, sort_keys=True,
                                                         default=json_default))
    events = pd.DataFrame(record.events, columns=["timestamp_us", "event", "scenario_id", "detail"])
    events.to_csv(root / "raw" / "events.csv", index=False)
    if layout == "compact":
        _write_compact(root, record)
    else:
        _write_paper(root, fmt, record)
    row = {k: record.manifest.get(k) for k in MANIFEST_COLUMNS}
    row["flight_id"] = record.flight_id
    row["checksum"] = flight_checksum(root)
    row["rows"] = _most_frequent_rows({k: v for k, v in record.navigator.items() if k not in TRUTH_TOPICS})
    if record.windows:
        row["attack_start_us"] = int(min(w[0] for w in record.windows))
        row["attack_end_us"] = int(max(w[1] for w in record.windows))
    return row


def flight_checksum(root: Path) -> str:
    """A digest of every file of a flight folder (names and bytes, BLAKE2b-128): recorded in the
    manifest when the flight is written, compared when it is read, so a changed byte is caught and
    the dataset fingerprint (which covers the manifest) follows the contents."""
    h = hashlib.blake2b(digest_size=16)
    for f in sorted(p for p in root.rglob("*") if p.is_file()):
        h.update(f.relative_to(root).as_posix().encode() + b"\0")
        h.update(f.read_bytes())
    return "b2:" + h.hexdigest()


def _most_frequent_rows(topics: dict[str, pd.DataFrame]) -> int:
    """Rows of the view's most_frequent table (distinct timestamps of its most frequent topic)."""
    if not topics:
        return 0
    counts = [(name, pd.Index(df["Timestamp"]).nunique()) for name, df in topics.items()]
    return max(counts, key=lambda item: item[1])[1]


def _write_paper(root: Path, fmt: str, record: FlightRecord) -> None:
    for view, topics in _views(record):
        (root / "sensors" / view).mkdir(parents=True, exist_ok=True)
        for name, df in topics.items():
            _write_table(df, root / "sensors" / view / name, fmt)
        if view == "uorb":
            continue  # the uORB view has no combined tables in the paper's layout
        (root / "combined").mkdir(exist_ok=True)
        link_topics = {k: v for k, v in topics.items() if k not in TRUTH_TOPICS}
        for table, df in combine(link_topics, record.windows).items():
            _write_table(df, root / "combined" / f"{view}_{table}", fmt)


def _write_compact(root: Path, record: FlightRecord) -> None:
    windows = [list(w) for w in record.windows]
    for view, topics in _views(record):
        reuse, shared = {}, {}
        if view == "simulator":  # what the attack did not touch is the navigator's: stored once
            for name, df in topics.items():
                same = compact.shared_fields(df, record.navigator[name]) if name in record.navigator else None
                if same is None:
                    continue
                if same == list(df.columns) == list(record.navigator[name].columns):
                    reuse[name] = "navigator"
                elif same:
                    shared[name] = ("navigator", same)
        tmp = root / f".{view}.parquet.tmp"
        compact.write_view(tmp, topics, windows, reuse, shared)
        os.replace(tmp, root / f"{view}.parquet")


def json_default(obj):
    """``json.dumps(default=...)`` for numpy values and paths; TypeError for anything else."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class Dataset:
    """A written dataset: the manifest plus lazy access to each flight's tables."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        recover(self.path)  # a writer killed mid-replace left its partial folder (or the old dataset aside)
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: no such dataset folder")
        if (self.path / "manifest.parquet").exists():
            self.manifest = pd.read_parquet(self.path / "manifest.parquet")
        elif (self.path / "manifest.csv").exists():
            # ids are text: "007" stays "007"
            self.manifest = pd.read_csv(self.path / "manifest.csv", dtype={"scenario_id": "string", "flight_id": str,
                                                                           "source_flight": "string"})
        else:
            raise DatasetError(f"{self.path}: no manifest.parquet or manifest.csv; the dataset is missing or "
                               "incomplete (the manifest is written last)")
        missing = [c for c in ("flight_id", "mode", "split") if c not in self.manifest.columns]
        if missing:
            raise DatasetError(f"{self.path}/manifest: missing column(s) {missing}")
        check_manifest(self.manifest, self.path / "manifest")
        info = self.path / "dataset.json"
        try:
            self.info = json.loads(info.read_text()) if info.exists() else {}
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise DatasetError(f"{info}: not valid JSON ({exc}); it holds the dataset's format and versions") from None
        if not isinstance(self.info, dict):
            raise DatasetError(f"{info}: expected a JSON object (format, layout, profile, seed, versions)")
        self._verified: set[str] = set()
        self._checksums: dict | None = None

    def __len__(self) -> int:
        return len(self.manifest)

    @property
    def flight_defaults(self) -> int:
        """Which generator defaults made the flights (generator.flight.FLIGHT_DEFAULTS); 1 for a
        dataset written before dataset.json said so."""
        return int(self.info.get("flight_defaults", 1))

    def flight_dir(self, flight_id: str) -> Path:
        return inside(self.path / "flights", check_id(flight_id, f"{self.path}: flight id"))

    def is_compact(self, flight_id: str) -> bool:
        """Whether the flight is stored in the compact layout (each flight says so by its files)."""
        return (self.flight_dir(flight_id) / "navigator.parquet").exists()

    def flight(self, flight_id: str, view: str = "navigator", table: str = "most_frequent",
               columns: list[str] | None = None) -> pd.DataFrame:
        """A combined table of one flight (``view`` navigator|simulator, ``table`` most_frequent|all_sensors);
        ``columns`` reads only those columns."""
        if view not in VIEWS:
            raise DatasetError(f"view {view!r}: expected one of {VIEWS}")
        if table not in TABLES:
            raise DatasetError(f"table {table!r}: expected one of {TABLES}")
        self.verify(flight_id)
        if not self.is_compact(flight_id):
            return _read_table(self.flight_dir(flight_id) / "combined" / f"{view}_{table}", columns)
        topics = read_view(self.flight_dir(flight_id), view, arrays=True)
        windows = self._windows(flight_id, view)
        df = combine({k: v for k, v in topics.items() if k not in TRUTH_TOPICS}, windows)[table]
        if columns is None:
            return df
        missing = [c for c in columns if c not in df.columns]
        if missing:
            raise DatasetError(f"{self.flight_dir(flight_id) / view}.parquet: no column(s) {missing}")
        return df[list(columns)]

    def trust(self, flight_id: str) -> None:
        """Read ``flight_id`` without comparing its checksum (its files were changed on purpose)."""
        self._verified.add(flight_id)

    def verify(self, flight_id: str) -> None:
        """DatasetError naming the flight when its files differ from the checksum the manifest
        recorded when it was written (datasets written before checksums: nothing to compare)."""
        if flight_id in self._verified or "checksum" not in self.manifest.columns:
            return
        if self._checksums is None:  # once: a manifest scan per flight was O(n^2) over a run's flights
            self._checksums = dict(zip(self.manifest["flight_id"].astype(str), self.manifest["checksum"]))
        expected = self._checksums.get(str(flight_id))
        if isinstance(expected, str) and expected:
            got = flight_checksum(self.flight_dir(flight_id))
            if got != expected:
                raise DatasetError(f"{self.flight_dir(flight_id)}: flight {flight_id!r} changed since it was written "
                                   f"(checksum {got}, the manifest recorded {expected}); its files are damaged or "
                                   "were edited: regenerate it, or remove it from the dataset")
        self._verified.add(flight_id)

    def _windows(self, flight_id: str, view: str) -> list[tuple]:
        meta = compact.read_meta(self.flight_dir(flight_id) / f"{view}.parquet")
        return [tuple(w) for w in meta.get("windows", [])]

    def check_flights(self, flight_ids: Iterable[str], view: str = "navigator", table: str = "most_frequent") -> None:
        """DatasetError naming the first flight table that is missing or unreadable (its footer or header
        is read, not its data): a run checks this before it writes anything."""
        import pyarrow.parquet as pq

        for fid in flight_ids:
            root = self.flight_dir(fid)
            if root.is_dir():
                self.verify(fid)
            if self.is_compact(fid):
                for name in dict.fromkeys(("navigator", view)):
                    try:
                        compact.read_meta(root / f"{name}.parquet")
                    except compact.CompactError as exc:
                        raise DatasetError(f"{exc}; regenerate or remove flight {fid!r}") from None
                continue
            base = root / "combined" / f"{view}_{table}"
            pq_path, csv_path = base.with_suffix(".parquet"), base.with_suffix(".csv")
            try:
                if pq_path.exists():
                    pq.read_metadata(pq_path)
                elif csv_path.exists():
                    with csv_path.open("rb") as fh:
                        if not fh.readline().strip():
                            raise ValueError("no header line")
                else:
                    raise DatasetError(f"{base}.(parquet|csv): missing; flight {fid!r} of the manifest has no table")
            except DatasetError:
                raise
            except Exception as exc:  # pyarrow raises its own types for a damaged file
                path = pq_path if pq_path.exists() else csv_path
                raise DatasetError(f"{path}: unreadable ({type(exc).__name__}: {exc}); regenerate or remove "
                                   f"flight {fid!r}") from None

    def topic(self, flight_id: str, topic: str, view: str = "navigator") -> pd.DataFrame:
        """One topic table of one flight (``view`` navigator, simulator or uorb)."""
        if view not in TOPIC_VIEWS:
            raise DatasetError(f"view {view!r}: expected one of {TOPIC_VIEWS}")
        self.verify(flight_id)
        if not self.is_compact(flight_id):
            self._view_folder(flight_id, view)
            return _read_table(self.flight_dir(flight_id) / "sensors" / view / topic)
        tables = read_view(self.flight_dir(flight_id), view, [topic])
        if topic not in tables:
            raise DatasetError(f"{self.flight_dir(flight_id) / view}.parquet: no topic {topic!r}")
        return tables[topic]

    def topics(self, flight_id: str, view: str = "navigator") -> list[str]:
        """The topic names of one flight's view (navigator, simulator or uorb)."""
        if view not in TOPIC_VIEWS:
            raise DatasetError(f"view {view!r}: expected one of {TOPIC_VIEWS}")
        if self.is_compact(flight_id):
            path = self.flight_dir(flight_id) / f"{view}.parquet"
            if not path.exists():
                hint = " (generated without the uORB view: scart-bench generate --uorb)" if view == "uorb" else ""
                raise DatasetError(f"{path}: missing; flight {flight_id!r} has no {view} view{hint}")
            return sorted(compact.read_meta(path)["topics"])
        return sorted(p.stem for p in self._view_folder(flight_id, view).iterdir())

    def _view_folder(self, flight_id: str, view: str) -> Path:
        folder = self.flight_dir(flight_id) / "sensors" / view
        if not folder.is_dir():
            hint = " (generated without the uORB view: scart-bench generate --uorb)" if view == "uorb" else ""
            raise DatasetError(f"{folder}: flight {flight_id!r} has no {view} view{hint}")
        return folder

    def events(self, flight_id: str) -> pd.DataFrame:
        return pd.read_csv(self.flight_dir(flight_id) / "raw" / "events.csv")

    def config(self, flight_id: str) -> dict:
        return json.loads((self.flight_dir(flight_id) / "raw" / "config.json").read_text())


def check_manifest(manifest: pd.DataFrame, where: Path) -> None:
    """DatasetError naming the flight and the field when a manifest row cannot be right: an empty or
    repeated flight id, or an attack window that ends before it starts or lies outside the flight."""
    ids = manifest["flight_id"].astype(str)
    if (ids.str.strip() == "").any() or manifest["flight_id"].isna().any():
        raise DatasetError(f"{where}: a row has an empty flight_id")
    dup = ids[ids.duplicated()]
    if len(dup):
        raise DatasetError(f"{where}: flight {dup.iloc[0]!r} is listed more than once")
    if "attack_start_us" not in manifest.columns or "attack_end_us" not in manifest.columns:
        return
    start = pd.to_numeric(manifest["attack_start_us"], errors="coerce")
    end = pd.to_numeric(manifest["attack_end_us"], errors="coerce")
    bad = start.notna() & end.notna() & (end <= start)
    if bad.any():
        i = bad[bad].index[0]
        raise DatasetError(f"{where}: flight {ids[i]!r} has attack_end_us {int(end[i])} <= attack_start_us "
                           f"{int(start[i])}; expected start < end (an attack window [start, end) in µs)")
    if "duration_s" in manifest.columns:
        limit = pd.to_numeric(manifest["duration_s"], errors="coerce") * 1e6 + 1e6  # a second of slack
        out = start.notna() & limit.notna() & ((start < 0) | (start > limit))
        if out.any():
            i = out[out].index[0]
            raise DatasetError(f"{where}: flight {ids[i]!r} has attack_start_us {int(start[i])} outside the flight "
                               f"(0 to {manifest['duration_s'][i]} s)")


def read_view(flight_dir: Path, view: str, names: list[str] | None = None,
              arrays: bool = False) -> dict[str, pd.DataFrame]:
    """The topic tables of one view of a compact flight folder (all, or those in ``names``), in the
    order they were written; a topic kept once in the navigator view is read from there.
    ``arrays``: each topic as a dict of column arrays instead of a table (faster)."""
    path = Path(flight_dir) / f"{view}.parquet"
    if not path.exists():
        hint = " (generated without the uORB view: scart-bench generate --uorb)" if view == "uorb" else ""
        raise DatasetError(f"{path}: missing; the flight has no {view} view{hint}")
    try:
        meta = compact.read_meta(path)
        order = [n for n in meta["topics"] if names is None or n in names]
        here = compact.read_topics(path, order, meta, arrays)
        elsewhere: dict[str, list[str]] = {}
        for n in order:
            if n not in here and n in meta.get("reuse", {}):
                elsewhere.setdefault(meta["reuse"][n], []).append(n)
        for other, wanted in elsewhere.items():
            here.update(compact.read_topics(Path(flight_dir) / f"{other}.parquet", wanted, arrays=arrays))
    except compact.CompactError as exc:
        raise DatasetError(str(exc)) from None
    return {n: here[n] for n in order if n in here}


def open_dataset(path: str | Path) -> Dataset:
    """Open a complete dataset (raises DatasetError naming the folder when it is not one)."""
    return Dataset(path)


def append_flights(out: str | Path, records: Iterable[FlightRecord], fmt: str = "parquet",
                   info: dict | None = None, layout: str | None = None) -> Path:
    """Add flights to the dataset at ``out`` (created when there is none), atomically.

    ``records`` may be a generator (one flight in memory at a time). A repeated flight id, or any
    error while the records are made or written, removes the flights written so far and leaves
    the dataset as it was; the manifest is replaced last, in one rename. Returns the manifest path.
    """
    writer = DatasetWriter(out, fmt=fmt, info=info, append=True, layout=layout)
    try:
        for r in records:
            writer.write(r)
    except BaseException:
        writer.abort()
        if writer.existing is None:  # nothing was there before: leave nothing behind
            shutil.rmtree(writer.out / "flights", ignore_errors=True)
            (writer.out / "dataset.json").unlink(missing_ok=True)
        raise
    return writer.close()
