"""The SCART node, the MAVROS stand-in and the navigator against a real roscore (ROS 1).

Skipped, with the reason, where ROS 1 (rospy, the message packages, roscore) is not installed:
``apt-get install -y --no-install-recommends ros-core python3-rospy python3-sensor-msgs
python3-geometry-msgs python3-nav-msgs``.
"""

from __future__ import annotations

import io
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from scart_bench.dataset import open_dataset

ROOT = Path(__file__).resolve().parents[1]
try:
    from scart_bench.generator.ros import ros1

    REASON = None if shutil.which("roscore") else "roscore is not installed (apt-get install ros-core)"
except (ImportError, ValueError) as exc:  # RosError: rospy is not installed
    ros1, REASON = None, f"ROS 1 is not installed ({exc})"
pytestmark = pytest.mark.skipif(REASON is not None, reason=REASON or "")

BIAS = """
[scenario]
id = "gps-bias-north"
[[scenario.start]]
condition = "time_window"
start_s = 1.0
[[scenario.end]]
condition = "duration"
seconds = 1.0
[[scenario.actions]]
action = "bias"
target = ["position"]
offset = 5.0
direction_deg = 0.0
"""


@pytest.fixture
def procs():
    """Processes a test starts: stopped at its end even when it fails."""
    started: list[subprocess.Popen] = []
    yield started
    for proc in started:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def master():
    import rospy

    with ros1.RosCore() as uri:
        rospy.init_node("scart_test", anonymous=True, disable_signals=True)
        yield uri


