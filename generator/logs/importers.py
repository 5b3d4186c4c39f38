"""Import a user's flight log as per-topic tables for csv mode (offline attack replay).

``load_flight_file(path)`` accepts a PX4 ULog (``.ulg``), an ArduPilot DataFlash log (``.bin``,
:mod:`.dataflash`), a CSV (``.csv``, also ``.csv.gz`` etc.), a Parquet file (``.parquet``) or a
scart-bench dataset flight folder, and returns
``{topic: DataFrame}``. Every table has an int64 ``Timestamp`` column (microseconds from the
start of the log: a ULog's logging start, else the earliest timestamp in the file, whichever
topics are asked for), sorted and strictly increasing, followed by the topic's numeric fields as
float64 columns. See ``load_flight_file`` for the rules per format.
``ulog_info(path)`` summarises a ULog (start, duration, topics with message counts and rates).
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import re
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import TRUTH_TOPICS, DatasetError, compact, read_view
from scart_bench.generator.logs.dataflash import read_dataflash
from scart_bench.generator.logs.rosbag import read_rosbag
from scart_bench.generator.logs.tables import (
    finish_tables,
    sanitize_field_name,
    sanitize_topic_name,
    unique_names,
)
from scart_bench.generator.logs.tlog import read_tlog

logger = logging.getLogger(__name__)

#: Accepted timestamp column names (compared case-insensitively), in order of preference, with the
#: unit their name states; None: the unit is inferred from the sampling interval (see time_unit).
TIME_COLUMNS: dict[str, str | None] = {
    "timestamp": None, "time_us": "us", "timestamp_us": "us", "time_usec": "us", "timestamp_ns": "ns",
    "time_ns": "ns", "timestamp_ms": "ms", "time_ms": "ms", "time": None, "time_s": "s", "t": None,
    "%time": None, "field.header.stamp": None,
}
#: Microseconds per unit.
TIME_UNITS = {"ns": 1e-3, "us": 1.0, "ms": 1e3, "s": 1e6}
#: What a drone log's time column must look like in a unit for that unit to be plausible: the
#: median sampling interval (s) and the span of the log (s).
PLAUSIBLE_INTERVAL_S = (1e-4, 2.0)
PLAUSIBLE_SPAN_S = (0.5, 12 * 3600.0)
#: Columns of scart-bench tables that are not sensor data.
IGNORED_COLUMNS = ("index", "is_anomaly", "anomaly_ids", "anomaly_kind")
_UNNAMED = re.compile(r"^Unnamed: \d+$")  # pandas' name for a written index without a name

#: Log formats read by their own module: extension -> reader (path, topics, allow_corrupt) -> (raw
#: topics, time zero in the file's time base).
LOG_READERS = {".bin": read_dataflash, ".tlog": read_tlog, ".bag": read_rosbag, ".db3": read_rosbag,
               ".mcap": read_rosbag}
#: Every log extension load_flight_file reads besides tables and folders.
LOG_SUFFIXES = (".ulg", *LOG_READERS)

CSV_SUFFIXES = (".csv",)
# pandas < 3 parses CSV floats with a fast parser that can be 1 ulp off; >= 3 is exact by default
# (and deprecates the option). lat/lon must round-trip bit-exactly.
_CSV_FLOAT = {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}
PARQUET_SUFFIXES = (".parquet", ".pq")
COMPRESSION_SUFFIXES = (".gz", ".bz2", ".xz", ".zip", ".zst")


# ----------------------------------------------------------------------------------------------
# PX4 ULog


def _read_ulog(path: Path, names: list[str] | None = None):
    """Parse a ULog with pyulog, turning its failures (and its stdout chatter) into DatasetError."""
    try:
        from pyulog import ULog
    except ImportError as exc:  # pragma: no cover - pyulog is a dependency
        raise DatasetError(f"{path}: reading PX4 ULog files needs the 'pyulog' package") from exc
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter):
            ulog = ULog(str(path), names)
    except Exception as exc:  # pyulog raises ULogException, struct.error, ValueError ...
        raise DatasetError(f"{path}: not a readable PX4 ULog file ({type(exc).__name__}: {exc}); "
                           "expected a .ulg log written by the PX4 logger") from exc
    text = chatter.getvalue().strip()
    if text:
        logger.debug("%s: pyulog: %s", path, text)
    return ulog


def _ulog_topics(data_list) -> list[tuple[str, object]]:
    """(topic name, pyulog Data) sorted by (message, multi_id): ``name`` for multi_id 0,
    ``name_<multi_id>`` otherwise (``name_m<multi_id>`` if that clashes with another message)."""
    out: list[tuple[str, object]] = []
    taken = {d.name for d in data_list if d.multi_id == 0}
    for d in sorted(data_list, key=lambda d: (d.name, d.multi_id)):
        name = d.name
        if d.multi_id:
            name = f"{d.name}_{d.multi_id}"
            if name in taken:
                name = f"{d.name}_m{d.multi_id}"
            taken.add(name)
        out.append((name, d))
    return out


def _ulog_fields(data: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict]:
    """Numeric fields of one ULog message as float64, sanitised, with degE7/mm conversion."""
    fields: dict[str, np.ndarray] = {}
    originals: list[str] = []
    for key, values in data.items():
        if key == "timestamp" or any(part.startswith("_padding") for part in key.split(".")):
            continue
        if values.dtype.kind not in "biuf":  # char arrays and other non-numeric fields
            continue
        originals.append(key)
        fields[key] = values
    notes: dict = {}
    scaled = {}
    lat, lon = fields.get("lat"), fields.get("lon")
    if lat is not None and lon is not None and lat.dtype.kind in "iu" and lon.dtype.kind in "iu":
        scaled["lat"] = scaled["lon"] = 1e-7
        for alt in ("alt", "alt_ellipsoid"):
            if alt in fields and fields[alt].dtype.kind in "iu":
                scaled[alt] = 1e-3
    out: dict[str, np.ndarray] = {}
    for key, new in zip(originals, unique_names([sanitize_field_name(k) for k in originals])):
        values = fields[key].astype(np.float64)
        if key in scaled:
            values = values * scaled[key]
        out[new] = values
    if scaled:
        notes["converted"] = {k: ("degE7 -> deg" if v == 1e-7 else "mm -> m") for k, v in scaled.items()}
    return out, notes


def ulog_truncated(path: Path) -> tuple[bool, int, int]:
    """(truncated, bytes in whole messages, file size): walks the ULog's message headers; a file
    whose last message runs past its end was cut (copied while written, a full SD card ...)."""
    size = path.stat().st_size
    pos = 16  # the file header
    with open(path, "rb") as fh:  # header by header: the log is never held in memory twice
        while pos + 3 <= size:
            fh.seek(pos)
            n = int.from_bytes(fh.read(2), "little")
            if pos + 3 + n > size:
                return True, pos, size
            pos += 3 + n
    return pos != size, pos, size


def _load_ulog(path: Path, topics: list[str] | None, allow_corrupt: bool) -> dict[str, pd.DataFrame]:
    names = None
    if topics is not None:
        names = sorted({t for t in topics} | {m.group(1) for t in topics if (m := re.match(r"(.+)_m?\d+$", t))})
    ulog = _read_ulog(path, names)
    if ulog.file_corruption:
        n = sum(len(d.data["timestamp"]) for d in ulog.data_list)
        if not allow_corrupt or n == 0:
            raise DatasetError(f"{path}: the ULog file is corrupt (pyulog found invalid data; {n} message(s) "
                               "readable); pass --allow-corrupt (allow_corrupt=True) to load the readable part")
        logger.warning("%s: ULog file corruption detected; loading the %d readable message(s)", path, n)
    cut, read, size = ulog_truncated(path)
    if cut:
        seconds = (int(ulog.last_timestamp) - int(ulog.start_timestamp)) / 1e6
        if not allow_corrupt:
            raise DatasetError(f"{path}: the ULog is truncated (its last message runs past the end of the file: "
                               f"{read} of {size} bytes hold whole messages, {seconds:.1f} s of logging); pass "
                               "--allow-corrupt (allow_corrupt=True) to use what was read")
        logger.warning("%s: the ULog is truncated; using the %.1f s of logging read (%d of %d bytes)",
                       path, seconds, read, size)
    if not ulog.data_list and topics is None:
        raise DatasetError(f"{path}: the ULog has no logged messages (empty log)")
    raw: dict[str, tuple] = {}
    for topic, d in _ulog_topics(ulog.data_list):
        if "timestamp" not in d.data:
            logger.warning("%s: message %s has no timestamp field; skipped", path, topic)
            continue
        fields, notes = _ulog_fields(d.data)
        notes = {**notes, "ulog_message": d.name, "multi_id": d.multi_id}
        if ulog.file_corruption:
            notes["file_corruption"] = True
        raw[topic] = (d.data["timestamp"].astype(np.int64), fields, notes)
    if topics is not None:
        missing = [t for t in topics if t not in raw]
        if missing:
            available = sorted(ulog_info(path)["topics"])
            raise DatasetError(f"{path}: topic(s) {missing} not found in the ULog; it has: {available}")
    # time zero: the start of logging, whichever messages were parsed
    return finish_tables(raw, path, topics, origin=int(ulog.start_timestamp), keep_last=True)


def _rate(ts: np.ndarray) -> tuple[float | None, float | None]:
    """(nominal rate from the median interval, mean rate over the span), in Hz."""
    ts = np.unique(np.asarray(ts, dtype=np.int64))
    if ts.shape[0] < 2:
        return None, None
    median = float(np.median(np.diff(ts)))
    span = float(ts[-1] - ts[0])
    return (1e6 / median if median > 0 else None), ((ts.shape[0] - 1) * 1e6 / span if span > 0 else None)


def ulog_info(path: str | Path) -> dict:
    """Summary of a PX4 ULog.

    Returns ``path``, ``hardware`` (``ver_hw``), ``software`` (git hash ``ver_sw``), ``start_us``
    (logging start, microseconds since boot), ``last_us``, ``duration_s`` (last - start),
    ``first_message_us`` (earliest message, may precede ``start_us``: latched topics keep their
    publication time), ``start_utc`` (ISO time at ``start_us`` from a GPS topic's
    ``time_utc_usec``, or None), ``dropouts``/``dropout_ms``, ``file_corruption``, and ``topics``:
    ``{topic: {message, multi_id, messages, rate_hz, mean_rate_hz, first_us, last_us}}`` where
    ``rate_hz`` is the nominal rate (1 / median interval) and ``mean_rate_hz`` counts messages
    over the topic's span (lower when the logger skipped samples).
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such file (expected a PX4 ULog .ulg file)")
    ulog = _read_ulog(path)
    topics: dict[str, dict] = {}
    start_utc = None
    for topic, d in _ulog_topics(ulog.data_list):
        if "timestamp" not in d.data:
            continue
        ts = d.data["timestamp"].astype(np.int64)
        rate, mean_rate = _rate(ts)
        topics[topic] = {"message": d.name, "multi_id": d.multi_id, "messages": int(ts.shape[0]),
                         "rate_hz": rate, "mean_rate_hz": mean_rate,
                         "first_us": int(ts.min()), "last_us": int(ts.max())}
        utc = d.data.get("time_utc_usec")
        if start_utc is None and utc is not None and d.name in ("vehicle_gps_position", "sensor_gps"):
            ok = np.flatnonzero(utc > 0)
            if ok.size:
                i = ok[0]
                at_start = int(utc[i]) - (int(ts[i]) - int(ulog.start_timestamp))
                start_utc = datetime.fromtimestamp(at_start / 1e6, tz=UTC).isoformat()
    firsts = [v["first_us"] for v in topics.values()]
    return {
        "path": str(path),
        "hardware": ulog.msg_info_dict.get("ver_hw"),
        "software": ulog.msg_info_dict.get("ver_sw"),
        "start_us": int(ulog.start_timestamp),
        "last_us": int(ulog.last_timestamp),
        "duration_s": (int(ulog.last_timestamp) - int(ulog.start_timestamp)) / 1e6,
        "first_message_us": min(firsts) if firsts else None,
        "start_utc": start_utc,
        "dropouts": len(ulog.dropouts),
        "dropout_ms": int(sum(d.duration for d in ulog.dropouts)),
        "file_corruption": bool(ulog.file_corruption),
        "topics": dict(sorted(topics.items())),
    }


