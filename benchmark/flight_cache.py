"""The run's flight cache: every flight a run reads (train, validation and test) is read from the
dataset once per run and kept in the run folder as raw arrays, which every job then maps instead of
reading every flight table again (a job used to re-read all of them: 8 detectors read each flight 8
times, plus once for the labels).

```
<run>/cache/flights/index.json   written last: format, key (dataset fingerprint, view, table), the
                                 column layouts, and per flight its rows, layout and byte offsets
<run>/cache/flights/<group>.bin  one raw array per column type (``f8``, ``f4``, ``i8``, ``i1``,
                                 ``b1``, ``str`` codes, ...): flight after flight, each flight's
                                 block column after column (as pandas keeps a table's columns)
```
A float64 column whose every value is a float32 value (bit for bit, as the compact dataset layout's
fields read back) is kept in ``f8f4.bin`` at half the size and read back as the same float64 values,
in the table's one float64 block.

A flight read back from the cache is the same table the dataset gives (same columns in the same
order, same dtypes, same values bit for bit, a default RangeIndex), so every detector, built-in or
plugin, scores it identically. Text columns (the label ids) are kept as int32 codes into a list of
the distinct strings. A table the cache cannot reproduce exactly (another index, an object column
holding non-text values, an extension dtype it does not know) raises :class:`CacheUnsupported` and
the run reads the dataset as before.

The cache is built into a temp folder beside it and renamed into place once complete, so a reader
sees a whole cache or none. Its key holds the dataset's fingerprint, so a changed dataset (or view)
is never read from an old cache: the runner rebuilds it. Feature selection (``--features`` /
``--exclude``, a detector's ``columns``) happens in each detector after the read, as before, so one
cache serves every choice of columns.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.errors import ScartBenchError

FORMAT = "scart-bench-flight-cache/2"
#: Folder of the cache inside a run folder.
CACHE_DIR = Path("cache") / "flights"


class CacheUnsupported(ScartBenchError):
    """A flight table that the cache cannot reproduce exactly; the run reads the dataset instead."""


class CacheInvalid(ScartBenchError):
    """The cache is missing, incomplete, damaged or belongs to another dataset."""


def cache_path(run_folder: str | Path) -> Path:
    return Path(run_folder) / CACHE_DIR


def cache_key(dataset_fingerprint: str, view: str = "navigator", table: str = "most_frequent") -> dict:
    """What the cached tables depend on: the dataset (its fingerprint) and which table of each flight."""
    return {"format": FORMAT, "dataset_fingerprint": dataset_fingerprint, "view": view, "table": table}


# -- columns ------------------------------------------------------------------------------------

def _column_kind(s: pd.Series) -> dict:
    """How a column is stored: ``{"group": file, "dtype": ...}``; CacheUnsupported when not exactly."""
    dt = s.dtype
    if isinstance(dt, np.dtype) and dt == np.dtype(np.float64):
        v = s.to_numpy()
        with np.errstate(over="ignore", invalid="ignore"):  # 1e300 becomes inf in float32: not equal, kept whole
            back = v.astype(np.float32).astype(np.float64)
        if np.array_equal(v.view(np.int64), back.view(np.int64)):
            return {"group": HALF, "dtype": dt.str}  # exactly float32 values: half the bytes
    if isinstance(dt, np.dtype) and dt.kind in "biuf" and dt.isnative:
        return {"group": dt.str.lstrip("<>|="), "dtype": dt.str}
    if isinstance(dt, pd.StringDtype):
        na = "nan" if dt.na_value is not pd.NA else "NA"
        return {"group": "str", "dtype": "string", "storage": dt.storage, "na_value": na}
    if dt == np.dtype(object):
        values = s.to_numpy()
        if all(type(v) is str for v in values):
            return {"group": "str", "dtype": "object"}
    raise CacheUnsupported(f"column {s.name!r} has dtype {dt} the flight cache cannot store exactly")


#: The group of float64 columns held as float32 (their values are float32 values).
HALF = "f8f4"


def _group_dtype(group: str) -> np.dtype:
    return np.dtype(np.int32) if group == "str" else np.dtype(np.float32) if group == HALF else np.dtype(group)


def _text_column(codes: np.ndarray, cats: np.ndarray, kind: dict) -> pd.Series | pd.api.extensions.ExtensionArray:
    values = cats[np.maximum(codes, 0)] if len(cats) else np.full(codes.shape, "", dtype=object)
    if kind["dtype"] == "object":
        return pd.Series(values, dtype=object)  # a bare array of str would be inferred as str
    dtype = pd.StringDtype(kind["storage"], na_value=np.nan if kind["na_value"] == "nan" else pd.NA)
    values = values.copy()
    values[codes < 0] = None
    return pd.array(values, dtype=dtype)


# -- writing ------------------------------------------------------------------------------------

class _Builder:
    """Appends flights to the group files of a cache folder being built."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.files: dict[str, object] = {}
        self.sizes: dict[str, int] = {}
        self.kinds: list[dict] = []  # column entries: name + kind
        self.kind_ids: dict[str, int] = {}
        self.layouts: list[list[int]] = []
        self.layout_ids: dict[tuple[int, ...], int] = {}
        self.strings: list[str] = []
        self.string_ids: dict[str, int] = {}
        self.flights: dict[str, dict] = {}

    def _entry(self, name: str, kind: dict) -> int:
        key = json.dumps({"name": name, **kind}, sort_keys=True)
        if key not in self.kind_ids:
            self.kind_ids[key] = len(self.kinds)
            self.kinds.append({"name": name, **kind})
        return self.kind_ids[key]

    def _codes(self, s: pd.Series) -> np.ndarray:
        """The column's strings as int32 codes into ``self.strings`` (-1: missing), new strings
        numbered in order of first appearance."""
        local, uniques = pd.factorize(s.to_numpy(dtype=object), use_na_sentinel=True)
        ids = np.full(len(uniques) + 1, -1, dtype=np.int32)  # the last slot: factorize's -1
        for k, v in enumerate(uniques):
            if isinstance(v, str):
                j = self.string_ids.get(v)
                if j is None:
                    j = self.string_ids[v] = len(self.strings)
                    self.strings.append(v)
                ids[k] = j
        return ids[local]

    def add(self, fid: str, df: pd.DataFrame) -> None:
        if fid in self.flights:
            return
        if not isinstance(df.index, pd.RangeIndex) or df.index.start != 0 or df.index.step != 1:
            raise CacheUnsupported(f"flight {fid}: its table has an index other than 0..n-1")
        if df.attrs:
            raise CacheUnsupported(f"flight {fid}: its table carries attrs the flight cache does not keep")
        names = list(df.columns)
        if len(set(names)) != len(names) or not all(isinstance(c, str) for c in names):
            raise CacheUnsupported(f"flight {fid}: column names are not distinct strings")
        entries = [self._entry(c, _column_kind(df[c])) for c in names]
        layout = self.layout_ids.setdefault(tuple(entries), len(self.layouts))
        if layout == len(self.layouts):
            self.layouts.append(entries)
        offsets: dict[str, int] = {}
        by_group: dict[str, list[int]] = {}
        for i, e in enumerate(entries):
            by_group.setdefault(self.kinds[e]["group"], []).append(i)
        for group, cols in by_group.items():
            if group == "str":
                block = np.stack([self._codes(df.iloc[:, i]) for i in cols], axis=1)
            else:
                block = np.stack([df.iloc[:, i].to_numpy() for i in cols], axis=1)
            # column after column (columns x rows, C order): the layout of the table's blocks in
            # pandas, kept so that numpy reductions over a read table round exactly as before
            block = np.ascontiguousarray(block.T, dtype=_group_dtype(group))
            fh = self.files.get(group)
            if fh is None:
                fh = self.files[group] = open(self.folder / f"{group}.bin", "wb")
                self.sizes[group] = 0
            offsets[group] = self.sizes[group]
            fh.write(block.tobytes())
            self.sizes[group] += block.nbytes
        self.flights[fid] = {"rows": len(df), "layout": layout, "offsets": offsets}

    def close(self, key: dict) -> None:
        for fh in self.files.values():
            fh.flush()
            os.fsync(fh.fileno())
            fh.close()
        index = {"key": key, "columns": self.kinds, "layouts": self.layouts, "strings": self.strings,
                 "sizes": self.sizes, "flights": self.flights}
        tmp = self.folder / ".index.json.tmp"
        tmp.write_text(json.dumps(index, separators=(",", ":")) + "\n", encoding="utf-8")
        os.replace(tmp, self.folder / "index.json")  # written last: its presence means complete

    def abort(self) -> None:
        """Close every file whatever closing raises (on a full disk the final flush fails too): the
        caller removes the folder next, and must get to do so."""
        for fh in self.files.values():
            with contextlib.suppress(OSError):
                fh.close()


