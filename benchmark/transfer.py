"""Train here, test there: detectors trained and calibrated on one dataset, tested on another.

``scart-bench run --train-dataset GENERATED --dataset REAL`` (``train_dataset`` in a run file) fits
every detector on the normal train flights of GENERATED, calibrates its threshold on GENERATED's
validation flights, and scores the flights of REAL: every normal flight of REAL, whatever its split
(none is fitted or calibrated on), is a held-out normal flight, and REAL's attacked flights are the
attacked flights.

The two datasets name their columns differently (MAVLink link topics on generated flights, uORB
topics in PX4 logs, DataFlash messages in ArduPilot logs). Each flight's table is rewritten by
meaning (:func:`shared_table`), with the quantities of :mod:`scart_bench.generator.scart.meanings`,
the table the scenarios by meaning resolve with:

- a column whose ``topic.field`` stands for a quantity (``MEANING_OF``) becomes that quantity's
  column (``global_position_int.vx``, ``vehicle_local_position.vx`` and ``ekf1.VN`` are all
  ``velocity.vn``); when a flight has several, the first candidate of the quantity's list is kept;
- units are the generator's: degrees (ArduPilot's angles and courses) -> rad, pressure in Pa -> hPa
  and a magnetic field in mGauss -> Gauss (told by their size: above 2000 and 5);
  a PX4 attitude quaternion gives ``attitude.roll``, ``pitch`` and ``yaw`` where the flight has no
  Euler angles;
- what says *where* a flight is rather than how it flies is taken from the flight's own start:
  latitude/longitude become metres north/east of the flight's first fix (``position.north``,
  ``position.east``, ``gps.north``, ``gps.east``), and AMSL altitudes, the barometer's pressure and
  altitude, the magnetometer's field (its strength and direction are the site's) and the battery
  voltage (the pack's) their change since the first valid value;
- the mission item and the flight phase (control state, not measurements) are not kept; the arming
  columns (``armed``, ``arming_state``) are kept as they are for the burn-in;
- the run keeps the quantities every train, validation and test flight has (:func:`plan_transfer`),
  and says which columns of either dataset had no counterpart, and which flights lack a quantity
  that was dropped for that reason (a GPS-less log removes every position quantity);
- test flights logged at another rate are resampled to the training flights' row interval (each
  new row the last row at or before its time; labelled attacked when any row since the previous new
  row was), so that windows counted in rows span the same time on both.

A run on one dataset reads its flights by meaning too when they log different columns (firmware
builds of one fleet: ``EKF1`` or ``NKF1``; ``--columns auto``, :func:`open_meaning`): the run's
quantities are those a training flight has (the detectors learn them from the flights that have
them), and a flight without one has it as missing values, which every detector treats as any gap
(filled with the training mean); a line names those flights (attacked copies counted under their
source flight). Rows are not resampled: every flight is its own table by meaning.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from scart_bench.errors import RunError
from scart_bench.generator.geo import ne_from_latlon
from scart_bench.generator.scart import units
from scart_bench.generator.scart.meanings import MEANING_OF, QUANTITIES

__all__ = ["COLUMN_MODES", "MeaningRun", "TransferFlights", "TransferPlan", "column_meanings", "logged_columns",
           "open_meaning", "plan_transfer", "resample", "shared_table"]

#: How a run on one dataset reads its flights (``run --columns``): ``auto`` (by meaning when the run's
#: flights log different columns, else as logged), ``logged`` (each flight's own columns) or ``meaning``.
COLUMN_MODES = ("auto", "logged", "meaning")

#: Columns every flight table starts with; kept as they are.
LABEL_COLUMNS = ("Index", "Timestamp", "Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind")
#: Fields that say when a flight was armed (benchmark.protocol.arming_time_us): kept as they are.
ARMING_FIELDS = ("armed", "arming_state")
#: Quantities that are control state, not measurements: never shared.
NOT_SHARED = ("mission", "phase")
#: Quantities re-referenced to the flight's first valid value (they say where, or with what pack).
FROM_START = ("altitude.amsl", "gps.alt", "baro.alt", "baro.pressure", "battery.voltage", "mag.x", "mag.y", "mag.z")
#: latitude/longitude pairs -> (north, east) columns in metres from the flight's first fix.
LATLON = {("position.lat", "position.lon"): ("position.north", "position.east"),
          ("gps.lat", "gps.lon"): ("gps.north", "gps.east")}
#: A PX4 attitude quaternion (w, x, y, z; body FRD -> NED).
QUATERNION = QUANTITIES["attitude"]["q"]
#: Test flights whose median row interval is within this fraction of the training flights' keep their rows.
RATE_TOLERANCE = 0.1


def column_meanings(columns: Iterable[str]) -> dict[str, str]:
    """``quantity.field`` -> the column of a flight table that stands for it (the first candidate of
    the quantity's list that the table has and whose own meaning it is)."""
    have = set(columns)
    out: dict[str, str] = {}
    for q, fields in QUANTITIES.items():
        if q in NOT_SHARED:
            continue
        for f, candidates in fields.items():
            if (q, f) == ("attitude", "q"):
                continue  # its four parts are one quaternion: shared as roll, pitch and yaw instead
            meaning = f"{q}.{f}"
            hit = next((c for c in candidates if c in have and MEANING_OF.get(c) == meaning), None)
            if hit is not None:
                out[meaning] = hit
    return out


def _numeric(s: pd.Series) -> np.ndarray:
    v = pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64, copy=True)
    v[np.isinf(v)] = np.nan
    return v


