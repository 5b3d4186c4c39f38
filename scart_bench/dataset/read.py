"""Reading datasets: :func:`open_dataset` and :class:`Dataset` (manifest, flights, topics, events, configs),
with each flight's checksum verified on its first read."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from scart_bench.dataset import compact
from scart_bench.dataset.labels import combine
from scart_bench.dataset.locks import recover
from scart_bench.dataset.record import TABLES, TOPIC_VIEWS, TRUTH_TOPICS, VIEWS, DatasetError
from scart_bench.dataset.tables import flight_checksum, read_table
from scart_bench.names import check_id, inside


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
        """Which generator defaults made the flights (generator.engine.flight_batch.FLIGHT_DEFAULTS); 1 for a
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
