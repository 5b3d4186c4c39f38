"""``sitl --record`` written as it flies: a journal beside the dataset, so an interrupted recording keeps the flown part.

Every :data:`FLUSH_S` of simulated time the rows recorded since the last flush are appended to a
journal folder beside the dataset, ``DIR.sitl-recording/FLIGHT_ID/``: per view and topic a file of
timestamps (int64) and one of values (float64 rows), then ``state.json`` (rows per stream, the
attack windows and events so far, the flight's manifest and config), replaced atomically after
the data, so it never counts a row that is not on disk.

The journal starts with a ``state.json`` of no rows, written before the flight (a journal that
cannot even be started is refused up front: no promise is made that cannot be kept). At the end
the flight is written into ``DIR`` as before and the journal removed. When the process is killed,
or writing the flight fails (a full disk), the journal stays: the next ``scart-bench sitl --record
DIR`` first turns it into the flight, marked incomplete (its config has ``"incomplete": true`` and
the reason; its duration is the part flown until the last flush that was written whole). A flush
that fails during the flight (no space) is reported once and tried again at the next flush, from
the last whole one (the streams are cut back to the rows ``state.json`` counts), so a disk that
frees up mid-flight loses nothing; :attr:`Journal.kept_us` says how much of the flight the journal
holds, and the command says exactly that when the final write fails. A journal is never removed
without a line saying so. The journal lives beside the dataset, not in it, so the dataset's folder
holds only the dataset format.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scart_bench.generator.sitl.record import build_record, sitl_parts

FLUSH_S = 2.0
SUFFIX = ".sitl-recording"
STATE = "state.json"


def journal_root(dataset: str | Path) -> Path:
    """The folder beside dataset ``dataset`` that holds the journals of its sitl recordings."""
    dataset = Path(dataset).resolve()  # ``--record .`` has no name to extend
    return dataset.with_name(dataset.name + SUFFIX)


def _stream_paths(folder: Path, key: str) -> tuple[Path, Path]:
    return folder / f"{key}.ts.i64", folder / f"{key}.vals.f64"


def _plain(value):
    """numpy scalars and arrays (in events, counters) as JSON values."""
    return value.tolist() if isinstance(value, np.ndarray | np.generic) else str(value)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class Journal:
    """The journal of one sitl flight being recorded into dataset ``dataset``."""

    def __init__(self, dataset: str | Path, flight_id: str, extra_config: dict, split: str,
                 log: Callable[[str], None]):
        self.flight_id = flight_id
        self.folder = journal_root(dataset) / flight_id
        self.extra_config, self.split, self.log = extra_config, split, log
        self.rows: dict[str, int] = {}  # rows per stream that state.json counts (written whole)
        self.cols: dict[str, int] = {}
        self.kept_us = 0  # flight time the journal holds: the end of the last flush written whole
        self.failed = False  # the last flush failed
        self._reported = False

    def start(self, server) -> None:
        """Write the journal's first state (no rows yet); OSError when it cannot be written at all."""
        self.folder.mkdir(parents=True, exist_ok=True)
        state = {"flight_id": self.flight_id, "rows": {}, "cols": {},
                 "parts": sitl_parts(server, self.extra_config, self.split)}
        _write_atomic(self.folder / STATE, json.dumps(state, default=_plain))

    def due(self, step_index: int, dt: float) -> bool:
        """True on the steps that end a flush period."""
        return step_index > 0 and step_index % max(1, round(FLUSH_S / dt)) == 0

    def flush(self, server) -> bool:
        """Append what ``server`` recorded since the last flush written whole; True when it was written.

        A failed flush (no space) is reported once and tried again at the next one: the streams are
        first cut back to the rows ``state.json`` counts, so no half-written rows are ever counted."""
        parts = sitl_parts(server, self.extra_config, self.split)
        try:
            rows, cols = self._append(server.views)
            state = {"flight_id": self.flight_id, "rows": rows, "cols": cols, "parts": parts}
            _write_atomic(self.folder / STATE, json.dumps(state, default=_plain))
        except OSError as exc:
            self.failed = True
            if not self._reported:
                self._reported = True
                self.log(f"sitl: the recording journal {self.folder} cannot be written ({exc.strerror or exc}): the "
                         f"flight goes on and the journal is tried again every {FLUSH_S:g} s; it holds the first "
                         f"{self.kept_us / 1e6:.1f} s")
            return False
        if self.failed:
            self.log(f"sitl: the recording journal {self.folder} is written again ({parts['end_us'] / 1e6:.1f} s)")
        self.rows, self.cols, self.kept_us, self.failed = rows, cols, int(parts["end_us"]), False
        return True

    def _append(self, views: dict) -> tuple[dict[str, int], dict[str, int]]:
        """Append every stream's rows after the counted ones; the new counts (not yet in state.json)."""
        rows, cols = dict(self.rows), dict(self.cols)
        for view, topics in views.items():
            for topic, (ts, vals) in topics.items():
                key = f"{view}.{topic}"
                done = self.rows.get(key, 0)
                if len(ts) <= done:
                    continue
                block = np.vstack(vals[done:len(ts)]).astype(np.float64)
                ts_path, vals_path = _stream_paths(self.folder, key)
                for path, data, width in ((ts_path, np.asarray(ts[done:len(ts)], dtype=np.int64), 1),
                                          (vals_path, block, block.shape[1])):
                    _cut(path, done * width * 8)  # drop what a failed flush left after the counted rows
                    with open(path, "ab") as fh:
                        fh.write(data.tobytes())
                rows[key], cols[key] = len(ts), block.shape[1]
        return rows, cols

    def remove(self) -> None:
        """The flight is in the dataset: the journal goes (and its root, when empty)."""
        shutil.rmtree(self.folder, ignore_errors=True)
        try:
            self.folder.parent.rmdir()
        except OSError:
            pass