def _first_valid(v: np.ndarray) -> float:
    ok = np.flatnonzero(np.isfinite(v))
    return float(v[ok[0]]) if ok.size else float("nan")


def _euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (rad, ZYX) of quaternions ``q`` (rows w, x, y, z)."""
    w, x, y, z = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def shared_values(flight: pd.DataFrame) -> dict[str, np.ndarray]:
    """The flight's quantities by meaning, in the generator's units, site quantities from the flight's
    start (see the module docstring): shared column name -> values."""
    cols = column_meanings(flight.columns)
    out: dict[str, np.ndarray] = {}
    for meaning, col in cols.items():
        v = _numeric(flight[col])
        topic, _, fld = col.partition(".")
        if units.quantity(topic, fld) == "angle_deg":
            v = np.deg2rad(v)
        if meaning == "baro.pressure" and np.isfinite(v).any() and np.nanmedian(v) > 2000.0:
            v = v / 100.0  # Pa -> hPa (PX4 and ArduPilot log Pa, MAVLink hPa; sea level is 1013 hPa)
        out[meaning] = v
    mag = [out[m] for m in ("mag.x", "mag.y", "mag.z") if m in out]
    if len(mag) == 3 and np.isfinite(mag[0]).any():
        if np.nanmedian(np.sqrt(mag[0] ** 2 + mag[1] ** 2 + mag[2] ** 2)) > 5.0:  # mGauss (Earth: 0.25-0.65 G)
            for m in ("mag.x", "mag.y", "mag.z"):
                out[m] = out[m] / 1000.0
    if "attitude.roll" not in out and all(c in flight.columns for c in QUATERNION):
        out["attitude.roll"], out["attitude.pitch"], out["attitude.yaw"] = _euler(
            np.stack([_numeric(flight[c]) for c in QUATERNION]))
    for (lat, lon), (north, east) in LATLON.items():
        if lat in out and lon in out:
            la, lo = out.pop(lat), out.pop(lon)
            ok = np.flatnonzero(np.isfinite(la) & np.isfinite(lo) & ((la != 0) | (lo != 0)))
            if ok.size:
                n, e = ne_from_latlon(la, lo, la[ok[0]], lo[ok[0]])
                out[north], out[east] = np.asarray(n, np.float64), np.asarray(e, np.float64)
        else:
            out.pop(lat, None)
            out.pop(lon, None)
    for name in FROM_START:
        if name in out:
            out[name] = out[name] - _first_valid(out[name])
    return out


def resample(table: pd.DataFrame, interval_us: int) -> pd.DataFrame:
    """The table on a regular grid of ``interval_us`` from its first row: each new row is the last row
    at or before its time; ``Is_Anomaly`` (and the attack ids) is set when any row since the
    previous new row was attacked."""
    ts = table["Timestamp"].to_numpy(np.int64)
    if ts.size < 2:
        return table.reset_index(drop=True)
    grid = np.arange(ts[0], ts[-1] + 1, int(interval_us), dtype=np.int64)
    idx = np.searchsorted(ts, grid, side="right") - 1
    out = table.iloc[idx].reset_index(drop=True)
    out["Timestamp"] = grid.astype(table["Timestamp"].dtype)
    if "Index" in out.columns:
        out["Index"] = np.arange(len(out), dtype=table["Index"].dtype)
    if "Is_Anomaly" in table.columns:
        lab = table["Is_Anomaly"].to_numpy() > 0
        count = np.concatenate([[0], np.cumsum(lab)])
        hi = idx + 1
        lo = np.concatenate([[0], hi[:-1]])
        hit = count[hi] - count[lo] > 0
        out["Is_Anomaly"] = hit.astype(table["Is_Anomaly"].dtype)
        last = np.maximum.accumulate(np.where(lab, np.arange(ts.size), -1))[idx]
        for col in ("Anomaly_Ids", "Anomaly_Kind"):
            if col in table.columns:
                src = table[col].iloc[np.where(hit, last, idx)].reset_index(drop=True)
                out[col] = src.astype(table[col].dtype)
    return out


def median_interval_us(table: pd.DataFrame) -> float:
    ts = table["Timestamp"].to_numpy(np.int64)
    return float(np.median(np.diff(ts))) if ts.size > 1 else float("nan")


def shared_table(flight: pd.DataFrame, columns: Iterable[str] | None = None,
                 interval_us: int | None = None) -> pd.DataFrame:
    """The flight's table by meaning: its label columns, its arming columns and the shared quantity
    columns (``columns``: these, in this order, NaN where the flight lacks one; default every one it
    has); resampled to ``interval_us`` when its own interval differs by more than RATE_TOLERANCE."""
    values = shared_values(flight)
    names = list(values) if columns is None else list(columns)
    keep = [c for c in LABEL_COLUMNS if c in flight.columns]
    arming = [c for c in flight.columns if isinstance(c, str) and c.rpartition(".")[2] in ARMING_FIELDS]
    n = len(flight)
    data = {c: flight[c].to_numpy(copy=True) for c in keep + arming}
    for name in names:
        data[name] = values.get(name, np.full(n, np.nan))
    out = pd.DataFrame(data, index=pd.RangeIndex(n))
    for c in keep + arming:  # text columns keep their dtype
        if out[c].dtype != flight[c].dtype:
            out[c] = out[c].astype(flight[c].dtype)
    if interval_us:
        own = median_interval_us(out)
        if math.isfinite(own) and abs(own - interval_us) > RATE_TOLERANCE * interval_us:
            out = resample(out, int(interval_us))
    return out


def name_flights(ids: Iterable[str], source_of: dict[str, str] | None = None, roles: dict[str, str] | None = None,
                 limit: int = 8) -> str:
    """Flights named for a user, with their role where ``roles`` has it: an attacked copy is counted under
    its source flight (``log-a (test) and its 12 attacked copies``, or ``3 attacked copies of log-b`` when
    the source itself is not among them); at most ``limit`` names, then how many more."""
    source_of, roles = source_of or {}, roles or {}
    ids = list(dict.fromkeys(str(f) for f in ids))
    listed = set(ids)
    copies: dict[str, int] = {}
    for f in ids:
        src = source_of.get(f)
        key = src if src and src != f else f
        copies[key] = copies.get(key, 0) + (key != f)
    names = []
    for key, n in copies.items():
        role = f" ({roles[key]})" if key in roles else ""
        some = f"{n} attacked cop{'y' if n == 1 else 'ies'}"
        names.append(key + role + (f" and its {some}" if n else "") if key in listed else f"{some} of {key}{role}")
    more = len(names) - limit
    return ", ".join(names[:limit]) + (f" and {more} more" if more > 0 else "")


def _labelled(tables: Iterable) -> Iterable[tuple[str, pd.DataFrame]]:
    """``(flight id, table)`` pairs from pairs or bare tables (numbered ``#i``)."""
    for i, t in enumerate(tables):
        yield (str(t[0]), t[1]) if isinstance(t, tuple) else (f"#{i}", t)


def _order() -> list[str]:
    """Quantity columns in the table's order (QUANTITIES, then the north/east columns of lat/lon)."""
    return list(dict.fromkeys([*(f"{q}.{f}" for q, fs in QUANTITIES.items() for f in fs),
                               *(v for pair in LATLON.values() for v in pair)]))


def lacking_lines(lacking: dict[str, list[str]], source_of: dict[str, str] | None = None,
                  roles: dict[str, str] | None = None) -> list[str]:
    """One line per set of flights lacking the same quantities: ``q1, q2: not in log-a, log-b ...``."""
    groups: dict[tuple[str, ...], list[str]] = {}
    for q, ids in lacking.items():
        if ids:
            groups.setdefault(tuple(ids), []).append(q)
    return [f"{', '.join(qs)}: not in {name_flights(ids, source_of, roles)}" for ids, qs in groups.items()]


@dataclass(frozen=True)
class TransferPlan:
    """What a transfer run shares between its datasets: the quantity columns, the row interval of the
    training flights, and what had no counterpart."""

    columns: tuple[str, ...]
    interval_us: int
    #: dataset ("train" / "test") -> columns of its flights that were left out, with why
    dropped: dict[str, dict[str, str]] = field(default_factory=dict)
    #: quantity left out because some flights lack it -> those flights (ids), for the user to see
    lacking: dict[str, list[str]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"columns": list(self.columns), "interval_us": int(self.interval_us),
                "dropped": {k: dict(v) for k, v in self.dropped.items()},
                "lacking": {k: list(v) for k, v in self.lacking.items()}}

    def describe(self) -> str:
        """One line: how many quantities are shared and what was dropped."""
        parts = [f"{len(self.columns)} quantities shared by meaning ({', '.join(self.columns)})"]
        for side, cols in self.dropped.items():
            if cols:
                named = sorted(c for c in cols if cols[c] != "no meaning")
                rest = len(cols) - len(named)
                parts.append(f"dropped from the {side} dataset: {', '.join(named) or 'none by meaning'}"
                             + (f" and {rest} column(s) with no quantity" if rest else ""))
        parts.append(f"test flights resampled to {self.interval_us / 1000:g} ms rows where theirs differ")
        return "; ".join(parts)


def plan_transfer(train_tables: Iterable, test_tables: Iterable, train_name: str = "train",
                  test_name: str = "test") -> TransferPlan:
    """The shared quantities: those every training/validation flight and every test flight has.
    The tables may come as ``(flight id, table)`` pairs, so that the flights lacking a quantity that
    is dropped for them are named (:attr:`TransferPlan.lacking`). Raises RunError naming both
    datasets when none is shared."""
    sides: dict[str, tuple[dict[str, set[str]], set[str], set[str]]] = {}
    intervals: list[float] = []
    for side, tables in (("train", train_tables), ("test", test_tables)):
        have: dict[str, set[str]] = {}
        cols: set[str] = set()
        used: set[str] = set()
        for fid, t in _labelled(tables):
            meanings = column_meanings(t.columns)
            got = set(shared_values(t))
            have[fid] = got
            cols |= {c for c in t.columns if isinstance(c, str) and "." in c}
            used |= set(meanings.values()) | ({*QUATERNION} if "attitude.roll" in got else set())
            if side == "train":
                intervals.append(median_interval_us(t))
        sides[side] = (have, cols, used)
    common = {side: set.intersection(*have.values()) if have else set() for side, (have, _, _) in sides.items()}
    union = {side: set().union(*have.values()) for side, (have, _, _) in sides.items()}
    shared = [c for c in _order() if c in common["train"] and c in common["test"]]
    if not shared:
        raise RunError(f"--train-dataset {train_name} / --dataset {test_name}: no quantity is in every flight of "
                       f"both (train flights have: {', '.join(sorted(common['train'])) or 'none'}; test flights "
                       f"have: {', '.join(sorted(common['test'])) or 'none'}); import the logs with their sensor "
                       "topics")
    dropped: dict[str, dict[str, str]] = {}
    lacking: dict[str, list[str]] = {}
    for side, (have, cols, used) in sides.items():
        other = "test" if side == "train" else "train"
        why = {}
        for c in [c for c in _order() if c in union[side] and c not in shared]:
            if c not in common[side]:
                why[c] = "not in every flight of this dataset"
                lacking.setdefault(c, []).extend(f for f, got in have.items() if c not in got)
            elif c not in union[other]:
                why[c] = "in no flight of the other dataset"
            else:
                why[c] = "not in every flight of the other dataset"
        arming = {c for c in cols if c.rpartition(".")[2] in ARMING_FIELDS}
        why.update({c: "no meaning" for c in sorted(cols - used - arming)})
        dropped[side] = why
    finite = [i for i in intervals if math.isfinite(i) and i > 0]
    interval = int(round(float(np.median(finite)))) if finite else 0
    return TransferPlan(tuple(shared), interval, dropped, {c: lacking[c] for c in _order() if c in lacking})


def plan_fingerprint(*parts: object) -> str:
    """sha256 of JSON parts (the datasets' fingerprints and the plan): the flight cache's key."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode("utf-8")).hexdigest()


class TransferFlights:
    """``flight(fid)``: a flight of either dataset as its shared table (picklable: opens the datasets
    in the process that reads). ``train_ids`` are read from the train dataset, the rest from the test
    dataset, which is resampled to the plan's interval."""

    def __init__(self, train_path: str, test_path: str, train_ids: Iterable[str] | dict[str, str],
                 columns: Iterable[str], interval_us: int):
        self.train_path, self.test_path = str(train_path), str(test_path)
        # the run's id of each train-dataset flight -> its id in that dataset (they differ where the
        # test dataset has a different flight of the same id: open_transfer)
        self.train_ids = ({str(k): str(v) for k, v in train_ids.items()} if isinstance(train_ids, dict)
                          else {str(f): str(f) for f in train_ids})
        self.columns = tuple(columns)
        self.interval_us = int(interval_us)
        self._open: dict = {}

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_open": {}}

    def _dataset(self, path: str):
        if path not in self._open:
            from scart_bench.dataset import open_dataset

            self._open[path] = open_dataset(path)
        return self._open[path]

    def flight(self, flight_id: str) -> pd.DataFrame:
        fid = str(flight_id)
        if fid in self.train_ids:
            return shared_table(self._dataset(self.train_path).flight(self.train_ids[fid]), self.columns)
        return shared_table(self._dataset(self.test_path).flight(fid), self.columns, self.interval_us)

    __call__ = flight


@dataclass
class TransferRun:
    """The two datasets of a transfer run and what the runner needs of them."""

    train: object  # the train Dataset
    test: object  # the test Dataset
    splits: object  # benchmark.protocol.Splits
    plan: TransferPlan
    reader: TransferFlights
    flights: pd.DataFrame  # flights.csv: the run's flights with their role and dataset
    #: the run's id -> the train dataset's id, for train-dataset flights renamed (TRAIN_PREFIX) because
    #: the test dataset has a different flight of the same id; empty when no id is shared
    renamed: dict[str, str] = field(default_factory=dict)
    #: where the thresholds are calibrated: "train_dataset" (its validation flights) or "dataset"
    calibrate_on: str = "train_dataset"

    def job_args(self) -> dict:
        """What a job needs to read the flights by meaning (JobSpec.transfer; plain data)."""
        ids = [*self.splits.train, *(self.splits.validation if self.calibrate_on == "train_dataset" else ())]
        return {"train_dataset": str(self.train.path.resolve()),
                "train_ids": {f: self.renamed.get(f, f) for f in ids} if self.renamed else ids,
                "columns": list(self.plan.columns), "interval_us": int(self.plan.interval_us)}

    def dropped_table(self) -> pd.DataFrame:
        """columns.csv: every column of either dataset left out of the shared table, and why."""
        rows = [{"dataset": side, "column": c, "why": why} for side, cols in self.plan.dropped.items()
                for c, why in cols.items()]
        return pd.DataFrame(rows, columns=["dataset", "column", "why"])


def transfer_roles(manifest: pd.DataFrame, calibrate_here: bool = False) -> pd.Series:
    """Roles of the test dataset's flights in a transfer run: every normal flight is a held-out normal
    flight (``test_normal``, whatever its split: nothing is fitted or calibrated on it), attacked
    flights are ``test_attacked`` (or ``no_effect``). ``calibrate_here`` (``--calibrate-on dataset``):
    its normal flights of split validation calibrate (``validation``) and are not tested."""
    from scart_bench.benchmark.protocol import NORMAL_MODE, assign_roles

    normal = manifest["mode"].astype(str) == NORMAL_MODE
    keep = ~normal | (manifest["split"].astype(str) == "validation") if calibrate_here else ~normal
    return assign_roles(manifest.assign(split=manifest["split"].where(keep, "test")))


def open_transfer(train_path, test_ds, note=print, calibrate_on: str = "train_dataset") -> TransferRun:
    """The transfer run of ``test_ds`` trained on the dataset at ``train_path``: splits, shared columns
    (every flight of both is read once) and the flight reader. Raises RunError (one line, naming the
    dataset) when the train dataset is missing or lacks train/validation flights, the test dataset has
    no test flights, a flight is in both, or no quantity is shared.

    ``calibrate_on="dataset"``: the thresholds are calibrated on ``test_ds``'s normal flights of split
    validation (read by meaning and resampled as its test flights are), which are then not tested;
    the detectors are still fitted on the train dataset's train flights only."""
    from scart_bench.benchmark.protocol import ProtocolError, Splits, assign_roles
    from scart_bench.dataset import DatasetError, is_dataset, open_dataset

    if not is_dataset(train_path):
        raise RunError(f"--train-dataset {train_path}: not a dataset (no manifest there)")
    here = calibrate_on == "dataset"
    try:
        train = open_dataset(train_path)
        train_roles = assign_roles(train.manifest)
        test_roles = transfer_roles(test_ds.manifest, calibrate_here=here)
    except (DatasetError, ProtocolError) as exc:
        raise RunError(f"--train-dataset {train_path} / --dataset {test_ds.path}: {exc}") from None
    ids = train.manifest["flight_id"].astype(str)
    test_ids = test_ds.manifest["flight_id"].astype(str)
    part = {r: tuple(ids[train_roles == r]) for r in (("train",) if here else ("train", "validation"))}
    for role, got in part.items():
        if not got:
            raise RunError(f"--train-dataset {train_path}: no normal flights with split {role!r}; a transfer run "
                           "trains and calibrates on the train dataset's train and validation flights")
    calibration = tuple(test_ids[test_roles == "validation"]) if here else ()
    if here and not calibration:
        raise RunError(f"--calibrate-on dataset: --dataset {test_ds.path} has no normal flight of split validation "
                       "to calibrate on (import some of your flights with --split validation, or --split auto)")
    tested = {r: tuple(test_ids[test_roles == r]) for r in ("test_normal", "test_attacked", "no_effect")}
    if not tested["test_normal"] and not tested["test_attacked"]:
        raise RunError(f"--dataset {test_ds.path}: no flights to test (normal or attacked)")
    fitted = part["train"] + part.get("validation", ())  # the train dataset's flights the run reads
    renamed = _run_ids(train, test_ds, fitted, set(test_ids), train_path)
    run_id = {v: k for k, v in renamed.items()}
    splits = Splits(tuple(run_id.get(f, f) for f in part["train"]),
                    calibration if here else tuple(run_id.get(f, f) for f in part["validation"]),
                    tested["test_normal"], tested["test_attacked"], tested["no_effect"], ())
    used_test = calibration + tested["test_normal"] + tested["test_attacked"]
    train.check_flights(dict.fromkeys(fitted))
    test_ds.check_flights(dict.fromkeys(used_test))
    plan = plan_transfer(((f, train.flight(f)) for f in fitted),
                         ((f, test_ds.flight(f)) for f in used_test), str(train_path), str(test_ds.path))
    where = (f"trained on {train.path} ({len(part['train'])} train flights), calibrated on {test_ds.path} "
             f"({len(calibration)} normal flights of split validation, not tested)" if here else
             f"trained and calibrated on {train.path} ({len(part['train'])} train, "
             f"{len(part['validation'])} validation flights)")
    note(f"transfer: {where}, tested on {test_ds.path} ({len(tested['test_normal'])} "
         f"normal, {len(tested['test_attacked'])} attacked flights); {plan.describe()}")
    sources = {**source_flights(train.manifest), **source_flights(test_ds.manifest)}
    roles = {**{f: f"{r}, {train_path}" for r, ids in part.items() for f in ids},
             **{f: f"validation, {test_ds.path}" for f in calibration},
             **{f: f"{'test' if r == 'test_normal' else 'attacked'}, {test_ds.path}"
                for r, ids in tested.items() for f in ids}}
    for line in lacking_lines(plan.lacking, sources, roles):
        note(f"transfer: dropped for every flight, since some lack it: {line}")
    reader = TransferFlights(str(train.path.resolve()), str(test_ds.path.resolve()),
                             {run_id.get(f, f): f for f in fitted}, plan.columns, plan.interval_us)
    tm = train.manifest.assign(role=train_roles, dataset=str(train.path))
    tm = tm[tm["role"].isin(tuple(part))]
    if renamed:  # the run's ids, and the train dataset's own beside them
        original = tm["flight_id"].astype(str)
        tm = tm.assign(flight_id=original.map(lambda f: run_id.get(f, f)), dataset_flight_id=original)
    rm = test_ds.manifest.assign(role=test_roles, dataset=str(test_ds.path))
    flights = pd.concat([tm, rm], ignore_index=True)
    flights = flights[["flight_id", "role", "dataset", *(c for c in flights.columns
                                                         if c not in ("flight_id", "role", "dataset"))]]
    return TransferRun(train, test_ds, splits, plan, reader, flights, renamed, calibrate_on)


#: Prefix of a train-dataset flight's id in a transfer run whose test dataset has another flight of that id.
TRAIN_PREFIX = "train+"


def _flight_digest(ds, flight_id: str) -> str:
    """What identifies a flight's contents: the checksum its manifest recorded, else the digest of its files."""
    from scart_bench.dataset.tables import flight_checksum

    if "checksum" in ds.manifest.columns:
        row = ds.manifest.loc[ds.manifest["flight_id"].astype(str) == flight_id, "checksum"]
        if len(row) and isinstance(row.iloc[0], str) and row.iloc[0]:
            return row.iloc[0]
    return flight_checksum(ds.flight_dir(flight_id))


def _run_ids(train, test_ds, train_ids: tuple[str, ...], test_ids: set[str], train_path) -> dict[str, str]:
    """Flights are keyed by (dataset, flight id): a train-dataset flight whose id the test dataset also
    uses gets the run id ``train+<id>`` when the two are different flights (two generated datasets
    both have normal-0000), so labels and scores stay apart. The same flight in both roles (the same
    dataset, or a copy of it) is refused: a detector would be tested on what it was fitted or
    calibrated on. Returns run id -> train dataset id for the renamed flights (empty when no id is shared)."""
    from scart_bench.names import IdError, check_id

    clash = [f for f in train_ids if f in test_ids]
    if not clash:
        return {}
    same_folder = train.path.resolve() == test_ds.path.resolve()
    same = [f for f in clash if same_folder or _flight_digest(train, f) == _flight_digest(test_ds, f)]
    if same:
        raise RunError(f"--train-dataset {train_path} / --dataset {test_ds.path}: flight {same[0]!r} is the same "
                       f"flight in both ({len(same)} such: same id and contents); a transfer run needs test flights "
                       "it was not trained or calibrated on")
    renamed = {}
    for f in train_ids:
        run_id = TRAIN_PREFIX + f
        try:
            check_id(run_id, f"--train-dataset {train_path}: flight id")
        except IdError as exc:
            raise RunError(f"{exc}; the test dataset has another flight {f!r}, so the run names this one "
                           f"{TRAIN_PREFIX}<id>") from None
        if run_id in test_ids:
            raise RunError(f"--train-dataset {train_path} / --dataset {test_ds.path}: flight id {f!r} is in both "
                           f"and {run_id!r} is taken by the test dataset; a transfer run needs ids it can tell apart")
        renamed[run_id] = f
    return renamed


# -- a run on one dataset, by meaning ------------------------------------------------------------

def source_flights(manifest: pd.DataFrame) -> dict[str, str]:
    """Attacked copy -> the flight of the same dataset it copies (``source_flight``), where the manifest says."""
    if "source_flight" not in manifest.columns:
        return {}
    ids = manifest["flight_id"].astype(str)
    known = set(ids)
    return {f: s for f, s in zip(ids, manifest["source_flight"]) if isinstance(s, str) and s in known and s != f}


def logged_columns(ds, flight_id: str) -> frozenset[str]:
    """The ``topic.field`` columns of a flight's table (the navigator view), from the compact layout's
    metadata where it has it (no data read), else from the table itself."""
    from scart_bench.dataset import compact
    from scart_bench.dataset.record import TRUTH_TOPICS

    root = ds.flight_dir(flight_id)
    path = root / "navigator.parquet"
    if path.exists():
        try:
            meta = compact.read_meta(path)
            fields = {s["name"]: [c for c, _ in s["columns"]] for s in meta.get("stored", [])}
            for name, other in meta.get("reuse", {}).items():
                if name not in fields:
                    elsewhere = compact.read_meta(compact.view_file(path, other))  # (a copy: its source's view)
                    fields.update({s["name"]: [c for c, _ in s["columns"]] for s in elsewhere.get("stored", [])
                                   if s["name"] == name})
            return frozenset(f"{t}.{c}" for t in meta["topics"] if t not in TRUTH_TOPICS for c in fields[t]
                             if c != "Timestamp" and c not in LABEL_COLUMNS)
        except (compact.CompactError, KeyError, TypeError, ValueError, OSError):
            pass  # read the table below
    else:  # the paper layout: the combined table's header
        import csv

        import pyarrow.parquet as pq

        base = root / "combined" / "navigator_most_frequent"
        try:
            if base.with_suffix(".parquet").exists():
                names = pq.read_schema(base.with_suffix(".parquet")).names
            else:
                with base.with_suffix(".csv").open(newline="") as fh:
                    names = next(csv.reader(fh))
            return frozenset(c for c in names if "." in c and c not in LABEL_COLUMNS)
        except (OSError, StopIteration, ValueError):
            pass  # read the table below
    return frozenset(c for c in ds.flight(flight_id).columns if isinstance(c, str) and c not in LABEL_COLUMNS)


def differing_columns(ds, train: Iterable[str], scored: Iterable[str]) -> str | None:
    """Why a run on ``ds`` should read its flights by meaning: its training flights log different
    columns, or a validation/test flight lacks a column every training flight logs (the run would
    fail on it). None when neither (every generated dataset; logs of one firmware build)."""
    cols = {f: logged_columns(ds, f) for f in dict.fromkeys([*train, *scored])}
    train = list(dict.fromkeys(train))
    first = train[0]
    for f in train[1:]:
        if cols[f] != cols[first]:
            lack, extra = sorted(cols[first] - cols[f]), sorted(cols[f] - cols[first])
            return (f"the training flights log different columns: {f} lacks {len(lack)} of {first}'s"
                    + (f" (e.g. {', '.join(lack[:3])})" if lack else "")
                    + (f" and has {len(extra)} it has not (e.g. {', '.join(extra[:3])})" if extra else ""))
    common = frozenset.intersection(*(cols[f] for f in train))
    for f in dict.fromkeys(scored):
        lack = sorted(common - cols[f])
        if lack:
            return (f"flight {f} lacks {len(lack)} column(s) every training flight logs "
                    f"(e.g. {', '.join(lack[:3])})")
    return None


@dataclass
class MeaningRun:
    """A run on one dataset whose flights are read by meaning (:func:`open_meaning`)."""

    plan: TransferPlan  # the quantities (no resampling: interval 0) and the flights lacking one
    reader: TransferFlights
    why: str

    def job_args(self, dataset: str) -> dict:
        """What a job needs to read the flights by meaning (JobSpec.transfer, every flight from ``dataset``)."""
        return {"train_dataset": dataset, "train_ids": [], "columns": list(self.plan.columns), "interval_us": 0}

    def dropped_table(self) -> pd.DataFrame:
        """columns.csv: the columns of the dataset's flights left out, and why."""
        rows = [{"dataset": side, "column": c, "why": why} for side, cols in self.plan.dropped.items()
                for c, why in cols.items()]
        return pd.DataFrame(rows, columns=["dataset", "column", "why"])


def open_meaning(ds, splits, mode: str = "auto", note=print) -> MeaningRun | None:
    """How a run on one dataset reads its flights (``run --columns``): None for as logged (``logged``,
    or ``auto`` when :func:`differing_columns` finds nothing), else by meaning. Then the quantities are
    those a training flight has; a flight lacking one has it as missing values, and a line names it
    (attacked copies under their source flight, which is what is read to tell). RunError when no
    training flight has any quantity."""
    if mode not in COLUMN_MODES:
        raise RunError(f"--columns {mode!r}: expected one of {', '.join(COLUMN_MODES)}")
    if mode == "logged":
        return None
    why = "--columns meaning" if mode == "meaning" else differing_columns(ds, splits.train, splits.scored)
    if why is None:
        return None
    run_ids = list(dict.fromkeys([*splits.train, *splits.scored]))
    sources = source_flights(ds.manifest)
    read_ids = list(dict.fromkeys(sources.get(f, f) for f in run_ids))
    have: dict[str, set[str]] = {}
    no_meaning: set[str] = set()
    for f in read_ids:  # one flight at a time: only what it has is kept
        t = ds.flight(f)
        values = shared_values(t)
        have[f] = {q for q, v in values.items() if np.isfinite(v).any()}
        used = set(column_meanings(t.columns).values()) | ({*QUATERNION} if "attitude.roll" in values else set())
        no_meaning |= {c for c in t.columns if isinstance(c, str) and "." in c and c not in used
                       and c.rpartition(".")[2] not in ARMING_FIELDS}
    trained = set().union(*(have[f] for f in splits.train))
    columns = [q for q in _order() if q in trained]
    if not columns:
        raise RunError(f"--dataset {ds.path}: reading its flights by meaning ({why}), no training flight has a "
                       "quantity of the meaning table; use --columns logged with --features")
    lacking = {q: [f for f in run_ids if q not in have[sources.get(f, f)]] for q in columns}
    lacking = {q: ids for q, ids in lacking.items() if ids}
    untrained = [q for q in _order() if q not in trained and any(q in h for h in have.values())]
    dropped = {"dataset": {**{q: "in no training flight" for q in untrained},
                           **{c: "no meaning" for c in sorted(no_meaning)}}}
    plan = TransferPlan(tuple(columns), 0, dropped, lacking)
    note(f"columns by meaning ({why}): {len(columns)} quantities ({', '.join(columns)})"
         + (f"; left out, in no training flight: {', '.join(untrained)}" if untrained else "")
         + f"; {len(no_meaning)} logged column(s) with no quantity left out (columns.csv)")
    roles = {f: r for r in ("train", "validation") for f in getattr(splits, r)}
    roles.update({f: "test" for f in splits.test_normal})
    roles.update({f: "csv_source" for f in splits.csv_source})
    for line in lacking_lines(lacking, sources, roles):
        note(f"columns by meaning: missing values (filled as any gap) where a flight lacks a quantity: {line}")
    path = str(ds.path.resolve())
    return MeaningRun(plan, TransferFlights(path, path, {}, plan.columns, 0), why)
