"""jMAVSim in the loop (issue 52): the project's flight software flies jMAVSim through PX4's simulator
MAVLink API (headless, lockstep), with the SCART layer at the sensor point.

jMAVSim is built once per session from ``../shared/sim/jmavsim`` (or the checkout named by
``SCART_JMAVSIM_SRC``) into a temporary folder; shared/ stays untouched. Without java, ant or the
source the module skips with one line saying which.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.params import MissionParams

SOURCE = Path(os.environ.get("SCART_JMAVSIM_SRC", Path(__file__).resolve().parents[2] / "shared/sim/jmavsim"))


def _missing() -> str | None:
    if shutil.which("java") is None:
        return "jMAVSim tests need java (Debian: apt-get install default-jdk-headless)"
    if shutil.which("ant") is None:
        return "jMAVSim tests need ant to build jMAVSim (Debian: apt-get install ant)"
    if not (SOURCE / "build.xml").is_file():
        return f"no jMAVSim source at {SOURCE} (set SCART_JMAVSIM_SRC)"
    try:
        import pymavlink  # noqa: F401
    except ImportError:
        return "jMAVSim tests need pymavlink"
    return None


REASON = _missing()
pytestmark = pytest.mark.skipif(REASON is not None, reason=REASON or "")

#: a short mission for the attack: one 60 m leg north and back, 1 s of hover at the take-off point
SHORT = MissionParams(corners=((60.0, 0.0),), takeoff_hold_s=1.0, jitter_m=0.0, jitter_speed=0.0,
                      max_duration_s=90.0)
#: a GPS position bias growing east at 0.8 m/s from 17 s to 33 s after boot, at the sensor point
#: (position and velocity consistent, so the estimator's gates pass it and the estimate follows)
DRIFT = {
    "id": "gps-bias-east", "injection_point": "sensor",
    "start": [{"condition": "time_window", "start_s": 17.0}],
    "end": [{"condition": "time_window", "start_s": 33.0}],
    "actions": [{"action": "drift", "target": ["gps.lat", "gps.lon", "gps.vn", "gps.ve"], "rate": 0.8,
                 "direction_deg": 90.0}],
}
#: the same scenario with a window that never opens in a flight of at most 90 s
NEVER = {**DRIFT, "id": "never", "start": [{"condition": "time_window", "start_s": 500.0}],
         "end": [{"condition": "time_window", "start_s": 600.0}]}


@pytest.fixture(scope="module")
def jar(tmp_path_factory):
    from scart_bench.generator.hil.jmavsim import build

    return build(SOURCE, tmp_path_factory.mktemp("jmavsim"))


@pytest.fixture(scope="module")
def default_flight(jar):
    from scart_bench.generator.hil.flights import fly_jmavsim

    return fly_jmavsim(jar, seed=0)


@pytest.fixture(scope="module")
def spoofed_flight(jar):
    from scart_bench.generator.hil.flights import fly_jmavsim
    from scart_bench.generator.scart.scenario import scenario_from_dict

    # over TCP (jMAVSim's -tcp: it serves, the bridge connects); the default flight goes over UDP
    return fly_jmavsim(jar, seed=1, scenarios=[scenario_from_dict(DRIFT)], mission=SHORT, transport="tcp")


def _item_of(flight) -> tuple[np.ndarray, np.ndarray]:
    """Navigator phase and mission item at each truth row."""
    est = flight.estimate
    idx = np.clip(np.searchsorted(est[:, 0], flight.truth[:, 10], side="right") - 1, 0, None)
    return est[idx, 4].astype(int), est[idx, 5].astype(int)


def _line_distance(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(along-track, signed cross-track) of points relative to the leg a -> b."""
    u = (b - a) / np.linalg.norm(b - a)
    n = np.array([-u[1], u[0]])
    return (xy - a) @ u, (xy - a) @ n


