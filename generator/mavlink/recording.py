"""A proxied flight in the dataset layout: both views, labels from the layer, the event log.

The navigator view is what the proxy forwarded to the mission computer (attacked), the
simulator view what it received from the autopilot (ground truth of the link; a live link has
no ``truth`` topic). The flight is an attacked flight of mode ``simulation`` (closed loop: the
mission computer reacts to what it is fed), split ``test``.

:func:`save_recording` writes it into a new dataset, or appends it to an existing one (for
example one made with ``scart-bench generate --normal-only``, which holds the normal train and
validation flights a benchmark run needs); the manifest is replaced atomically, so the dataset
is complete before and after.

A dataset at an fsspec URL (``--record s3://bucket/prefix``) is checked up front
(:func:`check_record_url`), written in a local copy and published with its manifest last by the
command (``scart_bench.storage.staged_dataset``); the journals and checkpoints of its
recordings are kept in the local cache, beside :func:`url_anchor`, so that a killed recording or a
failed upload is added by the next ``--record`` of the same URL.
"""

from __future__ import annotations

import contextlib
import hashlib
import shutil
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import (
    DatasetError,
    FlightRecord,
    append_flights,
    flight_record,
    insert_labels,
    is_dataset,
    open_dataset,
)
from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.modes import scenario_manifest

LIVE_SOURCE = "mavlink-proxy"


def _table(topic: str, ts: list[int], vals: list[np.ndarray], windows) -> pd.DataFrame:
    t = np.asarray(ts, dtype=np.int64)
    df = pd.DataFrame(np.vstack(vals) if vals else np.zeros((0, len(TOPICS[topic].fields))),
                      columns=list(TOPICS[topic].field_names))
    df.insert(0, "Timestamp", t)
    return insert_labels(df, t, windows)


def proxy_record(proxy, flight_id: str, extra_config: dict) -> FlightRecord:
    """The flight a :class:`scart_bench.generator.mavlink.proxy.MavlinkProxy` has seen so far."""
    end_us = proxy.end_us
    windows = proxy.layer.labelled_windows(0, end_us)
    nav = {t: _table(t, *proxy.views.forwarded[t], windows) for t in TOPICS if t in proxy.views.forwarded}
    sim = {t: _table(t, *proxy.views.received[t], windows) for t in TOPICS if t in proxy.views.received}
    manifest = scenario_manifest(proxy.scenarios, "simulation", proxy.seed, source=LIVE_SOURCE)
    config = {
        **extra_config, "seed": proxy.seed, "mode": "simulation", "source": LIVE_SOURCE,
        "listen": f"udp:{proxy.listen[0]}:{proxy.listen[1]}",
        "forward": f"udp:{proxy.forward[0]}:{proxy.forward[1]}",
        "scenarios": [s.to_dict() for s in proxy.scenarios], "stats": proxy.stats.to_dict(),
        "first_autopilot_time_us": proxy.first_time_us,
        "recorded_at": datetime.fromtimestamp(proxy.started_wall, UTC).isoformat(timespec="seconds"),
    }
    return flight_record(flight_id, nav, sim, manifest, config, windows, proxy.layer.event_log(0, end_us),
                         end_us=end_us)


def new_flight_id(path: str | Path | None = None, prefix: str = "live", taken: set[str] | None = None) -> str:
    """A flight id from the current time, unique in the dataset at ``path`` (if any) and not in ``taken``."""
    base = f"{prefix}-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S')}"
    taken = flight_ids(path) | set(taken or ())
    fid, k = base, 1
    while fid in taken:
        k += 1
        fid = f"{base}-{k}"
    return fid


def url_anchor(url: str) -> Path:
    """The local stand-in of the dataset at ``url``: the journals and checkpoints of its live
    recordings are kept beside it (in the cache, keyed by the URL), where the next ``--record`` of
    the same URL finds them."""
    from scart_bench.storage import default_cache

    key = hashlib.sha256(url.rstrip("/").encode()).hexdigest()[:24]
    return default_cache() / "recordings" / key / "dataset"


def check_record_url(url: str, option: str = "--record") -> Path | None:
    """Refuse up front (StorageError, one line) a URL a recording cannot be published to: not
    writable, or objects there but no manifest. Returns a local copy of the dataset there (whose
    flight ids are taken), None when there is none yet."""
    from scart_bench.storage import StorageError, check_writable, fetch_dataset, has_manifest, has_objects

    check_writable(url)
    if has_manifest(url):
        return fetch_dataset(url)
    if has_objects(url):
        raise StorageError(f"{option} {url}: holds objects but no manifest (not a complete scart-bench dataset); "
                           "give a new prefix or an existing dataset to add the flight to")
    return None


