"""Scenarios and grids by meaning on real logs: DataFlash fields resolve, phase triggers apply, and
``attack --dataset`` copies every configuration that applies and counts the others by reason."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import open_dataset
from scart_bench.generator.geo import ne_from_latlon
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.offline import applicable, attack_file, with_phases
from scart_bench.generator.scart.grid import load_configurations

ROOT = Path(__file__).parents[1]
SHARED = ROOT.parent / "shared/data"
DATAFLASH = sorted((SHARED / "dataflash").glob("*.bin"))
RFLYMAD = SHARED / "ulog/rflymad_TestCase_1_1000000000.ulg"
SMALL = SHARED / "ulog/px4_sample_log_small.ulg"
SCENARIOS = ROOT / "data/scenarios"
needs = pytest.mark.skipif(len(DATAFLASH) < 2 or not RFLYMAD.exists(), reason=f"shared logs not found in {SHARED}")

EAST_BIAS = """
[scenario]
id = "gps-east"
injection_point = "sensor"
[[scenario.start]]
condition = "time_window"
start_s = 40.0
[[scenario.end]]
condition = "duration"
seconds = 20.0
[[scenario.actions]]
action = "bias"
target = ["gps.lat", "gps.lon"]
offset = 50.0
direction_deg = 90.0
"""


@needs
@pytest.mark.parametrize("log", DATAFLASH, ids=lambda p: p.stem)
def test_a_50_m_east_gps_bias_on_a_dataflash_log_is_50_m_east_inside_the_window_only(tmp_path, log):
    scenario = tmp_path / "east.toml"
    scenario.write_text(EAST_BIAS)
    out = attack_file(log, scenario, tmp_path / "out", allow_corrupt=True)
    ds = open_dataset(out)
    fid = ds.manifest["flight_id"].iloc[0]
    src = load_flight_file(log, allow_corrupt=True)["gps"]
    got = ds.topic(fid, "gps", "navigator")
    assert np.array_equal(got["Timestamp"].to_numpy(), src["Timestamp"].to_numpy())
    t = got["Timestamp"].to_numpy()
    row = ds.manifest.set_index("flight_id").loc[fid]
    # from the first message of the log at or after 40 s (the loiter log has no messages from 30 s to 53 s), for 20 s
    assert 40e6 <= row["attack_start_us"] <= t[t >= 40e6][0]
    assert row["attack_end_us"] - row["attack_start_us"] == pytest.approx(20e6, abs=0.2e6)
    inside = (t >= row["attack_start_us"]) & (t < row["attack_end_us"])
    lat0, lon0 = src["Lat"].to_numpy(), src["Lng"].to_numpy()
    n, e = ne_from_latlon(got["Lat"].to_numpy(), got["Lng"].to_numpy(), lat0, lon0)
    assert 42.8 < lat0[inside].mean() < 42.9  # the logs' own latitude, not the generator's home
    assert np.allclose(e[inside], 50.0, atol=0.5) and np.allclose(n[inside], 0.0, atol=0.5)
    outside = ~inside
    assert np.array_equal(got["Lat"].to_numpy()[outside], lat0[outside])
    assert np.array_equal(got["Lng"].to_numpy()[outside], lon0[outside])
    assert np.array_equal(got["Is_Anomaly"].to_numpy().astype(bool), inside)  # the labels are the window


@needs
@pytest.mark.parametrize("log", [*DATAFLASH, SMALL, RFLYMAD], ids=lambda p: p.stem)
@pytest.mark.parametrize("example", ["gps_spoof", "sensor_gps_drift"])
def test_phase_triggered_examples_apply_to_logs_without_a_mission(tmp_path, log, example):
    """Their trigger, mission item 1 passed, is read from the log's phases; on the PX4 sample (a 1 s hop
    that never cruises) it never holds, which is a refusal naming the start conditions."""
    tables = with_phases(load_flight_file(log, allow_corrupt=True))
    jobs = load_configurations(SCENARIOS / f"{example}.toml", check_topics=False)
    fit, why = applicable(jobs, tables, log.name)
    assert len(fit) == 1 and not why
    if log == SMALL:
        with pytest.raises(Exception, match="never started"):
            attack_file(log, SCENARIOS / f"{example}.toml", tmp_path / "out")
        return
    ds = open_dataset(attack_file(log, SCENARIOS / f"{example}.toml", tmp_path / "out", allow_corrupt=True))
    row = ds.manifest.iloc[0]
    assert row["attack_start_us"] > 0 and row["attack_end_us"] > row["attack_start_us"]
    assert "flight_phase" not in ds.topics(row["flight_id"], "navigator")  # derived, never written


@needs
def test_grids_by_meaning_resolve_on_dataflash_and_ulog_topics():
    standard = load_configurations(SCENARIOS / "standard.toml", check_topics=False)
    for log in DATAFLASH:
        fit, why = applicable(standard, with_phases(load_flight_file(log, allow_corrupt=True)), log.name)
        assert len(fit) == len(standard) and not why
    fit, why = applicable(standard, with_phases(load_flight_file(RFLYMAD)), RFLYMAD.name)
    # PX4 logs its attitude as a quaternion: its roll and pitch (generator.logs.orientation) take the attacks
    assert len(fit) == len(standard) and not why


@needs
def test_attack_dataset_with_a_grid_copies_what_applies_and_counts_the_rest_by_reason(tmp_path, capsys):
    ds = tmp_path / "ds"
    assert main(["import", str(DATAFLASH[1]), "--out", str(ds), "--split", "test",
                 "--topics", "gps,ctun,att,ev,mode,imu"]) == 0
    assert main(["import", str(RFLYMAD), "--out", str(ds), "--split", "test", "--topics",
                 "vehicle_gps_position,vehicle_local_position,vehicle_land_detected,vehicle_status,vehicle_attitude"]) == 0
    grid = tmp_path / "small.toml"
    grid.write_text("""
