"""Evaluation protocol v2: the conformal operating point, the burn-in after arming, cluster-aware
intervals, the end transient, false alarms before onset and the detector's own alarm rule."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.evaluation import build_evaluation, flight_clusters
from scart_bench.benchmark.intervals import wilson
from scart_bench.benchmark.metrics import PaperTable
from scart_bench.benchmark.protocol import (
    Protocol,
    ProtocolError,
    ThresholdRule,
    arming_time_us,
    conformal_rank,
    counted_rows,
)
from scart_bench.detectors.base import feature_columns

US = 1_000_000


# -- the conformal threshold --------------------------------------------------------------------

@pytest.mark.parametrize("n, alpha, k", [(100, 0.05, 96), (30, 0.05, 30), (19, 0.05, 19), (200, 0.01, 199),
                                         (99, 0.1, 90), (8, 0.05, 9)])
def test_conformal_rank_is_the_stated_order_statistic(n, alpha, k):
    assert conformal_rank(n, alpha) == k
    values = np.random.default_rng(n).permutation(np.arange(1.0, n + 1.0))  # the i-th smallest is i
    rule = ThresholdRule("conformal", alpha=alpha)
    assert rule.calibrate(values) == float(min(k, n))
    assert rule.attainable(n) == (k <= n)
    batch = rule.calibrate_many(np.stack([values, values[::-1]]))
    assert batch.tolist() == [float(min(k, n))] * 2


def _flights(rng: np.random.Generator, n: int, rows: int = 50) -> dict[str, np.ndarray]:
    """``n`` synthetic normal flights: per-row scores from one distribution."""
    return {f"f{i}": rng.gamma(2.0, 1.0, size=rows) for i in range(n)}


def test_false_alarm_rate_of_fresh_flights_is_alpha():
    """Calibrated on 100 validation flights for alpha = 5 %, fresh normal flights from the same
    distribution are flagged at 1 - 96/101 = 4.95 %: the rate over 4,000 independent calibrations
    (one fresh flight each) lies in the binomial 99 % interval around it, and the v1 rule (the
    largest validation score + 5 %) is far below it (its rate is not stated, ~1 / (n + 1))."""
    rng = np.random.default_rng(20261124)
    protocol = Protocol(burn_in_s=0.0)
    reps, n = 4000, 100
    # the run's path (per-row scores through Protocol.thresholds) on a few calibrations ...
    maxima = np.empty((reps, n))
    for r in range(reps):
        if r < 40:
            validation = _flights(rng, n)
            t_flight, t_row = protocol.thresholds(validation)
            maxima[r] = [v.max() for v in validation.values()]
            assert t_flight == t_row == np.sort(maxima[r])[95]
        else:  # ... and the same distribution of flight maxima, drawn directly, for the rest
            maxima[r] = rng.gamma(2.0, 1.0, size=(n, 50)).max(axis=1)
    fresh = rng.gamma(2.0, 1.0, size=(reps, 50)).max(axis=1)
    flagged = float(np.mean(fresh > protocol.flight_rule.calibrate_many(maxima)))
    flagged_old = float(np.mean(fresh > ThresholdRule("max").calibrate_many(maxima)))
    expected = 1 - 96 / 101
    half = 2.576 * math.sqrt(expected * (1 - expected) / reps)
    assert expected - half <= flagged <= expected + half, flagged
    assert flagged_old < 0.02


def test_threshold_rule_errors_name_the_value():
    with pytest.raises(ProtocolError, match="alpha 1.5"):
        ThresholdRule("conformal", alpha=1.5)
    with pytest.raises(ProtocolError, match="burn_in_s"):
        Protocol(burn_in_s=-1.0)
    with pytest.raises(ProtocolError, match="alarm rule 'mine'"):
        Protocol(alarm_rule="mine")


def test_v1_run_folders_keep_their_rules():
    v1 = {"flight_rule": {"kind": "max", "margin": 0.05, "q": 0.999},
          "row_rule": {"kind": "max", "margin": 0.05, "q": 0.999}}
    p = Protocol.from_dict(v1)
    assert (p.burn_in_s, p.end_transient_s, p.alarm_rule, p.flight_rule.kind) == (0.0, 0.0, "calibrated", "max")
    assert Protocol.from_dict(Protocol().rules()) == Protocol()


# -- the burn-in after arming ------------------------------------------------------------------

def test_arming_time_is_read_from_the_flight():
    ts = np.arange(0, 10 * US, US // 10)
    generated = pd.DataFrame({"Timestamp": ts, "setpoint.armed": (ts >= 3 * US).astype(float)})
    assert arming_time_us(generated) == (3 * US, "setpoint.armed")
    px4 = pd.DataFrame({"Timestamp": ts, "vehicle_status.arming_state": np.where(ts >= 2 * US, 2.0, 1.0)})
    assert arming_time_us(px4) == (2 * US, "vehicle_status.arming_state")
    log = pd.DataFrame({"Timestamp": ts + 7, "attitude.roll": 0.0})
    assert arming_time_us(log) == (7, "first row")
    mask = counted_rows(ts, 3 * US, 5.0)  # the ground before arming and 5 s after it are left out
    assert not mask[ts < 8 * US].any() and mask[ts >= 8 * US].all()


def _evaluation(scores, labels, flights, protocol, alarms=None):
    ts = {f: np.arange(len(s)) * (US // 10) for f, s in scores.items()}
    truth = {f: (ts[f], np.asarray(labels.get(f, np.zeros(len(scores[f]))), dtype=np.int8)) for f in scores}
    return build_evaluation("toy", flights, truth, {f: np.asarray(s, float) for f, s in scores.items()}, protocol,
                            alarms=alarms)


def _table(rows):
    df = pd.DataFrame(rows, columns=["flight_id", "role", "mode", "attack_start_us", "attack_end_us", "armed_us",
                                     "source_flight", "scenario_id"])
    for c in ("attack_start_us", "attack_end_us", "armed_us"):
        df[c] = df[c].astype("Int64")
    return df


def test_arming_spike_never_sets_the_threshold():
    """Every normal flight has its largest score in the second after arming (1 s): without a
    burn-in that spike is the threshold and a held-out flight with a real excursion at 10 s
    passes; with the 5 s burn-in the threshold comes from the flights' ordinary maxima."""
    rng = np.random.default_rng(0)
    scores, rows = {}, []
    for i in range(40):
        s = rng.normal(0, 1, 200)  # 20 s at 10 Hz
        s[10:14] += 20.0  # arming step at 1.0 s
        fid = f"v{i}" if i < 30 else f"n{i}"
        if fid == "n39":
            s[100] = 8.0  # an excursion at 10 s
        scores[fid] = s
        rows.append((fid, "validation" if i < 30 else "test_normal", "normal", None, None, 1 * US, None, None))
    flights = _table(rows)
    v1 = _evaluation(scores, {}, flights, Protocol(burn_in_s=0.0))
    v2 = _evaluation(scores, {}, flights, Protocol())
    assert v1.flight_threshold > 15 and not v1.flights.loc["n39", "flagged"]
    assert v2.flight_threshold < 6 and v2.flights.loc["n39", "flagged"]
    assert not v2.rows["v0"].alarm[10:14].any()


