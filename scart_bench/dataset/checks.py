"""Checks of a dataset's manifest as data that may be damaged or hostile: every field of the expected
type and range (:func:`check_manifest`, when the dataset is opened), and each flight's row agreeing
with the flight itself, its labels and its attack event log (:func:`check_flight_row`, when the flight
is verified before its first read).

A manifest row is what a run believes about a flight: ``mode`` decides whether it is scored as a
held-out normal flight or an attacked one, ``[attack_start_us, attack_end_us)`` where the attack is.
A row that says ``normal`` for an attacked flight, or a window that is not the flight's own, is
refused with one line naming the manifest, the flight and the field, never used.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset.record import DatasetError
from scart_bench.names import IdError, check_id

#: The manifest's ``mode`` values: normal flights and the two attack modes.
MODES = ("normal", "simulation", "csv")
NORMAL_MODE = "normal"
#: The manifest's ``split`` values.
SPLITS = ("train", "validation", "test", "csv_source")
#: Largest row count of one flight (a day at 250 Hz is 21.6 M rows).
MAX_ROWS = 10**10
#: Longest flight (s): ten years; beyond that a duration is damage, not a flight.
MAX_DURATION_S = 10 * 365 * 86_400
MAX_US = MAX_DURATION_S * 10**6
#: Slack (µs) between the last message and a window's end: a second, as for the window's start.
SLACK_US = 1_000_000
CHECKSUM = re.compile(r"b2:[0-9a-f]{32}")
#: Events of the attack log that open and close windows; the defense's own events and the "timing
#: only" events of physical scenarios replayed in csv mode (which label nothing) are not attacks.
ATTACK_EVENTS = ("start", "end")

#: column -> (kind, lowest, highest) for the typed manifest columns; other columns are not checked.
FIELDS: dict[str, tuple[str, float, float]] = {
    "seed": ("int", 0, 2**64 - 1),
    "rows": ("int", 0, MAX_ROWS),
    "duration_s": ("float", 0, MAX_DURATION_S),
    "attack_start_us": ("int", 0, MAX_US),
    "attack_end_us": ("int", 0, MAX_US),
    "effect_rows": ("int", 0, MAX_ROWS),
    "effect_fields": ("int", 0, 10**7),
    "detectability": ("float", -math.inf, math.inf),
    "impact_max_dev_m": ("float", -math.inf, math.inf),
    "impact_final_dev_m": ("float", -math.inf, math.inf),
    "impact_landing_dist_m": ("float", -math.inf, math.inf),
    "no_effect": ("bool", 0, 1),
    "impact_mission_completed": ("bool", 0, 1),
    "impact_crashed": ("bool", 0, 1),
    "scenario_id": ("text", 0, 0),
    "action": ("text", 0, 0),
    "target": ("text", 0, 0),
    "injection_point": ("text", 0, 0),
    "params": ("text", 0, 0),
    "source_flight": ("text", 0, 0),
    "kind": ("text", 0, 0),
}
_TRUE = ("true", "1", "1.0", "yes")
_FALSE = ("false", "0", "0.0", "no", "")


def _bound(x: float) -> str:
    return f"{int(x):,}" if abs(x) < 1e15 else f"{x:g}"


def _shown(value: object) -> str:
    """``value`` as a user wrote it (numpy scalars as plain numbers), cut to 60 characters."""
    if isinstance(value, np.generic):
        value = value.item()
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _missing(value: object) -> bool:
    try:
        return value is None or bool(pd.isna(value))
    except (TypeError, ValueError):  # a list or an array: present (and wrong)
        return False


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool | np.bool_)


def check_manifest(manifest: pd.DataFrame, where: str | Path) -> None:
    """DatasetError naming ``where`` (the manifest file), the flight and the field when a row cannot be
    right: an empty, repeated or unsafe flight id; a mode or split that is not one of the known ones; a
    field of the wrong type (text in a number column, a fraction of a row) or out of its range (negative,
    huge, infinite); an empty checksum in a dataset that records them; an attack window that ends before
    it starts, lies outside the flight, is half given, or is set on a normal flight."""
    for name in ("flight_id", "mode", "split"):
        if name not in manifest.columns:
            raise DatasetError(f"{where}: no column {name!r}; expected the columns flight_id, mode, split, ...")
    manifest = manifest.reset_index(drop=True)
    ids = [_flight_id(v, i, where) for i, v in enumerate(manifest["flight_id"])]
    seen: set[str] = set()
    for fid in ids:
        if fid in seen:
            raise DatasetError(f"{where}: flight {fid!r} is listed more than once (field 'flight_id'); "
                               "expected unique flight ids")
        seen.add(fid)
    _choice(manifest, "mode", MODES, ids, where)
    _choice(manifest, "split", SPLITS, ids, where)
    for name, (kind, lo, hi) in FIELDS.items():
        if name in manifest.columns:
            _typed(manifest[name], name, kind, lo, hi, ids, where)
    if "checksum" in manifest.columns:
        for fid, value in zip(ids, manifest["checksum"]):
            if _missing(value) or not isinstance(value, str) or not value.strip():
                raise DatasetError(f"{where}: flight {fid!r} field 'checksum' is empty ({_shown(value)}); expected "
                                   "b2:<32 hex digits>: a dataset with a checksum column records every flight's "
                                   "(only datasets written before checksums have no such column)")
            if not CHECKSUM.fullmatch(value):
                raise DatasetError(f"{where}: flight {fid!r} field 'checksum' is {_shown(value)}; expected "
                                   "b2:<32 hex digits>")
    _windows(manifest, ids, where)


def numeric_columns(manifest: pd.DataFrame) -> pd.DataFrame:
    """``manifest`` with its number columns as numbers: a CSV manifest's column that held a text cell
    reads back as text throughout; once :func:`check_manifest` has accepted every cell, they are
    numbers again (a run reads ``int(rows)``)."""
    for name, (kind, _, _) in FIELDS.items():
        if kind in ("int", "float") and name in manifest.columns and manifest[name].dtype == object:
            manifest[name] = pd.to_numeric(manifest[name], errors="coerce")
    return manifest


def _flight_id(value: object, i: int, where) -> str:
    if _missing(value) or (isinstance(value, str) and not value.strip()):
        raise DatasetError(f"{where}: row {i + 1} has an empty flight_id; expected a flight id")
    try:
        return check_id(value, f"{where}: row {i + 1} field 'flight_id'")
    except IdError as exc:
        raise DatasetError(str(exc)) from None


def _choice(manifest: pd.DataFrame, name: str, allowed: tuple[str, ...], ids: list[str], where) -> None:
    for fid, value in zip(ids, manifest[name]):
        if not isinstance(value, str) or value not in allowed:
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(None if _missing(value) else value)}; "
                               f"expected one of {', '.join(allowed)}")


def _typed(column: pd.Series, name: str, kind: str, lo: float, hi: float, ids: list[str], where) -> None:
    """Each present value of ``column`` of ``kind`` (int, float, bool or text) and within [lo, hi]."""
    text_numbers = str(where).endswith(".csv")
    dtype = column.dtype
    if kind == "text" and (isinstance(dtype, pd.StringDtype) or dtype == np.dtype("str")):
        return  # text throughout
    if kind == "bool" and (dtype == np.bool_ or isinstance(dtype, pd.BooleanDtype)):
        return
    if kind in ("int", "float") and pd.api.types.is_numeric_dtype(dtype) and not pd.api.types.is_bool_dtype(dtype):
        # vectorised: a large manifest is checked in milliseconds; only a bad row is looked at below
        x = pd.to_numeric(column, errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
        present = ~np.isnan(x)
        bad = present & (~np.isfinite(x) | (x < lo) | (x > hi))
        if kind == "int":
            with np.errstate(invalid="ignore"):
                bad |= present & np.isfinite(x) & (x != np.floor(x))
        if not bad.any():
            return
        first = int(np.flatnonzero(bad)[0])
        ids, column = ids[first:first + 1], column.iloc[first:first + 1]
    for fid, value in zip(ids, column):
        if _missing(value):
            continue
        if kind == "text":
            if isinstance(value, str) or (_is_number(value) and text_numbers):
                continue  # a CSV has no types: a text column of digits reads back as numbers
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected text")
        if kind == "bool":
            text = str(value).strip().lower()
            if isinstance(value, bool | np.bool_) or text in _TRUE or text in _FALSE:
                continue
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected true or false")
        expected = "an integer" if kind == "int" else "a number"
        if isinstance(value, str) and text_numbers:  # a CSV has no types: one text cell makes the column text
            try:
                value = float(value)
            except ValueError:
                pass
        if not _is_number(value):
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected {expected}"
                               + (f" from {_bound(lo)} to {_bound(hi)}" if math.isfinite(hi) else ""))
        x = float(value)
        if not math.isfinite(x):
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected a finite number")
        if kind == "int" and x != math.floor(x):
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected {expected}")
        if not lo <= x <= hi:
            raise DatasetError(f"{where}: flight {fid!r} field {name!r} is {_shown(value)}; expected {expected} "
                               f"from {_bound(lo)} to {_bound(hi)}")


def _windows(manifest: pd.DataFrame, ids: list[str], where) -> None:
    has = [c for c in ("attack_start_us", "attack_end_us") if c in manifest.columns]
    if not has:
        return
    start = manifest["attack_start_us"] if "attack_start_us" in has else pd.Series(np.nan, index=manifest.index)
    end = manifest["attack_end_us"] if "attack_end_us" in has else pd.Series(np.nan, index=manifest.index)
    duration = manifest["duration_s"] if "duration_s" in manifest.columns else pd.Series(np.nan, index=manifest.index)
    for fid, mode, s, e, d in zip(ids, manifest["mode"], start, end, duration):
        if _missing(s) and _missing(e):
            continue
        if mode == NORMAL_MODE:
            field = "attack_start_us" if not _missing(s) else "attack_end_us"
            raise DatasetError(f"{where}: flight {fid!r} field {field!r} is {_shown(s if not _missing(s) else e)} on "
                               "a normal flight (mode 'normal'); expected it empty: a normal flight has no attack "
                               "window")
        if _missing(s) != _missing(e):
            field = "attack_start_us" if _missing(s) else "attack_end_us"
            raise DatasetError(f"{where}: flight {fid!r} field {field!r} is empty while the other end of the attack "
                               "window is set; expected both or neither")
        s, e = int(s), int(e)
        if e <= s:
            raise DatasetError(f"{where}: flight {fid!r} has attack_end_us {e} <= attack_start_us {s}; expected "
                               "start < end (an attack window [start, end) in µs)")
        if not _missing(d):
            limit = float(d) * 1e6 + SLACK_US
            for field, value in (("attack_start_us", s), ("attack_end_us", e)):
                if value > limit:
                    raise DatasetError(f"{where}: flight {fid!r} has {field} {value} outside the flight (0 to {d} s, "
                                       "field 'duration_s'); expected a window inside the flight")


# -- a manifest row against its flight -----------------------------------------------------------

@dataclass(frozen=True)
class Labels:
    """Where a flight's own labels put its attack. ``exact``: the windows themselves (the compact
    layout keeps them), so the manifest's window is their first start and last end; otherwise the
    labelled rows bound it: the start lies in ``(before, first]`` and the end in ``(last, after]``
    (``before``/``after``: the rows around the labelled ones, None at the flight's ends).
    ``timestamps``: the rows (to tell a window between two rows from one with unlabelled rows)."""

    source: Path
    first: int | None = None
    last: int | None = None
    before: int | None = None
    after: int | None = None
    exact: bool = False
    timestamps: np.ndarray | None = None


def labels_from_windows(windows: list, source: Path) -> Labels:
    """The labels of a compact flight: its stored windows ``[start, end, ...]`` (DatasetError naming
    the file when they are not pairs of integers)."""
    spans = []
    for w in windows:
        if not isinstance(w, list | tuple) or len(w) < 2 or not all(_is_number(v) for v in w[:2]):
            raise DatasetError(f"{source}: an attack window {_shown(w)} in its metadata; expected [start_us, end_us, "
                               "...] (damaged or not written by scart-bench)")
        spans.append((int(w[0]), int(w[1])))
    if not spans:
        return Labels(source, exact=True)
    return Labels(source, first=min(s for s, _ in spans), last=max(e for _, e in spans), exact=True)


def labels_from_rows(timestamps: np.ndarray, flags: np.ndarray, source: Path) -> Labels:
    """The labels of a flight's combined table (its ``Timestamp`` and ``Is_Anomaly`` columns)."""
    ts = np.asarray(timestamps, dtype=np.int64)
    on = np.flatnonzero(np.asarray(flags) != 0)
    if on.size == 0:
        return Labels(source, timestamps=ts)
    i, j = int(on[0]), int(on[-1])
    return Labels(source, first=int(ts[i]), last=int(ts[j]), before=int(ts[i - 1]) if i > 0 else None,
                  after=int(ts[j + 1]) if j + 1 < len(ts) else None, timestamps=ts)


def read_events(path: Path) -> tuple[list[tuple[int, str]], list[int]]:
    """The attack starts ``(time µs, scenario id)`` and ends (time µs) of a flight's event log
    (raw/events.csv); none when the flight has no log. DatasetError naming the file when it cannot be read."""
    if not path.exists():
        return [], []
    starts: list[tuple[int, str]] = []
    ends: list[int] = []
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            for k, row in enumerate(csv.DictReader(fh)):
                event, sid = row.get("event") or "", row.get("scenario_id") or ""
                if event not in ATTACK_EVENTS or sid == "defense" or "timing only" in (row.get("detail") or ""):
                    continue
                try:
                    t = int(float(row.get("timestamp_us") or ""))
                except (TypeError, ValueError, OverflowError):
                    raise DatasetError(f"{path}: row {k + 2} field 'timestamp_us' is {_shown(row.get('timestamp_us'))}; "
                                       "expected an integer (µs)") from None
                if event == "start":
                    starts.append((t, sid))
                else:
                    ends.append(t)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(f"{path}: unreadable ({type(exc).__name__}: {exc}); expected the flight's attack "
                           "event log (CSV)") from None
    return starts, ends


def check_flight_row(where: str | Path, fid: str, row: dict, labels: Labels, events: Path) -> None:
    """DatasetError naming the manifest ``where``, the flight and the field when the manifest row of
    ``fid`` disagrees with the flight's own labels or its event log: ``mode`` normal for a flight whose
    labels or log show an attack, or an attack window other than the labelled one or the logged one."""
    mode = row.get("mode")
    s, e = row.get("attack_start_us"), row.get("attack_end_us")
    s = None if _missing(s) else int(s)
    e = None if _missing(e) else int(e)
    starts, ends = read_events(events)
    head = f"{where}: flight {fid!r} field"
    if mode == NORMAL_MODE:
        if labels.first is not None:
            raise DatasetError(f"{head} 'mode' is 'normal', but its labels ({labels.source}) mark an attack from "
                               f"{labels.first} µs; expected 'simulation' or 'csv' for an attacked flight")
        if starts:
            t, sid = min(starts)
            raise DatasetError(f"{head} 'mode' is 'normal', but its event log ({events}) records attack {sid!r} "
                               f"starting at {t} µs; expected 'simulation' or 'csv' for an attacked flight")
        return
    if labels.first is not None:
        if s is None:
            raise DatasetError(f"{head} 'attack_start_us' is empty, but its labels ({labels.source}) mark an attack "
                               f"from {labels.first} µs; expected the window's start")
        lo_s, hi_s = (labels.first, labels.first) if labels.exact else (
            (labels.before + 1) if labels.before is not None else -math.inf, labels.first)
        if not lo_s <= s <= hi_s:
            raise DatasetError(f"{head} 'attack_start_us' is {s}, but its labels ({labels.source}) start the attack "
                               f"at {labels.first} µs; expected the window's own start")
        lo_e, hi_e = (labels.last, labels.last) if labels.exact else (
            labels.last + 1, labels.after if labels.after is not None else math.inf)
        if e is not None and not lo_e <= e <= hi_e:
            shown = f"end it at {labels.last} µs" if labels.exact else f"mark it until {labels.last} µs"
            raise DatasetError(f"{head} 'attack_end_us' is {e}, but its labels ({labels.source}) {shown}; expected "
                               "the window's own end")
    elif s is not None and e is not None:
        ts = labels.timestamps
        inside = labels.exact or (ts is not None and bool(((ts >= s) & (ts < e)).any()))
        if inside:
            raise DatasetError(f"{head} 'attack_start_us' is {s} (window to {e} µs), but its labels "
                               f"({labels.source}) mark no attack; expected it empty, or the flight's labels")
    if starts:
        t, _ = min(starts)
        if s != t:
            raise DatasetError(f"{head} 'attack_start_us' is {s if s is not None else 'empty'}, but its event log "
                               f"({events}) starts the attack at {t} µs; expected the logged start")
    if ends and s is not None and e != max(ends):
        raise DatasetError(f"{head} 'attack_end_us' is {e}, but its event log ({events}) ends the attack at "
                           f"{max(ends)} µs; expected the logged end")