def _cut(path: Path, size: int) -> None:
    """Truncate ``path`` to ``size`` bytes when it is longer (a missing file is left missing)."""
    try:
        if path.stat().st_size > size:
            os.truncate(path, size)
    except FileNotFoundError:
        pass


def _read_views(folder: Path, state: dict) -> dict:
    views: dict[str, dict] = {}
    for key, n in state["rows"].items():
        view, topic = key.split(".", 1)
        ts_path, vals_path = _stream_paths(folder, key)
        ts = np.fromfile(ts_path, dtype=np.int64, count=n)
        vals = np.fromfile(vals_path, dtype=np.float64, count=n * state["cols"][key]).reshape(n, -1)
        views.setdefault(view, {})[topic] = (ts, vals)
    return views


def recover(dataset: str | Path, save: Callable, log: Callable[[str], None], root: Path | None = None,
            remove: bool = True, shown: str | None = None) -> list[str]:
    """Turn the journals left beside ``dataset`` (or in ``root``) into flights marked incomplete; their ids.

    ``save(record)`` writes a FlightRecord into the dataset. A journal whose flight is in the dataset
    already, or that holds no flown row, is removed with a line saying so; one that cannot be added
    stays, with a line naming it. ``remove=False``: the recovered journals stay until the caller has
    published the dataset (:func:`discard`); ``shown``: the dataset as the user named it."""
    root = root if root is not None else journal_root(dataset)
    shown = shown or str(dataset)
    taken = _flight_ids(dataset)
    done = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []:
        state_path = folder / STATE
        if not state_path.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            log(f"sitl: journal {folder} removed: it has no {STATE} (its recording stopped before the journal's "
                "first write completed), so it holds no flight")
            continue
        try:
            state = json.loads(state_path.read_text(encoding="utf-8"))
            fid, parts = str(state["flight_id"]), state["parts"]
            if fid in taken:
                shutil.rmtree(folder, ignore_errors=True)
                log(f"sitl: journal {folder} removed: flight {fid} is in {shown} already")
                continue
            if not any(int(n) for n in state["rows"].values()):
                shutil.rmtree(folder, ignore_errors=True)
                log(f"sitl: journal {folder} removed: it holds no flown row of flight {fid} (stopped before its "
                    "first flush)")
                continue
            parts["config"].update(incomplete=True, incomplete_reason="the recording was interrupted; the flight "
                                   "holds what was flown until the last flush of its journal")
            save(build_record(fid, _read_views(folder, state), parts))
        except Exception as exc:  # noqa: BLE001  (one bad journal must not stop the next flight)
            log(f"sitl: journal {folder} not recovered ({type(exc).__name__}: {exc}); it stays, and the next "
                f"`scart-bench sitl --record {shown}` tries again")
            continue
        if remove:
            shutil.rmtree(folder, ignore_errors=True)
        taken.add(fid)
        log(f"sitl: recovered flight {fid} from its journal ({parts['end_us'] / 1e6:.1f} s flown, marked "
            f"incomplete) into {shown}")
        done.append(fid)
    if remove:
        discard(root, [])
    return done


def discard(root: Path, flight_ids: list[str]) -> None:
    """Remove the journals of ``flight_ids`` from ``root`` (their flights are in the dataset), and
    ``root`` itself when it is left empty."""
    for fid in flight_ids:
        shutil.rmtree(root / fid, ignore_errors=True)
    try:
        root.rmdir()
    except OSError:
        pass


def _flight_ids(dataset: str | Path) -> set[str]:
    """The flight ids of the dataset at ``dataset`` (none when there is no dataset yet)."""
    from scart_bench.dataset import is_dataset, open_dataset

    return set(open_dataset(dataset).manifest["flight_id"].astype(str)) if is_dataset(Path(dataset)) else set()