def test_default_mission_in_jmavsim(default_flight):
    """Takes off, flies every leg within 3 m of its line outside turns, lands within 2 m of home."""
    f = default_flight
    assert f.status == "landed", f.status
    wps = f.autopilot.waypoints
    truth = f.truth
    assert len(truth) > 1000  # HIL_STATE_QUATERNION at 50 Hz as asked
    xy, z = truth[:, 1:3], truth[:, 3]
    assert -z.min() > 0.9 * -wps[0, 2], f"climbed to {-z.min():.1f} m of {-wps[0, 2]:.1f}"
    phase, item = _item_of(f)
    for k in range(1, len(wps)):
        a, b = wps[k - 1, :2], wps[k, :2]
        length = float(np.linalg.norm(b - a))
        along, cross = _line_distance(xy, a, b)
        on = (phase == 2) & (item == k) & (along > 5.0) & (along < length - 5.0)
        assert on.sum() > 20, f"leg {k}: {on.sum()} truth rows"
        worst = float(np.abs(cross[on]).max())
        assert worst < 3.0, f"leg {k}: {worst:.2f} m off its line"
    assert np.linalg.norm(xy[-1]) < 2.0, f"landed {np.linalg.norm(xy[-1]):.2f} m from home"
    assert abs(z[-1]) < 0.3
    # lockstep's speed is measured by perf/jmavsim_speed.py, not asserted here (a loaded machine runs it slower)
    assert f.speed > 0.0


def test_gps_bias_at_sensor_point(spoofed_flight):
    """The true track leaves the mission by >= 10 m while the estimate follows the spoofed GPS."""
    f = spoofed_flight
    ap = f.autopilot
    wps = ap.waypoints
    xy = f.truth[:, 1:3]
    t_s = f.truth[:, 10] * 0.004
    _, cross = _line_distance(xy, wps[0, :2], wps[1, :2])
    inside = (t_s >= 17.0) & (t_s < 33.0)
    assert np.abs(cross[inside]).max() >= 10.0, f"true track {np.abs(cross[inside]).max():.1f} m off the mission"
    # the estimate follows the spoof: estimate - truth is the injected offset (0.8 m/s east, 16 s)
    est_at = f.estimate[np.clip(np.searchsorted(f.estimate[:, 0], f.truth[:, 10], side="right") - 1, 0, None)]
    gap_east = est_at[:, 2] - xy[:, 1]
    late = inside & (t_s > 30.0)
    expected = 0.8 * (t_s[late] - 17.0)
    assert np.abs(gap_east[late] - expected).max() < 2.0
    assert np.abs(gap_east[t_s < 17.0]).max() < 1.0
    # the labels cover exactly the attack window: every GPS fix inside it altered, none outside
    windows = ap.layer.labelled_windows(0, ap.step_index * 4000)
    assert [(s, e) for s, e, _, _ in windows] == [(17_000_000, 33_000_000)]
    steps, before = ap.records.table("sensor_gps", after=False)
    _, after = ap.records.table("sensor_gps", after=True)
    changed = np.any(before != after, axis=1)
    t_us = steps * 4000
    in_window = (t_us >= 17_000_000) & (t_us < 33_000_000)
    assert changed[in_window].all() and not changed[~in_window].any()
    assert in_window.sum() > 200


def test_layer_without_an_active_scenario_changes_nothing(spoofed_flight):
    """Replayed without a layer, the flown sensor stream gives the same motor commands only when
    the layer did nothing: so a layer whose scenario never starts is the same flight as no layer."""
    from scart_bench.generator.hil.bridge import replay
    from scart_bench.generator.hil.flights import autopilot_for
    from scart_bench.generator.scart.scenario import scenario_from_dict

    f = spoofed_flight
    plain = replay(f.inputs, autopilot_for(1, None, SHORT))
    idle = replay(f.inputs, autopilot_for(1, [scenario_from_dict(NEVER)], SHORT))
    attacked = replay(f.inputs, autopilot_for(1, [scenario_from_dict(DRIFT)], SHORT))
    assert np.array_equal(attacked, f.outputs)  # the replay is the flight, bit for bit
    assert np.array_equal(idle, plain)
    assert not np.array_equal(attacked, plain)
    first = int(np.argmax(np.any(attacked != plain, axis=1)))
    assert first * 0.004 >= 17.0  # nothing differs before the attack starts