# ----------------------------------------------------------------------------------------------
# CSV / Parquet tables


def _where(i: int, is_csv: bool) -> str:
    return f"row {i + 1} (line {i + 2} of the file)" if is_csv else f"row {i + 1}"


def _numeric(series: pd.Series, column: str, source: Path, is_csv: bool) -> np.ndarray:
    """A column as float64, or DatasetError naming the column and its first non-numeric row."""
    kind = series.dtype.kind
    if kind in "biuf":
        return series.to_numpy(dtype=np.float64)
    if kind in "mM":  # dates are not sensor values
        coerced = pd.Series(np.nan, index=series.index)
    else:
        coerced = pd.to_numeric(series, errors="coerce")
    bad = np.flatnonzero(coerced.isna().to_numpy() & series.notna().to_numpy())
    if bad.size:
        i = int(bad[0])
        raise DatasetError(f"{source}: column {column!r} has a non-numeric value {series.iloc[i]!r} in "
                           f"{_where(i, is_csv)}; expected numbers (empty cells count as missing)")
    return coerced.to_numpy(dtype=np.float64)


def time_unit(values: np.ndarray, column: str, source: Path) -> str:
    """The unit (ns, us, ms or s) of a time column, from its sampling interval and span.

    A unit is plausible when the median interval between distinct times is 0.1 ms .. 2 s and
    the span 0.5 s .. 12 h in it. Exactly one plausible unit is the answer; none or several
    raise DatasetError naming the column (rename it with a unit suffix, e.g. ``timestamp_us``).
    """
    v = np.unique(values[np.isfinite(values)])
    if v.shape[0] < 2:
        raise DatasetError(f"{source}: time column {column!r} has fewer than two distinct times; its unit "
                           "cannot be inferred: name it with a unit suffix (timestamp_us, time_s ...)")
    d = float(np.median(np.diff(v)))
    span = float(v[-1] - v[0])
    fits = [u for u, us in TIME_UNITS.items()
            if PLAUSIBLE_INTERVAL_S[0] <= d * us / 1e6 <= PLAUSIBLE_INTERVAL_S[1]
            and PLAUSIBLE_SPAN_S[0] <= span * us / 1e6 <= PLAUSIBLE_SPAN_S[1]]
    if len(fits) == 1:
        return fits[0]
    why = "fits none of ns, us, ms, s" if not fits else f"is ambiguous ({' or '.join(fits)})"
    raise DatasetError(f"{source}: time column {column!r}: the unit {why} for a median interval of {d:g} and a "
                       f"span of {span:g}; name the column with its unit: timestamp_ns, timestamp_us, "
                       "timestamp_ms or time_s")


