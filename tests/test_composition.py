"""Several scenarios per flight, environment attacks and reliability faults (the layer's second step)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import distance_to_path

from scart_bench.cli.main import main
from scart_bench.dataset import LABEL_COLUMNS, label_columns, open_dataset
from scart_bench.generator.modes import csv_mode, simulation_mode, simulation_record
from scart_bench.generator.params import GRAVITY, VehicleParams
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.scenario import (
    ScenarioError,
    check_composition,
    load_scenarios,
    scenario_from_dict,
)
from scart_bench.generator.telemetry.tables import flight_views

SCENARIOS = Path(__file__).resolve().parents[1] / "data" / "scenarios"
SEED = 5
ORDER = ("normal", "chain", "rf_spoof", "motor70", "motor_failure", "gust", "battery", "baro_loss")
FILES = {"chain": "chain_jam_then_drift", "rf_spoof": "env_gps_rf_spoof", "motor70": "fault_motor_efficiency",
         "motor_failure": "fault_motor_failure", "gust": "env_wind_gust", "battery": "fault_battery_sag",
         "baro_loss": "fault_sensor_loss"}


@pytest.fixture(scope="module")
def fleet():
    """One seed flown normally and with each composed / physical scenario, in one batch."""
    scs = [[]] + [load_scenarios(SCENARIOS / f"{FILES[k]}.toml") for k in ORDER[1:]]
    batch, layer = simulation_mode([SEED] * len(scs), scs)
    return batch, layer, {k: i for i, k in enumerate(ORDER)}


def _views(batch, layer, i):
    end_us = (int(batch.exit_step[i]) + 1) * 4000
    windows = layer.labelled_windows(i, end_us)
    nav, sim = flight_views(batch, i, windows)
    return nav, sim, windows


def _estimate_error(sim) -> pd.DataFrame:
    """Horizontal distance between the flight controller's position estimate and the truth."""
    # the nearest truth row (50 Hz) to each estimate: with realistic timing the messages are not on its clock
    est = sim["local_position_ned"].sort_values("Timestamp")
    m = pd.merge_asof(est, sim["truth"], on="Timestamp", direction="nearest", tolerance=10_000, suffixes=("_e", "_t"))
    m = m.dropna(subset=["x_t"])
    return pd.DataFrame({"t": m["Timestamp"], "err": np.hypot(m["x_t"] - m["x_e"], m["y_t"] - m["y_e"])})


def _path_gap(sim_a, sim_b) -> np.ndarray:
    a, b = sim_a["truth"], sim_b["truth"]
    n = min(len(a), len(b))
    return np.hypot(a["x"].to_numpy()[:n] - b["x"].to_numpy()[:n], a["y"].to_numpy()[:n] - b["y"].to_numpy()[:n])


# --- composition ---------------------------------------------------------------------------------
def test_chained_jamming_then_drift_gives_two_windows_with_ids_and_kinds(fleet):
    batch, layer, k = fleet
    nav, _, windows = _views(batch, layer, k["chain"])
    assert [(w[2], w[3]) for w in windows] == [("gps-jam", "attack"), ("link-drift", "attack")]
    (s1, e1, *_), (s2, e2, *_) = windows
    assert e1 - s1 == pytest.approx(5e6, abs=4000)  # the jamming lasts its 5 s
    assert 0 <= s2 - e1 <= 20_000  # the drift starts at the first link message after the jamming ends
    assert e2 - s2 == pytest.approx(20e6, abs=4000)
    lp = nav["local_position_ned"]
    ts = lp["Timestamp"].to_numpy()
    in1, in2 = (ts >= s1) & (ts < e1), (ts >= s2) & (ts < e2)
    assert (lp.loc[in1, "Anomaly_Ids"] == "gps-jam").all() and (lp.loc[in2, "Anomaly_Ids"] == "link-drift").all()
    assert (lp.loc[in1 | in2, "Anomaly_Kind"] == "attack").all()
    assert (lp.loc[~(in1 | in2), "Anomaly_Ids"] == "").all() and (lp.loc[~(in1 | in2), "Is_Anomaly"] == 0).all()
    assert lp["Is_Anomaly"].to_numpy().astype(bool).tolist() == (in1 | in2).tolist()


