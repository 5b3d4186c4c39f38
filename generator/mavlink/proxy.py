"""The live MAVLink man-in-the-middle: the SCART layer on a real autopilot <-> mission-computer link.

::

    autopilot --telemetry--> [listen]  proxy  [forward] --telemetry--> mission computer
    autopilot <--commands--- [listen]  proxy  [forward] <--commands--- mission computer

The proxy receives the autopilot's datagrams on the ``listen`` address (it learns the autopilot's
address from them) and sends telemetry on to the ``forward`` address from a second socket, on
which the mission computer's commands come back. Each datagram is cut into frames
(:func:`scart_bench.generator.mavlink.codec.split_frames`); malformed pieces are counted and dropped. A
frame of a topic the scenarios use is decoded, passed through the same
:class:`scart_bench.generator.scart.layer.AttackLayer` as in simulation mode (a batch of one flight, point
``link`` for telemetry and ``command`` for setpoints), and forwarded: the received bytes when the
layer left the values as they were, a re-encoded frame (same header, only the changed fields
rewritten) when it altered them, nothing when it dropped the message. Every other frame, in
both directions, is forwarded byte for byte; a datagram whose frames all pass is forwarded as
received.

The layer's clock is the autopilot's: the message timestamps (``time_boot_ms``/``time_usec``),
counted from the first one seen, never decreasing; messages without a timestamp take the last.
"""

from __future__ import annotations

import json
import math
import selectors
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.errors import ScartBenchError
from scart_bench.generator.flight_software.commander import empty_command
from scart_bench.generator.mavlink import DEFAULT_FORWARD, DEFAULT_LISTEN, parse_endpoint  # noqa: F401  (re-exported)
from scart_bench.generator.mavlink.codec import (
    BY_MSGID,
    CODECS,
    COMMAND_LONG_ID,
    HEARTBEAT_ID,
    KNOWN,
    STATE_MESSAGES,
    SYSTEM_TIME_ID,
    LinkState,
    Packer,
    split_frames,
)
from scart_bench.generator.scart.handling import HandlingStats
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.progress import log_to_stderr

#: the injection points a proxy on the link can serve
LINK_POINTS = ("link", "command")
_MAX_DATAGRAM = 65535
_DRAIN = 64  # datagrams read from one socket before looking at the other
#: How far (µs) a message timestamp may run ahead of the wall time elapsed since the last accepted one
#: (twice the wall time, plus this): enough for bursts and a stalled proxy, not for a far-future stamp.
MAX_CLOCK_LEAD_US = 5_000_000


class ProxyError(ScartBenchError):
    """The proxy cannot be set up as asked (bad address, unusable scenario, port in use)."""


def _is_loopback(host: str) -> bool:
    return host == "localhost" or host.startswith("127.") or host == "::1"


@dataclass
class ProxyStats(HandlingStats):
    """Counters of a proxy run and the time it took to handle each datagram."""

    datagrams: int = 0
    frames: int = 0
    forwarded: int = 0
    decoded: int = 0
    altered: int = 0
    dropped: int = 0  # by a scenario action
    malformed: int = 0
    unknown: int = 0  # message ids the dialect does not know, passed unchecked
    telemetry: int = 0
    commands: int = 0
    no_autopilot: int = 0  # command datagrams before the autopilot was heard from (dropped)
    foreign: int = 0  # datagrams from a second sender to the listen port (dropped: the first peer is kept)
    clock_jumps: int = 0  # message timestamps that leapt ahead of the wall clock (not taken as the time)
    forged: int = 0  # COMMAND_LONG frames forged by inject_command and sent to the autopilot
    refused_signed: int = 0  # forged frames not sent: the stream is signed and the proxy has no key
    lost: int = 0  # frames dropped by link_loss (the whole link silent)
    flooded: int = 0  # flooding frames the proxy added (flood)
    errors: int = 0  # datagrams passed unchanged because handling them raised

    def summary(self) -> str:
        return (f"{self.datagrams} datagrams, {self.frames} frames: {self.forwarded} forwarded "
                f"({self.altered} altered), {self.dropped} dropped by the scenario, {self.malformed} malformed "
                f"dropped, {self.unknown} of unknown message ids passed, {self.errors} errors, {self.foreign} "
                f"from a second sender dropped, {self.clock_jumps} timestamp leaps ignored, {self.forged} forged "
                f"commands sent ({self.refused_signed} not sent: signed link), {self.lost} lost to link_loss, {self.flooded} "
                f"flooding frames added; "
                f"handling p50 "
                f"{self.latency_ms(0.5):.3f} ms, p99 {self.latency_ms(0.99):.3f} ms")


