"""``scart-bench sitl``: a PX4-like flight controller that MAVLink clients fly (issue 19).

The clients are plain pymavlink (and MAVSDK-Python in test_sitl_mavsdk.py): no project code
talks MAVLink on their side. The pymavlink flights run in step-exact lockstep: the client's
``wait`` advances the simulation by 20 ms whenever it has nothing to read, so every flight is
reproducible and as fast as the simulation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink")
from pymavlink import mavutil  # noqa: E402

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import open_dataset  # noqa: E402
from scart_bench.generator.mavlink.recording import save_recording  # noqa: E402
from scart_bench.generator.scart.scenario import load_scenarios  # noqa: E402
from scart_bench.generator.sitl.server import SitlServer  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SPOOF = ROOT / "data" / "scenarios" / "gps_spoof.toml"
LOCAL = ("127.0.0.1", 0)
#: the square (north, east in m from home) flown at 10 m: the generator's default mission
SQUARE = ((10.0, 10.0), (40.0, 10.0), (40.0, 40.0), (10.0, 40.0))
ALT = 10.0
M_PER_DEG = 111194.93  # the client's own flat-earth conversion (no project code on the client side)
AUTO, LOITER, MISSION_MODE, LAND_MODE, OFFBOARD_MAIN = 4, 3, 4, 6, 6
NAN = float("nan")


class Client:
    """A pymavlink ground station, stepped in lockstep with the SITL (``sitl.advance`` while waiting)."""

    def __init__(self, sitl: SitlServer):
        self.sitl = sitl
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{sitl.address[1]}", source_system=255,
                                               source_component=190)
        self.mav = self.conn.mav
        self.seen: dict[str, list] = {}
        self.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def _drain(self):
        while True:
            m = self.conn.recv_match(blocking=False)
            if m is None:
                return
            if m.get_type() != "BAD_DATA":
                self.seen.setdefault(m.get_type(), []).append((self.sitl.time_s, m))
                yield m

    def wait(self, kind: str, cond=lambda m: True, timeout_s: float = 10.0):
        """The next ``kind`` message meeting ``cond`` within ``timeout_s`` of simulated time."""
        end = self.sitl.time_s + timeout_s
        while True:
            for m in self._drain():
                if m.get_type() == kind and cond(m):
                    return m
            if self.sitl.time_s >= end:
                raise AssertionError(f"no {kind} within {timeout_s} s (t={self.sitl.time_s:.2f} s)")
            self.sitl.advance(0.02)

    def command(self, command: int, *params: float) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        return self.wait("COMMAND_ACK", lambda m: m.command == command).result

    def upload(self, items: list[tuple]) -> int:
        """Mission upload (MISSION_COUNT, MISSION_REQUEST_INT -> MISSION_ITEM_INT, MISSION_ACK)."""
        self.mav.mission_count_send(1, 1, len(items), 0)
        while True:
            m = self._request_or_ack()
            if m.get_type() == "MISSION_ACK":
                return m.type
            frame, cmd, p1, p2, lat, lon, alt = items[m.seq]
            self.mav.mission_item_int_send(1, 1, m.seq, frame, cmd, 0, 1, p1, p2, 0, NAN, int(round(lat * 1e7)),
                                           int(round(lon * 1e7)), alt, 0)

    def _request_or_ack(self):
        end = self.sitl.time_s + 2.0
        while True:
            for m in self._drain():
                if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"):
                    return m
            assert self.sitl.time_s < end, "mission upload stalled"
            self.sitl.advance(0.02)


def square_items(home) -> list[tuple]:
    lat0, lon0 = home.latitude / 1e7, home.longitude / 1e7
    out = []
    for n, e in SQUARE:
        lat = lat0 + n / M_PER_DEG
        lon = lon0 + e / (M_PER_DEG * math.cos(math.radians(lat0)))
        out.append((mavutil.mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavutil.mavlink.MAV_CMD_NAV_WAYPOINT,
                    0.0, 1.0, lat, lon, ALT))
    return out


def fly_square(sitl: SitlServer) -> dict:
    """Arm, take off to 10 m, upload and fly the square, land and disarm; what the client saw."""
    c = Client(sitl)
    mav = mavutil.mavlink
    hb = c.wait("HEARTBEAT")
    home = c.wait("HOME_POSITION")
    c.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
    log = {"autopilot": hb.autopilot, "type": hb.type, "home": home, "acks": {}}
    log["acks"]["arm"] = c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    log["acks"]["takeoff"] = c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + ALT)
    c.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > (ALT - 0.5) * 1000, timeout_s=30)
    c.wait("HEARTBEAT", lambda m: (m.custom_mode >> 24) & 0xFF == LOITER)
    log["upload"] = c.upload(square_items(home))
    log["acks"]["start"] = c.command(mav.MAV_CMD_MISSION_START, 0, 0)
    t_start = sitl.time_s
    reached, times = [], []
    while len(reached) < len(SQUARE):
        reached.append(c.wait("MISSION_ITEM_REACHED", timeout_s=60).seq)
        times.append(sitl.time_s)
    log["reached"], log["mission_s"] = reached, (t_start, sitl.time_s)
    log["square_s"] = (times[0], times[-1])  # from the first corner to the last
    log["acks"]["land"] = c.command(mav.MAV_CMD_NAV_LAND)
    c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, timeout_s=60)
    log["disarmed_hb"] = c.wait("HEARTBEAT", lambda m: not m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    log["acks"]["disarm"] = c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    log["seen"] = c.seen
    c.conn.close()
    return log


def distance_to_square(points_ne: np.ndarray) -> np.ndarray:
    corners = np.array(SQUARE + SQUARE[:1])
    best = np.full(len(points_ne), np.inf)
    for a, b in zip(corners[:-1], corners[1:]):
        ab = b - a
        t = np.clip(((points_ne - a) @ ab) / (ab @ ab), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points_ne - (a + t[:, None] * ab), axis=1))
    return best


def _client_ne(log, home, t0, t1) -> np.ndarray:
    """North/east (m) of the GLOBAL_POSITION_INT the client received between t0 and t1 (on the square legs)."""
    lat0, lon0 = home.latitude / 1e7, home.longitude / 1e7
    rows = [(m.lat / 1e7, m.lon / 1e7) for t, m in log["seen"]["GLOBAL_POSITION_INT"] if t0 <= t <= t1]
    lat, lon = np.array(rows).T
    return np.column_stack([(lat - lat0) * M_PER_DEG, (lon - lon0) * M_PER_DEG * math.cos(math.radians(lat0))])


def _truth_ne(sitl: SitlServer, t0: float, t1: float) -> np.ndarray:
    ts, vals = sitl.views["simulator"]["truth"]
    t = np.asarray(ts) / 1e6
    v = np.vstack(vals)
    return v[(t >= t0) & (t <= t1), :2]


@pytest.fixture(scope="module")
def normal_flight():
    with SitlServer(LOCAL, seed=1, record=True, log=lambda line: None) as sitl:
        log = fly_square(sitl)
        return sitl, log


@pytest.fixture(scope="module")
def spoofed_flight():
    with SitlServer(LOCAL, load_scenarios(SPOOF), seed=1, record=True, log=lambda line: None) as sitl:
        log = fly_square(sitl)
        return sitl, log


# --- acceptance 1: a pymavlink client flies a mission ----------------------------------------------
def test_pymavlink_client_arms_takes_off_flies_the_square_lands_and_disarms(normal_flight):
    sitl, log = normal_flight
    mav = mavutil.mavlink
    assert log["autopilot"] == mav.MAV_AUTOPILOT_PX4 and log["type"] == mav.MAV_TYPE_QUADROTOR
    assert all(r == mav.MAV_RESULT_ACCEPTED for r in log["acks"].values()), log["acks"]
    assert log["upload"] == mav.MAV_MISSION_ACCEPTED
    assert log["reached"] == [0, 1, 2, 3]
    assert not sitl.commander.armed and not sitl.plant.armed
    # the true path went round the square, and the client saw it there
    t0, t1 = log["square_s"]
    truth = _truth_ne(sitl, t0, t1)
    assert distance_to_square(truth).max() < 4.0, "on the square (a metre or three wide at the corners)"
    seen = _client_ne(log, log["home"], t0, t1)
    assert distance_to_square(seen).max() < 4.0
    for n, e in SQUARE:  # every corner was visited
        assert np.hypot(truth[:, 0] - n, truth[:, 1] - e).min() < 3.0


def test_telemetry_runs_at_px4_onboard_rates(normal_flight):
    sitl, log = normal_flight
    seen = log["seen"]
    span = seen["SYSTEM_TIME"][-1][1].time_boot_ms / 1e3 - seen["SYSTEM_TIME"][0][1].time_boot_ms / 1e3
    for name, rate in (("ATTITUDE", 50), ("GLOBAL_POSITION_INT", 50), ("LOCAL_POSITION_NED", 30),
                       ("HIGHRES_IMU", 50), ("GPS_RAW_INT", 10), ("HEARTBEAT", 1), ("EXTENDED_SYS_STATE", 5),
                       ("SYS_STATUS", 5), ("BATTERY_STATUS", 2)):
        got = len(seen[name]) / span
        assert abs(got - rate) <= 0.05 * rate + 0.5, (name, got)
    states = {m.landed_state for _, m in seen["EXTENDED_SYS_STATE"]}
    assert states >= {1, 2, 3, 4}, "on ground, taking off, in air and landing were reported"
    assert "MISSION_CURRENT" in seen and "HOME_POSITION" in seen


def test_mission_download_params_and_command_errors():
    mav = mavutil.mavlink
    with SitlServer(LOCAL, seed=3, log=lambda line: None) as sitl:
        c = Client(sitl)
        home = c.wait("HOME_POSITION")
        assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_TEMPORARILY_REJECTED, \
            "no position estimate yet at boot: arming refused"
        assert c.command(mav.MAV_CMD_MISSION_START) == mav.MAV_RESULT_DENIED, "no mission"
        assert c.command(mav.MAV_CMD_NAV_TAKEOFF) == mav.MAV_RESULT_TEMPORARILY_REJECTED, "disarmed"
        assert c.command(mav.MAV_CMD_DO_SET_MODE, 1, 1, 0) == mav.MAV_RESULT_DENIED, "manual needs sticks"
        assert c.command(12345) == mav.MAV_RESULT_UNSUPPORTED
        items = square_items(home)
        assert c.upload(items) == mav.MAV_MISSION_ACCEPTED
        c.mav.mission_request_list_send(1, 1, 0)
        assert c.wait("MISSION_COUNT").count == 4
        for seq, (frame, cmd, _, _, lat, lon, alt) in enumerate(items):
            c.mav.mission_request_int_send(1, 1, seq, 0)
            it = c.wait("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s)
            assert (it.frame, it.command, it.x, it.y, it.z) == (frame, cmd, round(lat * 1e7), round(lon * 1e7), alt)
        c.mav.mission_clear_all_send(1, 1, 0)
        assert c.wait("MISSION_ACK").type == mav.MAV_MISSION_ACCEPTED
        c.mav.mission_request_list_send(1, 1, 0)
        assert c.wait("MISSION_COUNT").count == 0
        # parameters
        c.mav.param_request_list_send(1, 1)
        first = c.wait("PARAM_VALUE")
        names = {first.param_id} | {c.wait("PARAM_VALUE").param_id for _ in range(first.param_count - 1)}
        assert {"MIS_TAKEOFF_ALT", "MPC_XY_CRUISE", "COM_OF_LOSS_T", "NAV_ACC_RAD"} <= names
        c.mav.param_set_send(1, 1, b"MPC_XY_CRUISE", 7.5, mav.MAV_PARAM_TYPE_REAL32)
        assert c.wait("PARAM_VALUE", lambda m: m.param_id == "MPC_XY_CRUISE").param_value == 7.5
        import struct

        for wire in (struct.unpack("<f", struct.pack("<i", 2))[0], 1.0):  # bytewise (PX4, MAVSDK), then naive
            c.mav.param_set_send(1, 1, b"COM_OBL_ACT", wire, mav.MAV_PARAM_TYPE_INT32)
            got = c.wait("PARAM_VALUE", lambda m: m.param_id == "COM_OBL_ACT")
            assert got.param_type == mav.MAV_PARAM_TYPE_INT32
            assert struct.unpack("<i", struct.pack("<f", got.param_value))[0] == (2 if wire != 1.0 else 1)
        c.mav.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
        assert c.wait("PARAM_VALUE", lambda m: m.param_id == "COM_OF_LOSS_T").param_value == 1.0
        sitl.advance(1.5)
        assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + 5)
        c.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 3000, timeout_s=20)
        assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mav.MAV_RESULT_TEMPORARILY_REJECTED, \
            "no disarming in the air"
        assert sitl.stats.errors == 0


def _reposition_then_return(seed: int, record: bool = False) -> tuple[SitlServer, Client]:
    """Arm, take off to 5 m, DO_REPOSITION (COMMAND_INT) 15 m north-east, then Return (RTL_RETURN_ALT 12 m)."""
    mav = mavutil.mavlink
    sitl = SitlServer(LOCAL, seed=seed, record=record, log=lambda line: None)
    c = Client(sitl)
    home = c.wait("HOME_POSITION")
    c.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
    c.mav.param_set_send(1, 1, b"RTL_RETURN_ALT", 12.0, mav.MAV_PARAM_TYPE_REAL32)
    c.wait("PARAM_VALUE", lambda m: m.param_id == "RTL_RETURN_ALT")
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + 5) == 0
    c.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 4300, timeout_s=20)
    c.wait("HEARTBEAT", lambda m: (m.custom_mode >> 24) & 0xFF == LOITER)
    lat = home.latitude + int(round(15 / M_PER_DEG * 1e7))
    lon = home.longitude + int(round(15 / (M_PER_DEG * math.cos(math.radians(home.latitude / 1e7))) * 1e7))
    c.mav.command_int_send(1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0,
                           -1, mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, NAN, lat, lon, 5.0)
    c.log = {"reposition": c.wait("COMMAND_ACK", lambda m: m.command == mav.MAV_CMD_DO_REPOSITION).result}
    sitl.advance(12.0)
    c.log["at"] = sitl.plant.vs.pos[0].copy()
    c.log["rtl"] = c.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    return sitl, c


def test_reposition_by_command_int_and_return_to_launch():
    mav = mavutil.mavlink
    sitl, c = _reposition_then_return(5)
    with sitl:
        assert c.log["reposition"] == mav.MAV_RESULT_ACCEPTED and c.log["rtl"] == mav.MAV_RESULT_ACCEPTED
        assert np.allclose(c.log["at"], [15.0, 15.0, -5.0], atol=1.5), c.log["at"]
        c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, timeout_s=60)
        top = min(m.z for _, m in c.seen["LOCAL_POSITION_NED"])
        assert top < -11.0, "Return climbed to RTL_RETURN_ALT first"
        assert np.hypot(*sitl.plant.vs.pos[0, :2]) < 2.0, "and landed at home"
        modes = [(m.custom_mode >> 24) & 0xFF for _, m in c.seen["HEARTBEAT"]]
        assert 5 in modes, "AUTO.RTL was reported"


def test_a_lockstep_flight_is_reproducible():
    a, ca = _reposition_then_return(6, record=True)
    b, cb = _reposition_then_return(6, record=True)
    with a, b:
        for view in ("simulator", "navigator"):
            for topic, (ts, vals) in a.views[view].items():
                tb, vb = b.views[view][topic]
                assert ts == tb, (view, topic)
                np.testing.assert_array_equal(np.vstack(vals), np.vstack(vb), err_msg=f"{view} {topic}")


def test_remote_gets_telemetry_before_it_says_anything():
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.bind(LOCAL)
        gcs.settimeout(5.0)
        with SitlServer(LOCAL, remote=gcs.getsockname(), log=lambda line: None) as sitl:
            sitl.advance(0.1)
            data, addr = gcs.recvfrom(65535)
            assert addr[1] == sitl.address[1] and data[0] == 0xFD


def test_cli_lockstep_waits_for_a_client_and_records_a_normal_flight(tmp_path):
    import os
    import subprocess
    import sys

    port, out = _free_port(), tmp_path / "normal"
    cmd = [sys.executable, "-m", "scart_bench.cli", "sitl", "--listen", f"udp:127.0.0.1:{port}", "--lockstep",
           "--duration", "4", "--record", str(out), "--split", "train", "--flight-id", "n1"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert "listening on" in proc.stderr.readline()
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "flight n1 recorded" in stdout and "stopped after 4.0 s of flight" in stderr
    ds = open_dataset(out)
    row = ds.manifest.set_index("flight_id").loc["n1"]
    assert row["mode"] == "normal" and row["split"] == "train"
    att = ds.topic("n1", "attitude")
    assert att["Timestamp"].iloc[0] == 0 and len(att) == 200, "50 Hz from boot, for 4 s"


@pytest.mark.parametrize("args, words", [
    (["--listen", "udp:nohost"], ["--listen", "udp:HOST:PORT"]),
    (["--scenario", "data/scenarios/fault_sensor_loss.toml"], ["sensor_instance_loss", "simulation mode"]),
    (["--scenario", "missing.toml"], ["missing.toml", "no such file"]),
    (["--record", "README.md"], ["--record", "README.md"]),
    (["--speed", "0"], ["--speed"]),
    (["--scenario", str(SPOOF), "--split", "train"], ["--split", "test"]),
])
def test_bad_input_exits_2_with_one_clear_line(args, words, capsys):
    assert main(["sitl", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_without_pymavlink_the_error_says_how_to_install():
    import subprocess
    import sys

    code = ("import sys; sys.modules['pymavlink'] = None; from scart_bench.cli.main import main; "
            "sys.exit(main(['sitl', '--duration', '1']))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "pip install scart-bench[mavlink]" in res.stderr, res.stderr


def test_a_mission_started_on_the_ground_takes_off_first():
    mav = mavutil.mavlink
    with SitlServer(LOCAL, seed=7, log=lambda line: None) as sitl:
        c = Client(sitl)
        home = c.wait("HOME_POSITION")
        c.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
        frame, cmd, p1, p2, lat, lon, _ = square_items(home)[0]
        assert c.upload([(frame, cmd, p1, p2, lat, lon, 8.0)]) == mav.MAV_MISSION_ACCEPTED
        assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        assert c.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
        assert c.wait("MISSION_ITEM_REACHED", timeout_s=40).seq == 0
        c.wait("HEARTBEAT", lambda m: (m.custom_mode >> 24) & 0xFF == LOITER)
        climb = [m for _, m in c.seen["LOCAL_POSITION_NED"] if m.z > -7.0 and m.vz < -0.3]
        assert climb and max(math.hypot(m.x, m.y) for m in climb) < 1.0, "straight up to 8 m, then on"


GUST = """
[scenario]
id = "gust-north"
injection_point = "environment"
kind = "fault"

