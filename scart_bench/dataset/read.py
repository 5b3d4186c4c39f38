"""Reading datasets: :func:`open_dataset` and :class:`Dataset` (manifest, flights, topics, events, configs).

The manifest's fields are checked when the dataset is opened; each flight's checksum, and its manifest
row against its own labels and event log, on its first read (:mod:`.checks`)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from scart_bench.dataset import compact
from scart_bench.dataset.checks import (
    Labels,
    check_flight_row,
    check_manifest,
    labels_from_rows,
    labels_from_windows,
    numeric_columns,
)
from scart_bench.dataset.labels import combine
from scart_bench.dataset.locks import recover
from scart_bench.dataset.record import (
    FORMATS,
    LAYOUTS,
    TABLES,
    TOPIC_VIEWS,
    TRUTH_TOPICS,
    VIEWS,
    DatasetError,
)
from scart_bench.dataset.tables import flight_checksum, read_table
from scart_bench.jsonfile import JsonFileError, read_json
from scart_bench.names import check_id, inside


class Dataset:
    """A written dataset: the manifest plus lazy access to each flight's tables."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        recover(self.path)  # a writer killed mid-replace left its partial folder (or the old dataset aside)
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: no such dataset folder")
        self.manifest_path = self.path / "manifest.parquet"
        if not self.manifest_path.exists():
            self.manifest_path = self.path / "manifest.csv"
        if not self.manifest_path.exists():
            raise DatasetError(f"{self.path}: no manifest.parquet or manifest.csv; the dataset is missing or "
                               "incomplete (the manifest is written last)")
        self.manifest = _read_manifest(self.manifest_path)
        check_manifest(self.manifest, self.manifest_path)
        self.manifest = numeric_columns(self.manifest)
        info = self.path / "dataset.json"
        try:
            self.info = read_json(info) if info.exists() else {}
        except JsonFileError as exc:
            raise DatasetError(f"{exc}; it holds the dataset's format and versions") from None
        _check_info(self.info, info)
        self._verified: set[str] = set()
        self._rows: dict[str, dict] | None = None

    def __len__(self) -> int:
        return len(self.manifest)

    @property
    def flight_defaults(self) -> int:
        """Which generator defaults made the flights (generator.engine.flight_batch.FLIGHT_DEFAULTS); 1 for a
        dataset written before dataset.json said so."""
        return int(self.info.get("flight_defaults", 1))  # an integer >= 1 (checked when opened)

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
            return read_table(self.flight_dir(flight_id) / "combined" / f"{view}_{table}", columns)
        topics = read_view(self.flight_dir(flight_id), view, arrays=True)
        windows = self._windows(flight_id, view)
        df = combine({k: v for k, v in topics.items() if k not in TRUTH_TOPICS}, windows, tables=(table,))[table]
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
        recorded when it was written (datasets written before checksums: nothing to compare), or
        when its manifest row disagrees with the flight's own labels and event log (its mode, its
        attack window: :func:`scart_bench.dataset.checks.check_flight_row`)."""
        if flight_id in self._verified:
            return
        if self._rows is None:  # once: a manifest scan per flight was O(n^2) over a run's flights
            self._rows = {str(r["flight_id"]): r for r in self.manifest.to_dict("records")}
        row = self._rows.get(str(flight_id))
        expected = None if row is None else row.get("checksum")
        if isinstance(expected, str) and expected:  # an empty one is refused when the manifest is read
            got = flight_checksum(self.flight_dir(flight_id))
            if got != expected:
                raise DatasetError(f"{self.flight_dir(flight_id)}: flight {flight_id!r} changed since it was written "
                                   f"(checksum {got}, the manifest recorded {expected}); its files are damaged or "
                                   "were edited: regenerate it, or remove it from the dataset")
        if row is not None and self.flight_dir(flight_id).is_dir():
            check_flight_row(self.manifest_path, str(flight_id), row, self._labels(flight_id),
                             self.flight_dir(flight_id) / "raw" / "events.csv")
        self._verified.add(flight_id)
        try:
            for source in self.sources(flight_id):  # an attacked copy reads its untouched fields there
                self.verify(source)
        except DatasetError as exc:
            self._verified.discard(flight_id)
            raise DatasetError(f"{exc} (attacked copy {flight_id!r} keeps its untouched fields in that flight's "
                               "files)") from None

    def sources(self, flight_id: str) -> list[str]:
        """The flights whose files this flight's views read (an attacked copy written by ``attack --dataset``
        shares its untouched fields with its source flight); none for every other flight. DatasetError
        when such a flight is not in the dataset (removed?), naming both."""
        root = self.flight_dir(flight_id)
        if not self.is_compact(flight_id):
            return []
        found: set[str] = set()
        for view in TOPIC_VIEWS:
            path = root / f"{view}.parquet"
            if not path.exists():
                continue
            try:
                meta = compact.read_meta(path)
                found.update(compact.referenced_flights(meta))
            except compact.CompactError as exc:
                raise DatasetError(f"{exc}; regenerate or remove flight {flight_id!r}") from None
        if self._rows is None:
            self._rows = {str(r["flight_id"]): r for r in self.manifest.to_dict("records")}
        for source in sorted(found):
            if source not in self._rows or not self.flight_dir(source).is_dir():
                where = "the manifest" if source not in self._rows else "the dataset's flights folder"
                raise DatasetError(f"{root}: attacked copy {flight_id!r} keeps its untouched fields in flight "
                                   f"{source!r}, which is not in {where}; restore that flight, or remove the copy "
                                   "and attack again")
        return sorted(found)

    def _labels(self, flight_id: str) -> Labels:
        """Where the flight's own labels put its attack: the compact layout's stored windows (which the
        labels are made from), or the labelled rows of the paper layout's navigator table."""
        root = self.flight_dir(flight_id)
        if self.is_compact(flight_id):
            path = root / "navigator.parquet"
            try:
                windows = compact.read_meta(path).get("windows", [])
            except compact.CompactError as exc:
                raise DatasetError(str(exc)) from None
            if not isinstance(windows, list):
                raise DatasetError(f"{path}: its metadata's windows are {type(windows).__name__}; expected a list "
                                   "(damaged or not written by scart-bench)")
            return labels_from_windows(windows, path)
        base = root / "combined" / "navigator_most_frequent"
        path = base.with_suffix(".parquet") if base.with_suffix(".parquet").exists() else base.with_suffix(".csv")
        if not path.exists():
            return Labels(path)  # no table: check_flights and the reader name it
        try:
            df = read_table(base, ["Timestamp", "Is_Anomaly"])
            ts = pd.to_numeric(df["Timestamp"], errors="raise").to_numpy()
            flags = pd.to_numeric(df["Is_Anomaly"], errors="raise").fillna(0).to_numpy()
        except Exception as exc:  # pyarrow and pandas raise their own types for a damaged table
            raise DatasetError(f"{path}: its Timestamp and Is_Anomaly columns are unreadable "
                               f"({type(exc).__name__}: {exc}); regenerate or remove flight {flight_id!r}") from None
        return labels_from_rows(ts, flags, path)

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
            return read_table(self.flight_dir(flight_id) / "sensors" / view / topic)
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
        """The flight's attack event log (raw/events.csv: timestamp_us, event, scenario_id, detail)."""
        path = self.flight_dir(flight_id) / "raw" / "events.csv"
        try:
            return pd.read_csv(path)
        except FileNotFoundError:
            raise DatasetError(f"{path}: missing; flight {flight_id!r} has no event log") from None
        except pd.errors.EmptyDataError:
            return pd.DataFrame(columns=["timestamp_us", "event", "scenario_id", "detail"])
        except (ValueError, OSError, UnicodeDecodeError) as exc:
            raise DatasetError(f"{path}: unreadable ({type(exc).__name__}: {exc}); expected the flight's attack "
                               "event log (CSV)") from None

    def config(self, flight_id: str) -> dict:
        """The flight's raw/config.json (scenario, mission, seed, versions), read bounded."""
        path = self.flight_dir(flight_id) / "raw" / "config.json"
        try:
            return read_json(path)
        except JsonFileError as exc:
            raise DatasetError(f"{exc}; it holds flight {flight_id!r}'s configuration") from None


