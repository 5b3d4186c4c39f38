"""ArduPilot DataFlash logs (``.bin``): per-message topic tables, read with pymavlink's DFReader.

A DataFlash log describes itself: FMT messages give each message's name, field names and binary
format; newer logs add UNIT, MULT and FMTU messages giving each field's unit, its multiplier to
that unit and the instance field of multi-instance sensors. The rules (docs/own_logs.md):

- **Topics**: one per message name and instance, the name in lower case (``GPS`` -> ``gps``,
  instance 1 of ``IMU`` -> ``imu_1``, as a ULog's ``multi_id``).
- **Time**: the boot clock of each message, ``TimeUS`` (microseconds) or, in older logs,
  ``TimeMS`` (milliseconds). A message carrying GPS time (a ``Week`` or ``GWk`` field) gives its
  boot time in ``T`` (ms) when it has one: its ``TimeMS`` is the GPS time of week, not the boot
  clock. A message without a time field (``MODE``, ``EV``, ``PARM`` in older logs) is put at the
  boot time of the last timed message written before it: DataFlash is written in order. Time
  zero is the earliest boot time in the log, whichever topics are asked for.
- **Units**: the format characters' scalings are applied by DFReader (``L`` lat/lon 1e-7 ->
  degrees, ``c``/``C``/``e``/``E`` x 0.01); where FMTU gives a field a multiplier (MULT) and its
  format character has none, the value is multiplied by it (``MagX`` in mGauss -> Gauss). The
  units are ArduPilot's (attitude in degrees, altitudes in metres), listed per field in the
  table's ``attrs["units"]`` when the log has FMTU messages. Text fields are dropped.
- **No value**: a battery monitor's field (:data:`NO_SENSOR_FIELDS` of ``CURR``, ``BAT`` ...) that reads 0
  in every message of the log is no reading (ArduPilot logs 0 where no voltage or current sensor is
  fitted): it becomes a missing value (NaN), named in ``attrs["no_value"]``.
- **Damage**: bytes DFReader has to skip (a bad header in the middle) or unreadable bytes after the
  last whole message are refused unless ``allow_corrupt``; up to 528 bytes of trailing padding
  after the last whole message (ArduPilot's block logs end in a partial page) are not damage. A
  last message cut by the end of the file alone (the logger stopped mid-message: a power-off, as
  ArduPilot logs usually end) is not refused: the whole messages before it are read, with a warning.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from scart_bench.dataset import DatasetError
from scart_bench.generator.logs.tables import (
    RawTopics,
    sanitize_field_name,
    sanitize_topic_name,
    unique_names,
)

logger = logging.getLogger(__name__)

#: DataFlash message header bytes.
HEADER = b"\xa3\x95"
#: Format characters that hold text (or an int16 array ``a``): not sensor values.
TEXT_FORMATS = frozenset("nNZa")
#: Trailing bytes after the last whole message that are padding, not a cut message (DFReader's
#: own allowance: block logs are written in 512-byte pages).
TRAILING_PADDING = 528
#: Messages that describe the log rather than the flight: formats, units, and parameters (name/value
#: pairs, not a time series). Messages without a numeric field (``MSG``: text) are dropped too.
NOT_TELEMETRY = frozenset({"FMT", "FMTU", "UNIT", "MULT", "PARM", "FILE"})
#: Fields that say a message carries GPS time (its ``TimeMS`` is then the GPS time of week).
GPS_TIME_FIELDS = ("Week", "GWk")
#: Battery monitor messages and their fields that read 0 for the whole log where no sensor is fitted.
BATTERY_MESSAGES = frozenset({"CURR", "CUR2", "BAT", "BAT2", "BATT", "BCL"})
NO_SENSOR_FIELDS = frozenset({"Volt", "VoltR", "Curr", "CurrTot", "EnrgTot", "Vcc", "Res"})


def no_sensor(message: str, fields: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict]:
    """A battery monitor's fields with those that read 0 for the whole log (no sensor fitted) as NaN,
    and the notes naming them."""
    if message not in BATTERY_MESSAGES:
        return fields, {}
    empty = [n for n, v in fields.items() if n in NO_SENSOR_FIELDS and v.size and not np.any(v)]
    if not empty:
        return fields, {}
    out = {n: (np.full(v.shape, np.nan) if n in empty else v) for n, v in fields.items()}
    return out, {"no_value": {n: "0 for the whole log: no sensor fitted" for n in empty}}


def _open(path: Path):
    """A DFReader on ``path`` (it indexes the whole file)."""
    try:
        from pymavlink import DFReader
    except ImportError as exc:
        raise DatasetError(f"{path}: reading ArduPilot DataFlash logs needs the 'pymavlink' package (pip install "
                           "'scart-bench[mavlink]')") from exc

    if path.stat().st_size == 0:
        raise DatasetError(f"{path}: the DataFlash log is empty (0 bytes); expected a .bin log written by ArduPilot")
    try:
        reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    except Exception as exc:  # struct.error, KeyError, ValueError ... on a file that is no DataFlash log
        raise DatasetError(f"{path}: not a readable ArduPilot DataFlash log ({type(exc).__name__}: {exc}); "
                           "expected a .bin log written by ArduPilot") from exc
    return reader


def time_field(columns: list[str]) -> tuple[str, int] | None:
    """(the boot-clock field, microseconds per unit) of a message's columns, or None (untimed)."""
    if "TimeUS" in columns:
        return "TimeUS", 1
    if any(f in columns for f in GPS_TIME_FIELDS):
        return ("T", 1000) if "T" in columns else None
    if "TimeMS" in columns:
        return "TimeMS", 1000
    return None


