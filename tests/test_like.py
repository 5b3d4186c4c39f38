"""``generate --like LOG...`` and ``generate --profile FILE.toml`` (generator/like, docs/like.md).

Two shared fleet logs: ``arducopter_10-11-2014_105.bin`` (GPS with accuracy, a 25 s still hover) and
``arducopter_27-9-2014_71.bin`` (no GPS fix, two logging gaps).
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from scart_bench.cli.main import main
from scart_bench.generator.flight_software.mission_files import read_wpl
from scart_bench.generator.like import fit, tracks
from scart_bench.generator.like.profile_file import ProfileFileError, read_profile
from scart_bench.generator.params import SensorParams

FLEET = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet"
WITH_GPS = FLEET / "arducopter_10-11-2014_105.bin"
NO_GPS = FLEET / "arducopter_27-9-2014_71.bin"
#: the recovered mission stays this close (m, 3-D) to the flown track: RDP at 2 m, holds at their mean
TRACK_TOLERANCE_M = 3.0
#: a generated flight's hover accelerometer noise (x, y) is within this factor of the logs'
NOISE_FACTOR = 1.5

pytestmark = pytest.mark.skipif(not WITH_GPS.exists() or not NO_GPS.exists(), reason="needs ../shared/data")


@pytest.fixture(scope="module")
def like_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("like") / "ds"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["generate", "--like", str(WITH_GPS), str(NO_GPS), "--flights", "2", "--normal-only",
                     "--seed", "3", "--out", str(out)])
    return code, out, buf.getvalue()


@pytest.fixture(scope="module")
def measured():
    return {p.name: fit.measure_log(p) for p in (WITH_GPS, NO_GPS)}


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and "flights" in p.parts}


def test_like_writes_a_profile_and_missions_that_load_back(like_run):
    code, out, said = like_run
    assert code == 0, said
    doc = tomllib.loads((out / "profile.toml").read_text())
    assert doc["profile"]["base"] == "quick"
    missions = doc["mission"]["missions"]
    assert sorted(missions) == ["missions/arducopter_10-11-2014_105.waypoints",
                                "missions/arducopter_27-9-2014_71.waypoints"]
    for m in missions:
        assert read_wpl(out / m).commands, m
    prof = read_profile(out / "profile.toml")
    assert len(prof.config.mission.missions) == 2
    # fitted, not the defaults: the logs' vibration (y twice x and z on these frames) and a real receiver's GPS
    vib = prof.config.sensors.accel_vibration
    assert vib != SensorParams().accel_vibration and vib[1] > 1.5 * max(vib[0], vib[2]), vib
    assert prof.config.sensors.gps_bias_h > 1.0
    assert "[not_expressible]" in (out / "profile.toml").read_text()
    assert len(list((out / "flights").iterdir())) == 2


def test_the_profile_file_flies_the_same_flights_again(like_run, tmp_path):
    _, out, _ = like_run
    again = tmp_path / "again"
    assert main(["generate", "--profile", str(out / "profile.toml"), "--flights", "2", "--normal-only",
                 "--seed", "3", "--out", str(again)]) == 0
    assert _digest(again) == _digest(out)


def test_the_recovered_mission_follows_the_flown_track(measured):
    m = measured[WITH_GPS.name]
    assert m.mission and len(m.mission) >= 5
    assert m.track_error_m <= TRACK_TOLERANCE_M
    # the same measure sees a mission that does not follow the track: start and end only
    from scart_bench.generator.logs.importers import load_flight_file
    from scart_bench.generator.logs.phases import flight_phases

    tables = load_flight_file(WITH_GPS, allow_corrupt=True)
    track = tracks.flown_track(tables, flight_phases(tables))
    assert fit.track_error(track, [m.mission[0], m.mission[-1]]) > 2 * TRACK_TOLERANCE_M


def test_a_log_without_gps_keeps_the_default_position_noise_and_says_so(measured, tmp_path):
    from scart_bench.generator.like.write import fit_to_folder

    m = measured[NO_GPS.name]
    gps_lines = [n for n in m.notes if "GPS accuracy" in n]
    assert gps_lines == ["no GPS fix: GPS accuracy (position noise) default kept"]
    said: list[str] = []
    path = fit_to_folder([str(NO_GPS)], tmp_path / "p", say=said.append, calibrate=False)
    assert sum("no GPS fix: GPS accuracy (position noise) default kept" in s for s in said) == 1
    sensors = read_profile(path).config.sensors
    assert (sensors.gps_noise_h, sensors.gps_bias_h) == (SensorParams().gps_noise_h, SensorParams().gps_bias_h)
    assert m.mission_source.startswith("the altitude profile over home")


def test_a_generated_flight_has_the_logs_hover_accelerometer_noise(like_run):
    _, out, _ = like_run
    doc = tomllib.loads((out / "profile.toml").read_text())
    fleet = np.array([doc["measured"]["white_hover_acc_x"], doc["measured"]["white_hover_acc_y"]])  # what is fitted
    # each flight shakes as the vehicle whose log its mission came from (sensors.vibration_levels, seed mod N)
    levels = doc["sensors"].get("vibration_levels")
    import pandas as pd

    seeds = dict(pd.read_parquet(out / "manifest.parquet")[["flight_id", "seed"]].itertuples(index=False))
    flights = sorted((out / "flights").iterdir())
    got, want = [], []
    for folder in flights:
        g = fit.measure_log(folder)
        got.append([g.hover_white.get("acc_x", math.nan), g.hover_white.get("acc_y", math.nan)])
        level = np.array(levels[int(seeds[folder.name]) % len(levels)][0:2]) if levels else 1.0
        want.append(fleet * level)
    got = np.nanmedian(np.array(got), axis=0)
    ratio = got.mean() / np.mean(np.median(np.array(want), axis=0))
    assert 1 / NOISE_FACTOR <= ratio <= NOISE_FACTOR, (got, want)


@pytest.mark.parametrize("text, key, expected", [
    ('[profile]\nbase = "quick"\n[sensors]\naccel_noise_density = "loud"\n', "sensors.accel_noise_density",
     "expected a finite number"),
    ("[sensors]\nacel_noise_density = 0.1\n", "sensors.acel_noise_density", "a field of SensorParams"),
    ("[mission]\nclimb_speed = -1.0\n", "mission.climb_speed", "a number >= 0"),
    ('[profile]\nbase = "huge"\n', "profile.base", "one of quick, standard, paper"),
    ("[sensors]\nmag_field_ned = [0.2, 0.0]\n", "sensors.mag_field_ned", "a list of 3 values"),
    ("[sensors\n", "expected TOML", ""),
    # the quick profile mixes airframes, each with its own vehicle and gains: a [controller] would be ignored
    ("[controller]\nrate_p = [0.2, 0.2, 0.3]\n", "controller.rate_p", "set airframes = {} to fly the [controller]"),
])
def test_a_malformed_profile_exits_2_naming_the_key(tmp_path, capsys, text, key, expected):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    out = tmp_path / "out"
    code = main(["generate", "--profile", str(bad), "--flights", "1", "--normal-only", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert str(bad) in err and key in err and expected in err, err
    assert not out.exists()
    with pytest.raises(ProfileFileError):
        read_profile(bad)


def test_a_hand_written_profile_maps_onto_the_flight_config(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text('[profile]\nbase = "standard"\ngps_accuracy = "real_receiver"\n'
                 "[sensors]\nbaro_noise_pa = 2.5\nmag_field_ned = [0.2, 0.01, 0.4]\n"
                 "[mission]\ntakeoff_hold_s = 9.0\n[measured]\nanything = 1\n")
    prof = read_profile(f)
    assert prof.profile.name == "standard" and prof.profile.gps_accuracy == "real_receiver"
    assert prof.config.sensors.baro_noise_pa == 2.5 and prof.config.sensors.mag_field_ned == (0.2, 0.01, 0.4)
    assert prof.config.sensors.gps_bias_h == 2.75  # the real_receiver level under the file's own fields
    assert prof.config.mission.takeoff_hold_s == 9.0
    # without an airframe mix the [vehicle] and [controller] sections are flown
    f.write_text('[profile]\nbase = "quick"\nairframes = {}\n[vehicle]\nmass = 1.7\n')
    assert read_profile(f).config.vehicle.mass == 1.7 and not read_profile(f).config.airframes


def test_a_log_that_cannot_be_read_exits_2_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "notes.txt"
    bad.write_text("not a log\n")
    out = tmp_path / "out"
    assert main(["generate", "--like", str(WITH_GPS), str(bad), "--flights", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err, err
    assert not out.exists()
