"""A default flight starts as a PX4 flight does: on the ground until its GPS fix and the estimator's
origin, then arms, takes off, holds a hover, turns no faster than PX4's auto yaw limit, flies the
square and lands at home; GPS accuracy, satellites and the battery differ from flight to flight."""

from __future__ import annotations

import numpy as np
import pytest

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.startup import ARM_AFTER_ORIGIN_S, flight_start, startup_times
from scart_bench.generator.params import ControllerParams, MissionParams
from scart_bench.generator.telemetry.tables import flight_views

SEEDS = [101, 102, 103, 104, 105, 106]


@pytest.fixture(scope="module")
def flights():
    """Six default flights (realistic timing) and the same seeds with ideal timing (every message)."""
    real = simulate(SEEDS, FlightConfig())
    ideal = simulate(SEEDS, FlightConfig(timing="ideal"))
    return [flight_views(real, i)[0] | {"truth": flight_views(real, i)[1]["truth"]} for i in range(len(SEEDS))], \
        [flight_views(ideal, i)[0] for i in range(len(SEEDS))], real


def _lift_off_us(truth) -> int:
    return int(truth.loc[truth["z"] < -0.1, "Timestamp"].iloc[0])


def test_every_flight_waits_on_the_ground_and_lands_at_home(flights):
    views, _, batch = flights
    assert batch.status == ["landed"] * len(SEEDS)
    ground = [_lift_off_us(v["truth"]) / 1e6 for v in views]
    assert all(3.8 < g < 16.0 for g in ground), ground  # real PX4 logs: 3.8-16 s on the ground
    assert len({round(g, 1) for g in ground}) == len(SEEDS), "each flight has its own start"
    for v in views:
        truth = v["truth"]
        assert np.hypot(truth["x"].iloc[-1], truth["y"].iloc[-1]) < 3.0, "landed within a few metres of home"
        assert truth["y"].max() > 35.0, "flew the square"


def test_gps_has_a_fix_and_is_fused_before_the_vehicle_leaves_the_ground(flights):
    views, ideal, _ = flights
    for v, v0 in zip(views, ideal):
        lift = _lift_off_us(v["truth"])
        gps = v0["gps_raw_int"]
        first_fix = gps.loc[gps["fix_type"] >= 3, "Timestamp"].iloc[0]
        assert first_fix < lift - 2_000_000
        assert v["global_position_int"]["Timestamp"].iloc[0] < lift, "the estimator had its origin"
        armed = v["truth"].loc[v["truth"]["armed"] > 0.5, "Timestamp"].iloc[0]
        assert v["global_position_int"]["Timestamp"].iloc[0] + ARM_AFTER_ORIGIN_S[0] * 1e6 - 100_000 <= armed


def test_the_vehicle_hovers_after_take_off(flights):
    """The take-off point is held for takeoff_hold_s before the first leg (real logs hover ~9 s)."""
    views, _, _ = flights
    hold = MissionParams().takeoff_hold_s
    for v in views:
        truth = v["truth"]
        t = truth["Timestamp"].to_numpy() / 1e6
        at_alt = t[(truth["z"] < -9.0).to_numpy()][0]
        still = (t > at_alt + 1.0) & (t < at_alt + hold - 1.0)
        assert np.hypot(truth["vx"], truth["vy"]).to_numpy()[still].max() < 0.5


def test_yaw_rate_stays_within_px4_auto_limit(flights):
    """MPC_YAWRAUTO_MAX is 45 deg/s (0.785 rad/s): the body yaw rate never exceeds it by more than
    the rate loop's overshoot (~2 %) in a normal flight; it was 1.5-2.5 rad/s when the vehicle
    turned at the attitude controller's own rate."""
    views, _, _ = flights
    assert ControllerParams().yaw_rate_auto == pytest.approx(np.deg2rad(45.0))
    for v in views:
        rate = v["attitude"]["yawspeed"].to_numpy()  # the estimator's body yaw rate (gyro bias removed)
        smooth = np.convolve(rate, np.ones(5) / 5, mode="valid")  # 0.1 s: the sensor noise averaged out
        assert np.abs(smooth).max() < 0.82
        assert np.abs(smooth).max() > 0.6, "the vehicle does turn at the corners"


def test_gps_quality_and_battery_vary_per_flight_and_settle(flights):
    views, _, _ = flights
    eph_first = [v["gps_raw_int"]["eph"].iloc[0] for v in views]
    eph_last = [v["gps_raw_int"]["eph"].iloc[-1] for v in views]
    assert all(a > 1.2 * b for a, b in zip(eph_first, eph_last)), "accuracy improves after the fix"
    sats = [v["gps_raw_int"]["satellites_visible"] for v in views]
    assert all(s.iloc[0] < s.iloc[-1] for s in sats), "satellites climb after the fix"
    volts = [v["battery_status"]["voltage"].iloc[0] for v in views]
    assert len({round(x, 2) for x in volts}) > 3 and max(volts) <= 16.8 + 0.05


def test_start_times_are_drawn_per_seed_and_the_instant_start_stays_available():
    a = startup_times([7, 8])
    np.testing.assert_array_equal(a[0], flight_start(7))
    assert (a[:, 0] < a[:, 1]).all() and (a[:, 1] < a[:, 2]).all()
    old = startup_times([7, 8], ground_phase=False, arm_delay_s=1.0)
    np.testing.assert_array_equal(old, [[0.0, 0.0, 1.0]] * 2)
    truth = flight_views(simulate([7], FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=4.0))),
                         0)[1]["truth"]
    assert _lift_off_us(truth) < 2_500_000


def test_dataset_json_says_which_defaults_made_it_and_old_datasets_still_read(tmp_path):
    import json

    from scart_bench.dataset import open_dataset
    from scart_bench.generator.engine.flight_batch import FLIGHT_DEFAULTS
    from scart_bench.generator.generate import generate_dataset

    out = generate_dataset("quick", tmp_path / "ds", n_normal=1, with_attacks=False,
                           config=FlightConfig(mission=MissionParams(max_duration_s=12.0)))
    info = json.loads((out / "dataset.json").read_text())
    assert info["flight_defaults"] == FLIGHT_DEFAULTS == 5
    assert info["timing"] == "realistic" and info["ground_phase"] is True
    ds = open_dataset(out)
    assert ds.flight_defaults == 5
    fid = ds.manifest["flight_id"].iloc[0]
    gps_before = len(ds.topic(fid, "gps_raw_int"))
    # a dataset from before: no such keys in its dataset.json; it reads, and says it is of the first defaults
    for key in ("flight_defaults", "timing", "ground_phase", "takeoff_hold_s"):
        info.pop(key)
    (out / "dataset.json").write_text(json.dumps(info))
    old = open_dataset(out)
    assert old.flight_defaults == 1 and len(old.topic(fid, "gps_raw_int")) == gps_before