class _Views:
    """Per topic, the messages received (simulator view) and forwarded (navigator view)."""

    def __init__(self) -> None:
        self.received: dict[str, tuple[list[int], list[np.ndarray]]] = {}
        self.forwarded: dict[str, tuple[list[int], list[np.ndarray]]] = {}

    def add(self, view: str, topic: str, t_us: int, values: np.ndarray) -> None:
        """Append one message to ``view`` ("received" or "forwarded")."""
        ts, vals = getattr(self, view).setdefault(topic, ([], []))
        ts.append(t_us)
        vals.append(values)


class MavlinkProxy:
    """A MAVLink proxy that runs ``scenarios`` (one flight's scenario list) on the link.

    ``record``: keep both views for :meth:`record`; ``listeners``: objects with
    ``on_message(topic, t_us, values, layer)``, each fed with every forwarded topic message as the
    mission computer sees it (e.g. :class:`scart_bench.benchmark.live.StreamMonitor`); a listener that
    raises is counted and logged, and never changes what is forwarded. Use :meth:`open` then :meth:`serve`
    (blocking until ``stop`` is set) or :meth:`start`/:meth:`stop` for a background thread.
    """

    def __init__(self, listen: tuple[str, int], forward: tuple[str, int], scenarios: list[Scenario],
                 seed: int = 0, record: bool = False, listeners: list | tuple = (), log: Callable[[str], None] | None = None,
                 defense=None):
        if defense is not None and defense.response.rejects_gps:
            raise ProxyError(f"response {defense.response.action!r}: the proxy cannot stop the autopilot fusing GPS "
                             "over MAVLink; use hold, return or land (reject_gps runs in sitl and defend)")
        #: a generator.defense.LiveDefense: its monitor sees what is forwarded; on its anomaly notice the proxy
        #: sends the autopilot the response's COMMAND_LONG, as the mission computer would
        self.defense = defense
        for sc in scenarios:
            if sc.injection_point not in LINK_POINTS:
                raise ProxyError(f"scenario {sc.id!r} ({sc.source}): injection point {sc.injection_point!r} is not on "
                                 "the link; the proxy runs scenarios at 'link' (telemetry) and 'command' (setpoints)")
        self.listen = listen
        self.forward = forward
        self.scenarios = list(scenarios)
        self.seed = int(seed)
        self.layer = AttackLayer([self.scenarios], [self.seed], rates={t: v.rate_hz for t, v in TOPICS.items()})
        self.listeners = list(listeners)
        self.recording = bool(record)
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        for sc in scenarios:
            if any(name == "mission_tamper" for name, _ in sc.actions):
                raise ProxyError(f"scenario {sc.id!r} ({sc.source}): mission_tamper is not carried by the proxy "
                                 "(it does not rewrite MISSION_ITEM_INT uploads); use it in simulation mode")
        self.layer_topics = frozenset(t for t in self.layer.listened if t in CODECS)
        if "command" in self.layer.points:  # the setpoints are the command direction's clock
            self.layer_topics |= {"setpoint"}
        #: inject_command scenarios: a COMMAND_LONG is forged after the setpoint it rides on
        self.forging = any(a.name == "inject_command" for g in self.layer.groups for a in g.actions)
        self._loss = [(g, a.params["direction"]) for g in self.layer.groups for a in g.actions
                      if a.name == "link_loss"]
        self._signed_said = False
        self._flood = [(g, a) for g in self.layer.groups for a in g.actions if a.name == "flood"]
        self._flood_due = {True: 0.0, False: 0.0}  # flooding frames owed per direction
        self._flood_at = {True: None, False: None}  # the clock when they were last counted
        self._flood_seq = 0
        topics = set(CODECS) if (record or self.listeners or defense is not None) else set(self.layer_topics)
        self._codecs = {c.msgid: c for c in BY_MSGID.values() if c.topic in topics}
        self._state_ids = STATE_MESSAGES if "setpoint" in topics else frozenset()
        self.stats = ProxyStats()
        self.views = _Views()
        self.state_in = LinkState()  # decodes what arrives (simulator view)
        self.state_out = LinkState()  # decodes what is forwarded (navigator view)
        self.packer = Packer()
        self.autopilot: tuple[str, int] | None = None
        self.mission_computer: tuple[str, int] = forward
        self.first_time_us: int | None = None
        self.clock_us = 0
        self._clock_wall = time.monotonic()
        self.started_wall = time.time()
        self._up: socket.socket | None = None
        self._down: socket.socket | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error_logged = 0

    # -- sockets ----------------------------------------------------------------------------------
    def open(self) -> MavlinkProxy:
        """Bind the two sockets (the listen address, and an ephemeral port for the forward side)."""
        try:
            self._up = _udp_socket(self.listen)
            down_host = self.listen[0] if _is_loopback(self.forward[0]) else ""
            self._down = _udp_socket((down_host, 0))
        except OSError as exc:
            self.close()
            raise ProxyError(f"cannot bind udp:{self.listen[0]}:{self.listen[1]}: {exc.strerror or exc}") from exc
        return self

    @property
    def listen_address(self) -> tuple[str, int]:
        """The bound listen address (the real port when 0 was asked for)."""
        return self._up.getsockname()[:2]

    def close(self) -> None:
        for s in (self._up, self._down):
            if s is not None:
                s.close()
        self._up = self._down = None

    # -- running ----------------------------------------------------------------------------------
    def serve(self, stop: threading.Event | None = None, poll_s: float = 0.1,
              on_idle: Callable[[], None] | None = None) -> ProxyStats:
        """Forward traffic until ``stop`` (or :meth:`stop`) is set; returns the counters.
        ``on_idle`` runs in this thread after every poll (e.g. the recording's checkpoint)."""
        if self._up is None:
            self.open()
        stop = stop or self._stop
        sel = selectors.DefaultSelector()
        sel.register(self._up, selectors.EVENT_READ, True)
        sel.register(self._down, selectors.EVENT_READ, False)
        try:
            while not stop.is_set() and not self._stop.is_set():
                for key, _ in sel.select(poll_s):
                    self._drain(key.fileobj, key.data)
                if on_idle is not None:
                    on_idle()
        finally:
            sel.close()
        return self.stats

    def start(self) -> MavlinkProxy:
        """Serve in a background thread (for tests and the generator's loopback)."""
        if self._up is None:
            self.open()
        self._thread = threading.Thread(target=self.serve, name="mavlink-proxy", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _drain(self, sock: socket.socket, from_autopilot: bool) -> None:
        for _ in range(_DRAIN):
            try:
                data, addr = sock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionError:  # ICMP port unreachable from an earlier send: not fatal for UDP
                continue
            t0 = time.perf_counter_ns()
            self.stats.datagrams += 1
            if from_autopilot:
                if self.autopilot is None:
                    self.autopilot = addr
                    self.log(f"proxy: autopilot at udp:{addr[0]}:{addr[1]} (the first sender; others are dropped)")
                elif addr != self.autopilot:  # a second sender must not take over the link
                    self.stats.foreign += 1
                    if self.stats.foreign == 1:
                        self.log(f"proxy: dropping datagrams from udp:{addr[0]}:{addr[1]}: the autopilot is "
                                 f"udp:{self.autopilot[0]}:{self.autopilot[1]}")
                    self.stats.handle_ns.append(time.perf_counter_ns() - t0)
                    continue
                out = self._guarded(data, True)
                if out:
                    self._send(self._down, out, self.mission_computer)
            else:
                out = self._guarded(data, False)
                if out:
                    if self.autopilot is None:
                        self.stats.no_autopilot += 1
                    else:
                        self._send(self._up, out, self.autopilot)
            self.stats.handle_ns.append(time.perf_counter_ns() - t0)

    def _send(self, sock: socket.socket, data: bytes, addr) -> None:
        try:
            sock.sendto(data, addr)
        except OSError:  # peer not there (yet): UDP semantics, the datagram is lost
            pass

    def _guarded(self, data: bytes, telemetry: bool) -> bytes:
        try:
            return self.handle(data, telemetry)
        except Exception as exc:  # fail open: a bug in an action must not cut the link
            self.stats.errors += 1
            if self._error_logged < 5:
                self._error_logged += 1
                self.log(f"proxy: error handling a datagram ({type(exc).__name__}: {exc}); passed unchanged")
            return data

    # -- one datagram -----------------------------------------------------------------------------
    def handle(self, data: bytes, telemetry: bool) -> bytes:
        """The datagram to forward for one received datagram (empty: nothing to forward)."""
        frames, bad = split_frames(data)
        st = self.stats
        st.malformed += bad
        st.frames += len(frames)
        if telemetry:
            st.telemetry += len(frames)
        else:
            st.commands += len(frames)
        changed = bad > 0
        parts: list[bytes] = []
        ids: list[int] = []
        for f in frames:
            raw = data[f.start:f.end]
            codec = self._codecs.get(f.msgid)
            if codec is None or (codec.topic == "setpoint") == telemetry:
                if f.msgid in self._state_ids:
                    msg = self.packer.decode(raw)
                    self.state_in.observe(f.msgid, msg)
                    self.state_out.observe(f.msgid, msg)
                elif f.msgid not in KNOWN:
                    st.unknown += 1
                parts.append(raw)
                ids.append(f.msgid)
                continue
            out = self._topic_frame(codec, raw, f.version, f.signed)
            if out is None:
                changed = True
                continue
            if out is not raw:
                changed = True
            parts.append(out)
            ids.append(f.msgid)
        if self._flood:
            flood = self._flood_frames(telemetry)
            if flood:
                st.flooded += len(flood)
                parts, ids, changed = parts + flood, ids + [HEARTBEAT_ID] * len(flood), True
        if self._loss and self._link_lost(telemetry):
            # the link is silent: nothing passes but SYSTEM_TIME, the clock of the lockstep link
            keep = [p for p, i in zip(parts, ids) if i == SYSTEM_TIME_ID]
            st.lost += len(parts) - len(keep)
            parts, changed = keep, True
        st.forwarded += len(parts)
        if not changed:
            return data
        return b"".join(parts)

    def _flood_frames(self, telemetry: bool) -> list[bytes]:
        """The flooding frames owed in this direction since the last datagram (``rate_hz`` of each active
        flood scenario, on the proxy's clock): HEARTBEATs of a fake ground station (system 255), which
        the endpoints ignore but which fill the link."""
        now = self.clock_us
        last = self._flood_at[telemetry]
        self._flood_at[telemetry] = now
        rate = sum(float(np.asarray(a.params["rate_hz"]).reshape(-1)[0]) for g, a in self._flood if g.active[0])
        if last is None or rate <= 0:
            self._flood_due[telemetry] = 0.0
            return []
        self._flood_due[telemetry] += rate * max(now - last, 0) / 1e6
        k = int(self._flood_due[telemetry])
        self._flood_due[telemetry] -= k
        out = []
        for _ in range(k):
            self._flood_seq = (self._flood_seq + 1) & 0xFF
            out.append(self.packer.pack(KNOWN[HEARTBEAT_ID](6, 8, 0, 0, 4, 3), 255, 190, self._flood_seq))
        return out

    def _link_lost(self, telemetry: bool) -> bool:
        """A link_loss scenario is active in this direction."""
        way = "telemetry" if telemetry else "command"
        return any(bool(g.active[0]) and d in ("both", way) for g, d in self._loss)

    def _respond(self, t_us: int, header) -> None:
        """The anomaly notice: the response's COMMAND_LONG to the autopilot (its system and component from the
        telemetry's header), sent as from a ground station (system 255, component 190)."""
        from scart_bench.generator.defense import response_command

        self.defense.respond(t_us, np.zeros(2))
        row = response_command(self.defense.response.action, header.srcSystem, header.srcComponent)
        name = getattr(self.defense.monitor, "name", "detector")
        self.log(f"proxy: t={t_us / 1e6:.2f} s: anomaly notice from {name} ({len(self.defense.monitor.alarms)} alarm "
                 f"row(s)): {self.defense.response.action}, COMMAND_LONG {int(row[0])} sent to the autopilot")
        if self.autopilot is None:
            return
        msg = KNOWN[COMMAND_LONG_ID](int(row[8]), int(row[9]), int(row[0]), 0, *(float(x) for x in row[1:8]))
        self._send(self._up, self.packer.pack(msg, 255, 190, 0), self.autopilot)

    def _forge(self, row: np.ndarray, header, signed: bool) -> bytes:
        """The forged COMMAND_LONG of an inject_command row, as from the setpoint's sender (or nothing,
        on a signed stream: the autopilot would refuse an unsigned or wrongly signed frame)."""
        if signed:
            self.stats.refused_signed += 1
            if not self._signed_said:
                self._signed_said = True
                self.log("proxy: the command stream is signed (MAVLink 2 signing) and the proxy has no key: a "
                         "forged COMMAND_LONG would be refused by the autopilot; forged frames are not sent")
            return b""
        msg = KNOWN[COMMAND_LONG_ID](int(row[8]), int(row[9]), int(row[0]), 0, *(float(x) for x in row[1:8]))
        self.stats.forged += 1
        return self.packer.pack(msg, header.srcSystem, header.srcComponent, (header.seq + 1) & 0xFF)

    def _tick(self, t_msg: int | None) -> int:
        """The layer's clock: the autopilot's message time, never decreasing, and never leaping ahead of
        the wall clock by more than ``MAX_CLOCK_LEAD_US`` (a garbage or far-future timestamp is counted
        in ``stats.clock_jumps`` and ignored, so it cannot open a window that never ends)."""
        now = time.monotonic()
        if t_msg is not None:
            if self.first_time_us is None:
                self.first_time_us = t_msg
                self._clock_wall = now
            t_rel = t_msg - self.first_time_us
            if t_rel > self.clock_us:
                bound = self.clock_us + MAX_CLOCK_LEAD_US + 2e6 * (now - self._clock_wall)
                if t_rel > bound:
                    self.stats.clock_jumps += 1
                    return self.clock_us
                self.clock_us = t_rel
                self._clock_wall = now
        return self.clock_us

    def _topic_frame(self, codec, raw: bytes, version: int, signed: bool) -> bytes | None:
        msg = self.packer.decode(raw)
        self.stats.decoded += 1
        topic = codec.topic
        t_us = self._tick(codec.time_us(msg))
        values = np.asarray(codec.decode(msg, self.state_in), dtype=np.float64)
        new, ok = values, True
        forged = b""
        if topic in self.layer_topics:
            point = "command" if topic == "setpoint" else "link"
            msgs = {topic: values[None, :]}
            if point == "command" and self.forging:
                msgs["command_long"] = empty_command(1)
            res = self.layer.on_messages(point, 0, t_us, msgs)
            vals, delivered = res[topic]
            new, ok = vals[0], bool(delivered[0])
            if "command_long" in res and res["command_long"][0][0, 0] != 0 and res["command_long"][1][0]:
                forged = self._forge(res["command_long"][0][0], msg.get_header(), signed)
        if self.recording:
            self.views.add("received", topic, t_us, values)
        if not ok:
            self.stats.dropped += 1
            return forged or None
        out = raw
        if new is not values and not signed and not np.array_equal(new, values, equal_nan=True):
            if codec.alter(msg, new, values):
                out = self.packer.repack(msg, version)
                self.stats.altered += 1
        if self.recording or self.listeners or self.defense is not None:
            seen = np.asarray(codec.decode(msg, self.state_out), dtype=np.float64)
            if self.defense is not None:
                self.defense.observe(topic, t_us, seen, self.layer)
                if self.defense.pending:
                    self._respond(t_us, msg.get_header())
            if self.recording:
                self.views.add("forwarded", topic, t_us, seen)
            for listener in self.listeners:
                try:
                    listener.on_message(topic, t_us, seen, self.layer)
                except Exception as exc:  # a failing listener must not change what is forwarded
                    self.stats.errors += 1
                    if self._error_logged < 5:
                        self._error_logged += 1
                        self.log(f"proxy: a listener failed on a message ({type(exc).__name__}: {exc})")
        return out + forged if forged else out

    # -- the recorded flight --------------------------------------------------------------------
    @property
    def end_us(self) -> int:
        return self.clock_us + 1

    def windows(self) -> list[tuple[int, int]]:
        """Attack windows so far (an open one is closed at the current clock)."""
        return self.layer.windows(0, self.end_us)

    def record(self, flight_id: str, extra_config: dict | None = None):
        """The proxied flight as a :class:`scart_bench.dataset.FlightRecord` (both views, labels, events)."""
        from scart_bench.generator.mavlink.recording import proxy_record

        return proxy_record(self, flight_id, extra_config or {})


def _udp_socket(addr: tuple[str, int]) -> socket.socket:
    family = socket.AF_INET6 if ":" in addr[0] else socket.AF_INET
    s = socket.socket(family, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    s.bind(addr)
    s.setblocking(False)
    return s


def stats_line(stats: ProxyStats, wall_s: float) -> str:
    """One line for the log: counters and rate."""
    rate = stats.frames / wall_s if wall_s > 0 and math.isfinite(wall_s) else float("nan")
    return f"{stats.summary()}; {rate:.0f} frames/s"


@dataclass
class ProxyRun:
    """What :func:`run_proxy` did: the seconds it served, its counters, the flight it recorded (id, file)."""

    wall_s: float
    stats: ProxyStats
    flight_id: str | None = None
    path: object = None  # the recorded flight's file (pathlib.Path), None without ``record``


def run_proxy(listen: tuple[str, int], forward: tuple[str, int], scenarios: list[Scenario], *, seed: int = 0,
              record=None, flight_id: str | None = None, monitor=None, defense=None,
              duration_s: float | None = None, checkpoint_s: float | None = None, fmt: str = "parquet",
              extra: dict | None = None, detector: dict | None = None, stop: threading.Event | None = None,
              log: Callable[[str], None] = log_to_stderr) -> ProxyRun:
    """A live proxy from start to recording, as ``scart-bench proxy`` runs it: serve until ``stop`` is set,
    ``duration_s`` passes or (from the main thread) SIGINT/SIGTERM, then write the flight.

    ``record``: a :class:`~scart_bench.generator.mavlink.recording.RecordTarget` (flights a killed proxy
    left as checkpoints are added first; the flight is checkpointed every ``checkpoint_s`` while it
    flies); ``monitor``: a streaming detector (``benchmark.live.monitor_from_run``) scoring the stream,
    ``defense``: a :class:`~scart_bench.generator.defense.LiveDefense` answering its alarms;
    ``extra``: the recording's extra config, ``detector``: its detector entry (name, run), completed
    with the threshold and the alarm rows.
    """
    from scart_bench.dataset import is_dataset
    from scart_bench.generator.mavlink.recording import (
        CHECKPOINT_S,
        RecordingCheckpoint,
        discard_checkpoints,
        journal_root,
        new_flight_id,
        recover_recordings,
        save_recording,
    )
    from scart_bench.storage import StorageError

    fid = None
    if record is not None:
        root = journal_root(record.anchor)  # flights a killed proxy --record left as checkpoints
        record.add_left(root, lambda ds, remove: recover_recordings(ds, log=log, root=root, remove=remove,
                                                                     shown=record.shown), discard_checkpoints)
        fid = flight_id or new_flight_id(taken=record.taken)
        if fid in record.taken:
            raise ProxyError(f"--flight-id {fid}: {record.shown} holds a flight {fid} already; give another id")
    proxy = MavlinkProxy(listen, forward, scenarios, seed=seed, record=record is not None,
                         listeners=[monitor] if monitor is not None and defense is None else [], log=log,
                         defense=defense).open()
    extra = {} if extra is None else extra
    checkpoint = (RecordingCheckpoint(proxy, record.anchor, fid, extra, log=log,
                                      period_s=CHECKPOINT_S if checkpoint_s is None else checkpoint_s)
                  if record is not None else None)
    stop = threading.Event() if stop is None else stop

    def on_signal(signum, frame):
        stop.set()

    main_thread = threading.current_thread() is threading.main_thread()  # signals are the main thread's
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    timer = threading.Timer(duration_s, stop.set) if duration_s else None
    host, port = proxy.listen_address
    log(f"proxy: listening on udp:{host}:{port}, forwarding to udp:{forward[0]}:{forward[1]}; scenario "
        f"{', '.join(s.id for s in scenarios)} on {', '.join(sorted(proxy.layer_topics)) or 'no topic'}; "
        "Ctrl-C stops")
    t0 = time.monotonic()
    try:
        if timer is not None:
            timer.start()
        proxy.serve(stop, on_idle=checkpoint.maybe if checkpoint is not None else None)
    finally:
        if timer is not None:
            timer.cancel()
        for s, h in old.items():
            signal.signal(s, h)
        proxy.close()
    wall = time.monotonic() - t0
    log(f"proxy: stopped after {wall:.1f} s: {stats_line(proxy.stats, wall)}")
    for s, e in proxy.windows():
        log(f"proxy: attack window {s / 1e6:.2f} s - {e / 1e6:.2f} s (flight time)")
    if monitor is not None:
        monitor.flush()
        log(f"proxy: {monitor.summary()}")
    outcome = ProxyRun(wall, proxy.stats, fid)
    if record is not None:
        if monitor is not None:
            extra["detector"] = {**(detector or {}), "threshold": monitor.threshold, "alarm_rows": len(monitor.alarms)}
            if defense is not None:
                extra["defense"] = {"response": defense.response.action, "alarms": defense.response.alarms,
                                    "notice_us": defense.notice_us, "response_us": defense.response_us}
        try:
            with record.writing() as ds:  # a URL: written in a local copy, published manifest last
                outcome.path = save_recording(proxy.record(fid, json.loads(json.dumps(extra))), ds, fmt=fmt)
        except (OSError, StorageError):
            checkpoint.write()  # the whole flight, when the disk takes it (an upload that failed, say)
            if is_dataset(checkpoint.folder):
                log(f"proxy: the flight could not be written into {record.shown}; its checkpoint {checkpoint.folder} "
                    f"keeps it (up to the last checkpoint written), and the next `scart-bench proxy --record "
                    f"{record.shown}` adds it as flight {fid}, marked incomplete")
            raise
        checkpoint.discard()  # written whole: the checkpoint goes (a failed write above keeps it)
    return outcome
