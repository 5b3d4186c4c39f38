"""The ROS nodes' run loops, as ``scart-bench ros`` runs them, callable without the command line.

:func:`run_node` (the SCART layer between MAVROS and the mission computer, with its recording),
:func:`run_mavros` (the MAVROS stand-in bridging a MAVLink endpoint) and :func:`run_navigator` (the
mission computer flying the square) join the ROS master as ``name``, run until ``stop`` is set, their
time is up or (from the main thread) SIGINT/SIGTERM, and report what they did through ``log``.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from scart_bench.generator.ros import RosError
from scart_bench.progress import log_to_stderr


def _ros1():
    from scart_bench.generator.ros import ros1

    return ros1


def run_until(stop: threading.Event, duration: float | None, done: threading.Event | None = None) -> bool:
    """Wait for ``stop`` (set by SIGINT/SIGTERM when called from the main thread), ``duration`` wall seconds
    or ``done``; True when ``done`` was set."""
    main_thread = threading.current_thread() is threading.main_thread()  # signals are the main thread's
    old = ({s: signal.signal(s, lambda signum, frame: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
           if main_thread else {})
    end = time.monotonic() + duration if duration else math.inf
    try:
        while not stop.is_set() and time.monotonic() < end:
            if done is not None and done.is_set():
                return True
            stop.wait(0.05)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    return done is not None and done.is_set()


@dataclass
class NodeRun:
    """What :func:`run_node` did: seconds it ran, the flight it recorded (id, file)."""

    wall_s: float
    flight_id: str | None = None
    path: Path | None = None


def run_node(scenarios: list, input_ns: str, output_ns: str, *, name: str = "scart", seed: int = 0, record=None,
             flight_id: str | None = None, split: str = "test", fmt: str = "parquet", extra: dict | None = None,
             duration_s: float | None = None, stop: threading.Event | None = None,
             log: Callable[[str], None] = log_to_stderr) -> NodeRun:
    """The SCART node on the MAVROS topics under ``input_ns``, republished under ``output_ns``; ``record``:
    a :class:`~scart_bench.generator.mavlink.recording.RecordTarget` the flight is written to at the end,
    with ``extra`` in its config."""
    from scart_bench.generator.mavlink.recording import new_flight_id
    from scart_bench.generator.ros.layer import RosLayer, save_recording

    if record is not None and flight_id in record.taken:
        raise RosError(f"--flight-id {flight_id}: {record.shown} holds a flight {flight_id} already; give another id")
    layer = RosLayer(scenarios, seed=seed, record=record is not None)
    ros1 = _ros1()
    ros1.init_node(name)
    node = ros1.ScartNode(layer, input_ns, output_ns, log=log).start()
    log(
        f"ros node: {input_ns} -> {output_ns}; scenario {', '.join(s.id for s in scenarios) or 'none'} on "
        f"{', '.join(sorted(layer.used)) or 'no topic'}; Ctrl-C stops"
    )
    t0 = time.monotonic()
    try:
        run_until(threading.Event() if stop is None else stop, duration_s)
    finally:
        node.stop()
    outcome = NodeRun(time.monotonic() - t0)
    log(
        f"ros node: stopped after {outcome.wall_s:.1f} s: {layer.stats.summary()}; {node.relayed} setpoints, "
        "commands and states relayed"
    )
    for text in layer.log_errors:
        log(f"ros node: error in the layer ({text}); the message passed unchanged")
    for s, e in layer.windows():
        log(f"ros node: attack window {s / 1e6:.2f} s - {e / 1e6:.2f} s (flight time)")
    if record is not None:
        fid = flight_id or new_flight_id(prefix="ros", taken=record.taken)
        rec = layer.record(fid, json.loads(json.dumps(extra or {})), split=split)
        with record.writing() as ds:  # a URL: written in a local copy, published with its manifest last
            outcome.path = save_recording(rec, ds, fmt=fmt)
        outcome.flight_id = fid
    return outcome


def run_mavros(connect: tuple[str, int], *, ns: str = "/mavros", name: str = "mavros",
               duration_s: float | None = None, stop: threading.Event | None = None,
               log: Callable[[str], None] = log_to_stderr) -> None:
    """The MAVROS stand-in: the MAVLink endpoint ``connect`` (``scart-bench sitl``) on MAVROS topics under ``ns``."""
    ros1 = _ros1()
    ros1.init_node(name)
    standin = ros1.MavrosStandIn(connect, ns=ns, log=log).start()
    log(f"mavros stand-in: udp:{connect[0]}:{connect[1]} -> {ns}; Ctrl-C stops")
    stop = threading.Event() if stop is None else stop
    reader = threading.Thread(target=standin.spin, args=(stop,), name="mavlink-reader", daemon=True)
    reader.start()
    try:
        run_until(stop, duration_s)
    finally:
        stop.set()
        reader.join(timeout=2.0)
        standin.close()
    counts = ", ".join(f"{k} {v}" for k, v in sorted(standin.counts.items()))
    log(f"mavros stand-in: stopped; published {counts or 'nothing'}; {standin.setpoints} setpoints sent")


def run_navigator(*, ns: str = "/scart", name: str = "navigator", monitor=None, notice_topic: str | None = None,
                  timeout_s: float | None = None, stop: threading.Event | None = None,
                  log: Callable[[str], None] = log_to_stderr) -> bool:
    """The mission computer flying the square from the telemetry under ``ns`` (``monitor``: a live detector whose
    alarms go out on ``notice_topic``); True when the mission was flown, landed and disarmed."""
    ros1 = _ros1()
    ros1.init_node(name)
    nav = ros1.NavigatorNode(ns=ns, monitor=monitor, notice_topic=notice_topic, log=log).start()
    log(f"navigator: flying the square from {ns}; Ctrl-C stops")
    try:
        done = run_until(threading.Event() if stop is None else stop, timeout_s, nav.done)
    finally:
        nav.close()
    for t, what in nav.mission.log:
        log(f"navigator: t={t:.2f} s {what}")
    if monitor is not None:
        monitor.flush()
        log(f"navigator: {monitor.summary()}; {nav.notices} anomaly notices published on {notice_topic}")
    if not done:
        log(f"navigator: the mission did not finish (phase {nav.mission.phase})")
    return done
