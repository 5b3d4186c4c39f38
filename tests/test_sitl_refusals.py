"""The sitl refuses what PX4 refuses: what a MAVLink client receives for bad missions, commands and setpoints.

Each test flies a pymavlink ground station over loopback UDP against an in-process sitl stepped in
lockstep, and asserts the answer the client gets (MISSION_ACK type, COMMAND_ACK result, PARAM_VALUE)
and that the vehicle does not go where it was wrongly told.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pymavlink", reason="the sitl needs pymavlink (pip install scart-bench[mavlink])")
from pymavlink import mavutil  # noqa: E402

from scart_bench.generator.sitl import checks, missions  # noqa: E402
from scart_bench.generator.sitl.server import SitlServer  # noqa: E402

mav = mavutil.mavlink
NAN, INF = float("nan"), float("inf")
INT32_MAX = 2**31 - 1  # 214.7483647 deg as a MISSION_ITEM_INT latitude
REL_INT = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


class Client:
    """A pymavlink ground station stepping the sitl while it waits (``sitl.advance``)."""

    def __init__(self, sitl: SitlServer, system: int = 255):
        self.sitl = sitl
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{sitl.address[1]}", source_system=system,
                                               source_component=190)
        self.mav = self.conn.mav
        self.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self.texts: list[str] = []

    def wait(self, kind: str, cond=lambda m: True, timeout_s: float = 5.0):
        """The next ``kind`` message meeting ``cond`` within ``timeout_s`` of simulated time."""
        end = self.sitl.time_s + timeout_s
        while self.sitl.time_s < end:
            while (m := self.conn.recv_match(blocking=False)) is not None:
                if m.get_type() == "STATUSTEXT":
                    self.texts.append(m.text)
                if m.get_type() == kind and cond(m):
                    return m
            self.sitl.advance(0.02)
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def command(self, command: int, *params: float) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        return self.wait("COMMAND_ACK", lambda m: m.command == command).result

    def item(self, seq: int, lat: float, lon: float, alt: float, command: int = mav.MAV_CMD_NAV_WAYPOINT,
             frame: int = REL_INT, p2: float = 0.0) -> None:
        """One MISSION_ITEM_INT; ``lat``/``lon`` in degrees, or ints already scaled by 1e7."""
        x = lat if isinstance(lat, int) else int(round(lat * 1e7))
        y = lon if isinstance(lon, int) else int(round(lon * 1e7))
        self.mav.mission_item_int_send(1, 1, seq, frame, command, 0, 1, 0.0, p2, 0.0, NAN, x, y, alt, 0)

    def upload(self, items: list[tuple]) -> int:
        """A whole upload; each item ``(lat, lon, alt[, command, frame, p2])``; the MISSION_ACK type."""
        self.mav.mission_count_send(1, 1, len(items), 0)
        while True:
            m = self._request_or_ack()
            if m.get_type() == "MISSION_ACK":
                return m.type
            self.item(m.seq, *items[m.seq])

    def _request_or_ack(self):
        end = self.sitl.time_s + 2.0
        while self.sitl.time_s < end:
            while (m := self.conn.recv_match(blocking=False)) is not None:
                if m.get_type() == "STATUSTEXT":
                    self.texts.append(m.text)
                if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"):
                    return m
            self.sitl.advance(0.02)
        raise AssertionError("mission upload stalled")

    def mission_count(self) -> int:
        self.mav.mission_request_list_send(1, 1, 0)
        return self.wait("MISSION_COUNT").count


@pytest.fixture
def sitl():
    with SitlServer(("127.0.0.1", 0), seed=2, log=lambda line: None) as s:
        yield s


@pytest.fixture
def client(sitl):
    c = Client(sitl)
    c.wait("HOME_POSITION")
    yield c
    c.conn.close()


def _home_lat_lon(sitl: SitlServer) -> tuple[float, float]:
    lat, lon, _ = sitl.commander.home_global()
    return lat, lon


# --- acceptance: MISSION_COUNT 65535, latitude 214.7 deg, altitude inf, NaN speed --------------------
def test_mission_count_65535_is_answered_no_space_and_the_protocol_stays_usable(client, sitl):
    client.mav.mission_count_send(1, 1, 65535, 0)
    assert client.wait("MISSION_ACK").type == mav.MAV_MISSION_NO_SPACE, "above PX4 SITL's 65534 items"
    lat, lon = _home_lat_lon(sitl)
    assert client.upload([(lat + 1e-4, lon, 10.0)]) == mav.MAV_MISSION_ACCEPTED, "no upload left hanging"
    assert client.mission_count() == 1


@pytest.mark.parametrize("x, y, expected", [
    (INT32_MAX, None, mav.MAV_MISSION_INVALID_PARAM5_X),  # latitude 214.7483647 deg
    (-900_000_001, None, mav.MAV_MISSION_INVALID_PARAM5_X),  # -90.0000001 deg
    (None, 1_800_000_001, mav.MAV_MISSION_INVALID_PARAM6_Y),  # longitude 180.0000001 deg
])
def test_a_waypoint_off_the_planet_is_refused_with_the_coordinate_named(client, sitl, x, y, expected):
    lat, lon = _home_lat_lon(sitl)
    good = (lat + 1e-4, lon, 10.0)
    bad = (x if x is not None else lat, y if y is not None else lon, 10.0)
    assert client.upload([good, bad]) == expected
    assert client.mission_count() == 0, "the stored mission is unchanged (none)"
    assert any("refused" in t for t in client.texts)


@pytest.mark.parametrize("alt", [INF, -INF, 20_000.0, -5_000.0])
def test_a_waypoint_at_an_infinite_or_absurd_altitude_is_refused(client, sitl, alt):
    lat, lon = _home_lat_lon(sitl)
    assert client.upload([(lat, lon + 1e-4, alt)]) == mav.MAV_MISSION_INVALID_PARAM7


def test_nan_and_negative_speeds_are_refused_in_commands_and_missions(client, sitl):
    speed = mav.MAV_CMD_DO_CHANGE_SPEED
    assert client.command(speed, 1, NAN) == mav.MAV_RESULT_DENIED
    assert client.command(speed, 2, -3.0) == mav.MAV_RESULT_DENIED, "a negative climb speed"
    assert client.command(speed, 1, INF) == mav.MAV_RESULT_DENIED
    assert sitl.commander.speed == sitl.params["MPC_XY_CRUISE"], "the cruise speed is unchanged"
    assert client.command(speed, 1, -1.0) == mav.MAV_RESULT_ACCEPTED, "MAVLink's -1: no change"
    assert client.command(speed, 1, 50.0) == mav.MAV_RESULT_ACCEPTED
    assert sitl.commander.speed == sitl.params["MPC_XY_VEL_MAX"], "capped at MPC_XY_VEL_MAX as PX4 caps it"
    lat, lon = _home_lat_lon(sitl)
    change_speed = (0, 0, 0.0, speed, mav.MAV_FRAME_MISSION, NAN)
    assert client.upload([(lat, lon, 10.0), change_speed]) == mav.MAV_MISSION_INVALID_PARAM2


# --- commands ---------------------------------------------------------------------------------------
def test_take_off_to_an_infinite_altitude_is_denied_and_the_vehicle_stays_on_the_ground(client, sitl):
    sitl.advance(1.5)
    assert client.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    home_alt = sitl.commander.home_global()[2]
    assert client.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, INF) == mav.MAV_RESULT_DENIED
    assert client.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_alt + 50_000) == \
        mav.MAV_RESULT_DENIED, "50 km up"
    assert client.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 214.7, 8.5, home_alt + 5) == \
        mav.MAV_RESULT_DENIED, "latitude 214.7"
    sitl.advance(2.0)
    assert sitl.plant.position[2] > -0.3, "still on the ground"
    assert any("denied" in t for t in client.texts), "a STATUSTEXT says why"
    assert client.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_alt + 5) == mav.MAV_RESULT_ACCEPTED


def test_bad_command_parameters_are_denied_not_crashed_on(client, sitl):
    cmds = [
        (mav.MAV_CMD_COMPONENT_ARM_DISARM, NAN),
        (mav.MAV_CMD_COMPONENT_ARM_DISARM, 7),
        (mav.MAV_CMD_DO_SET_MODE, NAN, 4, 3),
        (mav.MAV_CMD_DO_SET_MISSION_CURRENT, NAN),
        (mav.MAV_CMD_REQUEST_MESSAGE, INF),
        (mav.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 214.7, 8.5, 500.0),
        (mav.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 47.4, 8.5, INF),
    ]
    for c in cmds:
        assert client.command(*c) == mav.MAV_RESULT_DENIED, c
    assert sitl.stats.errors == 0
    assert client.command(mav.MAV_CMD_MISSION_START, INF) == mav.MAV_RESULT_DENIED, "an infinite parameter"
    assert client.command(mav.MAV_CMD_MISSION_START, NAN) == mav.MAV_RESULT_DENIED, "no mission (not a crash)"


def test_a_reposition_by_command_int_to_latitude_214_7_is_denied(client, sitl):
    sitl.advance(1.5)
    client.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    client.mav.command_int_send(1, 1, REL_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, NAN, INT32_MAX,
                                85_000_000, 5.0)
    ack = client.wait("COMMAND_ACK", lambda m: m.command == mav.MAV_CMD_DO_REPOSITION)
    assert ack.result == mav.MAV_RESULT_DENIED and sitl.commander.target is None


def test_out_of_range_parameter_values_are_refused_and_the_reply_keeps_the_old_value(client, sitl):
    for value in (-3.0, NAN, 1e9):
        client.mav.param_set_send(1, 1, b"MPC_Z_VEL_MAX_UP", value, mav.MAV_PARAM_TYPE_REAL32)
        assert client.wait("PARAM_VALUE", lambda m: m.param_id == "MPC_Z_VEL_MAX_UP").param_value == 3.0
    client.mav.param_set_send(1, 1, b"MIS_TAKEOFF_ALT", 5e6, mav.MAV_PARAM_TYPE_REAL32)
    assert client.wait("PARAM_VALUE", lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 2.5
    client.mav.param_set_send(1, 1, b"MPC_Z_VEL_MAX_UP", 4.0, mav.MAV_PARAM_TYPE_REAL32)
    assert client.wait("PARAM_VALUE", lambda m: m.param_id == "MPC_Z_VEL_MAX_UP").param_value == 4.0


def test_offboard_setpoints_with_infinite_or_far_targets_are_ignored(client, sitl):
    pos_only = 0b0000_1101_1111_1000
    for x, z in ((INF, -5.0), (3.0, -INF), (3e7, -5.0), (3.0, -50_000.0)):
        client.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, pos_only, x, 2.0, z,
                                                      0, 0, 0, 0, 0, 0, 0, 0)
    sitl.advance(0.1)
    assert sitl.stats.ignored_setpoints == 4 and sitl.commander.offboard.count == 0
    assert client.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0) == \
        mav.MAV_RESULT_TEMPORARILY_REJECTED, "refused setpoints do not count as streaming"


# --- the upload protocol: sequence, busy, timeout ------------------------------------------------------
def test_an_item_outside_the_announced_count_is_answered_invalid_sequence(client, sitl):
    lat, lon = _home_lat_lon(sitl)
    client.mav.mission_count_send(1, 1, 2, 0)
    assert client.wait("MISSION_REQUEST_INT").seq == 0
    client.item(5, lat, lon, 10.0)
    assert client.wait("MISSION_ACK").type == mav.MAV_MISSION_INVALID_SEQUENCE
    client.item(0, lat, lon, 10.0)
    assert client.wait("MISSION_REQUEST_INT", lambda m: m.seq == 1).seq == 1, "the upload goes on"


def test_a_second_client_gets_an_error_while_an_upload_runs(client, sitl):
    other = Client(sitl, system=254)
    client.mav.mission_count_send(1, 1, 3, 0)
    client.wait("MISSION_REQUEST_INT")
    other.mav.mission_count_send(1, 1, 1, 0)
    assert other.wait("MISSION_ACK").type == mav.MAV_MISSION_ERROR
    other.conn.close()


def test_an_abandoned_upload_is_asked_again_then_times_out_and_the_protocol_is_idle(client, sitl, monkeypatch):
    now = [0.0]
    monkeypatch.setattr(sitl.missions, "clock", lambda: now[0])
    lat, lon = _home_lat_lon(sitl)
    client.mav.mission_count_send(1, 1, 3, 0)
    client.wait("MISSION_REQUEST_INT")
    client.item(0, lat, lon, 10.0)
    client.wait("MISSION_REQUEST_INT", lambda m: m.seq == 1)
    asked = 0
    while now[0] < missions.TIMEOUT_S + 1.0:  # the client went away: 6 s of wall time pass
        now[0] += 0.1
        sitl.step()
        while (m := client.conn.recv_match(blocking=False)) is not None:
            asked += m.get_type() == "MISSION_REQUEST_INT" and m.seq == 1
            if m.get_type() == "STATUSTEXT":
                client.texts.append(m.text)
    assert 6 <= asked <= missions.TIMEOUT_S / missions.RETRY_S, "asked again about every 0.5 s"
    assert any("timeout" in t.lower() for t in client.texts)
    assert sitl.missions.upload is None
    other = Client(sitl, system=254)
    assert other.upload([(lat, lon, 10.0)]) == mav.MAV_MISSION_ACCEPTED, "idle again: anyone may upload"
    other.conn.close()


def test_the_bounds_are_the_documented_ones():
    assert checks.MAX_MISSION_ITEMS == 65534 and checks.MAX_HEIGHT_M == 10_000.0
    assert checks.target_ok(np.array([15.0, 15.0, -5.0]))
    assert not checks.target_ok(np.array([math.nan, 0.0, -5.0]))
    assert not checks.target_ok(np.array([0.0, 0.0, -10_001.0]))
