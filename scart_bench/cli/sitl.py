"""``scart-bench sitl``: a simulated PX4-like vehicle that any MAVLink tool can fly, with the SCART layer.

The engine is :mod:`scart_bench.generator.sitl.server`; this module parses the options, loads the
scenario, runs the vehicle until Ctrl-C (or ``--duration`` of simulated time) and writes the
recording.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from scart_bench.cli.common import RESPONSES, UsageError, record_folder
from scart_bench.names import check_id

DEFAULT_LISTEN = "udp:127.0.0.1:14580"


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cmd_sitl(args: argparse.Namespace) -> int:
    from scart_bench.generator.mavlink import parse_endpoint
    from scart_bench.generator.sitl.endpoint import bind_udp

    listen = parse_endpoint(args.listen, "--listen")
    remote = parse_endpoint(args.remote, "--remote") if args.remote else None
    _check_options(args)
    sock = bind_udp(listen)  # before the slow imports: a datagram arriving meanwhile waits in the socket
    try:
        return _run(args, listen, remote, sock)
    finally:
        sock.close()


def _check_options(args: argparse.Namespace) -> None:
    if args.scenario is not None and not Path(args.scenario).is_file():
        raise UsageError(f"--scenario {args.scenario}: no such file")
    if args.duration is not None and args.duration <= 0:
        raise UsageError(f"--duration {args.duration}: expected a positive number of seconds")
    if args.speed <= 0:
        raise UsageError(f"--speed {args.speed}: expected a positive factor (1.0 = real time)")
    if len({args.detector is None, args.run is None, args.response is None}) > 1:
        raise UsageError("--detector, --run and --response go together: the detector fitted in that benchmark run "
                         "and what the flight controller does on its alarm")
    if args.alarms < 1:
        raise UsageError(f"--alarms {args.alarms}: expected a whole number >= 1")
    if args.flight_id is not None:
        check_id(args.flight_id, "--flight-id")


def _run(args: argparse.Namespace, listen, remote, sock) -> int:
    try:
        from scart_bench.generator.sitl.server import SitlServer
    except ImportError as exc:
        raise UsageError(f"the sitl needs pymavlink, which is not installed: pip install scart-bench[mavlink] "
                         f"({exc})") from exc
    from scart_bench.generator.mavlink.recording import RecordTarget, new_flight_id, save_recording
    from scart_bench.generator.scart.scenario import load_scenarios
    from scart_bench.generator.sitl.journal import Journal, discard, journal_root, recover
    from scart_bench.storage import StorageError

    target = RecordTarget(args.record, record_folder) if args.record else None
    scenarios = load_scenarios(args.scenario) if args.scenario else []
    if scenarios and args.split != "test":
        raise UsageError(f"--split {args.split}: an attacked flight (--scenario) is always a test flight")
    defense = _defense(args) if args.detector else None
    sitl = SitlServer(listen, scenarios, seed=args.seed, remote=remote, record=target is not None, log=_log,
                      sock=sock, defense=defense)
    fid = None
    extra = {"scenario_file": args.scenario}
    if defense is not None:
        extra["defense"] = {"detector": args.detector, "run": str(args.run), "threshold": defense.monitor.threshold,
                            "response": args.response, "alarms": args.alarms}
    if target is not None:
        root = journal_root(target.anchor)  # flights of earlier recordings that only their journals hold
        target.add_left(root, lambda ds, remove: recover(ds, lambda rec: save_recording(rec, ds, fmt=args.format),
                                                         _log, root=root, remove=remove, shown=target.shown),
                        discard)
        kept = {p.name for p in root.iterdir()} if root.is_dir() else set()  # journals that could not be added
        fid = args.flight_id or new_flight_id(prefix="sitl", taken=target.taken | kept)
        if fid in target.taken:
            raise UsageError(f"--flight-id {fid}: {target.shown} holds a flight {fid} already; give another id")
        if fid in kept:
            raise UsageError(f"--flight-id {fid}: the journal {root / fid} holds flight {fid}, not yet added to "
                             f"{target.shown} (see the line above); give another id, so that it is kept")
        sitl.journal = Journal(target.anchor, fid, extra, args.split, _log)
        try:
            sitl.journal.start(sitl)
        except OSError as exc:
            sitl.journal.remove()
            raise UsageError(f"--record {target.shown}: its journal {sitl.journal.folder} cannot be written "
                             f"({exc.strerror or exc}), so a flight whose final write failed would be lost; free "
                             "space there or record elsewhere") from None
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    host, port = sitl.address
    pace = "lockstep (as fast as it can, from the first client message)" if args.lockstep else \
        f"{args.speed:g} x real time"
    attack = ", ".join(s.id for s in scenarios) or "none"
    _log(f"sitl: listening on udp:{host}:{port}" + (f", sending to udp:{remote[0]}:{remote[1]}" if remote else "")
         + f"; PX4-like quadrotor, system 1 component 1; {pace}; scenario {attack}; Ctrl-C stops")
    t0 = time.monotonic()
    try:
        sitl.serve(stop, speed=None if args.lockstep else args.speed, duration_s=args.duration)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        sitl.close()
    wall = time.monotonic() - t0
    if defense is not None:
        defense.monitor.flush()
        _log(f"sitl: {defense.monitor.summary()}")
    _log(f"sitl: stopped after {sitl.time_s:.1f} s of flight ({wall:.1f} s wall): {sitl.stats.summary()}")
    for s, e in sitl.windows():
        _log(f"sitl: attack window {s / 1e6:.2f} s - {e / 1e6:.2f} s (flight time)")
    if target is None:
        return 0
    if sitl.plant.step_index == 0:
        sitl.journal.remove()
        _log("sitl: nothing to record: the simulation never ran (no client was heard in --lockstep)")
        return 0
    sitl.journal.flush(sitl)
    try:
        with target.writing() as ds:  # a URL: written in a local copy, published manifest last
            path = save_recording(sitl.record(fid, extra, split=args.split), ds, fmt=args.format)
    except (OSError, StorageError):
        _kept_or_lost(sitl.journal, target, fid, sitl.time_s)
        raise
    sitl.journal.remove()
    print(f"flight {fid} recorded in {target.shown} ({path.name})")
    return 0


def _kept_or_lost(journal, target, fid: str, flown_s: float) -> None:
    """The final write failed: say exactly what the journal keeps (and that the next --record adds
    it), or that it keeps nothing and the flight is lost (its empty journal goes)."""
    kept = journal.kept_us / 1e6
    if not any(journal.rows.values()):
        journal.remove()
        _log(f"sitl: the flight could not be written into {target.shown}, and its journal {journal.folder} could "
             f"not keep any of it either (its writes failed): the {flown_s:.1f} s flown are lost")
        return
    part = "all of it" if not journal.failed else f"its first {kept:.1f} s (the last flush that could be written)"
    _log(f"sitl: the flight could not be written into {target.shown}; its journal {journal.folder} keeps {part} of "
         f"the {flown_s:.1f} s flown, and the next `scart-bench sitl --record {target.shown}` adds it as flight "
         f"{fid}, marked incomplete")


def _defense(args: argparse.Namespace):
    """The run's detector (refitted, its threshold calibrated) watching the navigator's view, with the response;
    refused in one line when it cannot score rows as fast as the link brings them."""
    from scart_bench.benchmark.defense import require_link_rate
    from scart_bench.benchmark.live import monitor_from_run
    from scart_bench.generator.defense import LiveDefense, Response

    monitor = monitor_from_run(Path(args.run), args.detector, list(args.plugin or []), log=_log, command="sitl")
    rate = require_link_rate(args.detector, monitor.detector, where="the live loop")
    _log(f"sitl: {args.detector} scores {rate:.0f} rows/s row by row; on {args.alarms} alarm row(s) the flight "
         f"controller takes {args.response}")
    return LiveDefense(monitor, Response(args.response, alarms=args.alarms))


def register(sub) -> None:
    p = sub.add_parser("sitl", help="a simulated PX4-like vehicle any MAVLink tool can fly (SCART layer on its link)",
                       description="One simulated quadrotor (the generator's physics, sensors, estimator and "
                       "controller) behind a MAVLink 2 endpoint that speaks like PX4: heartbeat and telemetry, "
                       "commands, missions, parameters and offboard setpoints. A --scenario runs on its link "
                       "(telemetry to the client, setpoints to the controller) or on its physics. Needs "
                       "pymavlink. See docs/sitl.md.")
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="udp:HOST:PORT",
                   help=f"where the vehicle binds; clients connect here (default {DEFAULT_LISTEN})")
    p.add_argument("--remote", metavar="udp:HOST:PORT",
                   help="also send telemetry here from the start (PX4's -o port, e.g. udp:127.0.0.1:14540 for "
                        "MAVSDK's default udpin://0.0.0.0:14540)")
    p.add_argument("--scenario", metavar="FILE",
                   help="a scenario file (TOML): link, command, sensor, environment or vehicle point")
    p.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall-clock second (default 1)")
    p.add_argument("--lockstep", action="store_true",
                   help="no wall-clock pacing: run as fast as the simulation can, from the first client message")
    p.add_argument("--seed", type=int, default=0, help="seed of the wind, sensor errors and scenario draws")
    p.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this much simulated time")
    p.add_argument("--record", metavar="DIR|URL", help="write the flight (both views, truth, labels) into this "
                   "dataset: a folder or a URL such as s3://bucket/prefix, added to a dataset there")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    p.add_argument("--flight-id", help="flight id of the recording (default sitl-<UTC time>)")
    p.add_argument("--split", choices=("train", "validation", "test"), default="test",
                   help="split of a recorded normal flight (attacked flights are always test)")
    p.add_argument("--detector", metavar="NAME", help="defense in the loop: this detector of --run scores what the "
                   "navigator receives; on its alarm the flight controller takes --response (docs/defense.md)")
    p.add_argument("--run", metavar="RUN", help="the benchmark run folder the detector comes from")
    p.add_argument("--response", choices=RESPONSES, help="what the flight controller does on the anomaly notice")
    p.add_argument("--alarms", type=int, default=1, metavar="N", help="alarm rows before the response (default 1)")
    p.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a plugin detector from module:Class or file.py:Class")
    p.set_defaults(func=cmd_sitl)