def _timestamps(series: pd.Series, column: str, unit: str | None, source: Path, is_csv: bool) -> np.ndarray:
    """The time column as int64 microseconds (``unit`` None: inferred with :func:`time_unit`)."""
    if series.dtype.kind in "mM":  # Parquet datetime / duration columns
        s = series
        if isinstance(s.dtype, pd.DatetimeTZDtype):
            s = s.dt.tz_convert(None)
        if s.isna().any():
            i = int(np.flatnonzero(s.isna().to_numpy())[0])
            raise DatasetError(f"{source}: time column {column!r} is empty in {_where(i, is_csv)}")
        kind = "datetime64[us]" if s.dtype.kind == "M" else "timedelta64[us]"
        return s.to_numpy(dtype=kind).astype(np.int64)
    values = _numeric(series, column, source, is_csv)
    missing = np.flatnonzero(~np.isfinite(values))
    if missing.size:
        i = int(missing[0])
        raise DatasetError(f"{source}: time column {column!r} is empty or not finite in {_where(i, is_csv)}")
    if unit is None:
        unit = time_unit(values, column, source)
    if series.dtype.kind in "iu" and unit in ("us", "ms", "s"):
        return series.to_numpy(dtype=np.int64) * int(TIME_UNITS[unit])
    if series.dtype.kind in "iu" and unit == "ns":
        return (series.to_numpy(dtype=np.int64) + 500) // 1000
    return np.rint(values * TIME_UNITS[unit]).astype(np.int64)


