"""The compact flight layout: one Parquet file per view per flight, topics stacked.

A view (``navigator``, ``simulator``, ...) of one flight is one table: each topic's rows, one topic
after the other, in the columns ``Topic`` (the topic's number), ``Timestamp``, the labels and one
``topic.field`` column per field (null on the other topics' rows, which Parquet stores in a few
bits). The file's metadata (key ``scart_bench``) holds, per topic, its row span and its columns with
their dtypes, so every topic table reads back exactly as it was given, and the attack windows from
which the combined tables' labels are made.

Sizes: fields stored as float32 where that loses nothing a sensor resolves (every field of the
generator's topics except latitude and longitude), written with byte-stream-split encoding and zstd,
which together make a flight about a tenth of the per-topic layout. A simulator-view topic that is
identical to the navigator's is not stored twice: the simulator file names it and the reader takes
it from the navigator file. Likewise a simulator topic with the navigator's rows (the same
timestamps) stores only the fields that differ (layout version 2): an attack on a topic usually
alters a few of its fields, and the span names the fields read from the navigator file. Sharing
is decided bit for bit, so every value reads back exactly as written.

An attacked copy of a dataset's flight (``scart-bench attack --dataset``) shares the same way with
its source flight (layout version 3, written only by such copies): a topic with the source's rows
stores its timestamps, its labels and the fields the attack changed; every other field is read from
the source flight's navigator file, named ``../<source flight id>/navigator`` (:func:`view_file`).
A copy of an all-topic log thus costs what its attacked topics cost.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from scart_bench.dataset.labels import LABEL_COLUMNS, SourceTopic
from scart_bench.dataset.schema import TOPICS, TRUTH_FIELDS
from scart_bench.dataset.tables import plain_columns
from scart_bench.errors import ScartBenchError
from scart_bench.jsonfile import JsonFileError, loads_bounded
from scart_bench.names import IdError, check_id

META_KEY = b"scart_bench"
#: Bumped when the compact file's layout changes; a reader refuses newer versions. Version 3 (fields
#: kept in another flight's file) is written only by files that do so; the others stay version 2.
COMPACT_VERSION = 3
#: Nested references (a view kept in a view kept in ...) followed before a file is called damaged.
_MAX_DEPTH = 4
_SAME_FLIGHT = re.compile(r"[a-z][a-z0-9_]*")
_OTHER_FLIGHT = re.compile(r"\.\./([^/\\]+)/([a-z][a-z0-9_]*)")
SHARED_COLUMNS = ("Timestamp", "Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind")
#: Quantities that keep float64: float32 would round a latitude or longitude to about a metre.
_WIDE_QUANTITIES = ("latitude", "longitude")


class CompactError(ScartBenchError):
    """A compact flight file is missing, damaged or of an unknown version."""


def float32_safe(topic: str, field: str) -> bool:
    """Whether ``topic.field`` is stored as float32: a field of the generator's own link topics or
    true state, other than latitude/longitude (float32 keeps ~7 digits: 0.1 mm at 1 km, 6 mPa of
    100 kPa, far below every sensor's noise). Fields of imported topics keep their type."""
    base = topic[len("twin_"):] if topic.startswith("twin_") else topic
    if base == "truth":
        return field in TRUTH_FIELDS
    t = TOPICS.get(base)
    if t is None:
        return False
    for f in t.fields:
        if f.name == field:
            return f.quantity not in _WIDE_QUANTITIES
    return False


def _column_key(topic: str, col: str) -> str:
    return col if col in SHARED_COLUMNS else f"{topic}.{col}"


def other_flight_ref(flight_id: str, view: str = "navigator") -> str:
    """How a view file names a view of another flight of the same dataset (its source flight)."""
    return f"../{flight_id}/{view}"


def view_file(path: Path, ref: str) -> Path:
    """The file a view file at ``path`` means by ``ref``: a view of the same flight (``navigator``)
    or of another flight of the dataset (``../<flight id>/navigator``); CompactError naming ``path``
    for anything else (metadata is data: it must not name a file outside the dataset)."""
    ref = str(ref)
    if _SAME_FLIGHT.fullmatch(ref):
        return Path(path).parent / f"{ref}.parquet"
    m = _OTHER_FLIGHT.fullmatch(ref)
    if m:
        try:
            fid = check_id(m.group(1), f"{path}: flight id in the view reference {ref!r}")
        except IdError as exc:
            raise CompactError(str(exc)) from None
        return Path(path).parent.parent / fid / f"{m.group(2)}.parquet"
    raise CompactError(f"{path}: its metadata names the view {ref!r}; expected a view name (navigator) or "
                       "../<flight id>/<view> (damaged or not written by scart-bench)")


def referenced_flights(meta: dict) -> list[str]:
    """The other flights whose files a view file's metadata reads (an attacked copy's source), sorted."""
    refs = [str(v) for v in meta.get("reuse", {}).values()]
    refs += [str(s["shared"]["view"]) for s in meta.get("stored", []) if isinstance(s, dict) and s.get("shared")]
    return sorted({m.group(1) for r in refs if (m := _OTHER_FLIGHT.fullmatch(r))})


def _arrow(values: pd.Series, key: str, downcast: bool) -> pa.Array:
    if downcast and values.dtype == np.float64:
        return pa.array(values.to_numpy(np.float32), type=pa.float32())
    if key in ("Anomaly_Ids", "Anomaly_Kind"):
        if isinstance(values.dtype, pd.StringDtype) and values.dtype.storage == "pyarrow":
            # already Arrow text with nothing missing (no null: pandas keeps a missing value as one): the
            # same array without a round trip through Python
            arr = pa.array(values)
            if arr.null_count == 0 and (pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type)):
                return arr.cast(pa.string())
        return pa.array(values.astype(object).where(values.notna(), "").astype(str).tolist(), type=pa.string())
    return pa.Array.from_pandas(values)