[grid]
id = "small"
[grid.axes]
action = ["bias"]
target = ["position", "attitude"]
level = [0]
duration_s = [10.0]
trigger = ["early", "late", "cruise"]
[targets.position]
fields = ["global_position_int.lat", "global_position_int.lon", "gps_raw_int.lat", "gps_raw_int.lon"]
magnitudes = [20.0]
[targets.attitude]
fields = ["attitude.roll", "attitude.pitch"]
magnitudes = [0.1]
[actions.bias]
param = "offset"
[triggers.early]
start = [{ condition = "time_window", start_s = 20.0 }]
[triggers.late]
start = [{ condition = "time_window", start_s = 200.0 }]
[triggers.cruise]
start = [{ condition = "flight_phase", phase = "cruise" }]
""")
    capsys.readouterr()
    assert main(["attack", "--dataset", str(ds), "--scenario", str(grid)]) == 0
    out, err = capsys.readouterr()
    m = open_dataset(ds).manifest
    copies = m[m["mode"] == "csv"]
    # DataFlash (258 s) and RflyMAD (36 s: its attitude from the quaternion; the trigger at 200 s, past the log's
    # end, moved earlier by generator.logs.logged_time): all 6 configurations each
    assert len(copies) == 6 + 6 and out.strip().endswith(f"12 attacked copies added to {ds}")
    assert not [x for x in err.splitlines() if "gave no copy" in x], err
    assert re.search(r"all 12 configuration x flight pair\(s\) applied", err), err
    # labels are exactly the event windows
    for fid in copies["flight_id"]:
        flight = open_dataset(ds).flight(fid, columns=["Timestamp", "Is_Anomaly"])
        row = copies.set_index("flight_id").loc[fid]
        inside = (flight["Timestamp"] >= row["attack_start_us"]) & (flight["Timestamp"] < row["attack_end_us"])
        assert (flight["Is_Anomaly"].astype(bool) == inside).all()