def test_gps_jamming_loses_the_fix_and_the_flight_controller_coasts_then_recovers(fleet):
    batch, layer, k = fleet
    i = k["chain"]
    _, sim, windows = _views(batch, layer, i)
    s, e = windows[0][:2]
    gps = sim["gps_raw_int"]
    t = gps["Timestamp"]
    before, during = gps[t < s], gps[(t >= s) & (t < e)]
    assert during["eph"].max() > 10 * before["eph"].max()  # reported accuracy degrades ...
    assert during["fix_type"].min() < 3 and before["fix_type"].min() == 3  # ... and the fix is lost
    assert (gps.loc[t >= e + 1e6, "fix_type"] == 3).all()  # re-acquired within a second of the end
    err = _estimate_error(sim)
    coast = err[(err.t >= s) & (err.t < e)]["err"]
    assert coast.max() < 15.0  # inertial dead reckoning for 5 s: it drifts, but it flies
    assert err[err.t >= e + 10e6]["err"].max() < 1.0  # GPS fused again: the estimate recovers
    assert batch.status[i] == "landed"
    land = sim["truth"].iloc[-1]
    assert np.hypot(land["x"], land["y"]) < 1.5
    assert batch.gps_rejections[i][0] <= 5  # the covariance grew while coasting: GPS is accepted back


def test_composed_scenario_runs_in_csv_mode_with_only_its_message_level_part(fleet):
    batch, layer, k = fleet
    nav_in, _, _ = _views(batch, layer, k["normal"])
    link = {t: df.drop(columns=list(LABEL_COLUMNS)) for t, df in nav_in.items()}
    chain = load_scenarios(SCENARIOS / "chain_jam_then_drift.toml")
    (nav, windows, events), = csv_mode([link], [chain], [SEED])
    # the jamming keeps its timing (so the chain holds) but changes nothing and is not labelled
    assert [(w[2], w[3]) for w in windows] == [("link-drift", "attack")]
    jam = [e for e in events if e["scenario_id"] == "gps-jam"]
    assert [e["event"] for e in jam] == ["start", "end"] and all("timing only" in e["detail"] for e in jam)
    assert windows[0][0] == jam[1]["timestamp_us"]
    # simulation mode and csv mode start the chain at the same mission point
    _, _, sim_windows = _views(batch, layer, k["chain"])
    assert abs(windows[0][0] - sim_windows[1][0]) < 0.5e6
    s, e = windows[0][:2]
    for topic in ("gps_raw_int", "attitude"):
        out, src = nav[topic], link[topic]
        ts = out["Timestamp"].to_numpy()
        inside = (ts >= s) & (ts < e)
        changed = (out[[c for c in src.columns if c != "Timestamp"]].to_numpy()
                   != src.drop(columns="Timestamp").to_numpy()).any(axis=1)
        assert not changed[~inside].any()  # nothing outside the drift window (jamming included)
        assert changed[inside].any() == (topic == "gps_raw_int")
        assert (out.loc[inside, "Anomaly_Ids"] == "link-drift").all()


# --- environment ---------------------------------------------------------------------------------
def test_rf_spoofing_drags_the_vehicle_with_a_plausible_fix(fleet):
    batch, layer, k = fleet
    _, sim_n, _ = _views(batch, layer, k["normal"])
    _, sim, windows = _views(batch, layer, k["rf_spoof"])
    s, e = windows[0][:2]
    gps = sim["gps_raw_int"]
    during = gps[(gps.Timestamp >= s) & (gps.Timestamp < e)]
    assert during["fix_type"].min() == 3 and during["satellites_visible"].min() >= 10
    assert during["eph"].max() < 0.5  # a strong, clean fake constellation
    assert _path_gap(sim, sim_n).max() > 5.0  # the true path is dragged off the square
    assert batch.gps_rejections[k["rf_spoof"]][1] == 0  # velocities stay consistent: none rejected