[[scenario.start]]
condition = "time_window"
start_s = 8.0

[[scenario.end]]
condition = "duration"
seconds = 4.0

[[scenario.actions]]
action = "wind_gust"
speed = 8.0
direction_deg = 0.0
rise_s = 0.5
"""


GPS_BIAS = """
[scenario]
id = "gps-bias-east"
injection_point = "sensor"

[[scenario.start]]
condition = "time_window"
start_s = 8.0

[[scenario.end]]
condition = "duration"
seconds = 4.0

[[scenario.actions]]
action = "bias"
target = ["sensor_gps.lat", "sensor_gps.lon"]
offset = 2.0
direction_deg = 90.0
"""


def _hover(scenarios, seed: int = 8) -> SitlServer:
    """Arm, take off to 5 m and hover until t = 13 s (a scenario acts from 8 s); the recorded server."""
    mav = mavutil.mavlink
    sitl = SitlServer(LOCAL, scenarios, seed=seed, record=True, log=lambda line: None)
    c = Client(sitl)
    home = c.wait("HOME_POSITION")
    sitl.advance(1.5)
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + 5)
    sitl.advance(13.0 - sitl.time_s)
    sitl.close()
    return sitl


@pytest.fixture(scope="module")
def calm_hover():
    return _hover([])


@pytest.mark.parametrize("toml, axis, sign, point", [(GUST, 0, 1.0, "environment"), (GPS_BIAS, 1, -1.0, "sensor")])
def test_physical_and_sensor_scenarios_move_the_vehicle(calm_hover, toml, axis, sign, point, tmp_path):
    path = tmp_path / "scenario.toml"
    path.write_text(toml)
    sitl = _hover(load_scenarios(path))
    assert sitl.windows() == [(8_000_000, 12_000_000)]
    rec = sitl.record("x")
    assert rec.manifest["injection_point"] == point
    moved = {}
    for name, s in (("calm", calm_hover), ("attacked", sitl)):
        track = sign * _truth_ne(s, 8.0, 13.0)[:, axis]
        moved[name] = track.max() - track[0]
    assert moved["attacked"] > moved["calm"] + 0.5, moved


def test_sensor_instance_loss_is_refused_with_a_clear_error():
    from scart_bench.generator.sitl.server import SitlError

    with pytest.raises(SitlError, match="sensor_instance_loss"):
        SitlServer(LOCAL, load_scenarios(ROOT / "data" / "scenarios" / "fault_sensor_loss.toml"))


# --- acceptance 4: offboard -----------------------------------------------------------------------
def test_offboard_needs_setpoints_and_their_loss_triggers_the_failsafe():
    mav = mavutil.mavlink
    with SitlServer(LOCAL, seed=4, log=lambda line: None) as sitl:
        c = Client(sitl)
        c.wait("HOME_POSITION")
        sitl.advance(1.5)
        assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        offboard = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, OFFBOARD_MAIN, 0)
        assert c.command(mav.MAV_CMD_DO_SET_MODE, *offboard) == mav.MAV_RESULT_TEMPORARILY_REJECTED, \
            "no setpoints streaming yet"
        pos_only = 0b0000_1101_1111_1000  # position + yaw
        last = [0.0]

        def stream(seconds: float, z: float = -6.0, every: float = 0.05):
            end = sitl.time_s + seconds
            while sitl.time_s < end:
                c.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, pos_only, 3.0, 2.0, z,
                                                         0, 0, 0, 0, 0, 0, 0.0, 0)
                last[0] = sitl.time_s
                sitl.advance(every)
                list(c._drain())

        stream(0.5)
        assert c.command(mav.MAV_CMD_DO_SET_MODE, *offboard) == mav.MAV_RESULT_ACCEPTED
        t_switch = sitl.time_s
        stream(10.0)
        stream(3.0, every=0.6)  # a slow stream (gaps under COM_OF_LOSS_T) keeps offboard
        modes = {(m.custom_mode >> 16) & 0xFF for t, m in c.seen["HEARTBEAT"] if t > t_switch + 0.1}
        assert modes == {OFFBOARD_MAIN}
        assert np.allclose(sitl.plant.vs.pos[0], [3.0, 2.0, -6.0], atol=1.0), sitl.plant.vs.pos[0]
        assert sitl.stats.failsafes == 0
        stopped = last[0]
        text = c.wait("STATUSTEXT", lambda m: "offboard" in m.text.lower(), timeout_s=5.0)
        t_failsafe = sitl.time_s
        assert "failsafe" in text.text.lower()
        hb = c.wait("HEARTBEAT", lambda m: (m.custom_mode >> 16) & 0xFF == AUTO)
        assert (hb.custom_mode >> 24) & 0xFF == LAND_MODE, "COM_OBL_ACT 0: land"
        assert 1.0 <= t_failsafe - stopped <= 1.0 + 0.1, "after COM_OF_LOSS_T (1 s) without setpoints"
        c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, timeout_s=30)
        assert sitl.stats.failsafes == 1


def test_offboard_body_frame_velocity_flies_along_the_heading():
    mav = mavutil.mavlink
    with SitlServer(LOCAL, seed=4, log=lambda line: None) as sitl:
        c = Client(sitl)
        home = c.wait("HOME_POSITION")
        sitl.advance(1.5)
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home.altitude / 1000 + 5)
        c.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 4300, timeout_s=20)
        forward = 0b0000_1101_1110_0111  # vx, vy (body frame) only: z holds, yaw holds

        def send():
            c.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_BODY_NED, forward, 0, 0, 0, 2.0, 0, 0,
                                                     0, 0, 0, 0, 0)
            sitl.advance(0.05)

        send()
        assert c.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0) == 0
        list(c._drain())  # read what is queued: the next messages are fresh
        start = c.wait("LOCAL_POSITION_NED")
        heading = c.wait("ATTITUDE").yaw
        for _ in range(100):
            send()
        list(c._drain())
        end = c.wait("LOCAL_POSITION_NED")
        dn, de = end.x - start.x, end.y - start.y
        assert math.hypot(dn, de) > 6.0 and abs(end.z - start.z) < 0.5
        assert abs(math.remainder(math.atan2(de, dn) - heading, 2 * math.pi)) < math.radians(5)


# --- acceptance 3 (pymavlink): the SCART layer on the link ------------------------------------------
def test_gps_spoofing_on_the_link_pulls_the_mission_off_the_square_while_the_client_sees_it(spoofed_flight,
                                                                                            normal_flight):
    sitl, log = spoofed_flight
    assert log["reached"] == [0, 1, 2, 3], "the deceived mission still completes"
    (start, end), = sitl.windows()
    t0, t1 = log["square_s"]
    assert t0 < start / 1e6 < t1, "the attack starts on the square (after the second corner)"
    seen = _client_ne(log, log["home"], t0, t1)
    assert distance_to_square(seen).max() < 6.0, "the client's telemetry stays on the square"
    # where the client is told the last corner is reached, the vehicle really is far from it
    corner = np.array(SQUARE[-1])
    last_seen = _client_ne(log, log["home"], t1 - 0.05, t1)[-1]
    last_true = _truth_ne(sitl, t1 - 0.05, t1)[-1]
    assert np.linalg.norm(last_seen - corner) < 2.0
    assert np.linalg.norm(last_true - corner) > 10.0, last_true
    nsitl, nlog = normal_flight
    normal_true = _truth_ne(nsitl, nlog["square_s"][1] - 0.05, nlog["square_s"][1])[-1]
    assert np.linalg.norm(normal_true - corner) < 2.0, "without the attack it is there"


def test_recorded_flights_are_labelled_and_score_in_a_benchmark_run(normal_flight, spoofed_flight, tmp_path):
    out = tmp_path / "ds"
    save_recording(normal_flight[0].record("sitl-normal-train", split="train"), out)
    save_recording(normal_flight[0].record("sitl-normal-val", split="validation"), out)
    spoofed = spoofed_flight[0]
    save_recording(spoofed.record("sitl-spoofed"), out)
    ds = open_dataset(out)
    row = ds.manifest.set_index("flight_id").loc["sitl-spoofed"]
    assert row["mode"] == "simulation" and row["scenario_id"] == "gps-spoof-link" and row["split"] == "test"
    (start, end), = spoofed.windows()
    assert (row["attack_start_us"], row["attack_end_us"]) == (start, end)
    nav = ds.topic("sitl-spoofed", "local_position_ned")
    sim = ds.topic("sitl-spoofed", "local_position_ned", view="simulator")
    ts = nav["Timestamp"].to_numpy()
    inside = (ts >= start) & (ts < end)
    np.testing.assert_array_equal(nav["Is_Anomaly"].to_numpy(), inside.astype(np.int8))
    moved = np.hypot(*(nav[["x", "y"]].to_numpy() - sim[["x", "y"]].to_numpy()).T)
    assert moved[~inside].max() == 0.0 and moved[inside].max() > 5.0
    truth = ds.topic("sitl-spoofed", "truth", view="simulator")
    assert len(truth) > 0 and truth["Is_Anomaly"].sum() == 0
    run = tmp_path / "run"
    assert main(["run", "--detectors", "statistical", "--dataset", str(out), "--out", str(run)]) == 0
    import pandas as pd

    flights = pd.read_csv(run / "flight_scores.csv")
    assert "sitl-spoofed" in set(flights["flight_id"])


# --- acceptance 2 and 3 (MAVSDK-Python): the CLI flown by MAVSDK's action, mission and telemetry plugins ---
def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(LOCAL)
        return s.getsockname()[1]


async def _mavsdk_square(port: int) -> dict:
    """Fly the square with MAVSDK-Python 4 (native binding): arm, take off, mission, land; what it saw."""
    import asyncio

    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mission import MissionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.mission import MissionItem, MissionPlan

    log: dict = {"positions": [], "progress": []}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as drone:
        await drone.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await drone.first_autopilot(timeout_s=20.0)
        assert system is not None, "MAVSDK found no autopilot"
        log["autopilot"] = (await system.autopilot_type()).name
        action, mission, telemetry = ActionAsync(system), MissionAsync(system), TelemetryAsync(system)
        async for ok in telemetry.subscribe_health_all_ok():
            if ok:
                break
        home = await telemetry.home()
        await action.set_takeoff_altitude(ALT)
        await action.arm()
        await action.takeoff()
        async for pos in telemetry.subscribe_position():
            if pos.relative_altitude_m > ALT - 0.5:
                break
        lat0, lon0 = home.latitude_deg, home.longitude_deg
        items = [MissionItem(lat0 + n / M_PER_DEG, lon0 + e / (M_PER_DEG * math.cos(math.radians(lat0))), ALT, 5.0,
                             False, NAN, NAN, MissionItem.CameraAction.NONE, NAN, NAN, 1.0, NAN, NAN,
                             MissionItem.VehicleAction.NONE) for n, e in SQUARE]
        await mission.upload_mission(MissionPlan(items))
        await mission.start_mission()

        async def watch():
            async for pos in telemetry.subscribe_position():
                current = log["progress"][-1][0] if log["progress"] else 0
                log["positions"].append((pos.latitude_deg, pos.longitude_deg, current))

        watcher = asyncio.ensure_future(watch())
        async for p in mission.subscribe_mission_progress():
            log["progress"].append((p.current, p.total))
            if p.current == p.total:
                break
        watcher.cancel()
        log["finished"] = await mission.is_mission_finished()
        await action.land()
        async for in_air in telemetry.subscribe_in_air():
            if not in_air:
                break
        async for armed in telemetry.subscribe_armed():
            if not armed:
                break
        log["home"] = (lat0, lon0)
    return log


def _fly_cli_with_mavsdk(tmp_path, *extra: str) -> tuple[dict, str]:
    import asyncio
    import os
    import signal
    import subprocess
    import sys

    port = _free_port()
    cmd = [sys.executable, "-m", "scart_bench.cli", "sitl", "--listen", f"udp:127.0.0.1:{port}", "--lockstep",
           "--seed", "1", *extra]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        line = ""
        while "listening on" not in line:
            line = proc.stderr.readline()
            assert line or proc.poll() is None, "sitl exited early"
        log = asyncio.run(asyncio.wait_for(_mavsdk_square(port), timeout=300))
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    return log, stdout


def _mavsdk_ne(log, after_item: int = -1) -> np.ndarray:
    """North/east (m) of the positions MAVSDK reported during the mission (once ``after_item`` was reached)."""
    lat0, lon0 = log["home"]
    lat, lon, current = np.array(log["positions"]).T
    lat, lon = lat[current > after_item], lon[current > after_item]
    return np.column_stack([(lat - lat0) * M_PER_DEG, (lon - lon0) * M_PER_DEG * math.cos(math.radians(lat0))])


@pytest.fixture(scope="module")
def mavsdk_asyncio():
    try:
        import mavsdk.asyncio  # noqa: F401  (MAVSDK-Python >= 4: the native binding, its library in the wheel)
    except ImportError:
        pytest.skip("MAVSDK-Python >= 4 is not installed (pip install 'mavsdk>=4.1', in the dev extra)")


def test_mavsdk_flies_the_square_mission_with_its_action_and_mission_plugins(mavsdk_asyncio, tmp_path):
    log, _ = _fly_cli_with_mavsdk(tmp_path)
    assert log["autopilot"] == "PX4"
    assert log["finished"] and log["progress"][-1] == (4, 4)
    assert [c for c, _ in log["progress"]] == sorted({c for c, _ in log["progress"]}), "items in order"
    seen = _mavsdk_ne(log)
    for n, e in SQUARE:
        assert np.hypot(seen[:, 0] - n, seen[:, 1] - e).min() < 2.5, "every corner was reached"


def test_mavsdk_mission_under_gps_spoofing_is_recorded_labelled_and_scored(mavsdk_asyncio, normal_flight, tmp_path):
    out = tmp_path / "ds"
    save_recording(normal_flight[0].record("sitl-normal-train", split="train"), out)
    save_recording(normal_flight[0].record("sitl-normal-val", split="validation"), out)
    log, stdout = _fly_cli_with_mavsdk(tmp_path, "--scenario", str(SPOOF), "--record", str(out),
                                       "--flight-id", "mavsdk-spoofed")
    assert "flight mavsdk-spoofed recorded in" in stdout
    assert log["finished"], "the deceived mission completes"
    seen = _mavsdk_ne(log, after_item=0)  # from the first corner on
    assert distance_to_square(seen).max() < 6.0, "MAVSDK's telemetry stays on the square"
    ds = open_dataset(out)
    row = ds.manifest.set_index("flight_id").loc["mavsdk-spoofed"]
    assert row["mode"] == "simulation" and row["scenario_id"] == "gps-spoof-link"
    start, end = int(row["attack_start_us"]), int(row["attack_end_us"])
    nav = ds.topic("mavsdk-spoofed", "local_position_ned")
    truth = ds.topic("mavsdk-spoofed", "truth", view="simulator")
    inside = ((nav["Timestamp"] >= start) & (nav["Timestamp"] < end)).to_numpy()
    np.testing.assert_array_equal(nav["Is_Anomaly"].to_numpy(), inside.astype(np.int8))
    t_true = truth["Timestamp"].to_numpy()
    true_xy = np.column_stack([np.interp(nav["Timestamp"], t_true, truth[c]) for c in ("x", "y")])
    gap = np.hypot(*(nav[["x", "y"]].to_numpy() - true_xy).T)
    assert gap[~inside & (nav["Timestamp"] < start).to_numpy()].max() < 2.0
    assert gap[inside].max() > 10.0, "inside the window the vehicle is really elsewhere"
    t_true = truth["Timestamp"].to_numpy()
    attacked = truth[["x", "y"]].to_numpy()[(t_true >= start) & (t_true < end)]
    assert distance_to_square(attacked).max() > 8.0, "off the square"
    run = tmp_path / "run"
    assert main(["run", "--detectors", "statistical", "--dataset", str(out), "--out", str(run)]) == 0
    import pandas as pd

    assert "mavsdk-spoofed" in set(pd.read_csv(run / "flight_scores.csv")["flight_id"])
