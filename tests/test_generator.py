"""The built-in flight generator and the dataset it writes (normal flights)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import truth

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetWriter, open_dataset
from scart_bench.dataset.schema import HOME_LAT, HOME_LON, TOPICS, TRUTH_FIELDS
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.geo import latlon_to_ned
from scart_bench.generator.params import MissionParams
from scart_bench.generator.telemetry.tables import normal_record

F = {name: i for i, name in enumerate(TRUTH_FIELDS)}
SHORT = FlightConfig(mission=MissionParams(max_duration_s=12.0))


def test_normal_flights_fly_the_square_and_land_at_home(normal_fleet):
    corners = np.array(MissionParams().corners)
    alt = MissionParams().altitude
    winds = np.linalg.norm(normal_fleet.wind, axis=1)
    assert len(normal_fleet) == 20
    assert winds.max() - winds.min() > 1.0, "flights should see different winds"
    for i in range(len(normal_fleet)):
        _, tr = truth(normal_fleet, i)
        assert normal_fleet.status[i] == "landed"
        assert (-tr[:, F["z"]]).max() > alt - 1.0, "took off to mission altitude"
        for c in corners:
            d = np.hypot(tr[:, F["x"]] - c[0], tr[:, F["y"]] - c[1])
            k = int(np.argmin(d))
            assert d[k] < 2.0, f"flight {i} missed corner {c} by {d[k]:.2f} m"
            assert abs(-tr[k, F["z"]] - alt) < 1.0, f"flight {i} at corner {c} not at mission altitude"
        end = tr[-1]
        assert np.hypot(end[F["x"]], end[F["y"]]) < 1.5, f"flight {i} landed {end[:2]} from home"
        assert end[F["landed"]] == 1 and end[F["armed"]] == 0, "on the ground and disarmed"


def test_hover_and_cruise_physics(normal_fleet):
    """Hover: zacc about -9.81, gyros about 0; cruise at 5 m/s tilts a few degrees; lat/lon agree with x/y."""
    hold = simulate([100], FlightConfig(mission=MissionParams(takeoff_hold_s=12.0, max_duration_s=40.0)))
    steps, imu, _ = hold.simulator["highres_imu"]
    t = steps * 0.004
    t_truth, tr_hold = hold.simulator["truth"][0] * 0.004, hold.simulator["truth"][1][0]
    at_alt = t_truth[-tr_hold[:, F["z"]] > 9.5][0]  # after its ground phase and climb
    rows = (t > at_alt + 1.0) & (t < at_alt + 9.0)
    assert abs(np.median(imu[0][rows, 2]) + 9.81) < 0.15
    assert np.all(np.abs(np.median(imu[0][rows, 3:6], axis=0)) < 0.01), "gyros about zero"
    calm = int(np.argmin(np.linalg.norm(normal_fleet.wind, axis=1)))
    tsteps, tr = truth(normal_fleet, calm)
    speed = np.hypot(tr[:, F["vx"]], tr[:, F["vy"]])
    airborne = -tr[:, F["z"]] > 5
    acc = np.gradient(tr[:, [F["vx"], F["vy"]]], 0.02, axis=0)
    cruise = airborne & (speed > 4.0) & (np.linalg.norm(acc, axis=1) < 0.5)  # steady cruise
    tilt = np.degrees(np.hypot(tr[cruise, F["roll"]], tr[cruise, F["pitch"]]))
    assert 0.5 < np.median(tilt) < 12  # 9.7 deg before the PX4 start and yaw limit, 10.2 since
    _, gpi, _ = normal_fleet.simulator["global_position_int"]
    s_loc, loc, _ = normal_fleet.simulator["local_position_ned"]
    s_gpi = normal_fleet.simulator["global_position_int"][0]
    common = np.intersect1d(s_loc, s_gpi)
    a = gpi[0][np.searchsorted(s_gpi, common)]
    b = loc[0][np.searchsorted(s_loc, common)]
    x, y = latlon_to_ned(a[:, 0], a[:, 1])
    assert np.max(np.hypot(x - b[:, 0], y - b[:, 1])) < 0.1


@pytest.fixture(scope="module")
def written(normal_fleet, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "normal"
    w = DatasetWriter(out)
    for i in range(3):
        w.write(normal_record(normal_fleet, i, f"normal-{i:04d}", "train", {}))
    w.close()
    return open_dataset(out)


def test_written_rates_positions_and_gps_error(written):
    fid = "normal-0000"
    for name, topic in TOPICS.items():
        df = written.topic(fid, name)
        ts = df["Timestamp"].to_numpy()
        rate = (len(ts) - 1) / ((ts[-1] - ts[0]) / 1e6)
        assert abs(rate / topic.rate_hz - 1) < 0.05, f"{name}: {rate:.2f} Hz vs {topic.rate_hz} Hz"
    for name in ("global_position_int", "gps_raw_int"):
        df = written.topic(fid, name)
        assert df["lat"].dtype == np.float64
        x, y = latlon_to_ned(df["lat"].to_numpy(), df["lon"].to_numpy())
        assert np.max(np.hypot(x, y)) < 100, "lat/lon within 100 m of the PX4 SITL home"
        assert abs(df["lat"].mean() - HOME_LAT) < 1e-3 and abs(df["lon"].mean() - HOME_LON) < 1e-3
    gps = written.topic(fid, "gps_raw_int", view="navigator")
    tr = written.topic(fid, "truth", view="simulator")
    # the GPS reports the state of ~112 ms earlier (PX4 SITL delay): compare at validity time
    t_valid = gps["Timestamp"].to_numpy() - 112_000
    tx = np.interp(t_valid, tr["Timestamp"], tr["x"])
    ty = np.interp(t_valid, tr["Timestamp"], tr["y"])
    gx, gy = latlon_to_ned(gps["lat"].to_numpy(), gps["lon"].to_numpy())
    err = np.hypot(gx - tx, gy - ty)
    assert 0.05 < np.std(np.concatenate([gx - tx, gy - ty])) < 1.0, f"GPS error std {np.std(err):.3f}"


def test_tables_layout_labels_and_views(written):
    for fid in written.manifest["flight_id"]:
        for view in ("navigator", "simulator"):
            for table in ("most_frequent", "all_sensors"):
                df = written.flight(fid, view=view, table=table)
                assert list(df.columns[:3]) == ["Index", "Timestamp", "Is_Anomaly"]
                assert df["Timestamp"].dtype == np.int64
                assert np.all(np.diff(df["Timestamp"].to_numpy()) > 0)
                assert (df["Is_Anomaly"] == 0).all()
        assert set(written.topics(fid, "navigator")) == set(TOPICS)
        assert set(written.topics(fid, "simulator")) == set(TOPICS) | {"truth"}


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_and_different_seeds_differ(tmp_path):
    for run in ("a", "b"):
        batch = simulate([1, 2], SHORT)
        w = DatasetWriter(tmp_path / run)
        for i in range(2):
            w.write(normal_record(batch, i, f"f{i}", "train", {}))
        w.close()
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")
    ds = open_dataset(tmp_path / "a")
    a, b = ds.flight("f0"), ds.flight("f1")
    n = min(len(a), len(b))
    assert not np.allclose(a["highres_imu.xacc"][:n], b["highres_imu.xacc"][:n])


def test_batch_equals_flights_flown_one_by_one():
    together = simulate([11, 12, 13], SHORT)
    alone = simulate([12], SHORT)
    s, v, _ = together.simulator["local_position_ned"]
    s1, v1, _ = alone.simulator["local_position_ned"]
    np.testing.assert_allclose(v[1], v1[0], atol=1e-9)


def _looks_complete(folder: Path) -> bool:
    return (folder / "manifest.parquet").exists() or (folder / "manifest.csv").exists()


def test_generate_bad_input_exit_2_and_nothing_complete(tmp_path, capsys):
    assert main(["generate", "--profile", "huge", "--out", str(tmp_path / "a")]) == 2
    assert "huge" in capsys.readouterr().err
    assert main(["generate", "--flights", "0", "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b").exists()
    other = tmp_path / "notes"
    other.mkdir()
    (other / "thesis.txt").write_text("keep me")
    assert main(["generate", "--out", str(other), "--flights", "1"]) == 2
    assert "not a scart-bench dataset" in capsys.readouterr().err
    assert (other / "thesis.txt").read_text() == "keep me" and not _looks_complete(other)
    if os.geteuid() != 0:  # root can write anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert main(["generate", "--out", str(locked / "ds"), "--flights", "1"]) == 2
    else:
        assert main(["generate", "--out", "/proc/scart-bench-ds", "--flights", "1"]) == 2
    assert "not writable" in capsys.readouterr().err


def test_generate_csv_format_writes_paper_layout(tmp_path):
    from scart_bench.generator.generate import generate_dataset

    out = generate_dataset("quick", tmp_path / "csv", seed=1, fmt="csv", n_normal=1, with_attacks=False,
                           config=SHORT)
    assert (out / "manifest.csv").exists()
    df = pd.read_csv(out / "flights" / "normal-0000" / "combined" / "navigator_all_sensors.csv")
    assert list(df.columns[:3]) == ["Index", "Timestamp", "Is_Anomaly"]
    ds = open_dataset(out)
    assert ds.flight("normal-0000")["global_position_int.lat"].dtype == np.float64


def test_csv_mode_in_its_own_process_writes_the_same_dataset(tmp_path, monkeypatch):
    """Generation replays csv mode in a second process while simulation mode flies; the dataset
    (every file, the manifest's row order included) equals the one made one mode after the other."""
    from scart_bench.generator import attacks
    from scart_bench.generator.generate import generate_dataset

    side = generate_dataset("quick", tmp_path / "side", seed=5, n_normal=4, config=SHORT)
    monkeypatch.setattr(attacks._CsvProcess, "start", classmethod(lambda cls, *a, **k: None))
    serial = generate_dataset("quick", tmp_path / "serial", seed=5, n_normal=4, config=SHORT)
    assert _digest(side) == _digest(serial)
    modes = open_dataset(side).manifest["mode"].tolist()
    assert "csv" in modes and modes == sorted(modes, key=["normal", "simulation", "csv"].index)