# --- reliability faults --------------------------------------------------------------------------
def test_motor_at_70_percent_completes_and_is_labelled_a_fault(fleet):
    batch, layer, k = fleet
    v = VehicleParams()
    margin = (3 + 0.7) * v.max_thrust / (v.mass * GRAVITY)
    assert margin > 1.5  # thrust to spare: the flight should complete
    i = k["motor70"]
    nav, sim, windows = _views(batch, layer, i)
    assert batch.status[i] == "landed"
    land = sim["truth"].iloc[-1]
    assert np.hypot(land["x"], land["y"]) < 1.5
    assert _path_gap(sim, _views(batch, layer, k["normal"])[1]).max() < 3.0
    assert [(w[2], w[3]) for w in windows] == [("fault-motor-70", "fault")]
    lp = nav["local_position_ned"]
    assert set(lp.loc[lp["Is_Anomaly"] == 1, "Anomaly_Kind"]) == {"fault"}
    record = simulation_record(batch, layer, i, "sim-m70", load_scenarios(SCENARIOS / "fault_motor_efficiency.toml"),
                               {})
    assert record.manifest["kind"] == "fault"


def test_motor_failure_loses_the_vehicle_soon_after(fleet):
    batch, layer, k = fleet
    i = k["motor_failure"]
    _, _, windows = _views(batch, layer, i)
    (s, e, sid, kind), = windows
    assert (sid, kind) == ("fault-motor-failure", "fault") and s == pytest.approx(25e6, abs=4000)
    assert batch.status[i] == "crashed"  # no yaw/attitude authority on three rotors
    assert (int(batch.exit_step[i]) + 1) * 4000 - s < 5e6


def _during(df, s, e):
    t = df["Timestamp"]
    return df[(t >= s) & (t < e)]


def test_wind_gust_pushes_the_vehicle_off_its_path_for_a_while(fleet):
    batch, layer, k = fleet
    i = k["gust"]
    _, sim, windows = _views(batch, layer, i)
    (s, e, sid, kind), = windows
    assert kind == "fault" and batch.status[i] == "landed"
    tr = sim["truth"]
    t = tr["Timestamp"].to_numpy()
    off = distance_to_path(tr[["x", "y"]].to_numpy(), batch.waypoints[i][:, :2])
    gap = _path_gap(sim, _views(batch, layer, k["normal"])[1])
    tg = t[: gap.size]
    assert gap[tg < s].max() == 0.0 and gap[(tg >= s) & (tg < e + 3e6)].max() > 0.75  # pushed off course ...
    assert np.median(off[t > e + 10e6]) < 0.5  # ... and back on the square after


def test_battery_sag_shows_in_the_reported_voltage(fleet):
    batch, layer, k = fleet
    _, sim_n, _ = _views(batch, layer, k["normal"])
    _, sim, windows = _views(batch, layer, k["battery"])
    s = windows[0][0]
    v, v_n = sim["battery_status"], sim_n["battery_status"]
    late = min(v["Timestamp"].iloc[-1], v_n["Timestamp"].iloc[-1])
    drop = (_during(v_n, s + 6e6, late)["voltage"].mean() - _during(v, s + 6e6, late)["voltage"].mean())
    assert drop == pytest.approx(3.0, abs=0.3)  # the full 3 V once the 5 s ramp is over
    assert (_during(v, 0, s)["voltage"].to_numpy() == _during(v_n, 0, s)["voltage"].to_numpy()).all()
    assert batch.status[k["battery"]] == "landed"