def _scales(fmt, ids: str, mults: dict[str, float]) -> np.ndarray:
    """Per column: the multiplier to the field's unit (DFReader's format scaling, else FMTU's MULT:
    ``ids`` holds one multiplier id per column, ``mults`` the MULT table)."""
    out = []
    for i, own in enumerate(fmt.msg_mults):
        if own is not None:
            out.append(own)
            continue
        m = mults.get(ids[i]) if i < len(ids) else None
        out.append(m if m not in (None, 0.0) and math.isfinite(m) else 1.0)
    return np.asarray(out, dtype=np.float64)


def _apply(values: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Scale columns, dividing by 1/s for s < 1 as DFReader does (1e7 * 1e-7 loses an ulp, / 1e7 not)."""
    out = values.copy()
    for j, s in enumerate(scales):
        if s == 1.0:
            continue
        inv = 1.0 / s
        out[:, j] = values[:, j] / round(inv) if 0 < s < 1 and abs(inv - round(inv)) < 1e-6 else values[:, j] * s
    return out


#: In a damaged log, a message whose boot time is this far (us) from both its neighbours' in its
#: topic is garbled (DataFlash has no checksum: a message whose header survived the damage parses
#: with whatever bytes follow).
SPIKE_US = 5_000_000


class _Collector:
    """Rows of the selected messages per (name, instance), with their boot times."""

    def __init__(self, wanted: set[str] | None):
        self.wanted = wanted
        self.rows: dict[tuple[str, object], list] = {}
        self.times: dict[tuple[str, object], list[int]] = {}
        self.formats: dict[str, object] = {}
        self.seen: dict[tuple[str, object], int] = {}
        self.own: dict[tuple[str, object], list[bool]] = {}  # the row is a timed message (not given a time)
        self.clock: list[int] = []  # every timed message's boot time (us), in file order
        self.mult_ids: dict[int, str] = {}  # message type number -> FMTU MultIds
        self.kind: dict[int, tuple] = {}  # message type number -> (has sensor fields, its clock field)

    def add(self, m) -> None:
        fmt = m.fmt
        name = fmt.name
        if name == "FMTU" and "MultIds" in fmt.colhash:
            ids = m._elements[fmt.colhash["MultIds"]]
            self.mult_ids[int(m._elements[fmt.colhash["FmtType"]])] = (
                ids.decode("ascii", "replace") if isinstance(ids, bytes) else str(ids)).rstrip("\x00")
        if fmt.type not in self.kind:
            self.kind[fmt.type] = (name not in NOT_TELEMETRY and bool(data_columns(fmt)), time_field(fmt.columns))
        useful, tf = self.kind[fmt.type]
        if tf is not None:
            self.clock.append(int(m._elements[fmt.colhash[tf[0]]]) * tf[1])
        if not useful:
            return
        inst = m._elements[fmt.colhash[fmt.instance_field]] if fmt.instance_field else None
        key = (name, inst)
        self.seen[key] = self.seen.get(key, 0) + 1
        if self.wanted is not None and topic_name(name, inst) not in self.wanted:
            return
        self.formats[name] = fmt
        self.rows.setdefault(key, []).append(m._elements)
        self.times.setdefault(key, []).append(len(self.clock) - 1)  # its clock: the last timed message
        self.own.setdefault(key, []).append(tf is not None)

    def boot_times(self, damaged: bool) -> tuple[np.ndarray, np.ndarray]:
        """(boot time of every timed message, garbled mask): in a damaged log a message whose time
        is more than :data:`SPIKE_US` from both its neighbours' is garbled, and its time is replaced
        by the last good one (for the untimed messages that follow it)."""
        t = np.asarray(self.clock, dtype=np.int64)
        bad = np.zeros(t.shape[0], dtype=bool)
        if damaged and t.shape[0] >= 3:
            bad = (np.abs(np.diff(t, prepend=t[1])) > SPIKE_US) & (np.abs(np.diff(t, append=t[-2])) > SPIKE_US)
            good = np.flatnonzero(~bad)
            t = t[good[np.maximum(np.searchsorted(good, np.arange(t.shape[0]), side="right") - 1, 0)]]
        return t, bad


def topic_name(name: str, instance) -> str:
    """``GPS`` -> ``gps``; instance k > 0 of a multi-instance message -> ``gps_<k>``."""
    base = sanitize_topic_name(name)
    if instance in (None, 0, b"\x00", ""):
        return base
    if isinstance(instance, bytes):
        instance = instance.decode("ascii", "replace").strip("\x00")
    return f"{base}_{sanitize_topic_name(str(instance))}"


def data_columns(fmt) -> list[int]:
    """Indices of a message's sensor fields: numeric, not its clock, not its instance number."""
    tf = time_field(fmt.columns)
    return [i for i, c in enumerate(fmt.msg_fmts) if c not in TEXT_FORMATS and i < len(fmt.columns)
            and (tf is None or fmt.columns[i] != tf[0]) and fmt.columns[i] != fmt.instance_field]


def _table(fmt, rows: list, times: np.ndarray, ids: str, mults: dict[str, float], units: dict | None
           ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    tf = time_field(fmt.columns)
    keep = data_columns(fmt)
    raw = np.array([[float(r[i]) for i in keep] for r in rows], dtype=np.float64).reshape(len(rows), len(keep))
    values = _apply(raw, _scales(fmt, ids, mults)[keep])
    names = unique_names([sanitize_field_name(fmt.columns[i]) for i in keep])
    notes: dict = {"dataflash_message": fmt.name, "time_field": tf[0] if tf else None}
    if units:
        notes["units"] = {n: units[fmt.columns[i]] for n, i in zip(names, keep) if units.get(fmt.columns[i])}
    fields, marked = no_sensor(fmt.name, {n: values[:, j] for j, n in enumerate(names)})
    return np.asarray(times, dtype=np.int64), fields, {**notes, **marked}


def _check_damage(path: Path, reader, whole: int, end: int, allow_corrupt: bool, n_read: int, clock: list[int]
                  ) -> dict:
    """Refuse a damaged log unless ``allow_corrupt``; the notes for its tables.

    ``whole``: bytes in the messages read; ``end``: where the last of them ends. Bytes skipped
    between messages are damage, and so are more than :data:`TRAILING_PADDING` unreadable bytes
    after the last message; a cut last message alone (a header whose message runs past the end of
    the file) is a warning.
    """
    skipped = end - whole
    rest = reader.data_len - end
    cut = rest > 0 and bytes(reader.data_map[end:end + 2]) == HEADER
    if not skipped and not cut and rest <= TRAILING_PADDING:
        return {}
    if n_read == 0:
        raise DatasetError(f"{path}: no DataFlash message found in {reader.data_len} bytes; expected a .bin log "
                           "written by ArduPilot (messages starting with the bytes A3 95)")
    if cut and not skipped:
        # the logger stopped mid-message (power-off): every message before it is whole
        logger.warning("%s: its last DataFlash message is cut by the end of the file (%d of %d bytes hold whole "
                       "messages); using the %d whole message(s) before it", path, end, reader.data_len, n_read)
        return {}
    what = (f"{skipped} byte(s) between messages were unreadable and skipped" if skipped else
            f"its last message runs past the end of the file ({end} of {reader.data_len} bytes hold whole "
            "messages)" if cut else f"{rest} unreadable bytes follow the last whole message")
    seconds = (clock[-1] - min(clock)) / 1e6 if clock else 0.0
    if not allow_corrupt:
        raise DatasetError(f"{path}: the DataFlash log is damaged: {what}; {n_read} message(s), {seconds:.1f} s of "
                           "logging readable; pass --allow-corrupt (allow_corrupt=True) to use what was read")
    logger.warning("%s: the DataFlash log is damaged (%s); using the %d message(s) read", path, what, n_read)
    return {"file_corruption": True}


@contextlib.contextmanager
def _quiet():
    """Keep pymavlink's messages about bad bytes (printed by Python and by its compiled indexer, on
    file descriptor 2) off the terminal: the damage is reported once, as an error or a warning."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink, contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def read_dataflash(path: Path, topics: list[str] | None = None, allow_corrupt: bool = False
                   ) -> tuple[RawTopics, int]:
    """(raw topics, time zero in boot microseconds) of a DataFlash log; see the module doc."""
    found = _Collector(set(topics) if topics is not None else None)
    n = whole = end = 0
    with _quiet():
        reader = _open(path)
        try:
            while (m := reader.recv_msg()) is not None:
                found.add(m)
                n += 1
                whole += m.fmt.len
                end = reader.offset
        except Exception as exc:  # a garbled message DFReader cannot unpack
            if not allow_corrupt:
                raise DatasetError(f"{path}: the DataFlash log is damaged after {n} message(s) "
                                   f"({type(exc).__name__}: {exc}); pass --allow-corrupt to use what was read") from exc
            logger.warning("%s: the DataFlash log is damaged after %d message(s); using them", path, n)
    damage = _check_damage(path, reader, whole, end, allow_corrupt, n, found.clock)
    if not found.clock:
        raise DatasetError(f"{path}: the DataFlash log has no timed message (TimeUS or TimeMS); empty log?")
    if topics is not None:
        have = {topic_name(k, i) for k, i in found.seen}
        missing = [t for t in topics if t not in have]
        if missing:
            raise DatasetError(f"{path}: topic(s) {missing} not found in the DataFlash log; it has: {sorted(have)}")
    clock, garbled = found.boot_times(bool(damage))
    origin = int(clock[~garbled].min())
    units = _units(reader)
    raw: RawTopics = {}
    for key, rows in sorted(found.rows.items(), key=lambda kv: topic_name(*kv[0])):
        fmt = found.formats[key[0]]
        idx = np.asarray(found.times[key], dtype=np.int64)
        # written before the first timed message: at time zero
        ts = np.where(idx < 0, origin, clock[np.maximum(idx, 0)])
        drop = np.asarray(found.own[key]) & garbled[np.maximum(idx, 0)] & (idx >= 0)
        ts, fields, notes = _table(fmt, [r for r, d in zip(rows, drop) if not d], ts[~drop],
                                   found.mult_ids.get(fmt.type, ""), reader.mult_lookup, units.get(key[0]))
        if damage:
            notes["garbled_dropped"] = int(drop.sum())
        if len(ts):
            raw[topic_name(*key)] = (ts, fields, {**notes, **damage})
    reader.close()
    return raw, origin


def _units(reader) -> dict[str, dict[str, str]]:
    """message -> field -> unit (with its multiplier prefix), from the log's FMTU/UNIT/MULT messages."""
    out: dict[str, dict[str, str]] = {}
    for fmt in reader.formats.values():
        if fmt.units:
            out[fmt.name] = {c: u for c, u in zip(fmt.columns, fmt.units) if u}
    return out