#: a short hop for the real-time flight: 4 m up, 1 s of hover, 15 m north, back, land (about 35 s)
HOP = MissionParams(corners=((15.0, 0.0),), altitude=4.0, takeoff_hold_s=1.0, jitter_m=0.0, jitter_speed=0.0,
                    max_duration_s=60.0)


def test_real_time_flight(jar):
    """jMAVSim on its own clock (no lockstep): the flight keeps pace with it and lands at home, or, on a
    machine too loaded to answer in time, the bridge gives up in one line naming the lag (never a
    silent crash of a controller answering late)."""
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.hil.flights import REALTIME_MAX_LAG_S, fly_jmavsim

    try:
        f = fly_jmavsim(jar, seed=2, mission=HOP, lockstep=False)
    except HilError as exc:
        assert "behind the simulator's real-time clock" in str(exc) and "\n" not in str(exc)
        pytest.skip(f"this machine is too loaded for a real-time flight: {exc}")
    assert f.status == "landed", f.status
    assert np.linalg.norm(f.truth[-1, 1:3]) < 2.0
    # the simulator's clock set the pace: wall time about the flown time (lockstep runs faster)
    assert 0.7 < f.speed < 1.3, f.speed
    assert REALTIME_MAX_LAG_S > 0


class _ScriptedLink:
    """A link that delivers prepared batches of messages (a simulator that sends faster than we fly)."""

    def __init__(self, batches):
        self.batches = list(batches)
        self.last_heartbeat = 0.0

    def wait_first(self, timeout_s, alive=None):
        return self.batches.pop(0)

    def receive(self, timeout):
        if not self.batches:
            raise AssertionError("the bridge read past the script")
        return self.batches.pop(0)

    def heartbeat(self, armed):
        pass

    def request_truth(self, interval_us):
        pass

    def actuators(self, t_us, controls, armed):
        pass


def test_bridge_gives_up_when_it_falls_behind_a_real_time_simulator():
    """With a simulator on its own clock, sensor time queued behind the sample being flown is the lag;
    past ``max_lag_s`` the flight ends with one line, and without the limit (lockstep) it flies on."""
    from pymavlink.dialects.v20 import common as mav

    from scart_bench.generator.hil.bridge import Bridge
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.hil.flights import autopilot_for

    m = mav.MAVLink(None)

    def sensor(t_us):
        return m.hil_sensor_encode(t_us, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 1013.25, 0.0, 0.0, 15.0, 0)

    # 2 s on time (one sample per read), then 100 ms of samples arrive at once
    batches = [[sensor(4000 * k)] for k in range(500)] + [[sensor(4000 * k) for k in range(500, 525)]]
    late = Bridge(_ScriptedLink(batches), autopilot_for(0, None, HOP), max_lag_s=0.05)
    with pytest.raises(HilError, match=r"fell \d+ ms behind the simulator's real-time clock at 2\.0 s"):
        late.fly(max_s=2.2)
    calm = Bridge(_ScriptedLink(batches + [[]] * 5), autopilot_for(0, None, HOP))
    assert calm.fly(max_s=2.1).steps == 525


def test_simulator_addresses():
    """`udp:`/`tcp:` connect, `-listen` waits for the simulator; anything else is one line."""
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.hil.link import SimLink, TcpSimLink, open_link, parse_sim_address

    assert parse_sim_address("tcp:127.0.0.1:4560") == ("tcp", ("127.0.0.1", 4560))
    assert parse_sim_address("udp-listen:0.0.0.0:14560") == ("udp-listen", ("0.0.0.0", 14560))
    for bad in ("4560", "tcp:4560", "serial:/dev/ttyS0:57600", "tcp:host:99999", "udp:host:port"):
        with pytest.raises(HilError, match="expected one of udp:HOST:PORT"):
            parse_sim_address(bad)
    server = open_link("tcp-listen:127.0.0.1:0")
    try:
        assert isinstance(server, TcpSimLink) and server.where().startswith("expected on tcp:127.0.0.1:")
        with pytest.raises(HilError, match="never connected in 0.5 s"):
            server.wait_first(0.5)
    finally:
        server.close()
    client = open_link("udp:127.0.0.1:9")
    assert type(client) is SimLink
    client.close()


