"""Per-flight message timing: a profile's ``[timing]`` table (FlightConfig.timing_table), which
``generate --like`` fits from a fleet's message intervals (generator/like/timing.py, docs/like.md)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from scart_bench.cli.main import main
from scart_bench.generator.engine.simulate import simulate
from scart_bench.generator.like import timing as like_timing
from scart_bench.generator.like.profile_file import ProfileFileError, read_profile
from scart_bench.generator.telemetry.tables import flight_views
from scart_bench.generator.telemetry.timing import REALISTIC, message_timing

FLEET_LOG = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet/arducopter_10-11-2014_105.bin"
#: a flight's attitude interval CV is within this factor of its table's
CV_FACTOR = 1.25


def _short(config, seconds: float = 12.0):
    """``config`` cut to a short flight (the timing is applied the same to any length)."""
    return dataclasses.replace(config, mission=dataclasses.replace(config.mission, max_duration_s=seconds))


def _cv(ts_us: np.ndarray) -> float:
    dt = np.diff(np.asarray(ts_us, dtype=float))
    return float(dt.std() / np.median(dt))


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """One short flight of the quick profile, with and without a [timing] table for the attitude."""
    f = tmp_path_factory.mktemp("timing") / "fleet.toml"
    f.write_text('[profile]\nbase = "quick"\n[timing]\nattitude = {cv = 0.008, drop = 0.0}\n')
    fitted = read_profile(f).config
    batch = simulate([5], _short(fitted))
    views = {"fitted": flight_views(batch, 0)[1],  # the same flight stamped without the table
             "plain": flight_views(dataclasses.replace(batch, timing_table=()), 0)[1]}
    return fitted, views


def test_a_timing_table_gives_flights_with_its_attitude_interval_cv(flown):
    cfg, views = flown
    assert cfg.timing_table == (("attitude", 0.008, 0.0, REALISTIC["attitude"][2], 1.0),)
    cv = _cv(views["fitted"]["attitude"]["Timestamp"])
    assert 0.008 / CV_FACTOR <= cv <= 0.008 * CV_FACTOR, cv
    default = _cv(views["plain"]["attitude"]["Timestamp"])  # the realistic table's 0.092
    assert default > 5 * cv, default
    # the other topics keep the realistic table's stamps, row for row
    for topic in ("highres_imu", "local_position_ned", "gps_raw_int"):
        assert views["fitted"][topic]["Timestamp"].equals(views["plain"][topic]["Timestamp"]), topic


def test_no_table_is_the_realistic_table_byte_for_byte():
    ts = np.arange(0, 60_000_000, 20_000, dtype=np.int64)
    for topic in REALISTIC:
        a = message_timing("realistic", 7, topic, ts, 50.0)
        b = message_timing("realistic", 7, topic, ts, 50.0, (("battery_status", 0.01, 0.0, 0.0),)
                           if topic != "battery_status" else ())
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), topic
    from scart_bench.generator.plan import plan_generation

    assert "timing_table" not in plan_generation("quick", n_normal=2).config_dict["flight_config"]


def test_a_spread_varies_the_cv_between_flights_as_one_vehicle_on_every_topic():
    ts = np.arange(0, 120_000_000, 20_000, dtype=np.int64)  # 50 Hz, 2 min
    table = (("attitude", 0.01, 0.0, 0.0, 4.0), ("highres_imu", 0.03, 0.0, 0.0, 4.0))
    got = []
    for seed in range(40):
        att = _cv(message_timing("realistic", seed, "attitude", ts, 50.0, table)[0])
        imu = message_timing("realistic", seed, "highres_imu", ts, 50.0, table)[0]
        got.append((att, _cv(np.sort(imu))))
    att, imu = np.array(got).T
    assert 0.01 / 4.4 <= att.min() and att.max() <= 0.01 * 4.4, (att.min(), att.max())
    assert att.max() / att.min() > 6  # log-uniform over a 16x range: 40 flights span most of it
    assert np.corrcoef(np.log(att), np.log(imu))[0, 1] > 0.9  # one quantile per flight for all its topics
    same = _cv(message_timing("realistic", 3, "attitude", ts, 50.0, (("attitude", 0.01, 0.0, 0.0, 1.0),))[0])
    assert abs(same - 0.01) < 0.001  # spread 1: every flight the table's CV
    assert like_timing.cv_spread([0.01, 0.01]) == 1.0 and like_timing.cv_spread([0.002, 0.027]) > 3
    two = [{"imu": (50.0, 0.012, 0.0, 0.0), "attitude": (10.0, 0.002, 0.0, 0.0)},
           {"imu": (50.0, 0.046, 0.0, 0.0), "attitude": (10.0, 0.027, 0.0, 0.0)}]
    section = like_timing.fleet_table(two, 2, 0.3)
    assert section["attitude"][0]["spread"] > 3 and section["highres_imu"][0]["spread"] == 1.0


def test_the_interval_figures_read_a_millisecond_clock_drops_and_late_messages():
    rng = np.random.default_rng(0)
    t = np.arange(3000) * 0.1 + rng.choice([-0.001, 0.0, 0.001], 3000, p=[0.2, 0.6, 0.2])
    t = np.delete(t, [100, 900, 901])  # three dropped messages
    t[2000] += 0.06  # a late one
    hz, cv, drop, late = like_timing.interval_figures(t)
    assert hz == pytest.approx(10.0, rel=1e-3)
    assert 0.005 <= cv <= 0.01, cv  # std of (a - b) / period, a, b in {-1, 0, 1} ms: 0.0089
    assert drop == pytest.approx(3 / 3000, rel=0.05) and late == pytest.approx(1 / 3000, rel=0.05)


@pytest.mark.skipif(not FLEET_LOG.exists(), reason="needs ../shared/data")
def test_like_writes_the_logs_timing_and_the_profile_reads_it_back(tmp_path):
    from scart_bench.generator.like.write import fit_to_folder

    path = fit_to_folder([str(FLEET_LOG)], tmp_path, say=lambda _: None, calibrate=False)
    text = path.read_text()
    assert "\n[timing]\n" in text and "message_rates_and_jitter" not in text
    table = {e[0]: e[1:] for e in read_profile(path).config.timing_table}
    # ArduCopter's ATT at 10 Hz on a millisecond clock: CV about 0.007, the realistic table's is 0.092
    assert 0.002 <= table["attitude"][0] <= 0.015, table
    assert 0.01 <= table["highres_imu"][0] <= 0.06, table  # its IMU at 50 Hz: 0.03
    assert all(e[3] == 1.0 for e in table.values())  # one log: no spread between vehicles


@pytest.mark.parametrize("text, key, expected", [
    ("[timing]\nattitud = {cv = 0.01}\n", "timing.attitud", "a topic of the timing table"),
    ("[timing]\nattitude = {cv = 0.9}\n", "timing.attitude.cv", "a number in [0, 0.3]"),
    ("[timing]\nattitude = {jitter = 0.01}\n", "timing.attitude.jitter", "one of cv, drop, late"),
    ('[timing]\nattitude = {drop = "often"}\n', "timing.attitude.drop", "a number in [0, 1]"),
    ("[timing]\nattitude = 0.01\n", "timing.attitude", "an inline table"),
    ("[timing]\nattitude = {drop = 0.7, late = 0.6}\n", "timing.attitude", "drop + late at most 1"),
    ("[timing]\nattitude = {spread = 0.5}\n", "timing.attitude.spread", "a number in [1, 10]"),
    ('[profile]\ntiming = "ideal"\n[timing]\nattitude = {cv = 0.01}\n', "timing", 'profile.timing = "realistic"'),
])
def test_a_bad_timing_key_exits_2_naming_the_file_and_key(tmp_path, capsys, text, key, expected):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    out = tmp_path / "out"
    code = main(["generate", "--profile", str(bad), "--flights", "1", "--normal-only", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"{bad}: {key}: expected" in err and expected in err, err
    assert not out.exists()
    with pytest.raises(ProfileFileError):
        read_profile(bad)