class _NothingAdded(Exception):
    """No journal or checkpoint was added: nothing to publish."""


class RecordTarget:
    """Where a live ``--record`` writes (sitl, proxy, ros node): a local dataset folder (checked by
    ``check_local``, which returns it), or a dataset at an fsspec URL, checked up front and written
    in a local copy published with its manifest last. ``anchor``: the local folder the journals and
    checkpoints are kept beside (the folder itself, or for a URL a stand-in in the cache);
    ``taken``: the flight ids the dataset holds; ``shown``: the target as the user named it."""

    def __init__(self, location: str, check_local: Callable[[Path], Path], option: str = "--record"):
        from scart_bench.storage import is_url, local_path

        self.url = is_url(location)
        if self.url:  # refused up front when it cannot be published to: never a local folder named "s3:"
            self.location: str | Path = location.rstrip("/")
            self.taken = flight_ids(check_record_url(self.location, option))
            self.anchor = url_anchor(self.location)
        else:
            self.location = self.anchor = check_local(local_path(location))
            self.taken = flight_ids(self.location)
        self.shown = str(self.location)

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """The local dataset to add flights to: the folder, or a copy of the URL's dataset published
        (manifest last) when the block succeeds; after a failure the URL is untouched."""
        from scart_bench.storage import staged_dataset

        with staged_dataset(self.location) as ds:
            yield ds

    def add_left(self, root: Path, recover: Callable[[Path, bool], list[str]],
                 discard: Callable[[Path, list[str]], None]) -> None:
        """Add the flights that journals or checkpoints in ``root`` hold (``recover(dataset, remove)``
        adds them, returns their ids); for a URL they are published first and only then discarded."""
        if not self.url:
            self.taken |= set(recover(Path(self.location), True))
            return
        if not root.is_dir():
            return
        try:
            with self.writing() as ds:
                ids = recover(ds, False)
                if not ids:
                    raise _NothingAdded
        except _NothingAdded:
            discard(root, [])
            return
        discard(root, ids)
        self.taken |= set(ids)


def flight_ids(path: str | Path | None) -> set[str]:
    """The flight ids of the dataset at local ``path`` (none when there is no dataset there)."""
    if path is None or not is_dataset(Path(path)):
        return set()
    return set(open_dataset(path).manifest["flight_id"].astype(str))


def save_recording(record: FlightRecord, out: str | Path, fmt: str = "parquet") -> Path:
    """Write the flight into dataset ``out``: appended when ``out`` is a dataset, else a new one."""
    out = Path(out)
    if record.navigator == {}:
        raise DatasetError(f"{out}: nothing was recorded (no telemetry of a known topic passed the proxy)")
    return append_flights(out, [record], fmt=fmt, info={"profile": "live", "source": LIVE_SOURCE})


# -- written as it flies -------------------------------------------------------------------------

#: Seconds (wall clock) between two checkpoints of a live recording.
CHECKPOINT_S = 5.0
JOURNAL_SUFFIX = ".proxy-recording"


def journal_root(dataset: str | Path) -> Path:
    """The folder beside dataset ``dataset`` that holds the checkpoints of its live recordings."""
    dataset = Path(dataset).resolve()
    return dataset.with_name(dataset.name + JOURNAL_SUFFIX)


