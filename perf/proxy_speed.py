"""Speed of the live MAVLink proxy: sustained messages per second and the latency it adds.

    python -m perf.proxy_speed [--rate 2000] [--seconds 10] [--scenario FILE] [--record]

The proxy runs in a process of its own (as ``scart-bench proxy`` would), with a link scenario
that is active during the whole measurement (by default the GPS spoofing of
``data/scenarios/gps_spoof.toml`` without its end: the mission computer first reports mission
item 2, so from then on every GLOBAL_POSITION_INT, LOCAL_POSITION_NED and GPS_RAW_INT is decoded,
altered by the layer and re-encoded: the worst case). This process plays the autopilot
and the mission computer on loopback and sends a flight-like telemetry mix (the generator's
topics at their rates, one MAVLink frame per datagram: the worst case per message). Printed:

- maximum throughput: frames forwarded per second with 32 datagrams in flight;
- sustained: frames per second received while sending at ``--rate`` for ``--seconds``, and loss;
- added latency: send-to-receive time through the proxy minus the median of the same path
  without the proxy (one direct loopback hop), p50 and p99, unloaded and at ``--rate``;
- the proxy's own handling time per datagram (receive to send, measured inside it).

Goal (issue 8): at least 2,000 messages/s with p99 added latency under 2 ms on 2 cores.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import select
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

LOCAL = ("127.0.0.1", 0)
#: gps_spoof.toml, active until the end of the run
ENDLESS_SPOOF = """
[scenario]
id = "gps-spoof-link-endless"
injection_point = "link"
[[scenario.start]]
condition = "mission_phase"
after_waypoint = 1
[[scenario.end]]
condition = "duration"
seconds = 1e9
[[scenario.actions]]
action = "gps_spoof"
target = ["global_position_int", "local_position_ned", "gps_raw_int"]
rate_deg_s = 1.5
max_deg = 30.0
"""


def _serve(conn, scenario: str, record: bool) -> None:
    """The proxy process: report the listen address, serve until told to stop, send back the counters."""
    from scart_bench.generator.mavlink.proxy import MavlinkProxy
    from scart_bench.generator.scart.scenario import load_scenarios

    forward = conn.recv()
    proxy = MavlinkProxy(LOCAL, forward, load_scenarios(scenario), record=record, log=lambda m: None).open()
    conn.send(proxy.listen_address)
    stop = threading.Event()
    threading.Thread(target=lambda: (conn.recv(), stop.set()), daemon=True).start()
    proxy.serve(stop, poll_s=0.05)
    conn.send(proxy.stats.to_dict())


def telemetry_stream(seconds: float) -> list[bytes]:
    """One frame per datagram: every telemetry topic at its rate, values of a vehicle circling home."""
    from scart_bench.dataset.schema import HOME_LAT, HOME_LON, SIM_RATE_HZ, TELEMETRY_TOPICS, TOPICS
    from scart_bench.generator.mavlink.codec import CODECS, Packer
    from scart_bench.generator.telemetry.schedule import due_steps

    packer = Packer()
    n_steps = int(seconds * SIM_RATE_HZ)
    due = {t: due_steps(TOPICS[t].rate_hz, n_steps) for t in TELEMETRY_TOPICS}
    out, seq = [], 0
    for step in range(n_steps):
        t_us = step * 4000
        a = 0.2 * t_us / 1e6
        x, y, vx, vy = 20 * np.cos(a), 20 * np.sin(a), -4 * np.sin(a), 4 * np.cos(a)
        lat, lon = HOME_LAT + x / 111_195.0, HOME_LON + y / 75_000.0
        values = {
            "attitude": [0.02, -0.05, a % np.pi, 0.01, 0.0, 0.2],
            "highres_imu": [0.3, 0.1, -9.8, 0.01, 0.0, 0.2, 0.2, 0.01, 0.4, 955.0, 498.0, 25.0],
            "global_position_int": [lat, lon, 498.0, 10.0, vx, vy, 0.0, (a + np.pi / 2) % (2 * np.pi)],
            "local_position_ned": [x, y, -10.0, vx, vy, 0.0],
            "gps_raw_int": [lat, lon, 498.0, 0.3, 0.5, 4.0, (a + np.pi / 2) % (2 * np.pi), vx, vy, 0.0, 3, 12],
            "scaled_pressure": [955.0, 25.0],
            "altitude": [498.0, 10.0, 10.0],
            "battery_status": [16.2, 12.0, 0.8],
        }
        for topic in TELEMETRY_TOPICS:
            if due[topic][step]:
                msg = CODECS[topic].new_message(np.asarray(values[topic], dtype=float), t_us)
                out.append(packer.pack(msg, 1, 1, seq))
                seq += 1
    return out


def _paced(frames: list[bytes], rate: float | None, src: socket.socket, dst, sink: socket.socket,
           window: int = 32) -> tuple[np.ndarray, np.ndarray, float]:
    """Send ``frames`` (at ``rate`` per second, or as fast as ``window`` outstanding allow) and
    receive them, in one thread; returns send and arrival times (ns; -1 when lost) and the wall time.

    Arrival order is send order on loopback, so the k-th datagram received is the k-th sent.
    """
    n = len(frames)
    sent = np.zeros(n, dtype=np.int64)
    arrivals = np.full(n, -1, dtype=np.int64)
    sink.setblocking(False)
    k = r = 0
    t0 = time.perf_counter_ns()
    last_rx = t0
    while r < n:
        while True:  # timestamp what has arrived before sending more
            try:
                sink.recvfrom(65535)
            except BlockingIOError:
                break
            last_rx = arrivals[r] = time.perf_counter_ns()
            r += 1
        now = time.perf_counter_ns()
        due = t0 + int(k * 1e9 / rate) if rate else now
        if k < n and now >= due and (rate or k - r < window):
            sent[k] = now
            src.sendto(frames[k], dst)
            k += 1
            continue
        wait = (due - now) / 1e9 if (k < n and rate) else (0.5 if k == n else 0.001)
        ready, _, _ = select.select([sink], [], [], max(wait, 0.0))
        if not ready and k == n and time.perf_counter_ns() - last_rx > 1e9:
            break  # the rest is lost
    sink.setblocking(True)
    return sent, arrivals, (time.perf_counter_ns() - t0) / 1e9


def _one_by_one(frames: list[bytes], src: socket.socket, dst, sink: socket.socket) -> np.ndarray:
    sink.settimeout(2.0)
    lat = np.zeros(len(frames))
    for k, f in enumerate(frames):
        t = time.perf_counter_ns()
        src.sendto(f, dst)
        sink.recvfrom(65535)
        lat[k] = (time.perf_counter_ns() - t) / 1e6
    return lat


def _prime(ap: socket.socket, mc: socket.socket, proxy_addr, frame: bytes) -> tuple[str, int]:
    """One datagram through, then the mission computer reports mission item 2 (the attack starts)."""
    from scart_bench.generator.mavlink.codec import CODECS, KNOWN, MISSION_CURRENT_ID, Packer

    mc.settimeout(5.0)
    ap.sendto(frame, proxy_addr)
    _, back = mc.recvfrom(65535)
    packer = Packer()
    sp = CODECS["setpoint"].new_message(np.array([4.0, 0.0, 0.0, 0.0, 2.0, 1.0]), 0)
    mc.sendto(packer.pack(KNOWN[MISSION_CURRENT_ID](2), 1, 191, 0) + packer.pack(sp, 1, 191, 1), back)
    ap.settimeout(5.0)
    ap.recvfrom(65535)
    return back


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rate", type=float, default=2000.0, help="offered load, messages/s (default 2000)")
    p.add_argument("--seconds", type=float, default=10.0, help="length of the sustained test (default 10)")
    p.add_argument("--scenario", help="a link scenario file (default: GPS spoofing active for the whole run)")
    p.add_argument("--record", action="store_true", help="the proxy also keeps both views (as with --record)")
    args = p.parse_args(argv)
    tmp = None
    if args.scenario is None:
        tmp = tempfile.TemporaryDirectory()
        args.scenario = str(Path(tmp.name) / "gps_spoof_endless.toml")
        Path(args.scenario).write_text(ENDLESS_SPOOF)

    n_sustained = int(args.rate * args.seconds)
    n_max = max(4 * n_sustained // 5, 5000)
    k_lat = 2000
    # the phases take consecutive parts of one flight-like stream (~212 messages per flight second)
    stream = telemetry_stream((1 + k_lat + n_sustained + n_max) / 212.0 + 2.0)
    ap, mc, direct = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3))
    for s in (ap, mc, direct):
        s.bind(LOCAL)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_serve, args=(child, args.scenario, args.record), daemon=True)
    proc.start()
    try:
        parent.send(mc.getsockname())
        proxy_addr = parent.recv()
        _prime(ap, mc, proxy_addr, stream[0])
        unloaded_part = stream[1:1 + k_lat]
        sustained_part = stream[1 + k_lat:1 + k_lat + n_sustained]
        max_part = stream[1 + k_lat + n_sustained:1 + k_lat + n_sustained + n_max]
        base = _one_by_one(unloaded_part, ap, direct.getsockname(), direct)
        unloaded = _one_by_one(unloaded_part, ap, proxy_addr, mc)
        sent, arr, wall = _paced(sustained_part, args.rate, ap, proxy_addr, mc)
        ok = arr >= 0
        loaded = (arr[ok] - sent[ok]) / 1e6
        sustained = ok.sum() / ((arr[ok].max() - sent[0]) / 1e9) if ok.any() else 0.0
        s2, a2, wall2 = _paced(max_part, None, ap, proxy_addr, mc)
        got = int((a2 >= 0).sum())
        max_rate = got / ((a2[a2 >= 0].max() - s2[0]) / 1e9) if got else 0.0
        parent.send("stop")
        stats = parent.recv()
    finally:
        proc.join(timeout=10)
        if proc.is_alive():
            proc.kill()
        for s in (ap, mc, direct):
            s.close()
        if tmp is not None:
            tmp.cleanup()

    d50 = float(np.median(base))

    def added(x: np.ndarray) -> tuple[float, float]:
        return float(np.percentile(x, 50)) - d50, float(np.percentile(x, 99)) - d50

    u50, u99 = added(unloaded)
    l50, l99 = added(loaded)
    print(f"proxy speed: scenario {Path(args.scenario).name} active, record={args.record}, one MAVLink frame per "
          f"datagram, proxy in its own process")
    print(f"  maximum throughput      {max_rate:10.0f} msg/s  ({got} of {n_max} messages, 32 in flight)")
    print(f"  sustained at {args.rate:.0f} msg/s  {sustained:10.0f} msg/s  received, {int((~ok).sum())} lost of "
          f"{len(ok)} in {wall:.1f} s")
    print(f"  added latency, unloaded  p50 {u50:6.3f} ms  p99 {u99:6.3f} ms  (direct loopback p50 {d50:.3f} ms "
          "subtracted)")
    print(f"  added latency at {args.rate:.0f}/s  p50 {l50:6.3f} ms  p99 {l99:6.3f} ms")
    print(f"  proxy handling/datagram  p50 {stats['handle_p50_ms']:6.3f} ms  p99 {stats['handle_p99_ms']:6.3f} ms  "
          f"({stats['frames']} frames, {stats['altered']} altered, {stats['malformed']} malformed)")
    met = sustained >= 0.98 * args.rate and args.rate >= 2000 and l99 < 2.0 and not (~ok).any()
    print(f"  goal >= 2000 msg/s with p99 added latency < 2 ms: {'met' if met else 'NOT met'}")


if __name__ == "__main__":
    main()