def same_bits(a: pd.Series, b: pd.Series) -> bool:
    """Whether two columns hold the same values bit for bit, in the same dtype (unlike
    ``Series.equals``, 0.0 and -0.0, or two NaNs of different payloads, differ)."""
    if a.dtype != b.dtype or len(a) != len(b):
        return False
    x, y = a.to_numpy(), b.to_numpy()
    if x.dtype.kind in "biufcmM":
        return x.tobytes() == y.tobytes()
    return a.reset_index(drop=True).equals(b.reset_index(drop=True))


def shared_fields(df: pd.DataFrame, other: pd.DataFrame) -> list[str] | None:
    """The columns of ``df`` that ``other`` holds bit for bit (timestamps and labels included),
    or None when the two tables' rows differ (other length or other timestamps)."""
    if len(df) != len(other) or "Timestamp" not in df or "Timestamp" not in other:
        return None
    mine, theirs = plain_columns(df), plain_columns(other)  # plain numbers: their bytes, no Series

    def same(c) -> bool:
        x, y = mine.get(c), theirs.get(c)
        if x is not None and y is not None:
            return x.dtype == y.dtype and len(x) == len(y) and x.tobytes() == y.tobytes()
        return same_bits(df[c], other[c])

    if not same("Timestamp"):
        return None
    return [str(c) for c in df.columns if c in other.columns and same(c)]


_DTYPE_NAMES: dict = {}


def _dtype_name(dtype) -> str:
    """``str(dtype)``, remembered: a wide log's topics name the same few dtypes thousands of times."""
    key = (type(dtype), dtype)
    try:
        return _DTYPE_NAMES[key]
    except KeyError:
        name = _DTYPE_NAMES[key] = str(dtype)
        return name
    except TypeError:  # an unhashable extension dtype
        return str(dtype)