def test_lost_barometer_fails_over_to_an_instance_with_its_own_offset(fleet):
    batch, layer, k = fleet
    _, sim_n, _ = _views(batch, layer, k["normal"])
    _, sim, windows = _views(batch, layer, k["baro_loss"])
    s = windows[0][0]
    a, b = _during(sim["truth"], s + 5e6, s + 15e6), _during(sim_n["truth"], s + 5e6, s + 15e6)
    # the second instance reads 0.8 m high: the flight controller, holding 10 m on it, flies lower
    lower = np.median(a["z"].to_numpy() - b["z"].to_numpy())
    assert lower == pytest.approx(0.8, abs=0.25)
    before = _during(sim["truth"], 0, s)["z"].to_numpy() - _during(sim_n["truth"], 0, s)["z"].to_numpy()
    assert np.abs(before).max() == 0.0
    assert batch.status[k["baro_loss"]] == "landed"


def test_label_columns_join_overlapping_scenarios_and_kinds():
    ts = np.arange(0, 10)
    cols = label_columns(ts, [(2, 6, "jam", "attack"), (4, 8, "motor", "fault"), (5, 7, "jam2", "attack")])
    assert cols["Is_Anomaly"].tolist() == [0, 0, 1, 1, 1, 1, 1, 1, 0, 0]
    assert cols["Anomaly_Ids"].tolist()[2:8] == ["jam", "jam", "jam+motor", "jam+motor+jam2", "motor+jam2", "motor"]
    assert cols["Anomaly_Kind"].tolist()[3:8] == ["attack", "attack+fault", "attack+fault", "attack+fault", "fault"]


# --- grids of compositions and bad compositions ----------------------------------------------------
def test_sweep_expands_compositions_and_references_follow_the_new_ids(tmp_path):
    src = (SCENARIOS / "chain_jam_then_drift.toml").read_text()
    path = tmp_path / "sweep.toml"
    path.write_text(src + '\n[sweep]\n"gps-jam.end.0.seconds" = [3.0, 5.0]\n"link-drift.actions.0.rate" = [0.1, 0.3, 1]\n')
    configs = load_configurations(path)
    assert len(configs) == 6
    ids = ["+".join(s.id for s in c) for c in configs]
    assert len(set(ids)) == 6 and "gps-jam-seconds3+link-drift-rate0.1" in ids
    for c in configs:
        jam, drift = c
        assert drift.start[0][1]["scenario"] == jam.id  # the chain still points at its jamming
    assert {c[0].end[0][1]["seconds"] for c in configs} == {3.0, 5.0}
    assert load_configurations(SCENARIOS / "chain_jam_then_drift.toml") == [
        load_scenarios(SCENARIOS / "chain_jam_then_drift.toml")]


def test_sweep_attack_writes_one_labelled_flight_per_combination(tmp_path, fleet):
    batch, layer, k = fleet
    nav, _, _ = _views(batch, layer, k["normal"])
    flight = tmp_path / "local_position_ned.csv"  # a single CSV: its topic is the file name
    nav["local_position_ned"].drop(columns=list(LABEL_COLUMNS)).to_csv(flight, index=False)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text("""
[[scenario]]
id = "noise"
[[scenario.start]]
condition = "time_window"
start_s = 10.0
[[scenario.end]]
condition = "duration"
seconds = 5.0
[[scenario.actions]]
action = "add_white_noise"
target = ["local_position_ned.x"]
std = 2.0
[[scenario]]
id = "bias"
[[scenario.start]]
condition = "scenario_started"
scenario = "noise"
after_s = 2.0
[[scenario.end]]
condition = "duration"
seconds = 10.0
[[scenario.actions]]
action = "bias"
target = ["local_position_ned.y"]
offset = 5.0
[sweep]
"noise.actions.0.std" = [1.0, 3.0]
""")
    out = tmp_path / "out"
    assert main(["attack", "--input", str(flight), "--scenario", str(sweep), "--out", str(out)]) == 0
    ds = open_dataset(out)
    assert len(ds) == 2
    for fid in ds.manifest["flight_id"]:
        table = ds.flight(fid, table="all_sensors")
        ids = set(table["Anomaly_Ids"]) - {""}
        assert any("+" in x for x in ids)  # the two overlap: several scenarios at once
        ev = ds.events(fid)
        starts = ev[ev.event == "start"].set_index("scenario_id")["timestamp_us"]
        assert starts.iloc[1] - starts.iloc[0] == pytest.approx(2e6, abs=0.05e6)