def _time_column(columns: list[str], source: Path) -> tuple[str, str | None]:
    """(column name, unit or None to infer) of the first accepted timestamp column, by preference."""
    lower = {str(c).lower(): c for c in reversed(columns)}
    for name, unit in TIME_COLUMNS.items():
        if name in lower:
            return lower[name], unit
    raise DatasetError(f"{source}: no timestamp column; expected one of {list(TIME_COLUMNS)} "
                       f"(case-insensitive; the unit is inferred unless the name states it); "
                       f"found columns {list(columns)[:20]}")


def own_layout(columns: list[str]) -> bool:
    """True for a table in scart-bench's dataset layout (``Timestamp`` with ``Index``/``Is_Anomaly``):
    microseconds from the flight's start."""
    return "Timestamp" in columns and ("Is_Anomaly" in columns or "Index" in columns)


#: Column prefix of ROS ``rostopic echo -p`` exports (``field.x``): not a topic name.
ROS_FIELD_PREFIX = "field"


def _frame_topics(df: pd.DataFrame, source: Path, stem: str, is_csv: bool,
                  split: bool = True, unit: str | None = None) -> dict[str, tuple]:
    """Topic tables of one flat table: split ``topic.field`` columns, else one topic ``stem``.

    A ROS export (every column ``field.<name>``) is one topic named after the file, fields
    ``<name>`` (``field.header.seq`` -> ``header_seq``).
    """
    columns = [str(c) for c in df.columns]
    df.columns = columns
    tcol, named_unit = _time_column(columns, source)
    if own_layout(columns):
        named_unit = "us"  # scart-bench's own tables: microseconds by definition
    fields = [c for c in columns if c != tcol and c.lower() not in IGNORED_COLUMNS and not _UNNAMED.match(c)]
    if not fields:
        raise DatasetError(f"{source}: no data columns besides the time column {tcol!r}")
    if len(df) == 0:
        raise DatasetError(f"{source}: the table is empty (a header but no data rows)")
    ts = _timestamps(df[tcol], tcol, unit or named_unit, source, is_csv)
    values = {c: _numeric(df[c], c, source, is_csv) for c in fields}
    dotted = split and all(re.fullmatch(r"[^.]+\.[^.].*", c) for c in fields)
    ros = dotted and {c.split(".", 1)[0] for c in fields} == {ROS_FIELD_PREFIX}
    groups: dict[str, list[str]] = {}
    for c in fields:
        topic = sanitize_topic_name(c.split(".", 1)[0]) if dotted and not ros else sanitize_topic_name(stem)
        groups.setdefault(topic, []).append(c)
    raw: dict[str, tuple] = {}
    for topic, cols in groups.items():
        block = np.column_stack([values[c] for c in cols])
        rows = ~np.all(np.isnan(block), axis=1)
        names = unique_names([sanitize_field_name(c.split(".", 1)[1] if dotted else c) for c in cols])
        notes = {"empty_rows_dropped": int((~rows).sum())}
        raw[topic] = (ts[rows], {n: values[c][rows] for n, c in zip(names, cols)}, notes)
    return raw


