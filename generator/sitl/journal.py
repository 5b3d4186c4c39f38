"""``sitl --record`` written as it flies: a journal beside the dataset, so an interrupted recording keeps the flown part.

Every :data:`FLUSH_S` of simulated time the rows recorded since the last flush are appended to a
journal folder beside the dataset, ``DIR.sitl-recording/FLIGHT_ID/``: per view and topic a file of
timestamps (int64) and one of values (float64 rows), then ``state.json`` (rows per stream, the
attack windows and events so far, the flight's manifest and config), replaced atomically after
the data, so it never counts a row that is not on disk.

At the end the flight is written into ``DIR`` as before and the journal removed. When the process
is killed, or writing the flight fails (a full disk), the journal stays: the next
``scart-bench sitl --record DIR`` first turns it into the flight, marked incomplete (its config has
``"incomplete": true`` and the reason; its duration is the part flown until the last flush). A
write that fails during the flight (no space) is reported once; the flight goes on and the
journal keeps what it holds. The journal lives beside the dataset, not in it, so the dataset's
folder holds only the dataset format.
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
        self.folder.mkdir(parents=True, exist_ok=True)
        self.extra_config, self.split, self.log = extra_config, split, log
        self.rows: dict[str, int] = {}
        self.cols: dict[str, int] = {}
        self.failed = False

    def due(self, step_index: int, dt: float) -> bool:
        """True on the steps that end a flush period."""
        return step_index > 0 and step_index % max(1, round(FLUSH_S / dt)) == 0

    def flush(self, server) -> None:
        """Append what ``server`` recorded since the last flush; after a failed write, do nothing more."""
        if self.failed:
            return
        try:
            self._append(server.views)
            state = {"flight_id": self.flight_id, "rows": self.rows, "cols": self.cols,
                     "parts": sitl_parts(server, self.extra_config, self.split)}
            _write_atomic(self.folder / STATE, json.dumps(state, default=_plain))
        except OSError as exc:
            self.failed = True
            self.log(f"sitl: the recording journal cannot be written ({exc.strerror or exc}): the flight goes on; "
                     f"{self.folder} keeps the part written so far")

    def _append(self, views: dict) -> None:
        for view, topics in views.items():
            for topic, (ts, vals) in topics.items():
                key, done = f"{view}.{topic}", self.rows.get(f"{view}.{topic}", 0)
                if len(ts) <= done:
                    continue
                rows = np.vstack(vals[done:]).astype(np.float64)
                ts_path, vals_path = _stream_paths(self.folder, key)
                with open(ts_path, "ab") as fh:
                    fh.write(np.asarray(ts[done:], dtype=np.int64).tobytes())
                with open(vals_path, "ab") as fh:
                    fh.write(rows.tobytes())
                self.rows[key], self.cols[key] = len(ts), rows.shape[1]

    def remove(self) -> None:
        """The flight is in the dataset: the journal goes (and its root, when empty)."""
        shutil.rmtree(self.folder, ignore_errors=True)
        try:
            self.folder.parent.rmdir()
        except OSError:
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


def recover(dataset: str | Path, save: Callable, log: Callable[[str], None]) -> list[str]:
    """Turn the journals left beside ``dataset`` into flights marked incomplete; their ids.

    ``save(record)`` writes a FlightRecord into the dataset. A journal that never flushed is removed.
    """
    root = journal_root(dataset)
    done = []
    for folder in sorted(p for p in root.glob("*") if p.is_dir()) if root.is_dir() else []:
        state_path = folder / STATE
        if not state_path.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            continue
        state = json.loads(state_path.read_text(encoding="utf-8"))
        parts = state["parts"]
        parts["config"].update(incomplete=True, incomplete_reason="the recording was interrupted; the flight "
                               "holds what was flown until the last flush of its journal")
        try:
            save(build_record(state["flight_id"], _read_views(folder, state), parts))
        except Exception as exc:  # noqa: BLE001  (one bad journal must not stop the next flight)
            log(f"sitl: journal {folder} not recovered ({type(exc).__name__}: {exc}); it stays")
            continue
        shutil.rmtree(folder, ignore_errors=True)
        log(f"sitl: recovered flight {state['flight_id']} from its journal ({parts['end_us'] / 1e6:.1f} s flown, "
            "marked incomplete)")
        done.append(state["flight_id"])
    if root.is_dir() and not any(root.iterdir()):
        root.rmdir()
    return done