def stack_view(topics: dict[str, pd.DataFrame], reuse: dict[str, str] | None = None,
               shared: dict[str, tuple[str, list[str]]] | None = None) -> tuple[pa.Table, dict]:
    """One view's topics as a stacked Arrow table plus its metadata. ``reuse`` maps a topic name
    to the view that holds it instead (not stored here); ``shared`` maps a stored topic to
    ``(view, fields)``: fields (not timestamps or labels) that view's same topic holds for the
    same rows, which are not stored here."""
    reuse = reuse or {}
    shared = shared or {}
    stored = [name for name in topics if name not in reuse]
    spans: list[dict] = []
    chunks: dict[str, list] = {}  # column -> [(row offset, array)]
    types: dict[str, pa.DataType] = {}
    owner: dict[str, str] = {}
    offset = 0
    for name in stored:
        df = topics[name]
        from_source = isinstance(df, SourceTopic)  # a copy's topic held as its source's table plus labels
        if not from_source and not isinstance(df, pd.DataFrame):
            raise CompactError(f"topic {name!r}: expected a table, got {type(df).__name__}")
        cols = []
        elsewhere_view, elsewhere = shared.get(name, ("", []))
        elsewhere = [c for c in elsewhere if c not in SHARED_COLUMNS]
        kept_elsewhere = set(elsewhere)
        labels = None
        dtypes = df.dtypes if from_source else df.dtypes.tolist()  # dtypes once per topic, not per column
        columns = {} if from_source else plain_columns(df)  # plain number columns: arrays, no Series
        for label, dtype in zip(df.columns, dtypes):
            col = str(label)
            if col in kept_elsewhere:
                cols.append([col, _dtype_name(dtype)])
                continue
            key = _column_key(name, col)
            if owner.setdefault(key, name) != name and key not in SHARED_COLUMNS:
                raise CompactError(f"topic {name!r} column {col!r}: the name {key!r} is taken by topic {owner[key]!r}")
            if not from_source:
                plain = columns.get(label)
                if plain is None or key in LABEL_COLUMNS:
                    arr = _arrow(df[label], key, float32_safe(name, col))
                elif float32_safe(name, col) and plain.dtype == np.float64:  # as _arrow, from the array
                    arr = pa.array(plain.astype(np.float32), type=pa.float32())
                else:
                    arr = pa.Array.from_pandas(plain)
            elif col in LABEL_COLUMNS:
                labels = labels or df.label_arrays()
                arr = labels[col]
            else:  # the source's column: the same array for every copy of the source
                arr = df.cache.get(("arrow", col))
                if arr is None:
                    arr = df.cache[("arrow", col)] = _arrow(df.table[label], key, float32_safe(name, col))
            if key in types and types[key] != arr.type:
                try:
                    arr = arr.cast(types[key])
                except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as exc:
                    raise CompactError(f"topic {name!r} column {col!r}: type {arr.type} does not match "
                                       f"{types[key]} of the other topics") from exc
            types.setdefault(key, arr.type)
            chunks.setdefault(key, []).append((offset, arr))
            cols.append([col, _dtype_name(dtype)])
        span = {"name": name, "offset": offset, "rows": len(df), "columns": cols}
        if elsewhere:
            span["shared"] = {"view": elsewhere_view, "columns": elsewhere}
        spans.append(span)
        offset += len(df)
    total = offset
    arrays, names = [pa.array(np.repeat(np.arange(len(stored), dtype=np.int16),
                                        [s["rows"] for s in spans]) if stored else [], type=pa.int16())], ["Topic"]
    order = [k for k in SHARED_COLUMNS if k in chunks] + [k for k in chunks if k not in SHARED_COLUMNS]
    for key in order:
        parts, at = [], 0
        for start, arr in chunks[key]:
            if start > at:
                parts.append(pa.nulls(start - at, types[key]))
            parts.append(arr)
            at = start + len(arr)
        if at < total:
            parts.append(pa.nulls(total - at, types[key]))
        arrays.append(pa.concat_arrays(parts) if parts else pa.array([], types[key]))
        names.append(key)
    refs = [*reuse.values(), *(view for view, _ in shared.values())]
    version = 3 if any(_OTHER_FLIGHT.fullmatch(str(r)) for r in refs) else 2  # version 2 files stay byte for byte
    meta = {"version": version, "topics": list(topics), "stored": spans, "reuse": reuse}
    return pa.Table.from_arrays(arrays, names=names), meta