# -- outcomes: end transient and false alarms before onset -------------------------------------

def test_end_transient_and_false_alarm_before_onset():
    """Attack from 5 s to 10 s: an alarm 1 s after its end is 'at the end' (counted by the window +
    end column), 4 s after it is late, and an alarm at 2 s is a false alarm before onset."""
    val = {f"v{i}": np.zeros(200) for i in range(20)}
    attacked = {"a_end": np.zeros(200), "a_late": np.zeros(200), "a_fa": np.zeros(200)}
    attacked["a_end"][110] = 5.0
    attacked["a_late"][140] = 5.0
    attacked["a_fa"][20] = 5.0
    attacked["a_fa"][60] = 5.0
    lab = np.zeros(200)
    lab[50:100] = 1
    rows = [(f, "validation", "normal", None, None, 0, None, None) for f in val]
    rows += [(f, "test_attacked", "simulation", 5 * US, 10 * US, 0, None, f) for f in attacked]
    ev = _evaluation({**val, **attacked}, dict.fromkeys(attacked, lab), _table(rows), Protocol(burn_in_s=1.0))
    out = ev.flights["outcome"]
    assert (out["a_end"], out["a_late"], out["a_fa"]) == ("at_end", "late", "detected")
    assert ev.flights["alarm_before_onset"].to_dict() | {} == {**dict.fromkeys(val, False), "a_end": False,
                                                               "a_late": False, "a_fa": True}
    got = PaperTable()(ev)
    assert got["tp_simulation"] == pytest.approx(1 / 3)
    assert got["tp_end_simulation"] == pytest.approx(2 / 3)
    assert got["late_simulation"] == pytest.approx(1 / 3)
    assert got["fa_before_onset_simulation"] == pytest.approx(1 / 3)
    assert got["detected_after_fa_simulation"] == 1