def _read_manifest(path: Path) -> pd.DataFrame:
    """The manifest table (ids as text), DatasetError naming the file when it is not readable."""
    try:
        if path.suffix == ".parquet":
            return pd.read_parquet(path)
        # ids are text: "007" stays "007"
        return pd.read_csv(path, dtype={"scenario_id": "string", "flight_id": str, "source_flight": "string"})
    except Exception as exc:  # pyarrow and pandas raise their own types for a damaged file
        raise DatasetError(f"{path}: unreadable ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}); "
                           "expected the dataset's manifest (damaged or not written by scart-bench)") from None


def _check_info(info: dict, path: Path) -> None:
    """DatasetError naming dataset.json and the field when a field the readers use has the wrong type."""
    fd = info.get("flight_defaults", 1)
    if isinstance(fd, bool) or not isinstance(fd, int) or not 1 <= fd <= 1_000_000:
        raise DatasetError(f"{path}: field 'flight_defaults' is {fd!r}; expected an integer >= 1")
    if "format" in info and info["format"] not in FORMATS:
        raise DatasetError(f"{path}: field 'format' is {info['format']!r}; expected one of {', '.join(FORMATS)}")
    if "layout" in info and info["layout"] not in LAYOUTS:
        raise DatasetError(f"{path}: field 'layout' is {info['layout']!r}; expected one of {', '.join(LAYOUTS)}")


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
            other_path = compact.view_file(path, other)
            if not other_path.exists():
                raise DatasetError(f"{path}: keeps topic(s) {', '.join(wanted[:5])} in {other_path}, which is missing")
            here.update(compact.read_topics(other_path, wanted, arrays=arrays))
    except compact.CompactError as exc:
        raise DatasetError(str(exc)) from None
    except (KeyError, TypeError, IndexError, AttributeError) as exc:  # spans of the wrong shape
        raise DatasetError(f"{path}: its {compact.META_KEY.decode()} metadata is damaged ({type(exc).__name__}: "
                           f"{exc}); regenerate the flight") from None
    return {n: here[n] for n in order if n in here}


def open_dataset(path: str | Path) -> Dataset:
    """Open a complete dataset (raises DatasetError naming the folder when it is not one)."""
    return Dataset(path)
