"""Telemanom's tensorflow backend (Keras 3 on tensorflow-cpu) on the small synthetic flights of
test_telemanom: detection, determinism, pickling, and agreement with the torch backend.

Skipped where TensorFlow is not installed (``pip install 'scart-bench[tensorflow]'``; ``make test``
installs it), except the check of the message a user without it gets.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.stats import spearmanr
from test_telemanom import ATTACK, FAST, make_flight

from scart_bench.benchmark.config import read_run_file
from scart_bench.detectors.base import DetectorError, flight_score
from scart_bench.detectors.registry import make
from scart_bench.detectors.telemanom import Telemanom

RUNS = Path(__file__).resolve().parents[1] / "data" / "runs"


@pytest.fixture(scope="module")
def tf():
    tf = pytest.importorskip("tensorflow")
    try:  # small LSTMs: one thread is as fast, and does not stall on shared cores
        tf.config.threading.set_intra_op_parallelism_threads(1)
        tf.config.threading.set_inter_op_parallelism_threads(1)
    except RuntimeError:  # TensorFlow already started in this process: keep its pools
        pass
    return tf


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def train():
    return [make_flight(s) for s in range(4)]


@pytest.fixture(scope="module")
def fitted(tf, train) -> Telemanom:
    return Telemanom(random_state=0, backend="tensorflow", **FAST).fit(train)


@pytest.fixture(scope="module")
def fitted_torch(train) -> Telemanom:
    return Telemanom(random_state=0, **FAST).fit(train)


def test_missing_tensorflow_is_a_clear_error(monkeypatch):
    for name in ("tensorflow", "keras"):  # `import tensorflow` / `import keras` raise ImportError
        monkeypatch.setitem(sys.modules, name, None)
    det = Telemanom(backend="tensorflow", **{**FAST, "epochs": 1})
    with pytest.raises(DetectorError, match=r"needs tensorflow-cpu: pip install 'scart-bench\[tensorflow\]'"):
        det.fit([make_flight(0, rows=300)])


def test_invalid_backend_rejected():
    with pytest.raises(DetectorError, match="backend"):
        Telemanom(backend="jax").fit([make_flight(0, rows=300)])
    with pytest.raises(DetectorError, match="tensorflow-cpu"):
        Telemanom(backend="tensorflow", device="cuda").fit([make_flight(0, rows=300)])


def test_attack_scores_above_every_normal_flight(fitted):
    assert fitted.backend == "tensorflow"
    assert all(isinstance(w, np.ndarray) for state in fitted.model_states_ for w in state)
    assert 1 <= fitted.epochs_run_[0] <= FAST["epochs"]
    normal = [flight_score(fitted.score(make_flight(s))) for s in (100, 101, 102)]
    attacked = fitted.score(make_flight(103, attack=ATTACK))
    assert np.all(np.isfinite(attacked))
    assert flight_score(attacked) > max(normal)
    assert ATTACK[0] <= int(np.argmax(attacked)) < ATTACK[1] + 200
    # the dynamic threshold flags the attack and stays quiet on a normal flight
    alarms = fitted.alarms(make_flight(104, attack=ATTACK))
    assert alarms.sum() > 0
    assert alarms[ATTACK[0] : ATTACK[1] + fitted.error_buffer + 100].sum() / alarms.sum() >= 0.8
    assert fitted.alarms(make_flight(105)).mean() < 0.05


def test_same_seed_same_scores(fitted, train):
    """A second fit with the same seed gives the same scores bit for bit (Keras seeded, TensorFlow
    ops deterministic), and leaves numpy's and torch's global random states as they were."""
    flight = make_flight(7, attack=ATTACK)
    state = (np.random.get_state()[1].copy(), torch.random.get_rng_state())
    again = Telemanom(random_state=0, backend="tensorflow", **FAST).fit(train)
    assert np.array_equal(np.random.get_state()[1], state[0])
    assert torch.equal(torch.random.get_rng_state(), state[1])
    assert again.epochs_run_ == fitted.epochs_run_
    for w_a, w_b in zip(again.model_states_[0], fitted.model_states_[0]):
        np.testing.assert_array_equal(w_a, w_b)
    np.testing.assert_array_equal(again.score(flight), fitted.score(flight))


def test_pickle_round_trip(fitted):
    flight = make_flight(107, attack=ATTACK)
    clone = pickle.loads(pickle.dumps(fitted))
    assert "_nets_cache" not in clone.__dict__
    np.testing.assert_array_equal(clone.score(flight), fitted.score(flight))
    np.testing.assert_array_equal(clone.alarms(flight), fitted.alarms(flight))


def test_stream_matches_batch_scores(fitted):
    flight = make_flight(108, attack=(100, 200)).iloc[:300]
    X = flight[fitted.columns_].to_numpy(dtype=np.float64)
    stream = fitted.stream()
    live = np.array([stream.update(row) for row in X])
    np.testing.assert_allclose(live, fitted.score(flight), rtol=1e-4, atol=1e-6)


def test_backends_agree(fitted, fitted_torch):
    """Different frameworks, initialisations and arithmetic: not the same numbers, the same picture.

    On these flights (seed 0) the two agree as follows: the peak of the score on the same row,
    channel error levels ranked alike (Spearman ~0.89), alarms on the attacked flight overlapping
    by ~83 % (Jaccard)."""
    # both put the attacked flight above every normal one, with the peak in the attack window
    for det in (fitted, fitted_torch):
        normal = max(flight_score(det.score(make_flight(s))) for s in (100, 101))
        attacked = det.score(make_flight(104, attack=ATTACK))
        assert flight_score(attacked) > 10 * normal
        assert ATTACK[0] <= int(np.argmax(attacked)) < ATTACK[1] + 200
    # which channels the LSTM forecasts well or badly: ranked alike
    normal = [make_flight(s) for s in (100, 101)]
    level_tf = np.mean([fitted.smoothed_errors(f).mean(axis=0) for f in normal], axis=0)
    level_torch = np.mean([fitted_torch.smoothed_errors(f).mean(axis=0) for f in normal], axis=0)
    assert spearmanr(level_tf, level_torch).statistic > 0.7
    # the dynamic threshold flags mostly the same rows
    flight = make_flight(104, attack=ATTACK)
    a, b = fitted.alarms(flight), fitted_torch.alarms(flight)
    assert (a & b).sum() / (a | b).sum() > 0.5


def test_the_run_file_is_the_paper_configuration_on_tensorflow():
    ours = read_run_file(RUNS / "telemanom_tensorflow.toml")
    paper = read_run_file(RUNS / "telemanom_paper.toml")
    params = dict(ours["params"]["telemanom"])
    assert params.pop("backend") == "tensorflow"
    assert params == paper["params"]["telemanom"]
    assert ours["detectors"] == paper["detectors"] and ours["protocol"] == paper["protocol"]


def test_the_run_file_makes_a_tensorflow_telemanom():
    """What the run gives the detector (a fit from the command line: test_telemanom_paper; each
    job runs in its own process, which here would start TensorFlow once more)."""
    params = read_run_file(RUNS / "telemanom_tensorflow.toml")["params"]["telemanom"]
    det = make("telemanom", **params)
    assert isinstance(det, Telemanom) and det.get_params()["backend"] == "tensorflow"
    assert det.get_params()["hidden"] == [80, 80]
