"""``scart-bench proxy``: the SCART layer live on a MAVLink link, with recording and online detection.

The engine is :mod:`scart_bench.generator.mavlink.proxy`; this module parses the options, loads the
scenario, fits the detector of a benchmark run (runs keep scores, not fitted models: the named
detector is fitted again on the run's training flights with the run's parameters and seed, and
its row threshold is calibrated from the run's saved validation scores with the run's protocol),
runs the proxy until Ctrl-C (or ``--duration``) and writes the recording.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from scart_bench.benchmark.errors import UsageError


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _require_mavlink():
    try:
        from scart_bench.generator.mavlink import proxy
    except ImportError as exc:
        raise UsageError(f"the MAVLink proxy needs pymavlink, which is not installed: "
                         f"pip install scart-bench[mavlink] ({exc})") from exc
    return proxy


def build_monitor(run: Path, name: str, log=_log):
    """A :class:`scart_bench.generator.mavlink.monitor.StreamMonitor` for detector ``name`` of benchmark run ``run``."""
    import numpy as np

    from scart_bench.benchmark.protocol import Protocol
    from scart_bench.benchmark.store import RunStore
    from scart_bench.detectors import registry
    from scart_bench.generator.dataset import open_dataset
    from scart_bench.generator.mavlink.monitor import StreamMonitor

    store = RunStore(run)
    if not store.exists():
        raise UsageError(f"--run {run}: not a benchmark run folder (no config.json)")
    config = store.read_config()
    status = store.read_status(name)
    if not status or status.get("status") != "OK":
        done = [d for d in store.job_names() if (store.read_status(d) or {}).get("status") == "OK"]
        raise UsageError(f"--detector {name!r}: run {run} has no finished (OK) job for it; "
                         f"finished: {', '.join(done) or '(none)'}")
    params = (store.read_params(name) or {}).get("params", {})
    for spec in config.get("plugins", []):
        registry.load_plugin(spec)
    flights = store.read_flights()
    train = flights.loc[flights["role"] == "train", "flight_id"].astype(str).tolist()
    validation = flights.loc[flights["role"] == "validation", "flight_id"].astype(str).tolist()
    dataset = config.get("dataset", {}).get("path")
    if not dataset or not Path(dataset).exists():
        raise UsageError(f"--run {run}: its dataset {dataset!r} is gone; the detector cannot be fitted again")
    ds = open_dataset(dataset)
    det = registry.make(name, **params)
    log(f"proxy: fitting {name} on the {len(train)} training flights of run {run} ...")
    t0 = time.perf_counter()
    det.fit([ds.flight(fid) for fid in train])
    scores = store.read_scores(name)
    missing = [fid for fid in validation if fid not in scores]
    if missing:
        raise UsageError(f"--run {run}: detector {name} has no saved scores for validation flight {missing[0]}")
    protocol = Protocol.from_dict(config["protocol"])
    _, row_threshold = protocol.thresholds({fid: np.asarray(scores[fid]) for fid in validation})
    log(f"proxy: {name} fitted in {time.perf_counter() - t0:.1f} s; row threshold {row_threshold:.4g} "
        f"({protocol.row_rule.describe()})")
    return StreamMonitor(det, row_threshold, name=name, log=log)


def cmd_proxy(args: argparse.Namespace) -> int:
    px = _require_mavlink()
    from scart_bench.generator.dataset import is_dataset
    from scart_bench.generator.mavlink.recording import new_flight_id, save_recording
    from scart_bench.generator.scart.scenario import load_scenarios

    listen = px.parse_endpoint(args.listen, "--listen")
    forward = px.parse_endpoint(args.forward, "--forward")
    if not Path(args.scenario).is_file():
        raise UsageError(f"--scenario {args.scenario}: no such file")
    if (args.detector is None) != (args.run is None):
        raise UsageError("--detector and --run go together: the detector is the one fitted in that benchmark run")
    if args.duration is not None and args.duration <= 0:
        raise UsageError(f"--duration {args.duration}: expected a positive number of seconds")
    record = Path(args.record) if args.record else None
    if record is not None and record.exists():
        if not record.is_dir():
            raise UsageError(f"--record {record}: exists and is not a folder")
        if any(record.iterdir()) and not is_dataset(record):
            raise UsageError(f"--record {record}: not empty and not a scart-bench dataset (no manifest); "
                             "give a new folder or an existing dataset to add the flight to")
    scenarios = load_scenarios(args.scenario)
    monitor = build_monitor(Path(args.run), args.detector) if args.detector else None

    proxy = px.MavlinkProxy(listen, forward, scenarios, seed=args.seed, record=record is not None,
                            monitor=monitor, log=_log).open()
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    timer = threading.Timer(args.duration, stop.set) if args.duration else None
    host, port = proxy.listen_address
    _log(f"proxy: listening on udp:{host}:{port}, forwarding to udp:{forward[0]}:{forward[1]}; scenario "
         f"{', '.join(s.id for s in scenarios)} on {', '.join(sorted(proxy.layer_topics)) or 'no topic'}; "
         "Ctrl-C stops")
    t0 = time.monotonic()
    try:
        if timer is not None:
            timer.start()
        proxy.serve(stop)
    finally:
        if timer is not None:
            timer.cancel()
        for s, h in old.items():
            signal.signal(s, h)
        proxy.close()
    wall = time.monotonic() - t0
    _log(f"proxy: stopped after {wall:.1f} s: {px.stats_line(proxy.stats, wall)}")
    for s, e in proxy.windows():
        _log(f"proxy: attack window {s / 1e6:.2f} s - {e / 1e6:.2f} s (flight time)")
    if monitor is not None:
        monitor.flush()
        _log(f"proxy: {monitor.summary()}")
    if record is not None:
        fid = args.flight_id or new_flight_id(record)
        extra = {"scenario_file": str(args.scenario)}
        if monitor is not None:
            extra["detector"] = {"name": args.detector, "run": str(args.run), "threshold": monitor.threshold,
                                 "alarm_rows": len(monitor.alarms)}
        path = save_recording(proxy.record(fid, json.loads(json.dumps(extra))), record, fmt=args.format)
        print(f"flight {fid} recorded in {record} ({path.name})")
    return 0


def register(sub) -> None:
    from scart_bench.generator.mavlink import DEFAULT_FORWARD, DEFAULT_LISTEN

    p = sub.add_parser("proxy", help="live MAVLink man-in-the-middle: run a scenario on an autopilot link",
                       description="A MAVLink 2 proxy between an autopilot (telemetry in on --listen) and a "
                       "mission computer (--forward): the scenario's topics are decoded, attacked by the SCART "
                       "layer and re-encoded; all other traffic, both ways, passes byte-identical. Needs "
                       "pymavlink (pip install scart-bench[mavlink]).")
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="udp:HOST:PORT",
                   help=f"where the autopilot sends its telemetry (default {DEFAULT_LISTEN}; loopback unless "
                        "told otherwise)")
    p.add_argument("--forward", default=DEFAULT_FORWARD, metavar="udp:HOST:PORT",
                   help=f"where the mission computer listens (default {DEFAULT_FORWARD})")
    p.add_argument("--scenario", required=True, metavar="FILE", help="a scenario file (TOML), points link/command")
    p.add_argument("--seed", type=int, default=0, help="seed of the scenario's random draws (default 0)")
    p.add_argument("--record", metavar="DIR", help="write the flight (both views, labels) into this dataset: "
                   "added to an existing dataset, or a new one")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    p.add_argument("--flight-id", help="flight id of the recording (default live-<UTC time>)")
    p.add_argument("--detector", metavar="NAME", help="score the navigator-side stream with this detector of --run")
    p.add_argument("--run", metavar="RUN", help="the benchmark run folder the detector comes from")
    p.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this many seconds (default: Ctrl-C)")
    p.set_defaults(func=cmd_proxy)
