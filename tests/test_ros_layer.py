"""The ROS-free part of the ROS node: MAVROS topics by meaning (ENU), the layer on one message, the mission.

These run without ROS; tests/test_ros.py runs the nodes against a real roscore.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scart_bench.dataset import open_dataset
from scart_bench.generator.geo import metres_per_degree
from scart_bench.generator.ros.layer import RosLayer, save_recording
from scart_bench.generator.ros.mission import SquareMission
from scart_bench.generator.ros.topics import MAVROS_TOPICS
from scart_bench.generator.scart.scenario import load_scenarios, scenario_from_dict

ROOT = Path(__file__).resolve().parents[1]
LAT0, LON0 = 47.397742, 8.545594


def _scenario(actions, start=None, end=None, sid="s"):
    table = {
        "id": sid,
        "actions": actions,
        "start": start or [{"condition": "time_window", "start_s": 1.0}],
        "end": end if end is not None else [{"condition": "duration", "seconds": 1.0}],
    }
    return scenario_from_dict(table, check_topics=False)


def _pose(x=3.0, y=4.0, z=10.0):
    return np.array([x, y, z, 0.0, 0.0, 0.0, 1.0])


def test_without_a_scenario_every_message_passes_as_received():
    layer = RosLayer([], record=True)
    assert not layer.used
    for name, topic in MAVROS_TOPICS.items():
        vals = np.arange(len(topic.fields), dtype=float) + 0.5
        assert layer.on_message(name, 1_000_000, vals) == (None, True)
    rec = layer.record("r1")
    assert rec.manifest["mode"] == "normal"
    for name in rec.navigator:
        assert rec.navigator[name].equals(rec.simulator[name])


def test_a_north_bias_moves_enu_y_and_latitude_inside_the_window_only():
    sc = _scenario([{"action": "bias", "target": ["position"], "offset": 5.0, "direction_deg": 0.0}])
    layer = RosLayer([sc], record=True)
    assert {"local_position_pose", "global_position_global"} <= layer.used
    m_lat = float(metres_per_degree(LAT0)[0])
    for k in range(31):
        t = 10_000_000 + k * 100_000  # stamps from an arbitrary start: the flight time counts from the first
        new_fix, _ = layer.on_message("global_position_global", t, np.array([LAT0, LON0, 500.0]))
        new_pose, _ = layer.on_message("local_position_pose", t, _pose())
        inside = 1.0 <= k / 10 < 2.0
        if inside:
            assert (
                new_pose[1] == pytest.approx(9.0) and new_pose[0] == 3.0 and new_pose[2] == 10.0
            )  # y is north
            assert (new_fix[0] - LAT0) * m_lat == pytest.approx(5.0, abs=1e-3) and new_fix[
                1
            ] == pytest.approx(LON0)
        else:
            assert new_pose is None and new_fix is None
    assert layer.windows() == [(1_000_000, 2_000_000)]


def test_shipped_scenarios_resolve_to_the_mavros_topics():
    layer = RosLayer(load_scenarios(ROOT / "data/scenarios/gps_spoof.toml"))
    action = layer.layer.groups[0].actions[0]
    assert {
        "global_position_global",
        "local_position_pose",
        "local_position_velocity_local",
        "global_position_raw_fix",
        "global_position_raw_gps_vel",
    } <= set(action.fields)
    assert action.fields["local_position_pose"] == (1, 0)  # north (y), east (x) of the ENU pose
    cond = layer.layer.groups[0].start_conds[0]
    assert cond.params["topic"] == "mission_current"


def test_gps_spoof_rotates_the_enu_pose_about_the_start():
    sc = _scenario(
        [{"action": "gps_spoof", "target": ["position"], "rate_deg_s": 90.0, "max_deg": 90.0}],
        end=[{"condition": "duration", "seconds": 10.0}],
    )
    layer = RosLayer([sc])
    layer.on_message("local_position_pose", 1, _pose(0.0, 0.0))
    layer.on_message("local_position_pose", 1_000_001, _pose(0.0, 0.0))  # the attack starts here (origin)
    new, _ = layer.on_message("local_position_pose", 2_000_001, _pose(0.0, 10.0))  # 10 m north, 90 deg later
    assert new[0] == pytest.approx(10.0, abs=1e-6) and new[1] == pytest.approx(0.0, abs=1e-6)  # now east


def test_conditions_read_enu_geofence_and_altitude():
    fence = _scenario(
        [{"action": "off", "target": ["battery"]}],
        start=[{"condition": "geofence", "center": [20.0, 0.0], "radius": 5.0}],
        end=[],
    )
    layer = RosLayer([fence])
    layer.on_message("local_position_pose", 1, _pose(x=0.0, y=20.0))  # 20 m north
    layer.on_message("battery", 2, np.array([12.0, -1.0, 0.9]))
    assert layer.windows(), "20 m north is inside the fence at [20 north, 0 east]"
    high = _scenario(
        [{"action": "off", "target": ["battery"]}],
        start=[{"condition": "altitude_above", "height": 5.0}],
        end=[],
    )
    layer = RosLayer([high])
    assert layer.layer.groups[0].start_conds[0].params["topic"] == "local_position_pose"
    layer.on_message("local_position_pose", 1, _pose(z=2.0))
    assert not layer.windows()
    layer.on_message("local_position_pose", 2, _pose(z=8.0))  # ENU z up: 8 m above home
    assert layer.windows()


def test_imu_offsets_follow_flu_axes():
    sc = _scenario(
        [{"action": "bias", "target": ["imu.zacc"], "offset": 1.0}],
        start=[{"condition": "time_window"}],
        end=[],
    )
    layer = RosLayer([sc])
    new, _ = layer.on_message("imu_data", 1, np.r_[0, 0, 0, 1, 0, 0, 0, 0, 0, 9.81])
    assert new[9] == pytest.approx(8.81)  # +1 on FRD z (down) is -1 on FLU z (up)


def test_the_recording_holds_both_views_and_the_window(tmp_path):
    sc = _scenario([{"action": "bias", "target": ["position"], "offset": 5.0, "direction_deg": 0.0}])
    layer = RosLayer([sc], record=True)
    for k in range(31):
        layer.on_message("local_position_pose", k * 100_000, _pose())
    save_recording(layer.record("f1"), tmp_path / "ds")
    ds = open_dataset(tmp_path / "ds")
    nav = ds.topic("f1", "local_position_pose", "navigator")
    sim = ds.topic("f1", "local_position_pose", "simulator")
    window = (nav.Timestamp >= 1_000_000) & (nav.Timestamp < 2_000_000)
    assert (nav.Is_Anomaly == window.astype(int)).all()
    assert np.allclose(nav.y - sim.y, np.where(window, 5.0, 0.0)) and (sim.y == 4.0).all()
    assert ds.manifest.iloc[0]["mode"] == "simulation"


def test_a_scenario_off_the_link_is_refused_in_one_line():
    sc = scenario_from_dict(
        {
            "id": "s",
            "injection_point": "sensor",
            "actions": [{"action": "bias", "target": ["sensor_gps.lat"], "offset": 1.0}],
        },
        check_topics=False,
    )
    with pytest.raises(ValueError, match="injection point 'sensor'"):
        RosLayer([sc])
    proc = subprocess.run(
        [sys.executable, "-m", "scart_bench", "ros", "node", "--scenario", "nope.toml"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "nope.toml" in proc.stderr


def test_the_mission_flies_the_square_from_what_it_perceives():
    """A point mass that follows the velocity setpoints: the mission arms, switches, flies, lands."""
    mission = SquareMission()
    pos, armed, mode, t, seen = np.zeros(3), False, "AUTO.LOITER", 0.0, []
    while not mission.done and t < 200:
        sp = mission.step(t, pos, armed, mode)
        if sp.request == "arm":
            armed = True
        elif sp.request == "offboard":
            mode = "OFFBOARD"
        elif sp.request == "land":
            mode = "AUTO.LAND"
        if mode == "AUTO.LAND":
            pos[2] = max(pos[2] - 0.05, 0.0)
            armed = pos[2] > 0
        else:
            pos = pos + 0.05 * sp.velocity
        seen.append(pos.copy())
        t += 0.05
    assert mission.done
    assert np.hypot(*pos[:2]) < 1.0
    path = np.array(seen)
    for n, e in ((10, 10), (40, 10), (40, 40), (10, 40)):
        assert np.hypot(path[:, 0] - e, path[:, 1] - n).min() < 1.0


def test_the_live_monitor_reads_detector_columns_of_mavros_topics():
    """The navigator's anomaly notice: a detector fitted on flights recorded by the node scores ROS topics."""
    import pandas as pd

    from scart_bench.benchmark.live import StreamMonitor
    from scart_bench.generator.ros.topics import topic_fields

    class Far:
        columns_ = ["local_position_pose.x", "local_position_pose.y"]
        history_rows_ = 1

        def score(self, frame: pd.DataFrame) -> np.ndarray:
            return np.hypot(frame.iloc[:, 0], frame.iloc[:, 1]).to_numpy()

    monitor = StreamMonitor(Far(), threshold=10.0, log=lambda msg: None)
    monitor.add_topics(topic_fields(), {n: t.rate_hz for n, t in MAVROS_TOPICS.items()})
    assert monitor.base_topic == "local_position_pose"
    for k, (x, y) in enumerate([(1, 1), (2, 2), (30, 0), (1, 0)]):
        monitor.on_message("local_position_pose", k * 33_000, _pose(x, y))
    monitor.flush()
    assert [round(s) for _, s in monitor.scores] == [1, 3, 30, 1] and len(monitor.alarms) == 1


def test_an_attacked_recording_must_be_a_test_flight(tmp_path, capsys):
    """As sitl: `ros node --scenario X --record D --split train` is refused before ROS is touched."""
    from scart_bench.cli.main import main

    spoof = Path(__file__).resolve().parents[1] / "data" / "scenarios" / "gps_spoof.toml"
    out = tmp_path / "rec"
    assert main(["ros", "node", "--scenario", str(spoof), "--record", str(out), "--split", "train"]) == 2
    assert "--split train: an attacked flight (--scenario) is always a test flight" in capsys.readouterr().err
    assert not out.exists()


def test_messages_without_a_stamp_take_the_last_stamped_time():
    """Float64 topics (rel_alt, compass_hdg) carry no header: their flight time is the last stamped one."""
    from scart_bench.generator.ros.layer import StampClock

    clock = StampClock()
    assert [clock.tick(s) for s in (None, 5_000_000, None, 5_400_000, 5_300_000, 0)] == [0, 0, 0, 400_000,
                                                                                          400_000, 400_000]