def _chain(ref_a: str, ref_b: str) -> list:
    def one(sid, ref):
        return scenario_from_dict({
            "id": sid, "start": [{"condition": "scenario_ended", "scenario": ref}],
            "actions": [{"action": "bias", "target": ["local_position_ned.x"], "offset": 1.0}]}, "chain.toml")
    return [one("a", ref_a), one("b", ref_b)]


def test_bad_compositions_name_the_problem():
    with pytest.raises(ScenarioError, match=r"'a' start\[0\] \(scenario_ended\) refers to unknown scenario 'zz'"):
        check_composition(_chain("zz", "a"), "chain.toml")
    with pytest.raises(ScenarioError, match="cycle: a -> b -> a"):
        check_composition(_chain("b", "a"), "chain.toml")
    with pytest.raises(ScenarioError, match="cycle"):
        simulation_mode([1], [_chain("b", "a")])


@pytest.mark.parametrize("bad", ["unknown", "cycle", "wrong_point"])
def test_bad_composition_files_exit_2_and_write_nothing(tmp_path, bad, capsys):
    base = (SCENARIOS / "chain_jam_then_drift.toml").read_text()
    if bad == "unknown":
        text = base.replace('scenario = "gps-jam"', 'scenario = "gps-jamm"')
    elif bad == "cycle":
        text = base.replace('condition = "mission_phase"\nafter_waypoint = 1',
                            'condition = "scenario_ended"\nscenario = "link-drift"')
    else:  # a message action at a physical injection point
        text = base.replace('action = "gps_jamming"\njs_db = 45.0', 'action = "bias"\ntarget = ["x"]\noffset = 1.0')
    assert text != base
    path = tmp_path / "bad.toml"
    path.write_text(text)
    flight = tmp_path / "f.csv"
    flight.write_text("Timestamp,x\n0,1\n1000,2\n")
    out = tmp_path / "out"
    assert main(["attack", "--input", str(flight), "--scenario", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and not out.exists()
    expect = {"unknown": "unknown scenario 'gps-jamm'", "cycle": "cycle: ", "wrong_point": "unknown action 'bias' at injection point 'environment'"}
    assert expect[bad] in err


def test_every_example_scenario_file_loads():
    for path in sorted(SCENARIOS.glob("*.toml")):
        configs = load_configurations(path)
        assert configs and all(c for c in configs), path.name
    doc = json.dumps([s.to_dict() for s in load_scenarios(SCENARIOS / "env_gps_jamming.toml")])
    assert "environment" in doc


def test_generate_with_a_composition_labels_both_modes(tmp_path):
    out = tmp_path / "ds"
    chain = SCENARIOS / "chain_jam_then_drift.toml"
    assert main(["generate", "--profile", "quick", "--flights", "3", "--scenarios", str(chain),
                 "--out", str(out)]) == 0
    ds = open_dataset(out)
    m = ds.manifest.set_index("flight_id")
    sim, csv = m.loc["sim-gps-jam+link-drift"], m.loc["csv-gps-jam+link-drift"]
    assert (sim["mode"], csv["mode"]) == ("simulation", "csv")
    assert sim["kind"] == csv["kind"] == "attack" and sim["injection_point"] == "environment+link"
    ids_sim = set(ds.flight("sim-gps-jam+link-drift")["Anomaly_Ids"]) - {""}
    ids_csv = set(ds.flight("csv-gps-jam+link-drift")["Anomaly_Ids"]) - {""}
    assert ids_sim == {"gps-jam", "link-drift"}  # both parts act in the closed loop
    assert ids_csv == {"link-drift"}  # only the message-level part acts on a recording
    bad = tmp_path / "bad.toml"
    bad.write_text(chain.read_text().replace('scenario = "gps-jam"', 'scenario = "nope"'))
    assert main(["generate", "--profile", "quick", "--flights", "3", "--scenarios", str(bad),
                 "--out", str(tmp_path / "ds2")]) == 2
    assert not (tmp_path / "ds2").exists()
