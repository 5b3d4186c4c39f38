"""Speed of ``scart-bench sitl``: how fast the simulated vehicle runs and how fast it answers.

    python -m perf.sitl_speed [--seconds 10] [--speed S | --lockstep] [--scenario FILE]

The sitl runs in a process of its own (the CLI, as a user starts it); this process is a plain
pymavlink ground station on loopback. It arms the vehicle, takes off and hovers while it
measures, over ``--seconds`` of wall-clock time:

- the simulation's pace: simulated seconds (from SYSTEM_TIME / ATTITUDE time_boot_ms) per wall
  second (with ``--speed S`` it should be S while the machine can keep up; ``--lockstep`` gives
  the maximum);
- the answer time of a command: COMMAND_LONG (MAV_CMD_REQUEST_MESSAGE for HEARTBEAT) to its
  COMMAND_ACK, wall-clock p50 and p99 (the server reads its socket between two 4 ms steps);
- the telemetry received per wall second.
"""

from __future__ import annotations

import argparse
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure(seconds: float, speed: float | None, scenario: str | None) -> dict:
    from pymavlink import mavutil

    mav = mavutil.mavlink
    port = _free_port()
    cmd = [sys.executable, "-m", "scart_bench.cli", "sitl", "--listen", f"udp:127.0.0.1:{port}"]
    cmd += ["--lockstep"] if speed is None else ["--speed", str(speed)]
    if scenario:
        cmd += ["--scenario", scenario]
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        while "listening on" not in proc.stderr.readline():
            if proc.poll() is not None:
                raise RuntimeError("the sitl exited early")
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        m.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        m.wait_heartbeat(timeout=10)
        home = m.recv_match(type="HOME_POSITION", blocking=True, timeout=10)
        m.recv_match(type="SYS_STATUS", blocking=True, timeout=30,
                     condition=f"SYS_STATUS.onboard_control_sensors_health & {mav.MAV_SYS_STATUS_PREARM_CHECK}")
        m.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        m.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, math.nan, math.nan,
                                home.altitude / 1000 + 10)
        acks, t_boot, msgs = [], [], 0
        start = time.perf_counter()
        next_cmd = start
        sent_at = None
        while time.perf_counter() - start < seconds:
            now = time.perf_counter()
            if sent_at is None and now >= next_cmd:
                m.mav.command_long_send(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 0, 0, 0, 0, 0, 0, 0)
                sent_at = time.perf_counter()
            msg = m.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            msgs += 1
            kind = msg.get_type()
            if kind == "COMMAND_ACK" and msg.command == mav.MAV_CMD_REQUEST_MESSAGE and sent_at is not None:
                acks.append(time.perf_counter() - sent_at)
                sent_at, next_cmd = None, time.perf_counter() + 0.02
            elif kind == "ATTITUDE":
                t_boot.append((time.perf_counter(), msg.time_boot_ms / 1e3))
        wall = time.perf_counter() - start
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    t = np.array(t_boot)
    pace = (t[-1, 1] - t[0, 1]) / (t[-1, 0] - t[0, 0])
    a = np.array(acks) * 1e3
    return {"pace": pace, "ack_p50_ms": float(np.percentile(a, 50)), "ack_p99_ms": float(np.percentile(a, 99)),
            "acks": len(a), "messages_per_s": msgs / wall, "cpus": os.cpu_count(), "load": os.getloadavg()[0]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--speed", type=float, default=None)
    g.add_argument("--lockstep", action="store_true")
    p.add_argument("--scenario")
    args = p.parse_args(argv)
    speed = None if args.lockstep or args.speed is None else args.speed
    r = measure(args.seconds, speed, args.scenario)
    mode = "lockstep (as fast as it can)" if speed is None else f"--speed {speed:g}"
    print(f"sitl {mode}: {r['pace']:.2f} simulated s per wall s; command -> COMMAND_ACK p50 {r['ack_p50_ms']:.2f} ms, "
          f"p99 {r['ack_p99_ms']:.2f} ms ({r['acks']} commands); {r['messages_per_s']:.0f} messages/s received "
          f"({r['cpus']} CPUs, load average {r['load']:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
