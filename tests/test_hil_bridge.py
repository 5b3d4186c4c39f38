"""The simulator bridge's MAVLink side without Java: a scripted simulator in lockstep, speaking first to
the bridge's listening port as Gazebo classic (``use_tcp`` false) and AirSim (``"UseTcp": false``) do."""

from __future__ import annotations

import socket
import threading

import numpy as np
import pytest

pytest.importorskip("pymavlink")


def _scripted_simulator(port: int, steps: int, got: dict) -> None:
    """Send HIL_SENSOR (hover at home) and HIL_GPS, one step per HIL_ACTUATOR_CONTROLS received."""
    from pymavlink.dialects.v20 import common as mavlink

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(5.0)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=51)
    t_us = 1_000_000
    got.update(controls=[], heartbeats=0, truth_requests=0)
    try:
        for k in range(steps):
            sock.sendto(mav.hil_sensor_encode(t_us, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.215, 0.01, 0.43, 955.9, 0.0,
                                              488.0, 15.0, 7167).pack(mav), ("127.0.0.1", port))
            if k % 12 == 0:
                sock.sendto(mav.hil_gps_encode(t_us, 3, 473977420, 85455940, 488000, 30, 40, 0, 0, 0, 0, 0, 10)
                            .pack(mav), ("127.0.0.1", port))
            while True:  # lockstep: the next step only after the answer to this one
                data = sock.recv(4096)
                msgs = [m for m in (mav.parse_buffer(data) or [])]
                got["heartbeats"] += sum(m.get_type() == "HEARTBEAT" for m in msgs)
                got["truth_requests"] += sum(m.get_type() == "COMMAND_LONG" and m.command == 511 for m in msgs)
                answers = [m for m in msgs if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
                if answers:
                    got["controls"].append((answers[0].time_usec, list(answers[0].controls)))
                    break
            t_us += 4000
    except OSError as exc:
        got["error"] = str(exc)
    finally:
        sock.close()


def test_listening_bridge_answers_every_sensor_message_in_lockstep():
    from scart_bench.generator.hil.bridge import Bridge
    from scart_bench.generator.hil.flights import autopilot_for
    from scart_bench.generator.hil.link import SimLink

    link = SimLink(listen=("127.0.0.1", 0))
    port = link.sock.getsockname()[1]
    got: dict = {}
    sim = threading.Thread(target=_scripted_simulator, args=(port, 250, got), daemon=True)
    sim.start()
    try:
        flight = Bridge(link, autopilot_for(0)).fly(max_s=1.0, first_timeout_s=5.0)
    finally:
        sim.join(10)
        link.close()
    assert "error" not in got, got.get("error")
    assert flight.steps == 250 and len(got["controls"]) == 250
    assert [t for t, _ in got["controls"]] == [1_000_000 + 4000 * k for k in range(250)]
    assert np.allclose([c for _, c in got["controls"]], 0.0)  # not armed before the estimator's origin
    assert got["truth_requests"] == 1 and got["heartbeats"] >= 1
    assert sum(g is not None for _, g in flight.inputs) == 21  # every HIL_GPS reached the flight software


def test_listening_bridge_says_when_nothing_comes():
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.hil.link import SimLink

    link = SimLink(listen=("127.0.0.1", 0))
    try:
        with pytest.raises(HilError, match=r"expected on udp:127\.0\.0\.1:\d+\) sent no message in 0.3 s"):
            link.wait_first(0.3)
    finally:
        link.close()


@pytest.mark.parametrize("extra, named", [
    (["--profile", "standard"], "--profile"),
    (["--timing", "ideal", "--gps-accuracy", "simulator"], "--gps-accuracy, --timing are"),
    (["--sensor-profile", "rflymad"], "--sensor-profile is"),
    (["--like", "log.bin"], "--like"),
])
def test_generate_physics_jmavsim_refuses_the_built_in_engine_s_options(tmp_path, capsys, extra, named):
    """jMAVSim flies the square or mission files with its own sensors and clock: a profile, a --like fit, a GPS
    accuracy, sensor profile or timing asked of it is one line naming them, exit 2, nothing written (they were
    dropped without a word), before Java or the jar is looked for."""
    from scart_bench.cli.main import main

    out = tmp_path / "out"
    assert main(["generate", "--physics", "jmavsim", "--jmavsim", str(tmp_path / "nowhere"), "--out", str(out),
                 "--flights", "1", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err and "for the built-in engine" in err, err
    assert not out.exists()
