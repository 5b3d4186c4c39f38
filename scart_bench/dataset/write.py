"""Writing datasets: a flight folder in either layout, and a whole dataset written or appended to atomically."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import compact
from scart_bench.dataset.labels import SourceTopic, combine
from scart_bench.dataset.locks import dataset_lock, exit_with_parent, recover
from scart_bench.dataset.read import open_dataset
from scart_bench.dataset.record import (
    FORMATS,
    MANIFEST_COLUMNS,
    MANIFEST_DEFAULTS,
    TRUTH_TOPICS,
    DatasetError,
    FlightRecord,
    check_layout,
    is_dataset,
    json_default,
)
from scart_bench.dataset.tables import flight_checksum, write_table
from scart_bench.names import check_id, inside

#: errno values that mean the disk (or the user's quota) is full
_FULL = (errno.ENOSPC, errno.EDQUOT)


@contextmanager
def writing(path: Path) -> Iterator[None]:
    """Turn an OSError while ``path`` is written into one DatasetError line naming the file: the
    ``write`` that finds the disk full names no file by itself (nor does pyarrow's), so a full disk
    said only "No space left on device"."""
    try:
        yield
    except DatasetError:
        raise
    except OSError as exc:
        text = str(exc)
        if exc.errno in _FULL or "No space left" in text or "Disk quota exceeded" in text:
            raise DatasetError(f"{path}: no space left on device while writing the dataset; free some space or "
                               "write it elsewhere (the old dataset, if any, is kept)") from None
        why = exc.strerror or (text.splitlines()[0] if text else type(exc).__name__)
        raise DatasetError(f"{path}: cannot be written ({why})") from None


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


class DatasetWriter:
    """Writes flights one by one and the manifest last (call ``close`` to complete).

    The only writer of manifests. A new dataset: a writer that is not closed leaves no
    manifest, so the folder never looks complete. ``append=True`` adds flights to the dataset
    at ``out`` (a new one if there is none): its format is kept, a flight id already there is
    refused before anything is written, and the manifest is replaced atomically at ``close``,
    so the dataset is complete before and after; ``abort`` removes the flights it wrote.
    ``share_sources`` (appending, compact layout, no workers): a flight whose manifest
    ``source_flight`` is a normal flight already in the dataset (an attacked copy) stores only
    the fields that differ from that flight's navigator view and reads the others from its file
    (:class:`SourceView`), so a copy costs what its attack changed, not what the log holds;
    ``source_views``: those flights' views already read (by flight id; the attack reads them once).
    """

    def __init__(self, out: str | Path, fmt: str = "parquet", info: dict | None = None,
                 overwrite: bool = False, workers: int = 0, append: bool = False, layout: str | None = None,
                 share_sources: bool = False, source_views: dict[str, SourceView] | None = None):
        if fmt not in FORMATS:
            raise DatasetError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
        self.out = Path(out)
        self.fmt = fmt
        self.layout = check_layout(fmt, layout)
        self.info = dict(info or {})
        self.existing: pd.DataFrame | None = None
        self.written: list[str] = []
        self._lock = dataset_lock(self.out).acquire() if append else None
        self._dataset = None
        self._source: SourceView | None = None
        self.source_views = dict(source_views or {})
        if append and is_dataset(self.out):
            ds = self._dataset = open_dataset(self.out)
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
        self.share_sources = bool(share_sources) and self.layout == "compact" and self._dataset is not None
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
            source = self._source_of(record) if self.share_sources else None
            self.rows.append(write_flight(self.out, self.fmt, record, self.layout, source))
            return
        while len(self._pending) >= 2 * self.workers:  # bound the records held in memory
            self.rows.append(self._pending.pop(0).result())
        self._pending.append(self._pool.submit(write_flight, self.out, self.fmt, record, self.layout))

    def _source_of(self, record: FlightRecord) -> SourceView | None:
        """The source flight a copy may share its untouched fields with: a normal flight of the
        dataset as it was opened, stored compact, checked (checksum) and itself sharing with none."""
        fid = str(record.manifest.get("source_flight") or "")
        if self._source is not None and self._source.flight_id == fid:
            return self._source
        ds = self._dataset
        rows = ds.manifest[ds.manifest["flight_id"].astype(str) == fid] if fid else ds.manifest.iloc[:0]
        if rows.empty or str(rows["mode"].iloc[0]) != "normal" or not ds.is_compact(fid) or ds.sources(fid):
            return None
        ds.verify(fid)  # a copy must not inherit damage: the source's checksum is compared first
        path = ds.flight_dir(fid) / "navigator.parquet"
        given = self.source_views.get(fid)
        self._source = given if given is not None and given.path == path else SourceView(path, fid)
        return self._source

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
        with writing(self.out / "dataset.json"):
            (self.out / "dataset.json").write_text(json.dumps({**self.info, "format": self.fmt, "layout": self.layout},
                                                              indent=2, sort_keys=True, default=json_default))
        manifest = pd.DataFrame(self.rows, columns=list(MANIFEST_COLUMNS))
        if self.existing is not None:
            old = self.existing.reindex(columns=list(MANIFEST_COLUMNS))
            if "checksum" not in self.existing.columns:
                # a dataset from before checksums gains the column: every row records one (an empty one
                # is refused by the reader), so its flights' are taken now, as they are
                old["checksum"] = [flight_checksum(inside(self.out / "flights", str(f))) for f in old["flight_id"]]
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
            with writing(final):
                if self.fmt == "parquet":
                    manifest.to_parquet(tmp, index=False)
                else:
                    manifest.to_csv(tmp, index=False)
                os.replace(tmp, final)
        finally:
            tmp.unlink(missing_ok=True)
            self._release()
        return final


def _views(record: FlightRecord) -> list[tuple[str, dict[str, pd.DataFrame]]]:
    views = [("navigator", record.navigator), ("simulator", record.simulator)]
    if record.uorb is not None:
        views.append(("uorb", record.uorb))
    return views


class SourceView:
    """The navigator view of a dataset's flight as stored (column arrays, bit for bit), against which an
    attacked copy's topics are compared: a field the copy holds unchanged, for the same rows, is
    read from this file instead of being written again (:mod:`scart_bench.dataset.compact`)."""

    def __init__(self, path: Path, flight_id: str):
        self.path = Path(path)
        self.flight_id = flight_id
        self.ref = compact.other_flight_ref(flight_id, "navigator")
        self._stacked: dict[tuple, np.ndarray] = {}
        self._tables: dict[str, tuple[pd.DataFrame, list[str]]] = {}
        try:
            meta = self.meta = compact.read_meta(self.path)
            self.arrays = compact.read_topics(self.path, list(meta["topics"]), meta, arrays=True)
            self.dtypes = {s["name"]: dict(map(tuple, s["columns"])) for s in meta["stored"]}
        except compact.CompactError as exc:
            raise DatasetError(f"{exc}; the source flight {flight_id!r} of the copies cannot be read") from None

    def tables(self) -> dict[str, pd.DataFrame] | None:
        """The view's topic tables as ``read_view`` gives them, made from the arrays already read (so
        that ``attack`` reads its source once for the replay and the comparison); None when the file
        keeps topics elsewhere (only a copy's does: read it with ``read_view``). The tables own their
        values: changing one leaves the comparison's arrays as stored."""
        spans = {s["name"]: s for s in self.meta["stored"]}
        if self.meta.get("reuse") or any(s.get("shared") for s in spans.values()) or set(spans) != set(self.arrays):
            return None
        return {n: compact.topic_frame(self.arrays[n], spans[n], copy=True) for n in self.meta["topics"] if n in spans}

    def fields(self, name: str, df: pd.DataFrame) -> list[str]:
        """The numeric fields of ``df`` (topic ``name``) that this flight's same topic holds bit for
        bit in the same dtype for the same timestamps (empty when the rows differ)."""
        base = self.arrays.get(name)
        if base is None or "Timestamp" not in df.columns or "Timestamp" not in base:
            return []
        if len(df) != len(base["Timestamp"]) or not _same_array(df["Timestamp"].to_numpy(), base["Timestamp"]):
            return []
        dtypes = self.dtypes.get(name, {})
        kinds = df.dtypes
        cols = [str(c) for c in df.columns]
        wanted = [c for c in cols if c not in compact.SHARED_COLUMNS and c in base and str(kinds[c]) == dtypes.get(c)]
        floats = [c for c in wanted if kinds[c] == np.float64]
        same = set()
        if floats:  # a log's fields: one array operation for the topic
            x = df.iloc[:, [cols.index(c) for c in floats]].to_numpy().view(np.uint64)
            y = self._floats(name, floats).view(np.uint64)
            same.update(c for c, eq in zip(floats, (x == y).all(axis=0)) if eq)
        same.update(c for c in wanted if c not in floats and _same_array(df[c].to_numpy(), base[c]))
        return [c for c in wanted if c in same]

    def fields_of_source(self, name: str, table: pd.DataFrame) -> list[str]:
        """``fields(name, df)`` for a copy's table that holds ``table`` (the source flight's, as loaded)
        bit for bit in every field: compared once for all the copies of the source."""
        got = self._tables.get(name)
        if got is None or got[0] is not table:
            got = self._tables[name] = (table, self.fields(name, table))
        return got[1]

    def _floats(self, name: str, cols: list[str]) -> np.ndarray:
        """The topic's float64 fields ``cols`` as one (rows x fields) array, kept for the next copy."""
        key = (name, tuple(cols))
        if key not in self._stacked:
            self._stacked = {k: v for k, v in self._stacked.items() if k[0] != name}
            self._stacked[key] = np.column_stack([np.asarray(self.arrays[name][c], dtype=np.float64) for c in cols])
        return self._stacked[key]


def _same_array(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two numeric arrays hold the same bits in the same dtype (0.0 and -0.0, or NaN payloads, differ)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape or a.dtype.kind not in "biuf":
        return False
    width = np.dtype(f"u{a.dtype.itemsize}") if a.dtype.itemsize in (1, 2, 4, 8) else None
    if width is None:
        return a.tobytes() == b.tobytes()
    return bool(np.array_equal(np.ascontiguousarray(a).view(width), np.ascontiguousarray(b).view(width)))


def built(record: FlightRecord) -> FlightRecord:
    """``record`` with every :class:`SourceTopic` (a copy's topic held as its source's table) built
    as a table, for the writers that take pandas tables (the paper's layout)."""
    views = [v for _, v in _views(record)]
    if not any(isinstance(df, SourceTopic) for v in views for df in v.values()):
        return record
    made: dict[int, pd.DataFrame] = {}  # a topic both views hold stays one table

    def frame(df):
        if not isinstance(df, SourceTopic):
            return df
        if id(df) not in made:
            made[id(df)] = df.frame()
        return made[id(df)]

    def frames(view):
        return None if view is None else {t: frame(df) for t, df in view.items()}

    return dataclasses.replace(record, navigator=frames(record.navigator), simulator=frames(record.simulator),
                               uorb=frames(record.uorb))


def write_flight(out: Path, fmt: str, record: FlightRecord, layout: str = "paper",
                 source: SourceView | None = None) -> dict:
    """Write one flight (raw folder plus its views, in ``layout``); returns its manifest row.
    ``source`` (compact layout): a flight of the same dataset whose stored fields this one reads
    where it holds the same values (an attacked copy and its source flight)."""
    if not any(k not in TRUTH_TOPICS for k in record.navigator):
        raise DatasetError(f"flight {record.flight_id!r}: cannot combine a flight with no topics")
    root = inside(out / "flights", check_id(record.flight_id, "flight id"))
    with writing(root / "raw"):
        (root / "raw").mkdir(parents=True, exist_ok=True)
    with writing(root / "raw" / "config.json"):
        (root / "raw" / "config.json").write_text(json.dumps(record.config, indent=2, sort_keys=True,
                                                             default=json_default))
    events = pd.DataFrame(record.events, columns=["timestamp_us", "event", "scenario_id", "detail"])
    with writing(root / "raw" / "events.csv"):
        events.to_csv(root / "raw" / "events.csv", index=False)
    if layout == "compact":
        _write_compact(root, record, source)
    else:
        _write_paper(root, fmt, built(record))
    row = {k: record.manifest.get(k) for k in MANIFEST_COLUMNS}
    for k in ("mode", "split"):  # a record built without flight_record: the reader refuses an empty one
        if row[k] is None:
            row[k] = MANIFEST_DEFAULTS[k]
    row["flight_id"] = record.flight_id
    row["checksum"] = flight_checksum(root)
    row["rows"] = _most_frequent_rows({k: v for k, v in record.navigator.items() if k not in TRUTH_TOPICS})
    if record.windows:
        row["attack_start_us"] = int(min(w[0] for w in record.windows))
        row["attack_end_us"] = int(max(w[1] for w in record.windows))
    return row


def _most_frequent_rows(topics: dict[str, pd.DataFrame]) -> int:
    """Rows of the view's most_frequent table (distinct timestamps of its most frequent topic)."""
    if not topics:
        return 0
    counts = [(name, _distinct(df["Timestamp"])) for name, df in topics.items()]
    return max(counts, key=lambda item: item[1])[1]


def _distinct(times: pd.Series) -> int:
    """``pd.Index(times).nunique()``, counted on the array where the timestamps are integers in order
    (every topic of a flight: an attacked all-topic log's copies count a hundred topics each)."""
    x = times.to_numpy()
    if x.dtype.kind == "i" and len(x) > 1:
        d = np.diff(x)
        if (d >= 0).all():
            return int(np.count_nonzero(d)) + 1
    return pd.Index(times).nunique()


def _write_paper(root: Path, fmt: str, record: FlightRecord) -> None:
    for view, topics in _views(record):
        with writing(root / "sensors" / view):
            (root / "sensors" / view).mkdir(parents=True, exist_ok=True)
        for name, df in topics.items():
            with writing((root / "sensors" / view / name).with_suffix(f".{fmt}")):
                write_table(df, root / "sensors" / view / name, fmt)
        if view == "uorb":
            continue  # the uORB view has no combined tables in the paper's layout
        with writing(root / "combined"):
            (root / "combined").mkdir(exist_ok=True)
        link_topics = {k: v for k, v in topics.items() if k not in TRUTH_TOPICS}
        for table, df in combine(link_topics, record.windows).items():
            with writing(root / "combined" / f"{view}_{table}.{fmt}"):
                write_table(df, root / "combined" / f"{view}_{table}", fmt)


def _share_with_navigator(name: str, df: pd.DataFrame, record: FlightRecord, reuse: dict, shared: dict) -> None:
    """A simulator topic the attack did not touch is the navigator's: stored once."""
    same = compact.shared_fields(df, record.navigator[name]) if name in record.navigator else None
    if same is None:
        return
    if same == list(df.columns) == list(record.navigator[name].columns):
        reuse[name] = "navigator"
    elif same:
        shared[name] = ("navigator", same)


def _write_compact(root: Path, record: FlightRecord, source: SourceView | None = None) -> None:
    windows = [list(w) for w in record.windows]
    for view, topics in _views(record):
        reuse, shared = {}, {}
        if source is not None:  # an attacked copy: its untouched fields are its source flight's
            for name, df in topics.items():
                if view != "navigator" and record.navigator.get(name) is df:
                    reuse[name] = "navigator"  # the very table: the navigator view's, read from there
                    continue
                same = getattr(record, "same_as_source", {})  # topics the copy holds as loaded (copies.py)
                fields = source.fields_of_source(name, same[name]) if name in same else source.fields(name, df)
                if fields:
                    shared[name] = (source.ref, fields)
                elif view == "simulator":
                    _share_with_navigator(name, df, record, reuse, shared)
        elif view == "simulator":
            for name, df in topics.items():
                if record.navigator.get(name) is df:
                    reuse[name] = "navigator"  # the very table (what comparing it would find)
                    continue
                _share_with_navigator(name, df, record, reuse, shared)
        tmp = root / f".{view}.parquet.tmp"
        with writing(root / f"{view}.parquet"):
            compact.write_view(tmp, topics, windows, reuse, shared)
            os.replace(tmp, root / f"{view}.parquet")


def append_flights(out: str | Path, records: Iterable[FlightRecord], fmt: str = "parquet",
                   info: dict | None = None, layout: str | None = None, share_sources: bool = False,
                   source_views: dict[str, SourceView] | None = None) -> Path:
    """Add flights to the dataset at ``out`` (created when there is none), atomically.

    ``records`` may be a generator (one flight in memory at a time). A repeated flight id, or any
    error while the records are made or written, removes the flights written so far and leaves
    the dataset as it was; the manifest is replaced last, in one rename. Returns the manifest path.
    ``share_sources``: attacked copies keep their untouched fields in their source flight's file
    (:class:`DatasetWriter`; ``source_views``: theirs already read).
    """
    writer = DatasetWriter(out, fmt=fmt, info=info, append=True, layout=layout, share_sources=share_sources,
                           source_views=source_views)
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