def test_missing_jar_and_silent_simulator(tmp_path, monkeypatch):
    """One-line errors: no Java, no jar, and a simulator that never sends its first message."""
    from scart_bench.generator.hil.errors import HilError
    from scart_bench.generator.hil.jmavsim import ENV_VAR, find_jar, find_java, free_udp_port
    from scart_bench.generator.hil.link import SimLink

    monkeypatch.delenv(ENV_VAR, raising=False)
    with monkeypatch.context() as m:
        m.setenv("PATH", str(tmp_path))
        with pytest.raises(HilError, match="needs Java and none is on PATH"):
            find_java()
    with pytest.raises(HilError, match="no jMAVSim given"):
        find_jar(None)
    with pytest.raises(HilError, match="no jmavsim_run.jar at") as err:
        find_jar(tmp_path)
    assert "\n" not in str(err.value)
    link = SimLink(("127.0.0.1", free_udp_port()))
    try:
        with pytest.raises(HilError, match="sent no message in 0.5 s"):
            link.wait_first(0.5)
    finally:
        link.close()


def test_generate_physics_jmavsim(jar, tmp_path):
    """`generate --physics jmavsim` writes a dataset: one normal and one attacked jMAVSim flight (a short
    hop from a mission file), the attacked one labelled over its window, jMAVSim's truth in the simulator
    view, both landed at home; no jar: exit 2."""
    from scart_bench.cli.main import main
    from scart_bench.dataset import open_dataset

    out = tmp_path / "jms"
    assert main(["generate", "--physics", "jmavsim", "--out", str(out), "--flights", "1", "--jmavsim",
                 str(tmp_path / "nowhere")]) == 2
    assert not out.exists()
    grid = Path(__file__).resolve().parents[1] / "data/scenarios/sensor_gps_jump.toml"
    hop = tmp_path / "hop.waypoints"  # take-off to 6 m, 18 m north held 8 s, return: about half the square
    hop.write_text("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488\t1\n"
                   "1\t0\t3\t22\t0\t0\t0\t0\t47.397742\t8.545594\t6\t1\n"
                   "2\t0\t3\t16\t8\t0\t0\t0\t47.397904\t8.545594\t6\t1\n"
                   "3\t0\t3\t20\t0\t0\t0\t0\t0\t0\t0\t1\n")
    assert main(["generate", "--physics", "jmavsim", "--jmavsim", str(jar), "--out", str(out), "--flights", "1",
                 "--scenarios", str(grid), "--seed", "4", "--missions", str(hop)]) == 0
    ds = open_dataset(out)
    m = ds.manifest.set_index("flight_id")
    assert list(m["mode"]) == ["normal", "simulation"]
    assert "truth" in ds.topics("normal-0000", "simulator")
    nav = ds.flight("sim-0000", "navigator", "all_sensors")
    start, end = int(m.loc["sim-0000", "attack_start_us"]), int(m.loc["sim-0000", "attack_end_us"])
    assert end - start == 10_000_000  # the scenario's 10 s
    inside = (nav["Timestamp"] >= start) & (nav["Timestamp"] < end)
    assert (nav["Is_Anomaly"] == inside.astype(int)).all()
    assert ds.flight("normal-0000", "navigator", "all_sensors")["Is_Anomaly"].sum() == 0
    for fid in ("normal-0000", "sim-0000"):  # the GPS jump is rejected by the gate: both fly home
        truth = ds.topic(fid, "truth", "simulator")
        assert -truth["z"].min() > 5.0 and float(np.hypot(truth["x"].iloc[-1], truth["y"].iloc[-1])) < 2.0, fid


