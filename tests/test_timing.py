"""Realistic message timing (generator.telemetry.timing): jitter, drops, late messages, GPS after its fix."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import open_dataset
from scart_bench.generator.attacks import SCENARIO_DIR
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.generate import generate_dataset
from scart_bench.generator.params import MissionParams
from scart_bench.generator.telemetry.tables import flight_views
from scart_bench.generator.telemetry.timing import GPS_FIX_S, fix_times_us, message_timing

REAL = FlightConfig(mission=MissionParams(max_duration_s=20.0), timing="realistic")
IDEAL = FlightConfig(mission=MissionParams(max_duration_s=20.0), timing="ideal")


@pytest.fixture(scope="module")
def flown():
    return simulate([21, 22, 23], REAL), simulate([22], REAL), simulate([21, 22, 23], IDEAL)


def _cv(ts: np.ndarray) -> float:
    d = np.diff(ts)
    return float(d.std() / d.mean())


def test_realistic_timing_jitters_drops_and_starts_gps_late(flown):
    real, _, ideal = flown
    nav, sim = flight_views(real, 0)
    nav0, _ = flight_views(ideal, 0)
    for topic in ("highres_imu", "attitude", "scaled_pressure", "gps_raw_int"):
        ts = nav[topic]["Timestamp"].to_numpy()
        assert np.all(np.diff(ts) >= 0) and ts[0] >= 0
        assert _cv(ts) > 0.01 and _cv(nav0[topic]["Timestamp"].to_numpy()) == 0.0
    assert 0.03 < _cv(nav["highres_imu"]["Timestamp"].to_numpy()) < 0.08  # the ArduCopter logs' 50 Hz IMU: 0.01-0.07
    assert _cv(nav["scaled_pressure"]["Timestamp"].to_numpy()) < 0.03  # no drops: the logs' 0.016-0.025
    gps_start = nav["gps_raw_int"]["Timestamp"].iloc[0] / 1e6
    assert GPS_FIX_S[0] <= gps_start <= GPS_FIX_S[1] + 0.2
    assert nav["global_position_int"]["Timestamp"].iloc[0] > nav["gps_raw_int"]["Timestamp"].iloc[0] + 2.9e6
    assert nav0["gps_raw_int"]["Timestamp"].iloc[0] == 0
    # messages are only stamped and dropped, never changed; the two views stay aligned
    for topic in nav:
        pd.testing.assert_frame_equal(nav[topic], sim[topic])
    both = nav["local_position_ned"].merge(nav0["local_position_ned"], on="x", suffixes=("", "_ideal"))
    assert len(both) >= len(nav["local_position_ned"]) - 2
    # over three flights the local position loses some messages (0.8 %), the truth none
    lost = sum(len(flight_views(ideal, i)[0]["local_position_ned"]) - len(flight_views(real, i)[0]["local_position_ned"])
               for i in range(3))
    assert lost > 0
    assert len(sim["truth"]) == len(flight_views(ideal, 0)[1]["truth"])


def test_realistic_timing_is_the_default():
    """A default flight (and every profile's) is stamped as a PX4 link stamps it: no topic is
    perfectly periodic, and GPS starts at the receiver's fix, not at boot."""
    from scart_bench.generator.profiles import PROFILES

    assert FlightConfig().timing == "realistic"
    assert all(p.flight_config().timing == "realistic" for p in PROFILES.values())
    nav, _ = flight_views(simulate([24], FlightConfig(mission=MissionParams(max_duration_s=12.0))), 0)
    for topic in ("highres_imu", "attitude", "gps_raw_int", "local_position_ned"):
        assert _cv(nav[topic]["Timestamp"].to_numpy()) > 0.01, topic
    assert nav["gps_raw_int"]["Timestamp"].iloc[0] >= GPS_FIX_S[0] * 1e6


def test_gps_topics_start_at_the_fix_the_closed_loop_flew_by(flown):
    """The first GPS message written (realistic timing) is the receiver's first fix, and the
    global position starts when the estimator fused GPS for the first time."""
    real, _, ideal = flown
    nav, _ = flight_views(real, 0)
    nav0, _ = flight_views(ideal, 0)
    gps = nav["gps_raw_int"]
    assert gps["fix_type"].iloc[0] == 3 and (gps["fix_type"] == 3).all()
    ideal_gps = nav0["gps_raw_int"]
    first_fix = ideal_gps.loc[ideal_gps["fix_type"] == 3, "Timestamp"].iloc[0]
    assert abs(gps["Timestamp"].iloc[0] - first_fix) <= 100_000  # one GPS period (the jitter aside)
    assert (ideal_gps.loc[ideal_gps["Timestamp"] < first_fix, "eph"] > 90).all(), "no fix, no accuracy"


def test_timing_is_seeded_per_flight_batch_equals_one_by_one(flown):
    real, alone, _ = flown
    together, single = flight_views(real, 1), flight_views(alone, 0)
    for view in (0, 1):
        for topic, df in together[view].items():
            pd.testing.assert_frame_equal(df, single[view][topic])
    again = flight_views(simulate([21, 22, 23], REAL), 2)[0]
    for topic, df in flight_views(real, 2)[0].items():
        pd.testing.assert_frame_equal(df, again[topic])
    assert fix_times_us(21) != fix_times_us(22)
    ts = np.arange(100) * 20_000
    a = message_timing("realistic", 5, "attitude", ts)
    b = message_timing("realistic", 5, "attitude", ts[:60])  # a shorter flight: the same first messages
    np.testing.assert_array_equal(a[0][:60], b[0])
    with pytest.raises(ValueError, match="timing must be one of"):
        simulate([1], FlightConfig(timing="jittery"))


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_dataset_with_realistic_timing_is_deterministic(tmp_path):
    """Normal, simulation-mode and csv-mode flights (whose sources now differ in schedule)."""
    cfg = FlightConfig(timing="realistic")
    for run in ("a", "b"):
        generate_dataset("quick", tmp_path / run, seed=3, n_normal=3, config=cfg,
                         scenarios=SCENARIO_DIR / "gps_spoof.toml")
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")
    m = open_dataset(tmp_path / "a").manifest.set_index("mode")
    assert {"normal", "simulation", "csv"} <= set(m.index)
    assert m.loc["simulation", "impact_max_dev_m"] >= 5.0
    assert not bool(m.loc["csv", "no_effect"])


def test_generate_timing_option(tmp_path, capsys):
    assert main(["generate", "--profile", "quick", "--flights", "1", "--normal-only", "--timing", "late",
                 "--out", str(tmp_path / "x")]) == 2
    assert "--timing 'late': expected one of ideal, realistic" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
