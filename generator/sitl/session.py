"""A live sitl flight from start to recording, as ``scart-bench sitl`` runs it, callable without the command line.

:func:`run_sitl` takes a bound socket, the scenarios and (optionally) where to record and a live defense; it
serves MAVLink clients until ``stop`` is set, ``duration_s`` of simulated time passes or (from the main
thread) SIGINT/SIGTERM, then writes the flight (journalled while it flies, so an interrupted recording
keeps the flown part).
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from scart_bench.generator.sitl.endpoint import SitlError
from scart_bench.progress import log_to_stderr


@dataclass
class SitlRun:
    """What :func:`run_sitl` did: seconds flown and of wall time, the flight it recorded (id, file)."""

    flown_s: float
    wall_s: float
    flight_id: str | None = None
    path: Path | None = None
    #: why the flight ended early: the plant's simulator ended or went silent (the flown part is recorded)
    error: str | None = None


def run_sitl(listen: tuple[str, int], scenarios: list, *, sock, seed: int = 0, remote: tuple[str, int] | None = None,
             record=None, flight_id: str | None = None, split: str = "test", fmt: str = "parquet", defense=None,
             extra: dict | None = None, speed: float | None = 1.0, duration_s: float | None = None,
             stop: threading.Event | None = None, log: Callable[[str], None] = log_to_stderr, plant=None) -> SitlRun:
    """Fly one simulated PX4-like vehicle on ``sock`` (bound to ``listen``); ``speed``: the pace in real time,
    None for lockstep (as fast as it can, from the first client message). ``record``: a
    :class:`~scart_bench.generator.mavlink.recording.RecordTarget` (flights earlier recordings left in their
    journals are added first); ``defense``: a :class:`~scart_bench.generator.defense.LiveDefense`;
    ``extra``: the recording's extra config; ``plant``: the vehicle (default the built-in physics; a started
    :class:`~scart_bench.generator.sitl.jmavsim_plant.JmavsimPlant` flies jMAVSim; the caller closes it)."""
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.mavlink.recording import new_flight_id, save_recording
    from scart_bench.generator.sitl.journal import Journal, discard, journal_root, recover
    from scart_bench.generator.sitl.server import SitlServer
    from scart_bench.storage import StorageError

    sitl = SitlServer(listen, scenarios, seed=seed, remote=remote, record=record is not None, log=log,
                      sock=sock, defense=defense, plant=plant)
    fid = None
    extra = {} if extra is None else extra
    if record is not None:
        root = journal_root(record.anchor)  # flights of earlier recordings that only their journals hold
        record.add_left(root, lambda ds, remove: recover(ds, lambda rec: save_recording(rec, ds, fmt=fmt),
                                                         log, root=root, remove=remove, shown=record.shown),
                        discard)
        kept = {p.name for p in root.iterdir()} if root.is_dir() else set()  # journals that could not be added
        fid = flight_id or new_flight_id(prefix="sitl", taken=record.taken | kept)
        if fid in record.taken:
            raise SitlError(f"--flight-id {fid}: {record.shown} holds a flight {fid} already; give another id")
        if fid in kept:
            raise SitlError(f"--flight-id {fid}: the journal {root / fid} holds flight {fid}, not yet added to "
                            f"{record.shown} (see the line above); give another id, so that it is kept")
        sitl.journal = Journal(record.anchor, fid, extra, split, log)
        try:
            sitl.journal.start(sitl)
        except OSError as exc:
            sitl.journal.remove()
            raise SitlError(f"--record {record.shown}: its journal {sitl.journal.folder} cannot be written "
                            f"({exc.strerror or exc}), so a flight whose final write failed would be lost; free "
                            "space there or record elsewhere") from None
    stop = threading.Event() if stop is None else stop

    def on_signal(signum, frame):
        stop.set()

    main_thread = threading.current_thread() is threading.main_thread()  # signals are the main thread's
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    host, port = sitl.address
    pace = "lockstep (as fast as it can, from the first client message)" if speed is None else f"{speed:g} x real time"
    attack = ", ".join(s.id for s in scenarios) or "none"
    physics = f" flying {plant.where()}" if hasattr(plant, "where") else ""
    log(f"sitl: listening on udp:{host}:{port}" + (f", sending to udp:{remote[0]}:{remote[1]}" if remote else "")
        + f"; PX4-like quadrotor{physics}, system 1 component 1; {pace}; scenario {attack}; Ctrl-C stops")
    t0 = time.monotonic()
    lost = None
    try:
        sitl.serve(stop, speed=speed, duration_s=duration_s)
    except HilError as exc:  # an external simulator ended or went silent: what was flown is still recorded
        lost = str(exc)
        log(f"sitl: {lost}; the flight ends here")
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        sitl.close()
    wall = time.monotonic() - t0
    if defense is not None:
        defense.monitor.flush()
        log(f"sitl: {defense.monitor.summary()}")
    log(f"sitl: stopped after {sitl.time_s:.1f} s of flight ({wall:.1f} s wall): {sitl.stats.summary()}")
    for s, e in sitl.windows():
        log(f"sitl: attack window {s / 1e6:.2f} s - {e / 1e6:.2f} s (flight time)")
    outcome = SitlRun(sitl.time_s, wall, error=lost)
    if record is None:
        return outcome
    if sitl.plant.step_index == 0:
        sitl.journal.remove()
        log("sitl: nothing to record: the simulation never ran (no client was heard in --lockstep)")
        return outcome
    sitl.journal.flush(sitl)
    try:
        with record.writing() as ds:  # a URL: written in a local copy, published manifest last
            outcome.path = save_recording(sitl.record(fid, extra, split=split), ds, fmt=fmt)
    except (OSError, StorageError):
        _kept_or_lost(sitl.journal, record, fid, sitl.time_s, log)
        raise
    sitl.journal.remove()
    outcome.flight_id = fid
    return outcome


def _kept_or_lost(journal, target, fid: str, flown_s: float, log: Callable[[str], None]) -> None:
    """The final write failed: say exactly what the journal keeps (and that the next --record adds
    it), or that it keeps nothing and the flight is lost (its empty journal goes)."""
    kept = journal.kept_us / 1e6
    if not any(journal.rows.values()):
        journal.remove()
        log(f"sitl: the flight could not be written into {target.shown}, and its journal {journal.folder} could "
            f"not keep any of it either (its writes failed): the {flown_s:.1f} s flown are lost")
        return
    part = "all of it" if not journal.failed else f"its first {kept:.1f} s (the last flush that could be written)"
    log(f"sitl: the flight could not be written into {target.shown}; its journal {journal.folder} keeps {part} of "
        f"the {flown_s:.1f} s flown, and the next `scart-bench sitl --record {target.shown}` adds it as flight "
        f"{fid}, marked incomplete")