# -- intervals that cover what varies ------------------------------------------------------------

def _csv_case(sources: bool):
    """16 csv flights, 12 detected: replays of 8 recordings (2 each, both copies of a recording share
    its outcome), or 16 independent flights."""
    rng = np.random.default_rng(1)
    val = {f"v{i}": rng.normal(0, 1, 100) for i in range(100)}
    test = {f"n{i}": rng.normal(0, 1, 100) for i in range(100)}
    attacked, rows = {}, []
    for j in range(16):
        s = rng.normal(0, 1, 100)
        if (j // 2) < 6:  # recordings 0-5 detected, 6-7 missed
            s[60] = 50.0
        attacked[f"c{j}"] = s
        rows.append((f"c{j}", "test_attacked", "csv", 5 * US, 8 * US, 0, f"src{j // 2}" if sources else None,
                     f"cfg{j}"))
    lab = np.zeros(100)
    lab[50:80] = 1
    rows += [(f, "validation", "normal", None, None, 0, None, None) for f in val]
    rows += [(f, "test_normal", "normal", None, None, 0, None, None) for f in test]
    return _evaluation({**val, **test, **attacked}, dict.fromkeys(attacked, lab), _table(rows),
                       Protocol(burn_in_s=0.0))


def test_replays_of_one_recording_widen_the_interval():
    clustered, independent = PaperTable()(_csv_case(True)), PaperTable()(_csv_case(False))
    assert clustered["tp_csv"] == independent["tp_csv"] == 0.75
    assert clustered["n_units_csv"] == 8 and independent["n_units_csv"] == 16
    wide = clustered["tp_csv_hi"] - clustered["tp_csv_lo"]
    narrow = independent["tp_csv_hi"] - independent["tp_csv_lo"]
    assert wide > narrow * 1.2, (wide, narrow)
    # the plain Wilson interval does not see the clustering
    assert clustered["tp_csv_wilson_lo"] == independent["tp_csv_wilson_lo"] == wilson(12, 16)[0]


def test_threshold_uncertainty_widens_the_false_alarm_interval():
    """The held-out false-alarm rate's interval includes the threshold's own spread: it is wider
    than the Wilson interval of the same count, and it contains alpha."""
    got = PaperTable()(_csv_case(False))
    assert got["far_no_attack_lo"] <= got["far_no_attack_wilson_lo"]
    assert got["far_no_attack_hi"] > got["far_no_attack_wilson_hi"]
    assert got["far_no_attack_lo"] <= 0.05 <= got["far_no_attack_hi"]
    assert got["alpha"] == 0.05 and got["alpha_attainable"] == 1.0


def test_clusters_join_sources_and_configurations():
    flights = pd.DataFrame({"flight_id": ["s1", "c1", "c2", "s3", "n1"],
                            "mode": ["simulation", "csv", "csv", "simulation", "normal"],
                            "source_flight": [None, "r1", "r1", None, None],
                            "scenario_id": ["x", "x", "y", "z", None]})
    c = flight_clusters(flights).tolist()
    assert c[0] == c[1] == c[2] and len({c[0], c[3], c[4]}) == 3


# -- the detector's own alarm rule -------------------------------------------------------------

def test_own_alarms_replace_the_threshold():
    val = {f"v{i}": np.zeros(100) for i in range(20)}
    att = {"a": np.zeros(100)}
    lab = np.zeros(100)
    lab[50:80] = 1
    rows = [(f, "validation", "normal", None, None, 0, None, None) for f in val]
    rows += [("a", "test_attacked", "simulation", 5 * US, 8 * US, 0, None, "x")]
    alarms = {f: np.zeros(100, bool) for f in [*val, "a"]}
    alarms["a"][60] = True
    ev = _evaluation({**val, **att}, {"a": lab}, _table(rows), Protocol(burn_in_s=0.0, alarm_rule="own"),
                     alarms=alarms)
    assert ev.alarm_source == "own" and math.isnan(ev.flight_threshold)
    assert ev.flights.loc["a", "outcome"] == "detected"  # its scores alone never beat any threshold
    assert math.isnan(PaperTable()(ev)["alpha"])


# -- features by meaning -----------------------------------------------------------------------

def test_control_and_state_flags_are_not_features():
    rng = np.random.default_rng(2)
    n = 50
    flight = pd.DataFrame({"Timestamp": np.arange(n), "attitude.roll": rng.normal(size=n),
                           "setpoint.vx": rng.normal(size=n), "setpoint.armed": np.r_[np.zeros(5), np.ones(n - 5)],
                           "setpoint.seq": np.repeat(np.arange(5), 10),
                           "vehicle_status.nav_state": np.repeat([0, 3], 25),
                           "vehicle_land_detected.landed": np.r_[np.ones(5), np.zeros(n - 5)]})
    cols, dropped = feature_columns([flight])
    assert cols == ["attitude.roll", "setpoint.vx"]
    assert sorted(dropped["control or state flag"]) == ["setpoint.armed", "setpoint.seq",
                                                        "vehicle_land_detected.landed", "vehicle_status.nav_state"]
    assert feature_columns([flight], include=["setpoint.*"])[0] == ["setpoint.vx", "setpoint.armed", "setpoint.seq"]


# -- a run end to end ---------------------------------------------------------------------------

def test_run_with_the_detectors_own_rule(tmp_path):
    """``--threshold own``: Telemanom's dynamic threshold decides the alarms (its saved alarms are
    the rows the metrics count), the table states no alpha, and the calibrated run of the same
    scores differs; the run folder says where each validation maximum sat."""
    from run_fixtures import write_dataset

    from scart_bench.benchmark.store import RunStore
    from scart_bench.cli.main import main

    ds = write_dataset(tmp_path / "ds")
    fast = ["--param", "telemanom.l_s=25", "--param", "telemanom.hidden=[16, 16]", "--param", "telemanom.epochs=2",
            "--param", "telemanom.max_train_windows=2000", "--param", "telemanom.device=\"cpu\""]
    own, cal = tmp_path / "own", tmp_path / "cal"
    assert main(["run", "--detectors", "telemanom", *fast, "--dataset", str(ds), "--out", str(own),
                 "--threshold", "own"]) == 0
    assert main(["run", "--detectors", "telemanom", *fast, "--dataset", str(ds), "--out", str(cal)]) == 0
    store = RunStore(own)
    alarms = store.read_alarms("telemanom")
    assert alarms is not None and set(alarms) == set(store.read_scores("telemanom"))
    m_own = pd.read_csv(own / "metrics.csv").iloc[0]
    m_cal = pd.read_csv(cal / "metrics.csv").iloc[0]
    assert math.isnan(m_own["alpha"]) and m_cal["alpha"] == 0.05
    assert math.isnan(m_own["flight_threshold"]) and math.isfinite(m_cal["flight_threshold"])
    fs = pd.read_csv(own / "flight_scores.csv").set_index("flight_id")
    for fid in ("normal-007", "normal-008", "normal-009"):  # held-out normal: flagged iff an own alarm after burn-in
        ts = np.arange(1000) * 20_000
        after = ts >= 8 * US  # the default burn-in: 8 s from the first row (no arming field)
        assert bool(fs.loc[fid, "flagged"]) == bool(alarms[fid][after].any())
    assert "its own alarm rule" in (own / "metrics.md").read_text()
    cal_table = pd.read_csv(cal / "calibration.csv")
    assert len(cal_table) == 3 and (cal_table["max_after_arming_s"] >= 8.0).all()
    assert cal_table["sets_threshold"].sum() >= 1
    assert pd.read_csv(cal / "arming.csv")["armed_by"].eq("first row").all()


def test_attacks_starting_inside_the_burn_in_are_counted():
    val = {f"v{i}": np.zeros(200) for i in range(20)}
    lab = np.zeros(200)
    lab[30:80] = 1
    rows = [(f, "validation", "normal", None, None, 0, None, None) for f in val]
    rows += [("early", "test_attacked", "simulation", 3 * US, 8 * US, 1 * US, None, "x"),
             ("late", "test_attacked", "simulation", 12 * US, 15 * US, 1 * US, None, "y")]
    ev = _evaluation({**val, "early": np.zeros(200), "late": np.zeros(200)}, {"early": lab, "late": lab},
                     _table(rows), Protocol(burn_in_s=5.0))
    assert PaperTable()(ev)["n_onset_in_burn_in"] == 1