class RecordingCheckpoint:
    """``proxy --record`` written as it flies: every :data:`CHECKPOINT_S` the flight seen so far is
    written, whole and atomically, as a one-flight dataset beside the recording's dataset
    (``DIR.proxy-recording/FLIGHT_ID``, marked incomplete). A proxy that stops normally writes the
    flight and removes its checkpoint; one that is killed, or whose final write fails, leaves it,
    and the next ``proxy --record DIR`` adds it to ``DIR`` (:func:`recover_recordings`)."""

    def __init__(self, proxy, dataset: str | Path, flight_id: str, extra_config: dict,
                 period_s: float = CHECKPOINT_S, log=None):
        self.proxy = proxy
        self.flight_id = flight_id
        self.extra_config = extra_config
        self.period_s = period_s
        self.folder = journal_root(dataset) / flight_id
        self.log = log or (lambda msg: None)
        self._last = time.monotonic()
        self._failed = False

    def maybe(self) -> None:
        """Write a checkpoint when the last one is older than the period (called by the serve loop)."""
        if time.monotonic() - self._last >= self.period_s:
            self.write()

    def write(self) -> None:
        from scart_bench.dataset import DatasetWriter, replacing

        self._last = time.monotonic()
        record = proxy_record(self.proxy, self.flight_id, {
            **self.extra_config, "incomplete": True,
            "incomplete_reason": "the proxy stopped before it wrote the recording (killed, or the write failed); "
                                 "the flight up to its last checkpoint"})
        if record.navigator == {}:
            return
        try:
            self.folder.parent.mkdir(parents=True, exist_ok=True)
            with replacing(self.folder) as partial:
                writer = DatasetWriter(partial, info={"profile": "live", "source": LIVE_SOURCE, "checkpoint": True})
                try:
                    writer.write(record)
                except BaseException:
                    writer.abort()
                    raise
                writer.close()
        except OSError as exc:  # a full disk: the flight goes on, the last good checkpoint stays
            if not self._failed:
                self.log(f"proxy: cannot write the recording's checkpoint in {self.folder} ({exc.strerror or exc}); "
                         "the flight goes on")
            self._failed = True

    def discard(self) -> None:
        """The recording was written: its checkpoint goes."""
        shutil.rmtree(self.folder, ignore_errors=True)
        with contextlib.suppress(OSError):
            self.folder.parent.rmdir()  # only when empty


def _record_of(ds, flight_id: str) -> FlightRecord:
    """A written flight read back as the record it was written from."""
    from scart_bench.dataset import compact

    views = {v: {t: ds.topic(flight_id, t, v) for t in ds.topics(flight_id, v)} for v in ("navigator", "simulator")}
    meta = compact.read_meta(ds.flight_dir(flight_id) / "navigator.parquet")
    windows = [tuple(w) for w in meta.get("windows", [])]
    row = ds.manifest.set_index("flight_id").loc[flight_id].to_dict()
    manifest = {k: v for k, v in row.items() if k not in ("rows", "duration_s", "checksum", "attack_start_us",
                                                          "attack_end_us") and not _missing(v)}
    events = ds.events(flight_id).to_dict("records")
    end_us = int(round(float(row["duration_s"]) * 1e6))
    return flight_record(flight_id, views["navigator"], views["simulator"], manifest, ds.config(flight_id), windows,
                         events, end_us=end_us)


def _missing(v) -> bool:
    try:
        return bool(pd.isna(v))
    except (TypeError, ValueError):
        return False


def recover_recordings(dataset: str | Path, log=None, root: Path | None = None, remove: bool = True,
                       shown: str | None = None) -> list[str]:
    """Add the checkpoints a killed ``proxy --record DATASET`` left (flights marked incomplete) to
    ``dataset``; returns their flight ids. ``root``: the folder of checkpoints when not the one
    beside ``dataset`` (a dataset at a URL); ``remove=False``: the checkpoints of the flights added
    stay until the caller has published the dataset (:func:`discard_checkpoints`)."""
    log = log or (lambda msg: None)
    root = root if root is not None else journal_root(dataset)
    shown = shown or str(dataset)
    if not root.is_dir():
        return []
    added = []
    taken = flight_ids(dataset)
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if not is_dataset(folder):
            shutil.rmtree(folder, ignore_errors=True)  # a checkpoint that never completed
            continue
        ds = open_dataset(folder)
        fresh = False
        for fid in ds.manifest["flight_id"].astype(str):
            if fid in taken:
                continue  # written after all (the process died after the write, before the cleanup)
            append_flights(dataset, [_record_of(ds, fid)], info={"profile": "live", "source": LIVE_SOURCE})
            taken.add(fid)
            added.append(fid)
            fresh = True
            log(f"proxy: added {fid}, an interrupted recording (incomplete: up to its last checkpoint), to {shown}")
        if remove or not fresh:
            shutil.rmtree(folder, ignore_errors=True)
    with contextlib.suppress(OSError):
        root.rmdir()
    return added


def discard_checkpoints(root: Path, flight_ids: list[str]) -> None:
    """Remove the checkpoints of ``flight_ids`` (added to the dataset and published) from ``root``,
    and ``root`` when it is left empty."""
    for fid in flight_ids:
        shutil.rmtree(root / fid, ignore_errors=True)
    with contextlib.suppress(OSError):
        root.rmdir()
