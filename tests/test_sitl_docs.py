"""docs/sitl.md's pymavlink examples run against ``scart-bench sitl`` as written, so the docs cannot drift.

The client is started before the vehicle, so its first heartbeats are lost: the example must say
hello until the vehicle answers (one heartbeat left it waiting forever). With the doc's tlog lines
it writes a tlog that the project's tlog importer reads back (pymavlink's ``setup_logfile`` writes
none on a UDP link). The code blocks are taken from the doc; only the port is changed.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("pymavlink", reason="the sitl needs pymavlink (pip install scart-bench[mavlink])")

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import open_dataset  # noqa: E402
from scart_bench.generator.logs.importers import load_flight_file  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "sitl.md"
DOC_PORT = "14580"


def _pymavlink_blocks() -> tuple[str, str]:
    """The doc's pymavlink mission and its tlog lines: the python blocks of its ``### pymavlink`` section."""
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("### pymavlink\n"):]
    section = section[:section.index("\n### ", 1)]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2, "docs/sitl.md's pymavlink section: the mission, then the tlog lines"
    return blocks[0], blocks[1]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_pymavlink_example_flies_despite_lost_heartbeats_and_its_tlog_imports(tmp_path):
    mission, tlog_lines = _pymavlink_blocks()
    connect = next(line for line in mission.splitlines() if "mavlink_connection(" in line)
    assert DOC_PORT in connect
    script = mission.replace(connect, connect + "\n" + tlog_lines) + "\ntlog.close()\n"
    port = str(_free_port())
    (tmp_path / "client.py").write_text(script.replace(DOC_PORT, port), encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    client = subprocess.Popen([sys.executable, "client.py"], cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env)
    sitl = None
    try:
        time.sleep(2.5)  # the client's first heartbeats go to a port nobody listens on: lost
        assert client.poll() is None, client.communicate()
        sitl = subprocess.Popen([sys.executable, "-m", "scart_bench.cli", "sitl", "--listen", f"udp:127.0.0.1:{port}",
                                 "--lockstep"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=env)
        out, err = client.communicate(timeout=300)
    finally:
        for proc in (client, sitl):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT) if proc is sitl else proc.kill()
        if sitl is not None:
            try:
                sitl.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                sitl.kill()
    assert client.returncode == 0, err
    assert out.splitlines()[-1] == "landed and disarmed" and out.count("reached") == 4, out
    tables = load_flight_file(tmp_path / "flight.tlog")
    assert {"global_position_int", "attitude", "heartbeat"} <= set(tables), sorted(tables)
    gpi = tables["global_position_int"]
    assert gpi["relative_alt"].max() > 9.5, "the take-off to 10 m is in the tlog"
    assert gpi["Timestamp"].is_monotonic_increasing and len(gpi) > 100
    assert main(["import", str(tmp_path / "flight.tlog"), "--out", str(tmp_path / "mine")]) == 0, \
        "the doc's `scart-bench import flight.tlog --out ...`"
    assert len(open_dataset(tmp_path / "mine").manifest) == 1