def _header(path: Path) -> list[str]:
    """The first line of a CSV as a list of names (to catch duplicate names pandas would mangle)."""
    try:
        with open(path, newline="", encoding="utf-8", errors="replace") as fh:
            return next(csv.reader(fh), [])
    except (OSError, csv.Error):
        return []


#: Most columns a CSV or Parquet input may have: a flight log has tens to a few thousand fields;
#: beyond this the file is not a flight table (and would take minutes to parse).
MAX_COLUMNS = 5_000


def _check_width(path: Path, n: int) -> None:
    if n > MAX_COLUMNS:
        raise DatasetError(f"{path}: {n} columns, more than the {MAX_COLUMNS} a flight table may have; keep the "
                           "fields you need (one CSV per topic, or a Parquet file with those columns)")


def _read_csv(path: Path) -> pd.DataFrame:
    compressed = path.suffix.lower() in COMPRESSION_SUFFIXES
    if not compressed:
        names = [n.strip() for n in _header(path)]
        _check_width(path, len(names))
        counts = Counter(names)
        dup = sorted(n for n, c in counts.items() if c > 1)
        if dup:
            raise DatasetError(f"{path}: duplicate column name(s) {dup} in the header")
    try:
        return pd.read_csv(path, low_memory=False, skipinitialspace=True, **_CSV_FLOAT)
    except pd.errors.EmptyDataError as exc:
        raise DatasetError(f"{path}: the CSV file is empty (expected a header with a timestamp column)") from exc
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError, OSError) as exc:
        raise DatasetError(f"{path}: not a readable CSV file ({type(exc).__name__}: {exc})") from exc


def _read_parquet(path: Path) -> pd.DataFrame:
    try:
        import pyarrow.parquet as pq

        _check_width(path, len(pq.read_schema(path).names))
        return pd.read_parquet(path)
    except DatasetError:
        raise
    except Exception as exc:  # pyarrow raises ArrowInvalid, OSError ...
        raise DatasetError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc})") from exc


def _stem(path: Path) -> str:
    name = path.name
    for suffix in (*COMPRESSION_SUFFIXES, *CSV_SUFFIXES, *PARQUET_SUFFIXES):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return name


