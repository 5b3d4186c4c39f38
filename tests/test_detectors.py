"""Built-in detectors: detection of a GPS noise attack and the shared conformance suite.

The conformance checks are small functions run against every name in ``CONFORMANCE_DETECTORS``
(one pytest case per detector per check); a new detector joins by adding its name there and,
if it needs small settings to be quick, an entry in ``FAST_PARAMS``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from detector_data import attacked_flight, normal_flights

from scart_bench.detectors.base import Detector, DetectorError, flight_score
from scart_bench.detectors.registry import make
from scart_bench.testing import check_detector, detector_checks

#: The detectors of this file's detection test: all eight built-ins.
DETECTORS = ["statistical", "tsbitmaps", "deepsvdd", "rdp", "rca", "goad", "neutral", "telemanom"]
#: Every detector the conformance suite runs against.
CONFORMANCE_DETECTORS = list(DETECTORS)

#: Settings that keep a fit on the small conformance flights to about a second on 2 cores.
FAST_PARAMS: dict[str, dict] = {
    "statistical": {"window": 20},
    "tsbitmaps": {"lag_window_size": 120, "lead_window_size": 40},
    "deepsvdd": {"epochs": 1, "max_train_windows": 256},
    "rdp": {"epochs": 1, "max_train_windows": 256},
    "rca": {"epochs": 1, "max_train_windows": 256},
    "goad": {"epochs": 1, "max_train_windows": 256, "model_params": {"n_trans": 8}},
    "neutral": {"epochs": 1, "max_train_windows": 256, "model_params": {"n_trans": 4}},
    "telemanom": {"epochs": 1, "max_train_windows": 256, "l_s": 25, "hidden": (8,)},
}
#: Settings of the detection test (full training data, fewer epochs than the defaults).
DETECTION_PARAMS: dict[str, dict] = {
    "deepsvdd": {"epochs": 5},
    "rdp": {"epochs": 5},
    "rca": {"epochs": 5},
    "goad": {"epochs": 5},
    "neutral": {"epochs": 5},
    "telemanom": {"epochs": 3},
}


# -- data --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def detection_data() -> tuple[list[pd.DataFrame], list[pd.DataFrame], pd.DataFrame]:
    """4 training flights, 3 held-out normal flights and 1 attacked flight."""
    return normal_flights(4, seed=0), normal_flights(3, seed=1), attacked_flight(seed=2)


@pytest.fixture(scope="module")
def small_data() -> tuple[list[pd.DataFrame], pd.DataFrame]:
    """2 short training flights and a short probe flight for the conformance checks."""
    return normal_flights(2, seed=10, rows=500), normal_flights(1, seed=11, rows=300)[0]


def fresh(name: str, **params) -> Detector:
    """A new detector with its fast settings (overridden by ``params``)."""
    return make(name, **{**FAST_PARAMS.get(name, {}), **params})


# -- detection ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", DETECTORS)
def test_attacked_flight_scores_above_every_normal_flight(name, detection_data):
    train, held_out, attacked = detection_data
    detector = make(name, **DETECTION_PARAMS.get(name, {})).fit(train)
    attacked_score = flight_score(detector.score(attacked))
    normal_scores = [flight_score(detector.score(f)) for f in held_out]
    assert attacked_score > max(normal_scores), (attacked_score, normal_scores)


def test_statistical_alarms_are_the_k_of_n_rule(detection_data):
    train, held_out, attacked = detection_data
    detector = make("statistical").fit(train)
    assert detector.has_alarms
    alarms = detector.alarms(attacked)
    np.testing.assert_array_equal(alarms, detector.score(attacked) > 1.0)
    assert alarms[attacked["Is_Anomaly"].to_numpy() == 1].any()
    # Requiring all four thresholds at once can only remove alarms.
    strict = make("statistical", min_exceed=4).fit(train).alarms(attacked)
    assert not (strict & ~alarms).any()


def test_tsbitmaps_gives_zero_score_on_constant_channels():
    train = [f.assign(**{"const.value": 3.0}) for f in normal_flights(2, seed=20, rows=400)]
    detector = make("tsbitmaps", columns=["const.value"]).fit(train)
    probe = normal_flights(1, seed=21, rows=400)[0].assign(**{"const.value": 3.0})
    np.testing.assert_array_equal(detector.score(probe), np.zeros(len(probe)))


def test_tsbitmaps_mean_combination_is_at_most_max(small_data):
    train, probe = small_data
    scores = {c: fresh("tsbitmaps", combine=c).fit(train).score(probe) for c in ("max", "mean")}
    assert np.all(scores["mean"] <= scores["max"] + 1e-12)


@pytest.mark.parametrize(
    "name, params",
    [
        ("statistical", {"min_exceed": 5}),
        ("statistical", {"window": 1}),
        ("tsbitmaps", {"combine": "median"}),
        ("tsbitmaps", {"alphabet_size": 1}),
        ("deepsvdd", {"model_params": {"no_such_argument": 1}}),
        ("goad", {"segments": 0}),
        ("neutral", {"window": 1}),
    ],
)
def test_invalid_parameters_raise_detector_error_at_fit(name, params, small_data):
    detector = fresh(name, **params)
    with pytest.raises(DetectorError):
        detector.fit(small_data[0])


# -- conformance suite (scart_bench.testing, the kit plugin authors use) ----------------------


def _conformance_cases():
    from scart_bench.detectors.registry import BUILTINS, _import_spec

    cases = []
    for name in CONFORMANCE_DETECTORS:
        cases += detector_checks(_import_spec(BUILTINS[name]), FAST_PARAMS.get(name, {}))
    return cases


@pytest.mark.parametrize("check", _conformance_cases(), ids=str)
def test_conformance(check):
    check()


class _NotCausal(Detector):
    """Scores each row by the mean of the whole flight: looks ahead, so it is not causal."""

    name = "lookahead"

    def __init__(self, columns=None, random_state=0):
        self.columns = columns
        self.random_state = random_state

    def _fit(self, X_list):
        pass

    def _score(self, X):
        return np.full(X.shape[0], float(np.abs(X).mean()))


class _StoresWrongly(Detector):
    """Renames its parameter on the way in (breaks get_params/clone)."""

    name = "renamer"

    def __init__(self, columns=None, random_state=0, window=5):
        self.columns = columns
        self.random_state = random_state
        self.win = window

    def _fit(self, X_list):
        pass

    def _score(self, X):
        return np.zeros(X.shape[0])


def test_check_detector_names_the_failed_check():
    with pytest.raises(AssertionError, match=r"(?s)'causal_scores'.*first 1 rows"):
        check_detector(_NotCausal)
    with pytest.raises(AssertionError, match=r"'init_only_stores_parameters'"):
        check_detector(_StoresWrongly)


@pytest.mark.parametrize("name", ["statistical", "tsbitmaps", "deepsvdd", "goad", "neutral", "telemanom"])
def test_streaming_one_row_at_a_time_gives_the_batch_scores(small_data, name):
    """A live monitor fed one row at a time (``stream().update``) scores as ``score`` on the flight.

    TSBitmaps keeps incremental bitmaps, the DeepOD models score only the newest window; gaps
    (NaN) in the stream are filled causally as in batch scoring.
    """
    train, probe = small_data
    detector = make(name, **FAST_PARAMS[name]).fit(train)
    probe = probe.copy()
    probe.loc[probe.index[40:45], detector.columns_[3]] = np.nan
    full = detector.score(probe)
    stream = detector.stream()
    raw = probe[detector.columns_].to_numpy(dtype=np.float64)
    streamed = np.array([stream.update(row) for row in raw[:200]])
    np.testing.assert_allclose(streamed, full[:200], rtol=2e-5, atol=1e-9)
    assert detector.score_last(probe.iloc[:200]) == pytest.approx(full[199], rel=2e-5)


def test_streaming_before_fit_raises():
    with pytest.raises(DetectorError, match="call fit"):
        make("tsbitmaps").stream()
