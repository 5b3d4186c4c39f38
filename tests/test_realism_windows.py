"""The window-level realism check (perf.realism_windows, issue 47): it must see a noise tell, not see
one where there is none, put a sine's power in its band and name a signal a log lacks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from perf import realism_windows as rw

HZ = 50.0
IMU = ("acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z")


def synthetic(name: str, side: str, seed: int, acc_noise: float = 0.1, acc_ar: float = 0.0,
              seconds: float = 35.0) -> rw.FlightSignals:
    """A hovering flight: slow attitude wander, IMU white (or AR(1)) noise, baro at 10 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * HZ)) / HZ
    f = rw.FlightSignals(name, side)
    for s in ("roll", "pitch", "yaw"):
        f.signals[s] = t, np.cumsum(rng.normal(0, 0.002, len(t))) + rng.normal(0, 0.002, len(t))
    for s in IMU:
        e = rng.normal(0, acc_noise if s.startswith("acc") else 0.01, len(t))
        if s.startswith("acc") and acc_ar:  # autocorrelated noise of the same std
            x = np.zeros(len(t))
            for i in range(1, len(t)):
                x[i] = acc_ar * x[i - 1] + e[i] * np.sqrt(1 - acc_ar ** 2)
            e = x
        f.signals[s] = t, e + (9.81 if s == "acc_z" else 0.0)
    tb = t[::5]
    f.signals["baro_alt"] = tb, 10 + rng.normal(0, 0.05, len(tb))
    return f


def fleet(side: str, seed: int, n: int = 10, **kw) -> list[rw.FlightSignals]:
    return [synthetic(f"{side}-{seed}-{i}", side, seed * 1000 + i, **kw) for i in range(n)]


def check(gen, real) -> rw.PhaseResult:
    return rw.compare(gen, real, phases=("all",), groups=False, log_set="test").phases["all"]


def test_same_process_is_not_told_apart():
    r = check(fleet("generated", 1), fleet("real", 2))
    assert r.flights == {"generated": 10, "real": 10}
    assert r.windows["generated"] == r.windows["real"] == 10 * 5  # 35 s: windows starting at 0, 5, ... 20 s
    assert r.flight_auc < 0.75
    assert r.window_auc < 0.75


def test_doubled_accelerometer_noise_is_told_apart():
    r = check(fleet("generated", 1, acc_noise=0.2), fleet("real", 2))
    assert r.flight_auc > 0.95
    top = r.features["feature"].head(6).tolist()
    assert any(c.startswith("acc_") and c.split("__")[1] in ("std", "dstd", "p5_25", "p2_5") for c in top), top


def test_autocorrelated_accelerometer_noise_is_told_apart():
    """The same std, but lag-1 autocorrelation 0.7 (the generator's tell in issue 47)."""
    r = check(fleet("generated", 1, acc_ar=0.7), fleet("real", 2))
    assert r.flight_auc > 0.95
    row = r.features.set_index("feature").loc["acc_x__dac1"]
    assert row["auc"] > 0.9 and row["generated"] > row["real"]


def test_sine_power_lands_in_its_band():
    t = np.arange(500) / HZ
    for f_hz, band in ((0.2, 0), (1.0, 1), (3.0, 2), (10.0, 3)):
        feats = rw.signal_features(np.sin(2 * np.pi * f_hz * t), HZ)
        powers = feats[2:6]
        assert int(np.argmax(powers)) == band, (f_hz, powers)
        assert powers[band] > np.log10(0.45)  # a unit sine's power is 0.5
        others = np.delete(powers, band)
        assert np.all(others < powers[band] - 1.5)  # at least 30x less outside its band
    # at 10 Hz, the 5-25 Hz band is above Nyquist: left out
    assert np.isnan(rw.signal_features(np.sin(2 * np.pi * t[:100]), 10.0)[5])


def test_signal_a_log_lacks_is_left_out_and_named(capsys):
    real = fleet("real", 2, n=4)
    del real[1].signals["baro_alt"]
    c = rw.compare(fleet("generated", 1, n=4), real, phases=("all",), groups=False, log_set="logs")
    assert "baro_alt" not in c.signals and "acc_x" in c.signals
    assert "real-2-1" in c.left_out["baro_alt"]
    text = c.report()
    assert "left out: baro_alt (lacking in 1 flight(s): logs/real-2-1)" in text
    assert not any(col.startswith("baro_alt") for col in c.phases["all"].features["feature"])


