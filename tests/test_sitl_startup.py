"""``scart-bench sitl`` binds its port before its slow start-up: a one-shot client is answered.

A client that sends a single HEARTBEAT while the command is still importing (before it prints
"listening") must still get the vehicle's telemetry: its datagram waits in the already bound
socket and the first poll reads it. Loopback only, bounded waits.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("pymavlink", reason="the sitl needs pymavlink (pip install scart-bench[mavlink])")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


UDP_TABLE = Path("/proc/net/udp")


def _bound(port: int) -> bool:
    """True once a socket is bound to the UDP port (read from the kernel's table: no probe that could
    take the port itself or be heard by the sitl)."""
    rows = UDP_TABLE.read_text().splitlines()[1:]
    return any(int(row.split()[1].rsplit(":", 1)[1], 16) == port for row in rows)


@pytest.mark.skipif(not UDP_TABLE.exists(), reason="reads the bound ports from Linux's /proc/net/udp")
def test_a_single_heartbeat_sent_during_start_up_is_answered():
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "scart_bench", "sitl", "--listen", f"udp:127.0.0.1:{port}",
                             "--duration", "3"], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    listening = []

    def read_stderr():
        for line in proc.stderr:
            if "listening" in line and not listening:
                listening.append(time.monotonic())

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        deadline = time.monotonic() + 30
        while not _bound(port):
            assert time.monotonic() < deadline and proc.poll() is None, "the sitl never bound its port"
            time.sleep(0.005)
        heartbeat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
        client.sendto(heartbeat.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190)), ("127.0.0.1", port))
        sent = time.monotonic()
        client.settimeout(20)
        data, _ = client.recvfrom(65535)
        assert data, "the vehicle answered the one heartbeat"
        reader.join(timeout=20)
        assert listening and sent < listening[0], "the heartbeat went out while the sitl was still starting"
    finally:
        client.close()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
