"""The SCART attack layer: scenarios, actions, conditions, both modes, grids and bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import distance_to_path, truth

from scart_bench.cli.main import main
from scart_bench.dataset import LABEL_COLUMNS, open_dataset
from scart_bench.dataset.schema import TRUTH_FIELDS
from scart_bench.generator.modes import csv_mode
from scart_bench.generator.scart.grid import load_configurations, load_grid
from scart_bench.generator.scart.scenario import ScenarioError, load_scenarios, scenario_from_dict
from scart_bench.generator.scart.units import M_PER_DEG_LAT, M_PER_DEG_LON
from scart_bench.generator.telemetry.tables import flight_views
from scart_bench.names import check_id

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "ulog"
RFLYMAD = SHARED / "rflymad_TestCase_1_1000000000.ulg"
PX4_SAMPLE = SHARED / "px4_sample_log_small.ulg"
#: the real PX4 logs of ../shared (a checkout without them skips these tests, as test_importers does)
needs_ulogs = pytest.mark.skipif(not (RFLYMAD.exists() and PX4_SAMPLE.exists()),
                                 reason=f"reference ULogs not found in {SHARED}")
X, Y = TRUTH_FIELDS.index("x"), TRUTH_FIELDS.index("y")


def _path_deviation(batch, i, j):
    """Max horizontal distance between the true paths of flights i and j over their common time."""
    si, ti = truth(batch, i)
    sj, tj = truth(batch, j)
    n = min(len(si), len(sj))
    return np.hypot(ti[:n, X] - tj[:n, X], ti[:n, Y] - tj[:n, Y])


# --- simulation mode -----------------------------------------------------------------------------
def test_link_gps_spoofing_moves_true_path_while_navigator_view_stays_on_course(attacked_fleet):
    batch, layer, k = attacked_fleet
    assert batch.status[k["spoof"]] == "landed"
    assert _path_deviation(batch, k["spoof"], k["normal"]).max() >= 5.0
    steps, nav, ok = batch.navigator["local_position_ned"]
    i = k["spoof"]
    (start, end), = layer.windows(i, 10**12)
    during = (steps * 4000 >= start) & (steps * 4000 < end) & ok[i]
    plan = np.vstack([[0.0, 0.0], batch.waypoints[i][:, :2]])
    seen = distance_to_path(nav[i][during][:, :2], plan)
    tsteps, tr = truth(batch, i)
    t_during = (tsteps * 4000 >= start) & (tsteps * 4000 < end)
    true_off = distance_to_path(tr[t_during][:, [X, Y]], plan)
    # the navigator sees itself on its path (it re-aims after each corner) while it is far off
    assert np.median(seen) < 1.5 and seen.max() < 5.0, np.percentile(seen, [50, 90, 100])
    assert true_off.max() >= 5.0 and true_off.max() > 2 * seen.max()


def test_sensor_gps_jump_is_rejected_and_flight_stays_on_square(attacked_fleet):
    batch, layer, k = attacked_fleet
    i = k["jump"]
    assert batch.gps_rejections[i, 0] >= 90, "every GPS position fusion in the 10 s window rejected"
    assert _path_deviation(batch, i, k["normal"]).max() < 2.0
    plan = np.vstack([[0.0, 0.0], batch.waypoints[i][:, :2]])
    assert distance_to_path(truth(batch, i)[1][:, [X, Y]], plan).max() < 2.5


def test_sensor_stealthy_drift_passes_gates_and_pulls_the_vehicle_off(attacked_fleet):
    batch, layer, k = attacked_fleet
    i = k["drift"]
    (start, end), = layer.windows(i, 10**12)
    steps, tr = truth(batch, i)
    in_window = (steps * 4000 >= start) & (steps * 4000 < end)
    n_gps_in_window = int((end - start) / 1e5)
    # while the drift runs, the estimator accepts it (no rejections inside the window)
    assert batch.gps_rejections[i, 0] < n_gps_in_window * 0.05 + (batch.exit_step[i] * 0.004 - end / 1e6) * 10 + 1
    plan = np.vstack([[0.0, 0.0], batch.waypoints[i][:, :2]])
    off = distance_to_path(tr[in_window][:, [X, Y]], plan)
    assert off[-1] >= 5.0, f"only {off[-1]:.1f} m off the square at the end of the drift"


# --- csv mode ----------------------------------------------------------------------------------------
def test_csv_mode_changes_only_the_navigator_view(attacked_fleet):
    batch, layer, k = attacked_fleet
    nav_in, _ = flight_views(batch, k["normal"])
    link = {t: df.drop(columns=list(LABEL_COLUMNS)) for t, df in nav_in.items()}
    spoof = load_scenarios("data/scenarios/gps_spoof.toml")
    (nav, windows, events), = csv_mode([link], [spoof], [5])
    assert len(windows) == 1
    (start, end, *_), = windows
    for topic, df in link.items():
        assert df.equals(link[topic])  # input untouched
        out = nav[topic]
        same = np.allclose(out.drop(columns=list(LABEL_COLUMNS)).to_numpy(), df.to_numpy(), equal_nan=True)
        if topic in ("global_position_int", "local_position_ned", "gps_raw_int"):
            assert not same
            ts = out["Timestamp"].to_numpy()
            outside = (ts < start) | (ts >= end)
            np.testing.assert_array_equal(out[outside].drop(columns=list(LABEL_COLUMNS)).to_numpy(),
                                          df[outside].to_numpy())
        else:
            assert same


def test_is_anomaly_matches_event_log_exactly(quick_dataset):
    ds = open_dataset(quick_dataset)
    attacked = ds.manifest[ds.manifest["mode"] != "normal"]
    assert {"simulation", "csv"} <= set(attacked["mode"])
    for fid in attacked["flight_id"]:
        ev = ds.events(fid)
        starts = ev[ev["event"] == "start"]["timestamp_us"].to_numpy()
        ends = ev[ev["event"] == "end"]["timestamp_us"].to_numpy()
        assert len(starts) == len(ends) >= 1
        for table in ("most_frequent", "all_sensors"):
            for view in ("navigator", "simulator"):
                df = ds.flight(fid, view=view, table=table)
                ts = df["Timestamp"].to_numpy()
                expect = np.zeros(len(ts), dtype=bool)
                for s, e in zip(starts, ends):
                    expect |= (ts >= s) & (ts < e)
                np.testing.assert_array_equal(df["Is_Anomaly"].to_numpy().astype(bool), expect, err_msg=fid)
                assert expect.any()


def test_csv_mode_attacks_non_training_flights(quick_dataset):
    ds = open_dataset(quick_dataset)
    m = ds.manifest.set_index("flight_id")
    csv = m[m["mode"] == "csv"]
    assert len(csv) == len(m[m["mode"] == "simulation"]) == 66
    assert set(m.loc[csv["source_flight"], "split"]) == {"csv_source"}  # reserved, never train/validation/test
    for fid, row in csv.head(3).iterrows():
        src = ds.topic(row["source_flight"], "gps_raw_int")
        copy = ds.topic(fid, "gps_raw_int", view="simulator")
        np.testing.assert_array_equal(src.drop(columns=list(LABEL_COLUMNS)).to_numpy(),
                                      copy.drop(columns=list(LABEL_COLUMNS)).to_numpy())


# --- the action formulas, on a synthetic 50 Hz stream ---------------------------------------------
RATE = 50
N = 12_000  # 240 s at 50 Hz


def _stream() -> dict[str, pd.DataFrame]:
    t = np.arange(N, dtype=np.int64) * (1_000_000 // RATE)
    x = np.linspace(0.0, 100.0, N)
    return {"local_position_ned": pd.DataFrame({
        "Timestamp": t, "x": x, "y": 0.5 * x, "z": np.full(N, -10.0), "vx": np.full(N, 0.5),
        "vy": np.full(N, 0.25), "vz": np.zeros(N)}),
        "global_position_int": pd.DataFrame({"Timestamp": t, "lat": np.full(N, 47.397742),
                                             "lon": np.full(N, 8.545594)})}


def _attack(action: dict, start_s=10.0, seconds=220.0):
    sc = scenario_from_dict({"id": "unit", "start": [{"condition": "time_window", "start_s": start_s}],
                             "end": [{"condition": "duration", "seconds": seconds}], "actions": [action]})
    src = _stream()
    (nav, windows, events), = csv_mode([src], [[sc]], [0])
    return src, nav, windows


def _in_window(df, windows):
    (s, e, *_), = windows
    ts = df["Timestamp"].to_numpy()
    return (ts >= s) & (ts < e)


def test_white_noise_std_in_metres():
    src, nav, w = _attack({"action": "add_white_noise", "target": ["local_position_ned.x", "global_position_int"],
                           "std": 2.0})
    m = _in_window(nav["local_position_ned"], w)
    assert m.sum() >= 10_000
    dx = (nav["local_position_ned"]["x"] - src["local_position_ned"]["x"])[m]
    assert abs(dx.std() / 2.0 - 1) < 0.1 and abs(dx.mean()) < 0.1
    g = nav["global_position_int"][m]
    assert abs((g["lat"] - 47.397742).std() * M_PER_DEG_LAT / 2.0 - 1) < 0.1
    assert abs((g["lon"] - 8.545594).std() * M_PER_DEG_LON / 2.0 - 1) < 0.1
    assert (nav["local_position_ned"]["x"][~m] == src["local_position_ned"]["x"][~m]).all()


def test_duplicate_returns_the_value_k_messages_back():
    src, nav, w = _attack({"action": "duplicate", "target": ["local_position_ned.x"], "k": 7})
    m = np.flatnonzero(_in_window(nav["local_position_ned"], w))
    x = src["local_position_ned"]["x"].to_numpy()
    np.testing.assert_array_equal(nav["local_position_ned"]["x"].to_numpy()[m], x[m - 7])


def test_avg_sensors_is_the_mean_of_the_last_n_messages():
    src, nav, w = _attack({"action": "avg_sensors", "target": ["local_position_ned.x"], "window": 5})
    m = np.flatnonzero(_in_window(nav["local_position_ned"], w))
    x = src["local_position_ned"]["x"].to_numpy()
    expect = np.array([x[i - 4:i + 1].mean() for i in m])
    np.testing.assert_allclose(nav["local_position_ned"]["x"].to_numpy()[m], expect, rtol=1e-12)


def test_stuck_holds_and_delayed_shifts_by_d():
    src, nav, w = _attack({"action": "stuck", "target": ["local_position_ned.x"]})
    m = np.flatnonzero(_in_window(nav["local_position_ned"], w))
    x = src["local_position_ned"]["x"].to_numpy()
    assert (nav["local_position_ned"]["x"].to_numpy()[m] == x[m[0]]).all()
    src, nav, w = _attack({"action": "delayed", "target": ["local_position_ned.x"], "delay_s": 0.5})
    m = np.flatnonzero(_in_window(nav["local_position_ned"], w))
    np.testing.assert_array_equal(nav["local_position_ned"]["x"].to_numpy()[m], x[m - 25])


def test_off_drops_and_slow_thins_messages():
    src, nav, w = _attack({"action": "off", "target": ["local_position_ned"]}, start_s=10, seconds=20)
    ts = nav["local_position_ned"]["Timestamp"].to_numpy()
    assert len(ts) == N - 20 * RATE
    assert not ((ts >= 10_000_000) & (ts < 30_000_000)).any()
    src, nav, w = _attack({"action": "slow", "target": ["local_position_ned"], "factor": 5}, start_s=10, seconds=20)
    assert len(nav["local_position_ned"]) == N - 20 * RATE + 20 * RATE // 5


def test_drift_velocity_matches_its_position_ramp():
    src, nav, w = _attack({"action": "drift", "target": ["local_position_ned"], "rate": 0.3,
                           "direction_deg": 90.0})
    m = _in_window(nav["local_position_ned"], w)
    d = (nav["local_position_ned"] - src["local_position_ned"])[m]
    t = nav["local_position_ned"]["Timestamp"][m].to_numpy() / 1e6
    slope_e = np.polyfit(t, d["y"], 1)[0]
    assert abs(slope_e - 0.3) < 1e-6 and np.allclose(d["vy"], 0.3) and np.allclose(d["vx"], 0.0, atol=1e-12)
    assert np.allclose(d["x"], 0.0, atol=1e-9), "east drift leaves north alone"


def test_gps_spoof_rotates_about_the_start_point():
    src, nav, w = _attack({"action": "gps_spoof", "target": ["local_position_ned"], "rate_deg_s": 1.0,
                           "max_deg": 20.0})
    m = np.flatnonzero(_in_window(nav["local_position_ned"], w))
    p0 = src["local_position_ned"][["x", "y"]].to_numpy()[m[0]]
    a = src["local_position_ned"][["x", "y"]].to_numpy()[m] - p0
    b = nav["local_position_ned"][["x", "y"]].to_numpy()[m] - p0
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1), atol=1e-9)
    ang = np.degrees(np.arctan2(b[-1, 1], b[-1, 0]) - np.arctan2(a[-1, 1], a[-1, 0]))
    assert abs(ang - 20.0) < 1e-6


# --- grids --------------------------------------------------------------------------------------------
def test_paper_grid_expands_to_2048_distinct_configurations_with_combinations_and_gps_spoofing():
    configs = load_configurations("data/scenarios/paper.toml")  # every scenario validated on loading
    assert len(configs) == 2048
    names = ["+".join(s.id for s in c) for c in configs]
    assert len(set(names)) == 2048
    assert len({tuple(s.params_json() for s in c) for c in configs}) == 2048
    combos = [c for c in configs if len(c) > 1]
    assert len(combos) >= 2048 / 4, "at least a quarter are combinations of attacks"
    assert all(len({(s.primary_action(), tuple(s.to_dict()["actions"][0]["target"])) for s in c}) == len(c)
               for c in combos), "a combination's parts differ in action or target"
    actions = {s.primary_action() for c in configs for s in c}
    assert actions >= {"gps_spoof", "add_white_noise", "random_change", "duplicate", "disconnect_sensor",
                       "avg_sensors", "bias", "drift", "sinusoid"}
    assert any(s.primary_action() == "gps_spoof" for c in combos for s in c)
    starts = {s.start[0][0] for c in combos for s in c[1:]}
    assert starts == {"scenario_started", "scenario_ended"}, "both concurrent and chained combinations"
    for name in names:
        check_id(name, "paper configuration")
    assert names == ["+".join(s.id for s in c) for c in load_configurations("data/scenarios/paper.toml")]


def test_single_action_grid_keeps_the_earlier_ids_and_the_paper_grid_shares_them():
    single = load_grid("data/scenarios/paper_single.toml")
    assert len(single) == 2048 and len({s.id for s in single}) == 2048
    assert single[0].id == "paper-add_white_noise-position-L0-d5-time"
    assert {s.primary_action() for s in single} >= {"add_white_noise", "random_change", "duplicate",
                                                    "disconnect_sensor", "avg_sensors"}
    # a single attack of the combined grid is the same scenario as in the single-action grid
    by_id = {s.id: s.params_json() for s in single}
    paper = [c[0] for c in load_configurations("data/scenarios/paper.toml") if len(c) == 1]
    shared = [s for s in paper if s.id in by_id]
    assert len(shared) == 1024 and all(by_id[s.id] == s.params_json() for s in shared)
    with pytest.raises(ScenarioError, match="combinations of attacks"):
        load_grid("data/scenarios/paper.toml")


def test_profile_grids_still_expand():
    assert len(load_configurations("data/scenarios/quick.toml")) == 66
    assert all(len(c) == 1 for c in load_configurations("data/scenarios/standard.toml"))


GRID = """
[grid]
id = "g"
[grid.axes]
action = ["bias"]
target = ["pos"]
level = [0, 1]
duration_s = [5.0]
trigger = ["t"]
combine = [{combine}]
[targets.pos]
fields = ["local_position_ned.x", "local_position_ned.y"]
magnitudes = [1.0, 2.0]
[targets.alt]
fields = ["local_position_ned.z"]
magnitudes = [1.0, 2.0]
[actions.bias]
param = "offset"
[actions.drift]
param = "rate"
[actions.gps_spoof]
param = "rate_deg_s"
levels = [1.0, 2.0]
targets = ["pos"]
[triggers.t]
start = [{{ condition = "time_window", start_s = 10.0 }}]
"""


def test_grid_combinations_expand_concurrent_and_chained(tmp_path):
    path = tmp_path / "g.toml"
    path.write_text(GRID.format(combine='{ mode = "concurrent", parts = [["bias", "pos"], ["drift", "alt"]] }, '
                                        '{ mode = "chained", parts = [["gps_spoof", "pos"], ["bias", "alt"], '
                                        '["drift", "pos"]] }'))
    configs = load_configurations(path)
    assert ["+".join(s.id for s in c) for c in configs] == [
        "g-bias-pos-L0-d5-t", "g-bias-pos-L1-d5-t",
        "g-bias-pos-L0-d5-t+g-drift-alt-L0-d5-with", "g-bias-pos-L1-d5-t+g-drift-alt-L1-d5-with",
        "g-gps_spoof-pos-L0-d5-t+g-bias-alt-L0-d5-then+g-drift-pos-L0-d5-then",
        "g-gps_spoof-pos-L1-d5-t+g-bias-alt-L1-d5-then+g-drift-pos-L1-d5-then"]
    conc, chain = configs[3], configs[5]
    assert conc[1].start == [("scenario_started", {"scenario": conc[0].id, "after_s": 0.0})]
    assert [s.start[0][1]["scenario"] for s in chain[1:]] == [chain[0].id, chain[1].id]
    assert chain[0].to_dict()["actions"][0]["rate_deg_s"] == 2.0  # the level picks each part's magnitude
    assert chain[1].to_dict()["actions"][0]["offset"] == 2.0


@pytest.mark.parametrize("combine, message", [
    ('{ mode = "both", parts = [["bias", "pos"], ["drift", "alt"]] }', "mode: expected one of concurrent, chained"),
    ('{ mode = "chained", parts = [["bias", "pos"]] }', "at least 2 parts"),
    ('{ mode = "chained", parts = [["bias", "pos"], ["bias", "pos"]] }', "appears twice"),
    ('{ mode = "chained", parts = [["wobble", "pos"], ["bias", "alt"]] }', "unknown action 'wobble'"),
    ('{ mode = "chained", parts = [["bias", "pos"], ["bias", "imu"]] }', "'imu' has no [targets.imu]"),
    ('{ mode = "chained", parts = [["gps_spoof", "alt"], ["bias", "pos"]] }', "applies only to pos"),
    ('{ mode = "chained", parts = [["bias", "pos"], "drift"] }', "parts[1]: expected [action, target]"),
    ('{ mode = "concurrent", parts = [["bias", "pos"], ["drift", "alt"]] }, '
     '{ mode = "concurrent", parts = [["drift", "alt"], ["bias", "pos"]] }', "repeats an earlier combination"),
])
def test_bad_grid_combinations_name_the_entry(tmp_path, combine, message):
    path = tmp_path / "g.toml"
    path.write_text(GRID.format(combine=combine))
    with pytest.raises(ScenarioError, match=re.escape(message)) as err:
        load_configurations(path)
    assert "grid.axes.combine[" in str(err.value) and str(path) in str(err.value)


def test_grid_combination_ids_stay_within_the_id_rule(tmp_path):
    path = tmp_path / "g.toml"
    text = GRID.format(combine='{ mode = "chained", parts = [["bias", "pos"], ["drift", "alt"], ["drift", "pos"], '
                               '["bias", "alt"]] }').replace('id = "g"', f'id = "{"g" * 45}"')
    path.write_text(text)
    with pytest.raises(ScenarioError, match="at most 200"):
        load_configurations(path)


# --- csv mode on real PX4 logs -------------------------------------------------------------------------
ULOG_SCENARIO = """
[scenario]
id = "ulog-gps"
[[scenario.start]]
condition = "time_window"
start_s = {start}
[[scenario.end]]
condition = "duration"
seconds = 3.0
[[scenario.actions]]
action = "add_white_noise"
target = ["vehicle_gps_position.lat", "vehicle_gps_position.lon"]
std = 20.0
"""


@needs_ulogs
@pytest.mark.parametrize("log, start, topics", [
    (RFLYMAD, 15.0, None),
    (PX4_SAMPLE, 2.0, "vehicle_gps_position,sensor_combined,vehicle_local_position,vehicle_attitude"),
])
def test_csv_mode_on_real_ulogs(tmp_path, log, start, topics):
    sc = tmp_path / "sc.toml"
    sc.write_text(ULOG_SCENARIO.format(start=start))
    out = tmp_path / "out"
    args = ["attack", "--input", str(log), "--scenario", str(sc), "--out", str(out)]
    if topics:
        args += ["--topics", topics]
    assert main(args) == 0
    ds = open_dataset(out)
    fid = ds.manifest["flight_id"].iloc[0]
    ev = ds.events(fid)
    s = int(ev[ev["event"] == "start"]["timestamp_us"].iloc[0])
    e = int(ev[ev["event"] == "end"]["timestamp_us"].iloc[0])
    assert e - s >= 2_900_000
    nav = ds.topic(fid, "vehicle_gps_position", "navigator")
    sim = ds.topic(fid, "vehicle_gps_position", "simulator")
    inside = (nav["Timestamp"] >= s) & (nav["Timestamp"] < e)
    assert inside.sum() >= 10
    np.testing.assert_array_equal(nav["Is_Anomaly"].to_numpy(), inside.to_numpy().astype(np.int8))
    dev = (nav["lat"] - sim["lat"]).abs() * M_PER_DEG_LAT
    assert dev[inside].max() > 10 and dev[~inside].max() == 0
    acc_nav = ds.topic(fid, "sensor_combined", "navigator")
    acc_sim = ds.topic(fid, "sensor_combined", "simulator")
    assert acc_nav.drop(columns=list(LABEL_COLUMNS)).equals(acc_sim.drop(columns=list(LABEL_COLUMNS)))
    comb = ds.flight(fid)
    assert list(comb.columns[:3]) == ["Index", "Timestamp", "Is_Anomaly"] and comb["Is_Anomaly"].any()


# --- bad scenario files -------------------------------------------------------------------------------
GOOD = {
    "start": '[[scenario.start]]\ncondition = "time_window"\nstart_s = 5.0\n',
    "end": '[[scenario.end]]\ncondition = "duration"\nseconds = 5.0\n',
    "action": '[[scenario.actions]]\naction = "bias"\ntarget = ["local_position_ned.x"]\noffset = 3.0\n',
}


@pytest.mark.parametrize("name, part, text, expect", [
    ("unknown action", "action", '[[scenario.actions]]\naction = "teleport"\ntarget = ["attitude"]\n',
     ["scenario.actions[0].action", "teleport", "add_white_noise", "gps_spoof"]),
    ("unknown condition", "start", '[[scenario.start]]\ncondition = "full_moon"\n',
     ["scenario.start[0].condition", "full_moon", "time_window"]),
    ("wrong type", "action", '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.roll"]\noffset = "big"\n',
     ["scenario.actions[0].offset", "expected a number"]),
    ("missing field", "action", '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.roll"]\n',
     ["scenario.actions[0]", "offset"]),
    ("negative duration", "end", '[[scenario.end]]\ncondition = "duration"\nseconds = -4.0\n',
     ["scenario.end[0].seconds", "> 0"]),
    ("unknown topic", "action", '[[scenario.actions]]\naction = "bias"\ntarget = ["gpz.lat"]\noffset = 1.0\n',
     ["target", "gpz", "global_position_int"]),
    ("unknown field", "action", '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.heading"]\noffset = 1.0\n',
     ["target", "attitude.heading", "roll"]),
])
def test_bad_scenario_files_name_file_key_and_allowed_values(tmp_path, capsys, name, part, text, expect):
    parts = dict(GOOD)
    parts[part] = text
    path = tmp_path / "bad.toml"
    path.write_text('[scenario]\nid = "bad"\n' + "".join(parts.values()))
    with pytest.raises(ValueError) as err:
        load_scenarios(path)
    for word in [str(path), *expect]:
        assert word in str(err.value), (name, str(err.value))
    # through the CLI: exit code 2 and nothing written
    flight = tmp_path / "flight.csv"
    pd.DataFrame({"timestamp_us": [0, 20000, 40000], "x": [0.0, 1.0, 2.0]}).to_csv(flight, index=False)
    out = tmp_path / "out"
    assert main(["attack", "--input", str(flight), "--scenario", str(path), "--out", str(out)]) == 2
    assert str(path) in capsys.readouterr().err
    assert not out.exists()


@needs_ulogs
def test_attack_with_a_grid_gives_one_copy_per_configuration(tmp_path):
    grid = tmp_path / "grid.toml"
    grid.write_text("""
[grid]
id = "ulog"
[grid.axes]
action = ["bias", "add_white_noise"]
target = ["gps"]
level = [0, 1]
duration_s = [3.0]
trigger = ["t"]
[targets.gps]
fields = ["vehicle_gps_position.lat", "vehicle_gps_position.lon"]
magnitudes = [5.0, 20.0]
[actions.bias]
param = "offset"
[actions.add_white_noise]
param = "std"
[triggers.t]
start = [{ condition = "time_window", start_s = 15.0 }]
""")
    out = tmp_path / "out"
    assert main(["attack", "--input", str(RFLYMAD), "--scenario", str(grid), "--out", str(out),
                 "--topics", "vehicle_gps_position,sensor_combined"]) == 0
    ds = open_dataset(out)
    assert sorted(ds.manifest["flight_id"]) == sorted(f"csv-ulog-{a}-gps-L{k}-d3-t" for a in ("bias", "add_white_noise")
                                                      for k in (0, 1))
    # time zero is the start of logging: the first message at or after 15 s starts it
    assert ds.manifest["attack_start_us"].between(15_000_000, 15_010_000).all()