def test_common_rate_is_the_slower_side():
    """An attitude logged at 10 Hz is compared at 10 Hz on both sides: the logging rate is no tell."""
    gen = fleet("generated", 1, n=3)
    real = fleet("real", 2, n=3)
    for f in real:
        t, x = f.signals["roll"]
        f.signals["roll"] = t[::5], x[::5]
    rates = rw.common_rates([*gen, *[rw.FlightSignals(f.name, "real", f.signals) for f in real]], ["roll", "acc_x"])
    assert rates == {"roll": 10.0, "acc_x": 50.0}


def _ardupilot_tables(gps: bool) -> dict[str, pd.DataFrame]:
    """An ArduCopter-like log: ATT in degrees, IMU, BARO, EKF1, CTUN, optional GPS."""
    rng = np.random.default_rng(0)
    t50 = np.arange(0, 40, 0.02)
    t10 = np.arange(0, 40, 0.1)
    us = lambda t: (t * 1e6).astype(np.int64)  # noqa: E731
    climb = np.clip((t10 - 10) * 2, 0, 10)
    tables = {
        "att": pd.DataFrame({"Timestamp": us(t10), "Roll": rng.normal(0, 1, len(t10)),
                             "Pitch": rng.normal(0, 1, len(t10)), "Yaw": 90 + rng.normal(0, 1, len(t10))}),
        "imu": pd.DataFrame({"Timestamp": us(t50), **{k: rng.normal(0, 0.1, len(t50)) for k in
                                                      ("AccX", "AccY", "GyrX", "GyrY", "GyrZ")},
                             "AccZ": -9.81 + rng.normal(0, 0.1, len(t50))}),
        "baro": pd.DataFrame({"Timestamp": us(t10), "Alt": climb + rng.normal(0, 0.1, len(t10))}),
        "ctun": pd.DataFrame({"Timestamp": us(t10), "Alt": climb}),
        "ekf1": pd.DataFrame({"Timestamp": us(t10), **{k: rng.normal(0, 0.1, len(t10))
                                                       for k in ("PN", "PE", "VN", "VE", "VD")}, "PD": -climb}),
    }
    if gps:
        tables["gps"] = pd.DataFrame({"Timestamp": us(t10[::2]), "Status": np.full(len(t10[::2]), 3.0)})
    return tables


def test_signals_by_meaning_from_an_ardupilot_log():
    f = rw.signals_from_tables("ap.bin", _ardupilot_tables(gps=True), "real")
    assert f.sources["roll"] == "att.Roll" and f.sources["acc_z"] == "imu.AccZ" and f.sources["vel_n"] == "ekf1.VN"
    assert np.abs(f.signals["yaw"][1]).max() < 2.0  # degrees -> rad: 90 deg ~ 1.57 rad
    assert f.signals["baro_alt"][1].max() > 5


def test_a_log_without_gps_fix_has_no_position():
    f = rw.signals_from_tables("ap.bin", _ardupilot_tables(gps=False), "real")
    assert not any(s in f.signals for s in rw.GPS_SIGNALS)
    assert "roll" in f.signals and "baro_alt" in f.signals
    assert any("position and velocity left out" in n for n in f.notes)


def test_phases_of_windows():
    """Ground before the climb, air after (a log without velocity: its horizontal speed is unknown)."""
    f = rw.signals_from_tables("ap.bin", _ardupilot_tables(gps=False), "real")
    rates = {s: rw.snap_rate(rw.native_hz(f.signals[s][0])) for s in ("roll", "acc_x", "baro_alt")}
    table = rw.flight_windows(f, rates)
    phases = dict(zip(table["start_s"], table["phase"], strict=True))
    assert phases[0.0] == "ground"
    assert phases[25.0] == "air"
    g = rw.signals_from_tables("ap.bin", _ardupilot_tables(gps=True), "real")
    assert dict(zip(*rw.flight_windows(g, rates)[["start_s", "phase"]].to_numpy().T, strict=True))[25.0] == "hover"


def test_select_signals():
    assert rw.select_signals("attitude,imu,baro") == ["roll", "pitch", "yaw", *IMU, "baro_alt"]
    with pytest.raises(ValueError, match="unknown signal or group 'wind'"):
        rw.select_signals("wind")


def test_cli_refuses_a_missing_dataset(capsys):
    with pytest.raises(SystemExit) as exc:
        rw.main(["--dataset", str(Path("/nonexistent/dataset"))])
    assert exc.value.code == 2
    assert "--dataset /nonexistent/dataset: no such folder" in capsys.readouterr().err


