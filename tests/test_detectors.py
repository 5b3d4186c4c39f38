"""Built-in detectors: detection of a GPS noise attack and the shared conformance suite.

The conformance checks are small functions run against every name in ``CONFORMANCE_DETECTORS``
(one pytest case per detector per check); a new detector joins by adding its name there and,
if it needs small settings to be quick, an entry in ``FAST_PARAMS``.
"""

from __future__ import annotations

import copy
import inspect
import pickle
import random
import sys
from collections.abc import Callable

import numpy as np
import pandas as pd
import pytest
from detector_data import attacked_flight, normal_flights
from sklearn.base import clone

from detectors.base import Detector, DetectorError, NotFittedError, flight_score
from detectors.registry import make

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


@pytest.fixture(scope="module")
def fitted(small_data) -> Callable[[str], Detector]:
    """A detector of each name fitted once on the conformance flights (with ``random_state=0``)."""
    cache: dict[str, Detector] = {}

    def get(name: str) -> Detector:
        if name not in cache:
            cache[name] = fresh(name).fit(small_data[0])
        return cache[name]

    return get


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


# -- conformance suite -------------------------------------------------------------------------


def check_init_only_stores_parameters(name, small_data, fitted):
    """``__init__`` stores its arguments unchanged and sets no fitted attribute."""
    params = {**FAST_PARAMS.get(name, {}), "random_state": 7, "columns": None}
    detector = make(name, **params)
    assert [k for k in vars(detector) if k.endswith("_")] == []
    signature = inspect.signature(type(detector).__init__).parameters
    expected = {k: p.default for k, p in signature.items() if k != "self"} | params
    assert detector.get_params() == expected
    assert {"columns", "random_state"} <= set(expected)
    assert clone(detector).get_params() == expected
    assert type(detector).name == name and type(detector).description


def check_fit_leaves_parameters_unchanged(name, small_data, fitted):
    detector = fresh(name)
    before = copy.deepcopy(detector.get_params())
    assert fitted(name).get_params() == before


def check_score_before_fit_raises(name, small_data, fitted):
    with pytest.raises(NotFittedError):
        fresh(name).score(small_data[1])


def check_fit_without_flights_raises(name, small_data, fitted):
    with pytest.raises(DetectorError):
        fresh(name).fit([])


def check_missing_column_is_named(name, small_data, fitted):
    detector = fitted(name)
    column = detector.columns_[len(detector.columns_) // 2]
    with pytest.raises(DetectorError, match=column.replace(".", r"\.")):
        detector.score(small_data[1].drop(columns=[column]))


def check_one_finite_score_per_row(name, small_data, fitted):
    probe = small_data[1]
    scores = fitted(name).score(probe)
    assert isinstance(scores, np.ndarray) and scores.dtype == np.float64
    assert scores.shape == (len(probe),)
    assert np.isfinite(scores).all()


def check_pickle_round_trip(name, small_data, fitted):
    detector = fitted(name)
    restored = pickle.loads(pickle.dumps(detector))
    np.testing.assert_array_equal(restored.score(small_data[1]), detector.score(small_data[1]))


def check_same_seed_same_scores(name, small_data, fitted):
    again = fresh(name).fit(small_data[0])
    np.testing.assert_array_equal(again.score(small_data[1]), fitted(name).score(small_data[1]))


def check_causal_scores(name, small_data, fitted):
    """Scores of the first k rows do not depend on later rows (batch = streaming)."""
    probe = small_data[1]
    detector = fitted(name)
    full = detector.score(probe)
    for k in (1, 2, 37, len(probe) // 2 + 3):
        np.testing.assert_allclose(detector.score(probe.iloc[:k]), full[:k], rtol=1e-6, atol=1e-9)


def check_no_global_side_effects(name, small_data, fitted):
    """Fitting and scoring leave the global random generators as they were."""
    torch = sys.modules.get("torch")
    np_state, py_state = np.random.get_state(), random.getstate()
    torch_state = torch.get_rng_state() if torch is not None else None
    fresh(name, random_state=5).fit(small_data[0]).score(small_data[1])
    after = np.random.get_state()
    assert all(np.array_equal(a, b) for a, b in zip(np_state, after))
    assert random.getstate() == py_state
    if torch_state is not None:
        assert torch.equal(torch.get_rng_state(), torch_state)


CHECKS = [
    check_init_only_stores_parameters,
    check_fit_leaves_parameters_unchanged,
    check_score_before_fit_raises,
    check_fit_without_flights_raises,
    check_missing_column_is_named,
    check_one_finite_score_per_row,
    check_pickle_round_trip,
    check_same_seed_same_scores,
    check_causal_scores,
    check_no_global_side_effects,
]


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
@pytest.mark.parametrize("name", CONFORMANCE_DETECTORS)
def test_conformance(name, check, small_data, fitted):
    check(name, small_data, fitted)