def _cli(tmp_path: Path, name: str, *args: str) -> subprocess.Popen:
    out = open(tmp_path / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
    return subprocess.Popen(
        [sys.executable, "-m", "scart_bench", *args],
        cwd=ROOT,
        stdout=out,
        stderr=out,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def _stop(proc: subprocess.Popen, tmp_path: Path, name: str) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    log = (tmp_path / f"{name}.log").read_text()
    assert proc.returncode == 0, log
    return log


def _wait(cond, what: str, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.05)


def _fill(msg, rng, k: int):
    """Every field of ``msg`` set to a random value of its type (nested messages, arrays, strings, times)."""
    import genpy

    for slot, kind in zip(msg.__slots__, msg._slot_types, strict=True):
        value = getattr(msg, slot)
        base = kind.split("[")[0]
        if kind.endswith("]"):
            size = int(kind[kind.index("[") + 1 : -1] or 3)
            if base in ("float64", "float32"):
                setattr(msg, slot, list(rng.normal(size=size)))
            elif base == "uint8":
                setattr(msg, slot, bytes(rng.integers(0, 255, size=size, dtype=np.uint8)))
            elif base == "string":
                setattr(msg, slot, [f"cell-{k}-{i}" for i in range(size)])
        elif base in ("float64", "float32"):
            setattr(msg, slot, float(rng.normal() * 100))
        elif base in ("int8", "uint8", "int16", "uint16", "int32", "uint32"):
            setattr(msg, slot, int(rng.integers(0, 100)))
        elif base == "bool":
            setattr(msg, slot, bool(k % 2))
        elif base == "string":
            setattr(msg, slot, f"frame-{k}")
        elif base == "time":
            setattr(msg, slot, genpy.Time(1000 + k, int(rng.integers(0, 999_999_999))))
        elif hasattr(value, "__slots__"):
            _fill(value, rng, k)
    return msg


def _bytes(msg) -> bytes:
    buf = io.BytesIO()
    msg.serialize(buf)
    return buf.getvalue()


def _pubsub(ns_in: str, ns_out: str, names):
    import rospy

    pubs, subs, got = {}, {}, {n: [] for n in names}
    for n in names:
        t = ros1.MAVROS_TOPICS[n]
        cls = ros1.msg_class(t.msg_type)
        pubs[n] = rospy.Publisher(ros1.join(ns_in, t.ros_name), cls, queue_size=1000)
        subs[n] = rospy.Subscriber(ros1.join(ns_out, t.ros_name), cls, got[n].append, queue_size=1000)
    outputs = {ros1.join(ns_out, ros1.MAVROS_TOPICS[n].ros_name) for n in names}
    _wait(
        lambda: (
            all(p.get_num_connections() > 0 for p in pubs.values())
            and all(s.get_num_connections() > 0 for s in subs.values())
            and outputs <= _node_sends_on()
        ),
        "the node's subscriptions and publications",
    )
    return pubs, subs, got


def _node_sends_on(node: str = "/scart") -> set[str]:
    """The topics on which ``node`` has an outbound connection, as the node itself sees them (its slave
    API's bus info). Our subscriber counts a connection once the handshake is read, a moment before the
    node's publisher adds it: a message the node relays in that moment reaches nobody."""
    from xmlrpc.client import ServerProxy

    import rosgraph
    import rospy

    try:
        uri = rosgraph.Master(rospy.get_name()).lookupNode(node)
        _, _, info = ServerProxy(uri).getBusInfo(rospy.get_name())
    except (rosgraph.MasterError, OSError):  # not registered yet
        return set()
    return {c[4] for c in info if c[2] == "o"}


def test_without_a_scenario_every_field_of_every_message_passes_unchanged(master, tmp_path, procs):
    node = _cli(tmp_path, "node", "ros", "node", "--input-ns", "/a_in", "--output-ns", "/a_out")
    procs.append(node)
    names = [n for n, t in ros1.MAVROS_TOPICS.items() if t.direction == "telemetry"]
    pubs, subs, got = _pubsub("/a_in", "/a_out", names)
    rng = np.random.default_rng(1)
    sent = {n: [] for n in names}
    for k in range(3):
        for n in names:
            msg = _fill(ros1.msg_class(ros1.MAVROS_TOPICS[n].msg_type)(), rng, k)
            pubs[n].publish(msg)
            sent[n].append(_bytes(msg))  # after publish: a rospy publisher writes its own count in header.seq
        time.sleep(0.05)
    _wait(lambda: all(len(got[n]) == 3 for n in names), "every message through the node")
    for n in names:
        assert [_bytes(m) for m in got[n]] == sent[n], n
    log = _stop(node, tmp_path, "node")
    assert "0 altered" in log and "0 dropped" in log
    for s in subs.values():
        s.unregister()


def test_a_gps_bias_offsets_the_navigator_side_inside_the_window_only_and_is_labelled(
    master, tmp_path, procs
):
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import NavSatFix

    scenario = tmp_path / "bias.toml"
    scenario.write_text(BIAS)
    node = _cli(
        tmp_path,
        "node",
        "ros",
        "node",
        "--input-ns",
        "/b_in",
        "--output-ns",
        "/b_out",
        "--scenario",
        str(scenario),
        "--record",
        str(tmp_path / "ds"),
        "--flight-id",
        "b1",
    )
    procs.append(node)
    pubs, subs, got = _pubsub("/b_in", "/b_out", ["global_position_global", "local_position_pose"])
    import rospy

    for k in range(31):
        stamp = rospy.Time(100, 0) + rospy.Duration(0, k * 100_000_000)
        fix = NavSatFix(latitude=47.397742, longitude=8.545594, altitude=498.0)
        fix.header.stamp = stamp
        pose = PoseStamped()
        pose.header.stamp = stamp
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 3.0, 4.0, 10.0
        pose.pose.orientation.w = 1.0
        pubs["global_position_global"].publish(fix)
        pubs["local_position_pose"].publish(pose)
        time.sleep(0.02)
    _wait(
        lambda: len(got["local_position_pose"]) == 31 and len(got["global_position_global"]) == 31,
        "31 of each",
    )
    for k, (pose, fix) in enumerate(
        zip(got["local_position_pose"], got["global_position_global"], strict=True)
    ):
        inside = 10 <= k < 20
        assert pose.pose.position.y == pytest.approx(9.0 if inside else 4.0), k
        assert pose.pose.position.x == 3.0 and pose.pose.position.z == 10.0
        assert (fix.latitude - 47.397742) * 111_200 == pytest.approx(5.0 if inside else 0.0, abs=0.05), k
    _stop(node, tmp_path, "node")
    ds = open_dataset(tmp_path / "ds")
    row = ds.manifest.set_index("flight_id").loc["b1"]
    assert (row.attack_start_us, row.attack_end_us) == (1_000_000, 2_000_000)
    for topic, fld, offset in (
        ("local_position_pose", "y", 5.0),
        ("global_position_global", "latitude", 5 / 111_200),
    ):
        nav, sim = ds.topic("b1", topic, "navigator"), ds.topic("b1", topic, "simulator")
        window = ((nav.Timestamp >= 1_000_000) & (nav.Timestamp < 2_000_000)).to_numpy()
        assert window.sum() == 10 and (nav.Is_Anomaly.to_numpy() == window).all()
        assert np.allclose(nav[fld] - sim[fld], np.where(window, offset, 0.0), atol=offset * 0.01)
        assert sim[fld].nunique() == 1  # the simulator side is never offset
    for s in subs.values():
        s.unregister()


def _off_path(truth) -> tuple[float, float]:
    """(horizontal distance from home at the end, the largest distance from the planned path at altitude) of
    the true flight (the sitl's truth topic, NED)."""
    x, y, z = (truth[c].to_numpy() for c in ("x", "y", "z"))
    path = np.array([(0, 0), (10, 10), (40, 10), (40, 40), (10, 40), (0, 0)], dtype=float)
    pts = np.c_[x, y]
    d = np.full(len(pts), np.inf)
    for a, b in zip(path[:-1], path[1:], strict=True):
        t = np.clip((pts - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        d = np.minimum(d, np.linalg.norm(pts - (a + t[:, None] * (b - a)), axis=1))
    return float(np.hypot(x[-1], y[-1])), float(d[-z > 5].max())


@pytest.mark.parametrize("scenario", [None, "gps_spoof.toml"])
def test_the_whole_loop_flies_the_square_and_a_gps_spoof_moves_it_off(master, tmp_path, scenario, procs):
    port = ros1._free_port()  # noqa: SLF001 (a test helper)
    sitl = _cli(
        tmp_path,
        "sitl",
        "sitl",
        "--listen",
        f"udp:127.0.0.1:{port}",
        "--lockstep",
        "--record",
        str(tmp_path / "sitl"),
        "--flight-id",
        "s1",
    )
    standin = _cli(tmp_path, "mavros", "ros", "mavros", "--connect", f"udp:127.0.0.1:{port}", "--ns", "/fcu")
    extra = ["--scenario", str(ROOT / "data" / "scenarios" / scenario)] if scenario else []
    node = _cli(
        tmp_path,
        "node",
        "ros",
        "node",
        "--input-ns",
        "/fcu",
        "--output-ns",
        "/mc",
        "--record",
        str(tmp_path / "node"),
        "--flight-id",
        "n1",
        *extra,
    )
    nav = _cli(tmp_path, "nav", "ros", "navigator", "--ns", "/mc", "--timeout", "150")
    procs.extend([sitl, standin, node, nav])
    try:
        nav.wait(timeout=170)
    finally:
        nav_log = _stop(nav, tmp_path, "nav")
        for proc, name in ((node, "node"), (standin, "mavros"), (sitl, "sitl")):
            _stop(proc, tmp_path, name)
    assert "mission flown, landed and disarmed" in nav_log
    truth = open_dataset(tmp_path / "sitl").topic("s1", "truth", "simulator")
    home_m, off_m = _off_path(truth)
    print(f"scenario {scenario}: landed {home_m:.2f} m from home, at most {off_m:.2f} m off the square")
    flown = open_dataset(tmp_path / "node")
    row = flown.manifest.set_index("flight_id").loc["n1"]
    nav_view = flown.topic("n1", "local_position_pose", "navigator")
    sim_view = flown.topic("n1", "local_position_pose", "simulator")
    moved = np.hypot(nav_view.x - sim_view.x, nav_view.y - sim_view.y).to_numpy()
    if scenario is None:
        assert home_m < 5.0 and off_m < 5.0
        assert row["mode"] == "normal" and moved.max() == 0.0
    else:
        assert off_m > 8.0
        assert row["mode"] == "simulation" and row.attack_end_us > row.attack_start_us > 0
        assert (moved[nav_view.Is_Anomaly.to_numpy() == 0] == 0).all() and moved.max() > 3.0
