"""Fuzz the sitl's message handling: every handled message type with random fields, NaN, inf, huge
counts and out-of-range enums. The sitl must answer or ignore each one within a bounded time, never
raise, and never take a target that is not finite or lies outside its bounds.

The messages are packed and parsed as on the wire (pymavlink), then handed to the server's own
dispatch (:meth:`SitlServer.handle`, which lets exceptions through; ``poll`` would count and log
them instead), and the vehicle is stepped 20 ms after each one.
"""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink", reason="the sitl needs pymavlink (pip install scart-bench[mavlink])")
hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is in the dev extra (make test installs it)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from scart_bench.generator.sitl import checks  # noqa: E402
from scart_bench.generator.sitl.commander import PARAM_SPECS  # noqa: E402
from scart_bench.generator.sitl.server import SitlServer  # noqa: E402

#: the most a target may lie above the origin: the checked bound plus the largest parameter that
#: home adds to it (a Return climbs RTL_RETURN_ALT, at most 150 m, above home)
HEIGHT_BOUND_M = checks.MAX_HEIGHT_M + max(p.high for p in PARAM_SPECS if p.name in ("RTL_RETURN_ALT",
                                                                                        "MIS_TAKEOFF_ALT"))
#: a message's handling plus 20 ms of flight, on a slow shared machine
MAX_S_PER_MESSAGE = 1.0
HANDLED_COMMANDS = (400, 22, 21, 20, 17, 176, 300, 224, 192, 178, 179, 511, 512, 520, 410)
NASTY_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 1e38, -1e38, 3.4e38, 1e-45, -1.0, -2.0, 214.7, 90.0, 180.0)


def _int_range(ftype: str) -> tuple[int, int]:
    bits = int("".join(ch for ch in ftype if ch.isdigit()))
    return (0, 2**bits - 1) if ftype.startswith("u") else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


def _field(name: str, ftype: str, length: int) -> st.SearchStrategy:
    """Values of one field: nasty floats, integers over their whole range and at its ends, text."""
    if name == "target_system":
        return st.sampled_from((0, 1, 1, 1, 7))
    if name == "param_id":
        return st.one_of(st.sampled_from([p.name for p in PARAM_SPECS]), st.text("ABCZ_", max_size=16)).map(str.encode)
    if name == "command":
        return st.one_of(st.sampled_from(HANDLED_COMMANDS), st.integers(0, 65535))
    if ftype == "char":
        return st.text("abcXYZ_01 ", max_size=length).map(str.encode)
    if ftype in ("float", "double"):
        one = st.one_of(st.sampled_from(NASTY_FLOATS), st.floats(width=32 if ftype == "float" else 64))
    else:
        lo, hi = _int_range(ftype)
        one = st.one_of(st.sampled_from((lo, hi, 0, 1, 2)), st.integers(lo, hi))
    return st.lists(one, min_size=length, max_size=length) if length else one


def _message(cls) -> st.SearchStrategy:
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # in wire order
    fields = {name: _field(name, ftype, lengths[name]) for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True)}
    return st.fixed_dictionaries(fields).map(lambda kw: cls(**kw))


@pytest.fixture(scope="module")
def flying():
    """A sitl with a client (a UDP sink that takes the answers), armed and taking off, and the handled types."""
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    with SitlServer(("127.0.0.1", 0), seed=9, log=lambda line: None) as sitl:
        addr = sink.getsockname()
        sitl.peers[addr] = 0.0
        sitl.advance(1.5)
        sitl.commander.arm()
        sitl.commander.takeoff(float("nan"))
        sitl.advance(1.0)
        yield sitl, addr, sorted(sitl._handlers)
    sink.close()


def _wire(msg) -> list:
    """``msg`` packed by a client (system 255) and parsed as the sitl parses datagrams."""
    data = msg.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190))
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return [m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]


def _within_bounds(ned) -> bool:
    ned = np.asarray(ned, dtype=float)
    return (bool(np.isfinite(ned).all()) and math.hypot(ned[0], ned[1]) <= checks.MAX_RANGE_M
            and checks.MIN_HEIGHT_M <= -ned[2] <= HEIGHT_BOUND_M)


def _assert_targets_bounded(sitl: SitlServer) -> None:
    cmd = sitl.commander
    for name in ("target", "mission_climb", "home"):
        value = getattr(cmd, name)
        assert value is None or _within_bounds(value), (name, value)
    o = cmd.offboard
    assert checks.setpoint_ok(o.pos, o.vel, o.yaw, o.yaw_rate), (o.pos, o.vel, o.yaw, o.yaw_rate)
    assert math.isfinite(cmd.speed) and math.isfinite(cmd.yaw_sp)
    assert cmd.mission_speed is None or math.isfinite(cmd.mission_speed)
    for item in cmd.mission:  # what was stored passed the checks (the height against the home of its upload)
        assert checks.mission_item_result(item, math.nan) == checks.MISSION_ACCEPTED, item
    assert np.isfinite(sitl.plant.position).all()


MESSAGE_TYPES = ("COMMAND_LONG", "COMMAND_INT", "SET_MODE", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ",
                 "PARAM_SET", "MISSION_COUNT", "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_REQUEST_LIST",
                 "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
                 "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT", "TIMESYNC", "HEARTBEAT",
                 "MISSION_ACK")
ANY_MESSAGE = st.one_of([_message(getattr(mavlink, f"MAVLink_{name.lower()}_message")) for name in MESSAGE_TYPES])


def test_the_fuzz_covers_every_handled_message_type(flying):
    _, _, handled = flying
    assert set(handled) <= set(MESSAGE_TYPES), set(handled) - set(MESSAGE_TYPES)


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(msgs=st.lists(ANY_MESSAGE, min_size=1, max_size=2))
def test_any_message_is_answered_or_ignored_quickly_and_never_moves_the_target_out_of_bounds(flying, msgs):
    sitl, addr, _ = flying
    for msg in msgs:
        for parsed in _wire(msg):
            t0 = time.perf_counter()
            sitl.handle(parsed, addr)  # raises if the handling raises
            sitl.advance(0.02)
            assert time.perf_counter() - t0 < MAX_S_PER_MESSAGE, parsed
            _assert_targets_bounded(sitl)
    assert sitl.stats.errors == 0


def _datagram(msg, cut: int, junk: bytes) -> bytes:
    """A client's frame cut short and/or with junk around it (a noisy or hostile link)."""
    frame = msg.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190))
    return junk + frame[:cut] + junk if cut else junk + frame


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(datagrams=st.lists(st.one_of(st.binary(max_size=280),
                                    st.builds(_datagram, ANY_MESSAGE, st.integers(0, 60), st.binary(max_size=8))),
                          min_size=1, max_size=4))
def test_garbage_and_broken_frames_over_loopback_udp_are_dropped_and_the_vehicle_still_answers(flying, datagrams):
    sitl, _, _ = flying
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.settimeout(2.0)
        for data in datagrams:
            client.sendto(data, sitl.address)
        t0 = time.perf_counter()
        sitl.advance(0.02)  # reads and handles them
        assert time.perf_counter() - t0 < MAX_S_PER_MESSAGE * len(datagrams)
        ping = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                    mavlink.MAVLINK_MSG_ID_HEARTBEAT, 0, 0, 0, 0, 0, 0)
        client.sendto(ping.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190)), sitl.address)
        sitl.advance(0.02)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        got = []
        while not any(m.get_type() == "COMMAND_ACK" for m in got):
            got += parser.parse_buffer(client.recv(65535)) or []
    assert sitl.stats.errors == 0
    _assert_targets_bounded(sitl)