@pytest.fixture(scope="module")
def generated_halves(normal_fleet):
    """The shared 20 generated flights (seeds 100-119) read by meaning, as two sets of 10."""
    from scart_bench.generator.telemetry.tables import flight_views

    flights = [rw.signals_from_tables(f"g{i}", flight_views(normal_fleet, i, ())[1], "generated")
               for i in range(20)]
    return flights[:10], flights[10:]


def test_generated_flights_by_meaning_and_phase(generated_halves):
    f = generated_halves[0][0]
    assert f.sources["roll"] == "attitude.roll" and f.sources["vel_n"] == "local_position_ned.vx"
    assert f.sources["acc_x"] == "highres_imu.xacc" and "baro_alt" in f.signals
    rates = {s: rw.snap_rate(rw.native_hz(f.signals[s][0])) for s in f.signals}
    phases = rw.flight_windows(f, rates)["phase"].tolist()
    assert phases[0] == "ground" and "hover" in phases and "cruise" in phases


def test_generated_seeds_are_not_told_apart_but_doubled_noise_is(generated_halves):
    """Two sets of the same generator's flights (other seeds): near 0.5; the same flights with their
    accelerometer's sample-to-sample noise doubled: near 1."""
    a, b = generated_halves
    same = rw.compare(a, [rw.FlightSignals(f.name, "real", f.signals) for f in b], phases=("all",),
                      signals=rw.select_signals("attitude,accelerometer"), groups=False).phases["all"]
    assert same.flight_auc < 0.8
    noisy = []
    for f in b:
        sig = dict(f.signals)
        for s in ("acc_x", "acc_y", "acc_z"):
            t, x = sig[s]
            smooth = np.convolve(x, np.ones(5) / 5, mode="same")
            sig[s] = t, x + (x - smooth)
        noisy.append(rw.FlightSignals(f.name, "real", sig))
    told = rw.compare(a, noisy, phases=("all",), signals=rw.select_signals("attitude,accelerometer"),
                      groups=False).phases["all"]
    assert told.flight_auc > 0.95


def test_feature_kinds_can_be_left_out():
    c = rw.compare(fleet("generated", 1, n=3), fleet("real", 2, n=3), phases=("all",), groups=False,
                   features=tuple(k for k in rw.FEATURES if k != "jitter"))
    kinds = {col.split("__")[1] for col in c.phases["all"].features["feature"]}
    assert "jitter" not in kinds and "dac1" in kinds
    with pytest.raises(ValueError, match="unknown feature 'wobble'"):
        rw.compare(fleet("generated", 1, n=2), fleet("real", 2, n=2), features=("wobble",))


def test_vertical_speed_ignores_a_noisy_altitude():
    """A hover whose altitude reads +-0.3 m noise at 10 Hz is still; a 1 m/s climb is not."""
    t = np.arange(0, 10, 0.1)
    noisy = 5 + np.random.default_rng(0).normal(0, 0.3, len(t))
    assert rw.vertical_speed((t, noisy), 0, 10) < 0.3
    assert rw.vertical_speed((t, 5 + t), 0, 10) == pytest.approx(1.0, abs=0.05)


def test_perf_realism_windows_flag_runs_this_check(capsys):
    from perf import realism

    with pytest.raises(SystemExit) as exc:
        realism.main(["--windows", "--dataset", "/nonexistent/dataset"])
    assert exc.value.code == 2
    assert "python -m perf.realism_windows: error: --dataset /nonexistent/dataset" in capsys.readouterr().err


def test_same_inputs_give_the_same_figures():
    gen, real = fleet("generated", 1, n=4), fleet("real", 2, n=4, acc_noise=0.15)
    a, b = (rw.compare(gen, real, phases=("all",), groups=False).phases["all"] for _ in range(2))
    assert (a.flight_auc, a.window_auc) == (b.flight_auc, b.window_auc)
    pd.testing.assert_frame_equal(a.features, b.features)


def test_cli_says_which_log_set_it_cannot_read(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(rw, "read_dataset", lambda *a, **k: fleet("generated", 1, n=2))
    notes = tmp_path / "logs"
    notes.mkdir()
    (notes / "notes.txt").write_text("not a log")
    assert rw.main(["--dataset", str(tmp_path), "--logs", str(notes), "--no-groups"]) == 2
    assert f"== {notes}: no readable log (expected .ulg" in capsys.readouterr().err
