"""``scart-bench sitl --physics jmavsim`` (issue 52): a ground station flies a jMAVSim vehicle through the
project's flight controller, with the SCART layer on the sitl's link.

The client is test_sitl's plain pymavlink ground station, stepped in lockstep with the sitl, whose
clock drives jMAVSim (started headless in lockstep). jMAVSim is built from ``../shared/sim/jmavsim`` into a
temporary folder as in test_jmavsim.py; without java, ant or the source the module skips with one line.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_jmavsim import REASON, SOURCE

pytestmark = pytest.mark.skipif(REASON is not None, reason=REASON or "")

if REASON is None:
    from pymavlink import mavutil
    from test_sitl import LOITER, M_PER_DEG, NAN, Client

    from scart_bench.cli.main import main
    from scart_bench.generator.scart.scenario import scenario_from_dict
    from scart_bench.generator.sitl.jmavsim_plant import JmavsimPlant
    from scart_bench.generator.sitl.server import SitlServer

#: the reposition target (m north of home) and the height flown
NORTH, ALT = 15.0, 5.0
#: what the client is shown on the link: every position report 6 m east of the truth, for 5 s from 4 m up
BIAS = {
    "id": "link-position-bias", "injection_point": "link",
    "start": [{"condition": "altitude_above", "height": 4.0}],
    "end": [{"condition": "duration", "seconds": 5.0}],
    "actions": [{"action": "bias", "target": ["position"], "offset": 6.0, "direction_deg": 90.0}],
}


@pytest.fixture(scope="module")
def jar(tmp_path_factory):
    from scart_bench.generator.hil.jmavsim import build

    return build(SOURCE, tmp_path_factory.mktemp("jmavsim"))


def _ne(lat_e7, lon_e7, home) -> np.ndarray:
    """North/east (m) from home, by the client's own flat-earth conversion."""
    lat0, lon0 = home.latitude / 1e7, home.longitude / 1e7
    return np.array([(lat_e7 / 1e7 - lat0) * M_PER_DEG,
                     (lon_e7 / 1e7 - lon0) * M_PER_DEG * math.cos(math.radians(lat0))])


@pytest.fixture(scope="module")
def flight(jar):
    """Arm, take off to 5 m, DO_REPOSITION 15 m north, Return at 5 m; the sitl and what the client saw."""
    mav = mavutil.mavlink
    with JmavsimPlant(jar=jar) as plant, \
            SitlServer(("127.0.0.1", 0), [scenario_from_dict(BIAS)], seed=3, record=True, log=lambda line: None,
                       plant=plant) as sitl:
        c = Client(sitl)
        home = c.wait("HOME_POSITION")
        c.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK,
               timeout_s=20)  # jMAVSim's GPS has its first fix about 9 s after start
        c.mav.param_set_send(1, 1, b"RTL_RETURN_ALT", ALT, mav.MAV_PARAM_TYPE_REAL32)
        c.wait("PARAM_VALUE", lambda m: m.param_id == "RTL_RETURN_ALT")
        acks = {"arm": c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1),
                "takeoff": c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + ALT)}
        c.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > (ALT - 0.7) * 1000, timeout_s=20)
        c.wait("HEARTBEAT", lambda m: (m.custom_mode >> 24) & 0xFF == LOITER)
        lat = home.latitude + int(round(NORTH / M_PER_DEG * 1e7))
        c.mav.command_int_send(1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0,
                               -1, mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, NAN, lat, home.longitude, ALT)
        acks["reposition"] = c.wait("COMMAND_ACK", lambda m: m.command == mav.MAV_CMD_DO_REPOSITION).result
        # there within the acceptance radius (NAV_ACC_RAD, 2 m), as the client sees it; then a second of hold
        c.wait("GLOBAL_POSITION_INT", lambda m: np.hypot(*(_ne(m.lat, m.lon, home) - [NORTH, 0.0])) < 2.0,
               timeout_s=20)
        sitl.advance(1.0)
        acks["rtl"] = c.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
        c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, timeout_s=40)
        c.wait("HEARTBEAT", lambda m: not m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, timeout_s=10)
        c.conn.close()
        ts, rows = sitl.views["simulator"]["truth"]
        sim = plant.sim
    return {"sim": sim, "sitl": sitl, "client": c, "home": home, "acks": acks,
            "truth_s": np.asarray(ts) / 1e6, "truth": np.vstack(rows)}


def test_a_ground_station_flies_a_jmavsim_vehicle_up_to_a_point_and_back_home(flight):
    """Truth from jMAVSim (HIL_STATE_QUATERNION): it climbed to the height asked, reached the reposition
    point and landed within 2 m of home, disarmed."""
    assert set(flight["acks"].values()) == {0}, flight["acks"]
    truth = flight["truth"]
    assert flight["sitl"].plant.truth_rows > 500  # jMAVSim's own truth, not the estimate
    assert -truth[:, 2].min() == pytest.approx(ALT, abs=1.0)
    # the client saw it within 2 m; jMAVSim's truth is within that plus the estimator's own error, which
    # reaches 2-3 m with jMAVSim's unseeded GPS noise (a vehicle that never went stays 15 m away)
    assert np.hypot(truth[:, 0] - NORTH, truth[:, 1]).min() < 5.0
    last = truth[-1]
    assert np.hypot(last[0], last[1]) < 2.0 and abs(last[2]) < 0.3
    assert last[9] == 0.0 and last[10] == 1.0  # disarmed, on the ground
    assert not flight["sim"].alive()  # the plant ended the jMAVSim it started