def _compact_meta(path: Path) -> dict | None:
    """The metadata of ``path`` when it is a view file of the project's compact layout (topics stacked
    in one table, :mod:`scart_bench.dataset.compact`), else None (an ordinary Parquet table)."""
    try:
        import pyarrow.parquet as pq

        if compact.META_KEY not in (pq.read_schema(path).metadata or {}):
            return None
    except Exception:  # not readable as Parquet: _read_parquet names the file
        return None
    try:
        return compact.read_meta(path)
    except compact.CompactError as exc:
        raise DatasetError(str(exc)) from None


def _load_compact_view(path: Path, meta: dict, topics: list[str] | None) -> dict[str, pd.DataFrame]:
    """The topic tables of one compact view file (a flight's ``navigator.parquet``, whatever it is
    called now): each topic read from its own rows, not the stacked table as one topic. A topic the
    file keeps in another view's file (the simulator view reuses the navigator's) is read from that
    file beside it. The true state (never on the link) is left out."""
    names = [n for n in meta.get("topics", []) if n not in TRUTH_TOPICS]
    try:
        elsewhere: dict[str, list[str]] = {}  # view -> topics (or some of their fields) kept in its file
        for n in names:
            if n in meta.get("reuse", {}):
                elsewhere.setdefault(str(meta["reuse"][n]), []).append(n)
        for span in meta.get("stored", []):
            if span.get("shared") and span.get("name") in names:
                elsewhere.setdefault(str(span["shared"]["view"]), []).append(span["name"])
        for view, wanted in elsewhere.items():
            other = path.parent / f"{view}.parquet"
            if not other.exists():
                raise DatasetError(f"{path}: keeps topic(s) {sorted(set(wanted))} (or some of their fields) in the "
                                   f"{view} view's file {other}, which is missing; pass the flight folder, or keep "
                                   "the two files together")
        tables = compact.read_topics(path, names, meta)
        for view, wanted in elsewhere.items():
            reused = [n for n in wanted if n not in tables]
            if reused:
                tables.update(compact.read_topics(path.parent / f"{view}.parquet", reused))
    except (KeyError, TypeError) as exc:  # metadata of the wrong shape
        raise DatasetError(f"{path}: its compact-layout metadata is damaged ({type(exc).__name__}: {exc})") from None
    except compact.CompactError as exc:
        raise DatasetError(str(exc)) from None
    raw: dict[str, tuple] = {}
    for stem in names:
        if stem in tables:  # our own tables: microseconds from the flight's start
            raw.update(_frame_topics(tables[stem], path, stem, False, split=False, unit="us"))
    if not raw:
        raise DatasetError(f"{path}: a compact flight view with no topic tables: empty flight")
    return finish_tables(raw, path, topics, origin=0)


# ----------------------------------------------------------------------------------------------
# scart-bench flight folder


def flight_view_tables(path: Path, view: dict[str, pd.DataFrame], topics: list[str] | None = None
                       ) -> dict[str, pd.DataFrame]:
    """What :func:`load_flight_file` gives for the compact flight folder ``path`` whose navigator view's
    tables (as ``read_view`` gives them) are ``view``: for a caller that has read them already."""
    raw = {}
    for stem, df in view.items():
        raw.update(_frame_topics(df, path / "navigator.parquet", stem, False, split=False, unit="us"))
    return finish_tables(raw, path, topics, origin=0)


def _load_flight_folder(path: Path, topics: list[str] | None) -> dict[str, pd.DataFrame]:
    if (path / "navigator.parquet").exists():  # the compact layout: every topic in one file
        return flight_view_tables(path, read_view(path, "navigator"), topics)
    folder = path / "sensors" / "navigator"
    if not folder.is_dir():
        hint = ""
        if (path / "manifest.parquet").exists() or (path / "manifest.csv").exists():
            hint = f"; this is a dataset: pass one flight folder, e.g. {path / 'flights' / '<flight_id>'}"
        raise DatasetError(f"{path}: a folder must be a scart-bench flight folder containing "
                           f"navigator.parquet or sensors/navigator/<topic>.parquet|csv{hint}")
    files: dict[str, Path] = {}
    for p in sorted(folder.iterdir()):
        suffix = p.suffix.lower()
        if suffix in PARQUET_SUFFIXES or (suffix in CSV_SUFFIXES and p.stem not in files):
            files[p.stem] = p
    if not files:
        raise DatasetError(f"{folder}: no topic tables (expected <topic>.parquet or <topic>.csv): empty flight")
    raw: dict[str, tuple] = {}
    for stem, p in files.items():
        is_csv = p.suffix.lower() in CSV_SUFFIXES
        df = _read_csv(p) if is_csv else _read_parquet(p)
        raw.update(_frame_topics(df, p, stem, is_csv, split=False, unit="us"))  # our own tables: microseconds
    return finish_tables(raw, path, topics, origin=0)  # already in time from the flight's start