class DatasetReader:
    """``read(fid)`` for :func:`build_cache` that pickles to worker processes: a flight's table
    from the dataset at ``path`` (opened once per process)."""

    def __init__(self, path: str | Path):
        self.path = str(path)

    def __call__(self, fid: str) -> pd.DataFrame:
        from scart_bench.dataset import open_dataset

        if _OPENED.get("path") != self.path:
            _OPENED.update(path=self.path, dataset=open_dataset(self.path))
        return _OPENED["dataset"].flight(fid)


_OPENED: dict = {}

#: Fewest flights read by worker processes: below it, starting them (~2 s each) costs more than it saves.
PARALLEL_READ_MIN = 200


def _read_all(ids: list[str], read: Callable[[str], pd.DataFrame], workers: int) -> Iterator[pd.DataFrame]:
    """The tables of ``ids`` in order: read here, or by ``workers`` spawned processes when more
    than one (Parquet decoding and the table assembly are CPU work that one process does serially)."""
    if workers <= 1 or len(ids) < PARALLEL_READ_MIN:
        yield from map(read, ids)
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        yield from pool.map(read, ids, chunksize=8)


def build_cache(folder: str | Path, key: dict, flight_ids: Iterable[str],
                read: Callable[[str], pd.DataFrame], workers: int = 1) -> FlightCache:
    """Read every flight once with ``read(fid)`` and write the cache at ``folder`` (replacing any).

    ``workers`` > 1: that many processes read the flights (``read`` must pickle, e.g. a
    :class:`DatasetReader`) and this one writes them in the given order: the same cache.

    Written in a temp folder beside ``folder`` and renamed into place when complete. Raises
    CacheUnsupported (nothing left behind) for a table it cannot reproduce exactly.
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    for stale in folder.parent.glob(f".{folder.name}.*"):  # left by an interrupted build
        shutil.rmtree(stale, ignore_errors=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.build-", dir=folder.parent))
    builder = _Builder(tmp)
    ids = [str(fid) for fid in dict.fromkeys(flight_ids)]
    try:
        for fid, df in zip(ids, _read_all(ids, read, int(workers)), strict=True):
            builder.add(fid, df)
        builder.close(key)
        remove_cache(folder)
        os.replace(tmp, folder)
    except BaseException:
        try:
            builder.abort()
        finally:  # a full disk must not leave the temp folder (all the free space) behind
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    return FlightCache(folder, key)


def remove_cache(folder: str | Path) -> None:
    """Remove a cache folder (renamed away first, so no half-removed cache is ever read)."""
    folder = Path(folder)
    if folder.exists():
        gone = folder.with_name(f".{folder.name}.old-{os.getpid()}")
        shutil.rmtree(gone, ignore_errors=True)
        os.replace(folder, gone)
        shutil.rmtree(gone, ignore_errors=True)


# -- reading ------------------------------------------------------------------------------------

class FlightCache:
    """Read access to a built cache: ``flight(fid)`` gives the table the dataset would give.

    ``key`` (optional) must equal the cache's key, else CacheInvalid: a cache of another dataset is
    never read. Each read maps only that flight's bytes of each group file and copies them out.
    """

    def __init__(self, folder: str | Path, key: dict | None = None):
        self.folder = Path(folder)
        index_path = self.folder / "index.json"
        try:
            index = json.loads(index_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise CacheInvalid(f"{self.folder}: no flight cache (index.json missing)") from None
        except (OSError, ValueError) as exc:
            raise CacheInvalid(f"{index_path}: unreadable ({type(exc).__name__}: {exc})") from None
        if key is not None and index.get("key") != key:
            raise CacheInvalid(f"{self.folder}: the flight cache was built for another dataset or table")
        for group, size in index["sizes"].items():
            path = self.folder / f"{group}.bin"
            if not path.is_file() or path.stat().st_size != size:
                raise CacheInvalid(f"{path}: missing or not {size} bytes; the flight cache is damaged")
        self.key = index["key"]
        self.columns = index["columns"]
        self.layouts = index["layouts"]
        self.strings = np.array(index["strings"], dtype=object)
        self.index = index["flights"]
        self.reads = 0

    def __contains__(self, fid: str) -> bool:
        return str(fid) in self.index

    def has(self, flight_ids: Iterable[str]) -> bool:
        return all(str(f) in self.index for f in flight_ids)

    def _block(self, group: str, n_cols: int, rec: dict, n: int) -> np.ndarray:
        """One group's (columns, rows) array of one flight, copied out of its file (float64 for HALF)."""
        dtype = _group_dtype(group)
        if not n:
            return np.zeros((n_cols, 0), dtype=np.float64 if group == HALF else dtype)
        mm = np.memmap(self.folder / f"{group}.bin", dtype=dtype, mode="r", offset=int(rec["offsets"][group]),
                       shape=(n_cols, n))
        block = np.array(mm, dtype=np.float64 if group == HALF else dtype)
        del mm
        return block

    def _float64_frame(self, by_group: dict[str, list[int]], entries: list[dict], rec: dict, n: int) -> pd.DataFrame:
        """The float64 columns of a flight (held in f8 and, as float32 values, in HALF) as one block."""
        half, full = by_group[HALF], by_group.get("f8", [])
        cols = sorted(half + full)
        at = {i: k for k, i in enumerate(cols)}
        block = np.empty((len(cols), n), dtype=np.float64)
        block[[at[i] for i in half]] = self._block(HALF, len(half), rec, n)
        if full:
            block[[at[i] for i in full]] = self._block("f8", len(full), rec, n)
        return pd.DataFrame(block.T, columns=[entries[i]["name"] for i in cols], index=pd.RangeIndex(n), copy=False)

    def flight(self, flight_id: str) -> pd.DataFrame:
        """The flight's table, equal to the dataset's (KeyError when it is not cached)."""
        rec = self.index[str(flight_id)]
        n = int(rec["rows"])
        entries = [self.columns[e] for e in self.layouts[rec["layout"]]]
        by_group: dict[str, list[int]] = {}
        for i, e in enumerate(entries):
            by_group.setdefault(e["group"], []).append(i)
        frames = []
        merged = False
        for group, cols in by_group.items():
            if HALF in by_group and group in (HALF, "f8"):
                if not merged:  # float64 columns held as float32 go back into the one float64 block
                    frames.append(self._float64_frame(by_group, entries, rec, n))
                    merged = True
                continue
            block = self._block(group, len(cols), rec, n).T  # rows x columns, each column contiguous
            names = [entries[i]["name"] for i in cols]
            if group == "str":
                frames.append(pd.DataFrame({name: _text_column(block[:, j], self.strings, entries[i])
                                            for j, (i, name) in enumerate(zip(cols, names))}, index=pd.RangeIndex(n)))
            else:  # one block of one dtype: no per-column copies
                frames.append(pd.DataFrame(block.astype(np.dtype(entries[cols[0]]["dtype"]), copy=False),
                                           columns=names, index=pd.RangeIndex(n), copy=False))
        self.reads += 1
        df = frames[0] if len(frames) == 1 else pd.concat(frames, axis=1)
        order = [e["name"] for e in entries]
        return df if list(df.columns) == order else df[order]