def test_a_link_scenario_shows_the_client_a_position_that_jmavsim_does_not_fly(flight):
    """In the attack window the client's GLOBAL_POSITION_INT is about 6 m east of jMAVSim's truth; after it,
    within the estimator's own error; the recording labels the window."""
    (start_us, end_us), = flight["sitl"].windows()
    assert 2.0 < (end_us - start_us) / 1e6 < 6.0
    t_truth, truth = flight["truth_s"], flight["truth"]
    east_error, inside = [], []
    for t, m in flight["client"].seen["GLOBAL_POSITION_INT"]:
        if t < t_truth[0]:
            continue
        i = min(np.searchsorted(t_truth, t), len(t_truth) - 1)
        ne = _ne(m.lat, m.lon, flight["home"])
        east_error.append(ne[1] - truth[i, 1])
        inside.append(start_us / 1e6 + 0.2 <= t < end_us / 1e6 - 0.2)
    east_error, inside = np.array(east_error), np.array(inside)
    assert inside.sum() > 50
    assert np.median(east_error[inside]) == pytest.approx(6.0, abs=1.0)
    late = np.array([t > end_us / 1e6 + 1.0 for t, _ in flight["client"].seen["GLOBAL_POSITION_INT"]
                     if t >= t_truth[0]])
    # afterwards only the estimator's own error (jMAVSim's GPS noise, the RTL's turns) and the client's
    # clock against the truth's at up to 5 m/s: under 0.5 m typically, a few samples 2.5-3 m (jMAVSim's
    # noise is not seeded), so the bound is on the 95th percentile
    late_error = np.abs(east_error[late])
    assert np.median(late_error) < 0.5 and np.percentile(late_error, 95) < 1.5, np.percentile(late_error, [50, 95, 100])
    rec = flight["sitl"].record("sitl-jmavsim", {})  # the recording: jMAVSim's truth, labels on the window
    assert len(rec.simulator["truth"]) == len(truth) and rec.manifest["injection_point"] == "link"
    labelled = next(df for df in rec.navigator.values() if df["Is_Anomaly"].any())
    ts = labelled["Timestamp"][labelled["Is_Anomaly"].astype(bool)]
    assert start_us <= ts.min() and ts.max() < end_us


def test_cli_says_in_one_line_what_is_missing(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("SCART_JMAVSIM", raising=False)
    assert main(["sitl", "--physics", "jmavsim", "--listen", "udp:127.0.0.1:0"]) == 2
    assert "no jMAVSim given: pass --jmavsim PATH" in capsys.readouterr().err
    assert main(["sitl", "--physics", "jmavsim", "--jmavsim", str(tmp_path), "--listen", "udp:127.0.0.1:0"]) == 2
    assert f"no jmavsim_run.jar at '{tmp_path}'" in capsys.readouterr().err
    wind = Path(__file__).resolve().parents[1] / "data" / "scenarios" / "env_wind_gust.toml"
    assert main(["sitl", "--physics", "jmavsim", "--jmavsim", str(tmp_path), "--scenario", str(wind),
                 "--listen", "udp:127.0.0.1:0"]) == 2
    assert "with --physics jmavsim the sitl runs scenarios at link, command, sensor" in capsys.readouterr().err
    assert main(["sitl", "--sim", "udp:127.0.0.1:4560", "--listen", "udp:127.0.0.1:0"]) == 2
    assert "--sim are for --physics jmavsim" in capsys.readouterr().err


def test_cli_starts_jmavsim_flies_it_and_stops_it(jar, capsys):
    """`sitl --physics jmavsim --jmavsim JAR --duration 2` runs 2 s of jMAVSim flight (no client: the vehicle
    stays on the ground) and ends the jMAVSim it started."""
    import subprocess

    before = subprocess.run(["pgrep", "-f", str(jar)], capture_output=True, text=True).stdout.split()
    assert main(["sitl", "--physics", "jmavsim", "--jmavsim", str(jar), "--listen", "udp:127.0.0.1:0",
                 "--speed", "10", "--duration", "2"]) == 0
    err = capsys.readouterr().err
    assert "flying jMAVSim" in err and "stopped after 2.0 s of flight" in err
    after = subprocess.run(["pgrep", "-f", str(jar)], capture_output=True, text=True).stdout.split()
    assert after == before


def test_a_jmavsim_that_ends_mid_flight_ends_the_sitl_in_one_line_and_the_flown_part_is_recorded(jar, tmp_path,
                                                                                                 capsys):
    import os
    import signal
    import subprocess
    import threading
    import time

    from scart_bench.dataset import open_dataset

    out = tmp_path / "ds"
    codes = []
    run = threading.Thread(target=lambda: codes.append(main([
        "sitl", "--physics", "jmavsim", "--jmavsim", str(jar), "--listen", "udp:127.0.0.1:0", "--speed", "10",
        "--duration", "60", "--record", str(out), "--flight-id", "cut-short"])))
    run.start()
    err, end = "", time.monotonic() + 60
    while "listening on" not in err and time.monotonic() < end:  # jMAVSim has answered: the vehicle flies
        err += capsys.readouterr().err
        time.sleep(0.2)
    found = subprocess.run(["pgrep", "-f", str(jar)], capture_output=True, text=True).stdout.split()
    assert "listening on" in err and found, "jMAVSim did not start"
    time.sleep(3.0)
    os.kill(int(found[0]), signal.SIGKILL)  # the jMAVSim this test's sitl started
    run.join(60)
    assert codes == [2]
    err += capsys.readouterr().err
    assert "scart-bench sitl: error: jMAVSim ended during the flight" in err
    ds = open_dataset(out)
    assert list(ds.manifest["flight_id"]) == ["cut-short"]
    assert 0.5 < ds.manifest["duration_s"].iloc[0] < 60.0  # the part flown before jMAVSim ended
    assert len(ds.topic("cut-short", "attitude")) > 25