# ----------------------------------------------------------------------------------------------
# entry point


def load_flight_file(path: str | Path, topics: list[str] | None = None, *,
                     allow_corrupt: bool = False, start_s: float | None = None,
                     end_s: float | None = None) -> dict[str, pd.DataFrame]:
    """Load a flight log as ``{topic: DataFrame}`` for csv mode.

    Every table: int64 ``Timestamp`` (microseconds from time zero: a ULog's start of logging,
    ``ULog.start_timestamp``; for tables the earliest timestamp in the file over all its topics;
    tables in scart-bench's own layout and flight folders keep their time; the same whichever
    ``topics`` are asked for. ``df.attrs["origin_us"]`` holds
    the original value; messages before it, a ULog's latched topics, are put at 0), sorted and
    strictly increasing (exact duplicate timestamps are dropped keeping the last row; the count
    is in ``df.attrs["duplicates_dropped"]`` and logged at debug level), then the numeric fields
    as float64. No ``Is_Anomaly`` column. ``topics`` restricts the result to those topics
    (DatasetError if one is missing); for ULogs only those messages are parsed.

    Formats:

    * PX4 ULog (``.ulg``, read with pyulog): one topic per (message, multi_id), named
      ``name`` for multi_id 0 and ``name_<multi_id>`` otherwise. Field names are sanitised
      (``accelerometer_m_s2[0]`` -> ``accelerometer_m_s2_0``, nested ``current.lat`` ->
      ``current_lat``); ``timestamp`` becomes ``Timestamp``; padding and non-numeric (char)
      fields are dropped; integer and bool fields become float64. Unit conversion: in a message
      whose ``lat`` and ``lon`` are integers (older PX4 ``vehicle_gps_position`` /
      ``sensor_gps``: int32 in 1e-7 degrees), ``lat``/``lon`` are converted to float64 degrees
      in place (x 1e-7), and integer ``alt`` / ``alt_ellipsoid`` from millimetres to metres
      (x 1e-3); ``df.attrs["converted"]`` lists what was converted. Float ``lat``/``lon``
      (``vehicle_global_position``) and newer ``latitude_deg``/``longitude_deg`` are already
      degrees and kept as they are. A corrupt or truncated file (its last message runs past
      the end) raises DatasetError unless ``allow_corrupt=True`` (then what was read is loaded,
      with a warning saying how much).
    * ArduPilot DataFlash (``.bin``, read with pymavlink's DFReader): one topic per message and
      instance (``gps``, ``imu_1``), ArduPilot's field names and units (the log's own scalings
      applied), time from each message's boot clock; see :mod:`scart_bench.generator.logs.dataflash`.
    * MAVLink telemetry log (``.tlog``, read with pymavlink): one topic per message of the
      autopilot (``global_position_int``), the project's units, the receive time; see
      :mod:`scart_bench.generator.logs.tlog`.
    * ROS bags (a ROS 1 ``.bag``, a ROS 2 bag folder or its ``.db3`` / ``.mcap`` file, read with
      rosbags): MAVROS topics mapped to the project's link topics, px4_msgs ``/fmu/out/*`` topics
      with their uORB names; see :mod:`scart_bench.generator.logs.rosbag`.
    * CSV / Parquet: the time column is the first of :data:`TIME_COLUMNS` (compared
      case-insensitively). A name with a unit (``timestamp_us``, ``time_ns``, ``time_s`` ...)
      is taken at its word; for ``timestamp``, ``time``, ``t`` and ROS's ``%time`` the unit (ns,
      us, ms or s) is inferred from the sampling interval and span (:func:`time_unit`), and
      an ambiguous column is refused, naming it. ``Index``, the label columns and pandas
      ``Unnamed: N`` columns are ignored. If every other column is ``topic.field``
      (scart-bench's combined tables), there is one topic per prefix and rows where all of that
      topic's fields are empty are dropped; otherwise, and for ROS exports whose columns are all
      ``field.<name>``, the table is one topic named after the file stem (sanitised to
      ``[a-z0-9_]``). Load a flight's ``all_sensors``
      table, not ``most_frequent``: the latter is resampled (values repeated at the base rate).
    * A scart-bench dataset flight folder: the navigator-view topic tables (``navigator.parquet``
      of the compact layout, or ``sensors/navigator``, Parquet preferred over CSV), labels dropped.
    * One view file of the compact layout (``flights/<id>/navigator.parquet``, recognised by its
      metadata whatever its name): its topic tables, as from the flight folder.

    ``start_s`` / ``end_s`` keep the messages in ``[start_s, end_s)`` seconds from time zero (e.g.
    before an injected fault or a crash) and make ``start_s`` the new time zero.

    Raises DatasetError naming the file for: a missing file, an unknown extension, an
    unreadable or corrupt ULog, a table without a recognised time column, non-numeric data
    (with the column and first bad row), and empty logs.
    """
    tables = _load_any(Path(path), topics, allow_corrupt)
    if start_s is None and end_s is None:
        return tables
    return trim(tables, start_s, end_s, Path(path))