def write_view(path: Path, topics: dict[str, pd.DataFrame], windows: list, reuse: dict[str, str] | None = None,
               shared: dict[str, tuple[str, list[str]]] | None = None) -> None:
    """Write one view's topics to ``path``: Parquet, zstd level 3, floats byte-stream-split and the
    integer timestamps delta-packed: both shrink what zstd is given (perf.generate_speed prints
    the size on disk)."""
    table, meta = stack_view(topics, reuse, shared)
    meta["windows"] = [list(w) for w in windows]
    table = table.replace_schema_metadata({META_KEY: json.dumps(meta, default=_json_default).encode()})
    encodings = {f.name: "BYTE_STREAM_SPLIT" for f in table.schema if pa.types.is_floating(f.type)}
    encodings.update({f.name: "DELTA_BINARY_PACKED" for f in table.schema
                      if f.name == "Timestamp" and pa.types.is_integer(f.type)})
    texts = [f.name for f in table.schema if pa.types.is_string(f.type) or f.name == "Topic"]
    pq.write_table(table, path, compression="zstd", compression_level=3, use_dictionary=texts,
                   column_encoding=encodings or None)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def read_meta(path: Path) -> dict:
    """The metadata of a compact view file (CompactError naming the file when it is not one)."""
    try:
        schema = pq.read_schema(path)
    except FileNotFoundError:
        raise CompactError(f"{path}: missing") from None
    except Exception as exc:  # pyarrow raises its own types for a damaged file
        raise CompactError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise CompactError(f"{path}: not a scart-bench flight view (no {META_KEY.decode()} metadata)")
    try:  # bounded: a file's metadata is data too (100,000 nested '[' must not be a RecursionError)
        meta = loads_bounded(raw, f"{path} (its {META_KEY.decode()} metadata)")
    except JsonFileError as exc:
        raise CompactError(str(exc)) from None
    version = meta.get("version", 0) if isinstance(meta, dict) else None
    if (not isinstance(meta, dict) or not isinstance(version, int) or not isinstance(meta.get("topics"), list)
            or not isinstance(meta.get("stored", []), list) or not isinstance(meta.get("reuse", {}), dict)):
        raise CompactError(f"{path}: its {META_KEY.decode()} metadata is not a scart-bench flight view's (expected "
                           "an object with an integer version, a topics list and the stored spans)")
    if version > COMPACT_VERSION:
        raise CompactError(f"{path}: written by a newer scart-bench (layout version {meta['version']}, this one "
                           f"reads up to {COMPACT_VERSION}); upgrade scart-bench or regenerate the dataset")
    return meta


def read_topics(path: Path, names: list[str] | None = None, meta: dict | None = None,
                arrays: bool = False, _depth: int = 0) -> dict[str, pd.DataFrame]:
    """The stored topic tables of a view file (all, or those in ``names``), exactly as written
    except that float32 fields come back as float64 (their float32 values); fields shared with
    another view are read from that view's file (beside this one, or in the source flight's folder
    for an attacked copy). ``arrays``: each topic as a dict of column arrays (no table is built)."""
    if _depth > _MAX_DEPTH:
        raise CompactError(f"{path}: its views name each other in a loop (more than {_MAX_DEPTH} files deep); "
                           "damaged or not written by scart-bench")
    meta = meta or read_meta(path)
    spans = {s["name"]: s for s in meta["stored"]}
    want = [n for n in (names if names is not None else list(spans)) if n in spans]
    if not want:
        return {}
    keys = ["Topic"]
    elsewhere: dict[str, list[str]] = {}  # other view -> topics with fields kept there
    for n in want:
        shared = spans[n].get("shared")
        if shared:
            if view_file(path, shared["view"]) == Path(path):
                raise CompactError(f"{path}: topic {n!r} names its own file as the one holding its fields")
            elsewhere.setdefault(shared["view"], []).append(n)
        for col, _ in spans[n]["columns"]:
            key = _column_key(n, col)
            if key not in keys and not (shared and col in shared["columns"]):
                keys.append(key)
    try:
        table = _read_columns(path, keys, [(n, spans[n]) for n in want])
    except Exception as exc:
        raise CompactError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None
    others = {}
    for view, topics in elsewhere.items():
        other_path = view_file(path, view)
        if not other_path.exists():
            raise CompactError(f"{path}: keeps fields of topic(s) {', '.join(sorted(topics)[:5])} in {other_path}, "
                               "which is missing" + (" (the source flight of this attacked copy: restore it, or remove "
                                                     "the copy and attack again)" if view.startswith("../") else ""))
        others.update(read_topics(other_path, topics, arrays=True, _depth=_depth + 1))
    out = {}
    for n in want:
        span = spans[n]
        part = table[n] if isinstance(table, dict) else table.slice(span["offset"], span["rows"])
        kept = set(span["shared"]["columns"]) if span.get("shared") else set()
        other = others.get(n, {})
        for col in kept:
            if col not in other or len(other[col]) != span["rows"]:
                raise CompactError(f"{path}: topic {n!r} field {col!r} is kept in the "
                                   f"{span['shared']['view']} view, which does not hold it for the same rows")
        data = {col: other[col] if col in kept else _to_numpy(part.column(_column_key(n, col)), dtype)
                for col, dtype in span["columns"]}
        out[n] = data if arrays else topic_frame(data, span)
    return out


