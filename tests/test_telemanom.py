"""Telemanom on small synthetic flights: detection, alarms, determinism, causality, pickle."""

from __future__ import annotations

import pickle

import numpy as np
import pandas as pd
import pytest
import torch

from scart_bench.dataset.schema import HOME_ALT, HOME_LAT, HOME_LON
from scart_bench.detectors.base import DetectorError, flight_score
from scart_bench.detectors.telemanom import Telemanom, dynamic_threshold, ewma, find_z

RATE_HZ = 50.0
M_PER_DEG_LAT = 111_320.0
G = 9.81


def _smootherstep(s: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero velocity and acceleration at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (s * (6.0 * s - 15.0) + 10.0)


def make_flight(
    seed: int, rows: int = 2000, attack: tuple[int, int] | None = None, noise_m: float = 20.0
) -> pd.DataFrame:
    """A small 50 Hz square-path flight (take-off, 30 m square, landing) in the combined layout.

    With ``attack=(start, end)``, rows ``start..end-1`` get white noise of ``noise_m`` metres on
    the horizontal position columns (local x/y and global lat/lon), flagged in ``Is_Anomaly``.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / RATE_HZ
    t = np.arange(rows) * dt
    # waypoints (north, east, down) and nominal leg durations, with per-flight jitter
    alt = 10.0 + rng.normal(0.0, 0.3)
    side = 30.0 + rng.normal(0.0, 0.5)
    wps = np.array([[0, 0, 0], [0, 0, -alt], [side, 0, -alt], [side, side, -alt], [0, side, -alt],
                    [0, 0, -alt], [0, 0, 0]], dtype=float)
    legs = np.array([5.0, 8.0, 8.0, 8.0, 8.0, 5.0]) * rng.uniform(0.95, 1.05, 6)
    legs = legs / legs.sum() * (t[-1] - 2.0)
    starts = 1.0 + np.concatenate([[0.0], np.cumsum(legs)[:-1]])
    pos = np.repeat(wps[:1], rows, axis=0)
    for k in range(len(legs)):
        pos = pos + _smootherstep((t - starts[k]) / legs[k])[:, None] * (wps[k + 1] - wps[k])
    vel = np.gradient(pos, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    wind = rng.normal(0.0, 0.02, 2)
    att = np.stack([acc[:, 1] / G + wind[1], -acc[:, 0] / G + wind[0], np.full(rows, 0.1)], axis=1)
    rates = np.gradient(att, dt, axis=0) + rng.normal(0.0, 0.005, (rows, 3))
    roll, pitch, yaw = (att + rng.normal(0.0, 0.002, att.shape)).T
    n_pos = pos + rng.normal(0.0, 0.05, pos.shape)
    cols = {
        "Index": np.arange(rows),
        "Timestamp": (t * 1e6).astype(np.int64),
        "Is_Anomaly": np.zeros(rows, dtype=np.int64),
        "attitude.roll": roll,
        "attitude.pitch": pitch,
        "attitude.yaw": yaw,
        "attitude.rollspeed": rates[:, 0],
        "attitude.pitchspeed": rates[:, 1],
        "highres_imu.xacc": acc[:, 0] + rng.normal(0, 0.05, rows),
        "highres_imu.yacc": acc[:, 1] + rng.normal(0, 0.05, rows),
        "highres_imu.zacc": -G - acc[:, 2] + rng.normal(0, 0.05, rows),
        "local_position_ned.x": n_pos[:, 0].copy(),
        "local_position_ned.y": n_pos[:, 1].copy(),
        "local_position_ned.z": n_pos[:, 2].copy(),
        "local_position_ned.vx": vel[:, 0] + rng.normal(0, 0.03, rows),
        "local_position_ned.vy": vel[:, 1] + rng.normal(0, 0.03, rows),
        "local_position_ned.vz": vel[:, 2] + rng.normal(0, 0.03, rows),
        "global_position_int.lat": HOME_LAT + n_pos[:, 0] / M_PER_DEG_LAT,
        "global_position_int.lon": HOME_LON + n_pos[:, 1] / (M_PER_DEG_LAT * np.cos(np.radians(HOME_LAT))),
        "global_position_int.alt": HOME_ALT - n_pos[:, 2],
    }
    if attack is not None:
        a0, a1 = attack
        noise = rng.normal(0.0, noise_m, (a1 - a0, 2))
        cols["local_position_ned.x"][a0:a1] += noise[:, 0]
        cols["local_position_ned.y"][a0:a1] += noise[:, 1]
        cols["global_position_int.lat"][a0:a1] += noise[:, 0] / M_PER_DEG_LAT
        cols["global_position_int.lon"][a0:a1] += noise[:, 1] / (
            M_PER_DEG_LAT * np.cos(np.radians(HOME_LAT))
        )
        cols["Is_Anomaly"][a0:a1] = 1
    return pd.DataFrame(cols)


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """Small LSTMs run fastest on one thread, and do not stall when the cores are shared."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


FAST = dict(l_s=25, hidden=(16, 16), epochs=4, max_train_windows=3000, patience=2)
ATTACK = (1000, 1300)


@pytest.fixture(scope="module")
def fitted() -> Telemanom:
    det = Telemanom(random_state=0, **FAST)
    return det.fit([make_flight(s) for s in range(4)])


def test_attack_scores_above_every_normal_flight(fitted):
    normal = [flight_score(fitted.score(make_flight(s))) for s in (100, 101, 102)]
    attacked = fitted.score(make_flight(103, attack=ATTACK))
    assert np.all(np.isfinite(attacked))
    assert flight_score(attacked) > max(normal)
    # the peak lies in the attack window (plus the EWMA's tail)
    assert ATTACK[0] <= int(np.argmax(attacked)) < ATTACK[1] + 200


def test_alarms_mostly_inside_attack_window(fitted):
    flight = make_flight(104, attack=ATTACK)
    alarms = fitted.alarms(flight)
    assert alarms.dtype == bool and alarms.shape == (len(flight),)
    assert alarms.sum() > 0
    inside = alarms[ATTACK[0] : ATTACK[1] + fitted.error_buffer + 100].sum()
    assert inside / alarms.sum() >= 0.8
    # a normal flight raises few alarms
    assert fitted.alarms(make_flight(105)).mean() < 0.05


def test_same_seed_same_scores():
    train = [make_flight(s) for s in range(2)]
    flight = make_flight(7, attack=ATTACK)
    a = Telemanom(random_state=3, **FAST).fit(train).score(flight)
    before = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        b = Telemanom(random_state=3, **FAST).fit(train).score(flight)
    finally:
        torch.use_deterministic_algorithms(before)
    np.testing.assert_array_equal(a, b)
    c = Telemanom(random_state=4, **FAST).fit(train).score(flight)
    assert not np.array_equal(a, c)


def test_no_global_rng_side_effects():
    torch.manual_seed(123)
    np.random.seed(123)
    expected_t, expected_n = torch.rand(3), np.random.rand(3)
    torch.manual_seed(123)
    np.random.seed(123)
    Telemanom(random_state=0, **{**FAST, "epochs": 1}).fit([make_flight(0, rows=600)])
    np.testing.assert_array_equal(torch.rand(3).numpy(), expected_t.numpy())
    np.testing.assert_array_equal(np.random.rand(3), expected_n)


def test_causal(fitted):
    flight = make_flight(106, attack=ATTACK)
    full = fitted.score(flight)
    for k in (1, 7, 30, 400, 1150):
        assert np.allclose(fitted.score(flight.iloc[:k]), full[:k], rtol=1e-6, atol=1e-9)
    # streaming from a trailing window of history_rows_ rows reproduces the score closely
    k = 1600
    tail = fitted.score(flight.iloc[k - fitted.history_rows_ : k])
    assert abs(tail[-1] - full[k - 1]) <= 0.05 * abs(full[k - 1]) + 1e-6


def test_forecasts_do_not_depend_on_how_many_windows_one_lstm_call_takes(fitted, monkeypatch):
    """Scoring forecasts 256 windows per LSTM call (it fits a core's cache); the scores are the
    ones of 1,024-window calls and of one window per call, bit for bit, and a row's score does not
    depend on how many rows follow it (a short last call is padded)."""
    from scart_bench.detectors import telemanom

    flight = make_flight(108, attack=ATTACK)
    ours = fitted.score(flight)
    for k in (1, 2, 3, 257, 1283):
        assert np.array_equal(fitted.score(flight.iloc[:k]), ours[:k]), k
    for chunk in (1024, 1):
        monkeypatch.setattr(telemanom, "_PREDICT_CHUNK", chunk)
        assert np.array_equal(fitted.score(flight), ours), chunk


def test_pickle_round_trip(fitted):
    flight = make_flight(107, attack=ATTACK)
    clone = pickle.loads(pickle.dumps(fitted))
    np.testing.assert_array_equal(clone.score(flight), fitted.score(flight))
    np.testing.assert_array_equal(clone.alarms(flight), fitted.alarms(flight))


def test_alarms_after_score_forecast_the_flight_once(fitted, monkeypatch):
    """A run with the own alarm rule scores a flight, then asks for its alarms: the second call
    reuses the forecast; another flight, or a changed copy of the same one, is forecast anew."""
    flight, other = make_flight(108, attack=ATTACK), make_flight(109)
    fresh = pickle.loads(pickle.dumps(fitted))
    expected_scores, expected_alarms = fresh.score(flight), fresh.alarms(flight)
    calls = []
    real = Telemanom._predict
    monkeypatch.setattr(Telemanom, "_predict", lambda self, X: calls.append(len(X)) or real(self, X))
    det = pickle.loads(pickle.dumps(fitted))
    np.testing.assert_array_equal(det.score(flight), expected_scores)
    np.testing.assert_array_equal(det.alarms(flight), expected_alarms)
    assert len(calls) == 1
    det.alarms(other)
    changed, row = flight.copy(), len(flight) - 100
    changed.loc[row, "local_position_ned.x"] += 5.0
    changed_scores = det.score(changed)
    assert len(calls) == 3 and changed_scores[row:].max() > expected_scores[row:].max()


def test_per_channel_and_targets():
    targets = ["global_position_int.lat", "local_position_ned.x"]  # not in column order
    det = Telemanom(per_channel=True, target_columns=targets, aggregate="mean", **FAST)
    det.fit([make_flight(s) for s in range(2)])
    assert len(det.model_states_) == 2 and det.error_scale_.shape == (2,)
    flight = make_flight(110)
    errors = det.smoothed_errors(flight)
    assert errors.shape == (len(flight), 2)
    # each model forecasts its own channel: errors are small next to the channel's spread
    X = det._transform(flight)
    assert np.all(errors.mean(axis=0) < 0.2 * X[:, det.target_idx_].std(axis=0))
    normal = flight_score(det.score(make_flight(110)))
    attacked = flight_score(det.score(make_flight(111, attack=ATTACK)))
    assert attacked > normal
    with pytest.raises(DetectorError, match="target_columns"):
        Telemanom(target_columns=["nope.x"], **FAST).fit([make_flight(0, rows=300)])


def test_invalid_parameters_rejected():
    with pytest.raises(DetectorError, match="aggregate"):
        Telemanom(aggregate="median").fit([make_flight(0, rows=300)])


def test_ewma_matches_pandas():
    x = np.random.default_rng(0).random((200, 3))
    expected = pd.DataFrame(x).ewm(span=12.5).mean().to_numpy()
    np.testing.assert_allclose(ewma(x, 12.5), expected, rtol=1e-10)


def test_dynamic_threshold_on_known_errors():
    rng = np.random.default_rng(1)
    e = np.abs(rng.normal(0.0, 0.1, 1500)) + 0.1
    e[900:960] += 3.0  # one clear burst
    e_s = ewma(e, 10)
    y = rng.normal(0.0, 1.0, 1500)
    z = find_z(e_s[750:1500], error_buffer=25)
    assert 2.5 <= z <= 12.0
    mask = dynamic_threshold(e_s, y, error_batch=25, window_size=30, error_buffer=25, p=0.13)
    hit = np.flatnonzero(mask)
    assert hit.size > 0
    assert hit.min() >= 850 and hit.max() <= 1100
    # pure noise: nothing survives the pruning
    quiet = ewma(np.abs(rng.normal(0.0, 0.1, 1500)) + 0.1, 10)
    assert dynamic_threshold(quiet, y).sum() == 0


def _spike_errors(n: int, spike_at: int) -> tuple[np.ndarray, np.ndarray]:
    """Hand-made smoothed errors: a flat 0.1 with a little noise and one error of 5.0."""
    rng = np.random.default_rng(7)
    e_s = 0.1 + rng.uniform(0.0, 0.01, n)
    e_s[spike_at] = 5.0
    return e_s, rng.normal(0.0, 0.01, n)


def test_dynamic_threshold_pads_error_buffer_rows_each_side():
    """One window: the anomalous sequence is the error above the threshold +- error_buffer rows
    (the published compare_to_epsilon pads by np.arange(1, error_buffer + 1))."""
    e_s, y = _spike_errors(100, 50)
    mask = dynamic_threshold(e_s, y, error_batch=100, window_size=1, error_buffer=3, p=0.13, inverse=False)
    assert np.flatnonzero(mask).tolist() == list(range(47, 54))


def test_dynamic_threshold_keeps_a_single_row_cut_by_the_batch_boundary():
    """Batches of 10, windows of 3 batches. The error at 37 is flagged by window 1 (newest rows
    30-39) as 34-39; window 2 may only flag its newest rows 40-49, where the padding leaves the
    single row 40: the published code keeps it (no sequence to prune), so the sequence is 34-40."""
    e_s, y = _spike_errors(60, 37)
    mask = dynamic_threshold(e_s, y, error_batch=10, window_size=3, error_buffer=3, p=0.13, inverse=False)
    assert np.flatnonzero(mask).tolist() == list(range(34, 41))