def trim(tables: dict[str, pd.DataFrame], start_s: float | None, end_s: float | None,
         source: Path) -> dict[str, pd.DataFrame]:
    """The messages in ``[start_s, end_s)`` with time zero moved to ``start_s``."""
    lo = int(round((start_s or 0.0) * 1e6))
    hi = None if end_s is None else int(round(end_s * 1e6))
    if lo < 0 or (hi is not None and hi <= lo):
        raise DatasetError(f"{source}: --start {start_s} / --end {end_s}: expected 0 <= start < end (seconds)")
    out = {}
    for topic, df in tables.items():
        ts = df["Timestamp"].to_numpy()
        keep = (ts >= lo) & (ts < hi if hi is not None else True)
        part = df[keep].reset_index(drop=True)
        part["Timestamp"] = part["Timestamp"] - lo
        part.attrs = {**df.attrs, "origin_us": int(df.attrs.get("origin_us", 0)) + lo,
                      "trimmed_s": [start_s or 0.0, end_s]}
        if len(part):
            out[topic] = part
    if not out:
        last = max(int(df["Timestamp"].iloc[-1]) for df in tables.values() if len(df)) / 1e6
        raise DatasetError(f"{source}: no message in [{start_s or 0.0}, {end_s}) s; the log spans 0 - {last:.1f} s")
    return out


def _load_any(path: Path, topics: list[str] | None, allow_corrupt: bool) -> dict[str, pd.DataFrame]:
    if not path.exists():
        raise DatasetError(f"{path}: no such file or folder (expected a flight log: {', '.join(LOG_SUFFIXES)}, "
                           ".csv, .parquet or a scart-bench flight folder)")
    if path.is_dir() and (path / "metadata.yaml").exists():  # a ROS 2 bag
        raw, origin = read_rosbag(path, topics, allow_corrupt)
        return finish_tables(raw, path, topics, origin=origin, keep_last=True)
    if path.is_dir():
        return _load_flight_folder(path, topics)
    suffixes = [s.lower() for s in path.suffixes[-2:]]
    suffix = suffixes[-1] if suffixes else ""
    if suffix == ".ulg":
        return _load_ulog(path, topics, allow_corrupt)
    if suffix in LOG_READERS:
        raw, origin = LOG_READERS[suffix](path, topics, allow_corrupt)
        return finish_tables(raw, path, topics, origin=origin, keep_last=True)
    if suffix in CSV_SUFFIXES or (suffix in COMPRESSION_SUFFIXES and len(suffixes) == 2
                                  and suffixes[0] in CSV_SUFFIXES):
        df = _read_csv(path)
        raw = _frame_topics(df, path, _stem(path), is_csv=True)
    elif suffix in PARQUET_SUFFIXES:
        meta = _compact_meta(path)
        if meta is not None:  # a flight's view file of the compact layout: one table per topic inside
            return _load_compact_view(path, meta, topics)
        df = _read_parquet(path)
        raw = _frame_topics(df, path, _stem(path), is_csv=False)
    else:
        raise DatasetError(f"{path}: unknown file type {suffix or '(no extension)'!r}; expected a PX4 ULog "
                           "(.ulg), an ArduPilot DataFlash log (.bin), a MAVLink telemetry log (.tlog), a ROS bag (.bag, or a ROS 2 "
                           "bag folder), a CSV (.csv, optionally compressed), a "
                           "Parquet file (.parquet) or a scart-bench flight folder")
    # scart-bench's own tables already count from the flight's start: keep it as time zero
    return finish_tables(raw, path, topics, origin=0 if own_layout(list(df.columns)) else None)