def topic_frame(data: dict[str, np.ndarray], span: dict, copy: bool = False) -> pd.DataFrame:
    """A topic's table from its column arrays as :func:`read_topics` gives them, text columns in
    their written dtype (``span``: the topic's stored span). ``copy``: the table owns its values."""
    df = pd.DataFrame(data, index=pd.RangeIndex(span["rows"]), copy=copy)
    for col, dtype in span["columns"]:
        if str(df[col].dtype) != dtype:  # text columns: restore the written dtype (object or str)
            try:
                df[col] = df[col].astype(dtype)
            except (TypeError, ValueError):
                pass
    return df


#: Columns read in one go from a view file. A view stacks its topics, so every column is as long
#: as all topics' rows together: a log imported with all its topics (3,346 fields on the RflyMAD
#: log) read at once materialised 1.3 GB of mostly-null columns. Wider reads go topic group by
#: topic group, each topic's rows kept (perf.attack_speed: 5 CPU s -> about 1 for that log).
READ_COLUMNS_AT_ONCE = 512


def _read_columns(path: Path, keys: list[str], spans: list[tuple[str, dict]]) -> pa.Table | dict[str, pa.Table]:
    """Columns ``keys`` of a view file: the whole table when they are few, else per topic of
    ``spans`` ((name, span)) the span's rows of the shared columns and of the topic's own columns."""
    if len(keys) <= READ_COLUMNS_AT_ONCE:
        return pq.read_table(path, columns=keys)
    f = pq.ParquetFile(path)
    shared = f.read(columns=[k for k in keys if k in SHARED_COLUMNS], use_threads=False)
    wanted = set(keys)
    out: dict[str, pa.Table] = {}
    group: list[tuple[str, dict]] = []
    width = 0

    def flush() -> None:
        own = list(dict.fromkeys(_column_key(n, c) for n, s in group for c, _ in s["columns"]))
        own = [k for k in own if k in wanted and k not in SHARED_COLUMNS]
        table = f.read(columns=own, use_threads=False)
        for n, s in group:
            part = table.slice(s["offset"], s["rows"])
            base = shared.slice(s["offset"], s["rows"])
            out[n] = pa.Table.from_arrays([*base.columns, *part.columns], names=[*base.column_names, *part.column_names])

    for n, s in spans:
        group.append((n, s))
        width += len(s["columns"])
        if width >= READ_COLUMNS_AT_ONCE:
            flush()
            group, width = [], 0
    if group:
        flush()
    return out


def _to_numpy(arr: pa.ChunkedArray, dtype: str) -> np.ndarray:
    if pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type):
        return np.array(["" if v is None else v for v in arr.to_pylist()], dtype=object)
    values = arr.to_numpy(zero_copy_only=False)
    if pa.types.is_floating(arr.type):
        return values.astype(dtype if dtype.startswith("float") else np.float64)
    return values