def test_generate_against_a_running_simulator_flies_a_mission_file(jar, tmp_path, capsys):
    """`generate --physics jmavsim --sim tcp:HOST:PORT` flies a simulator someone else started (here a
    jMAVSim serving TCP, as Gazebo classic and AirSim do) and writes the dataset; a bad address or
    --sim without --physics jmavsim is one line, exit 2, nothing written.

    With `--missions FILE` it flies a QGroundControl .plan (take-off to 10 m, a leg at 7 m/s held 4 s, a
    climb to 13 m, a 5 s loiter, return to launch at 5 m/s): within 2 m of its legs outside the turns,
    the holds held, landed at home, the file recorded; a malformed file is one line naming it, exit 2,
    nothing written."""
    import json

    from test_mission_files import CRUISE, PLAN, _segment_distance, check_flight

    from scart_bench.cli.main import main
    from scart_bench.dataset import open_dataset
    from scart_bench.generator.flight_software.mission_files import read_mission
    from scart_bench.generator.hil.jmavsim import JMavSim

    bad = tmp_path / "bad"
    assert main(["generate", "--physics", "jmavsim", "--sim", "tcp:localhost", "--out", str(bad),
                 "--normal-only", "--flights", "1"]) == 2
    assert main(["generate", "--sim", "tcp:127.0.0.1:4560", "--out", str(bad), "--flights", "1"]) == 2
    broken = tmp_path / "broken.plan"
    broken.write_text('{"fileType": "Plan", "mission": {')
    assert main(["generate", "--physics", "jmavsim", "--jmavsim", str(jar), "--missions", str(broken), "--out",
                 str(bad), "--normal-only", "--flights", "1"]) == 2
    assert "broken.plan: expected a QGroundControl .plan" in capsys.readouterr().err
    assert not bad.exists()
    out = tmp_path / "external"
    with JMavSim(jar, transport="tcp") as sim:
        assert main(["generate", "--physics", "jmavsim", "--sim", sim.link_address, "--missions", str(PLAN),
                     "--out", str(out), "--normal-only", "--flights", "1", "--seed", "3"]) == 0
    ds = open_dataset(out)
    assert list(ds.manifest["mode"]) == ["normal"]
    (fid,) = ds.manifest["flight_id"]
    cfg = json.loads((out / "flights" / fid / "raw" / "config.json").read_text())
    assert cfg["mission_file"] == PLAN.name and cfg["status"] == "landed"
    items = read_mission(PLAN).navigator_items(CRUISE)
    truth = ds.topic(fid, "truth", "simulator")
    assert len(truth) > 1000
    t = truth["Timestamp"].to_numpy() * 1e-6
    track = truth[["x", "y", "z", "vx", "vy", "vz"]].to_numpy()
    # legs this short are partly acceleration and braking: over a leg's middle half the median ground speed is
    # up to 0.9 m/s off the leg's here (6.5-7.1 at 7 m/s, 5.9 at 5 m/s), up to 1.5 m/s in the compiled kernel
    check_flight(t, track, items, "jMAVSim", speed_of=np.median, speed_tol=1.2)  # lands at home too
    # the file's speed change is flown: its 7 m/s legs faster than the return at the cruise speed
    air = track[:, 2] < -1.0
    ne, speed = track[air, :2], np.hypot(track[air, 3], track[air, 4])
    legs = {}
    for k in range(1, len(items)):
        a, b = items[k - 1, :2], items[k, :2]
        if np.hypot(*(b - a)) > 10.0:
            legs[k] = float(np.median(speed[_segment_distance(ne, a + 0.25 * (b - a), a + 0.75 * (b - a)) < 2.0]))
    fast = [v for k, v in legs.items() if items[k, 3] > CRUISE]
    slow = [v for k, v in legs.items() if items[k, 3] == CRUISE]
    assert fast and slow and min(fast) > max(slow) + 0.2, legs
