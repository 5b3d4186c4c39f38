"""The zoo's built-in detectors (issue 50): conformance, detection of a GPS noise attack, and each
adapter's scores equal to the wrapped library's own on the same input.

The conformance kit (scart_bench.testing) runs on every zoo detector here and on the paper's
eight in tests/test_detectors.py; ``test_every_builtin_passes_through_the_conformance_kit``
keeps the two lists covering every built-in.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from detector_data import attacked_flight, normal_flights

from scart_bench.detectors import registry
from scart_bench.detectors.base import flight_score
from scart_bench.testing import detector_checks

ZOO = list(registry.ZOO)

#: Settings that keep a conformance fit on the kit's small flights well under a second.
FAST_PARAMS: dict[str, dict] = {
    "iforest": {"n_estimators": 20},
    "kmeans": {"n_clusters": 4},
    "lstm_ae": {"window": 10, "hidden": 8, "epochs": 1, "max_train_windows": 128},
    "tcned": {"seq_len": 10, "epochs": 1, "max_train_windows": 128},
    "usad": {"seq_len": 10, "epochs": 1, "max_train_windows": 128},
    "deepsvdd_ts": {"seq_len": 10, "epochs": 1, "max_train_windows": 128},
    "dif_ts": {"seq_len": 10, "max_train_windows": 128, "model_params": {"n_ensemble": 2}},
}
#: Settings of the detection test: a little more training than the conformance settings.
DETECTION_PARAMS: dict[str, dict] = {
    **FAST_PARAMS,
    "iforest": {},
    "kmeans": {},
    "lstm_ae": {"window": 10, "hidden": 16, "epochs": 3, "max_train_windows": 512},
    "tcned": {"seq_len": 10, "epochs": 3, "max_train_windows": 512},
    "usad": {"seq_len": 10, "epochs": 3, "max_train_windows": 512},
    "deepsvdd_ts": {"seq_len": 10, "epochs": 3, "max_train_windows": 512},
    "dif_ts": {"seq_len": 10, "max_train_windows": 512, "model_params": {"n_ensemble": 4}},
}
#: The channels of the detection case: what the attack touches (position) and the rest of those
#: topics; on all 55 channels, the flight maximum of iforest, ecod, copod and hbos does not separate
#: this small case (docs/results-zoo.md).
POSITION_TOPICS = ("global_position_int", "local_position_ned", "gps_raw_int")
ROWS = 1500
#: Rows left out at the start of each flight (8 s), as the protocol leaves the ground before take-off out
#: (docs/protocol.md): before take-off the windows barely change, and LOF's density ratio explodes on
#: such near-duplicates (40 on the normal flights' row 12, 30 at the attack's peak: docs/results-zoo.md).
BURN_IN_ROWS = 400


# -- conformance -------------------------------------------------------------------------------------


def _conformance_cases():
    cases = []
    for name in ZOO:
        cases += detector_checks(registry._import_spec(registry.ZOO[name]), FAST_PARAMS.get(name, {}))
    return cases


@pytest.mark.parametrize("check", _conformance_cases(), ids=str)
def test_conformance(check):
    check()


def test_every_builtin_passes_through_the_conformance_kit():
    from test_detectors import CONFORMANCE_DETECTORS

    assert set(CONFORMANCE_DETECTORS) | set(ZOO) == set(registry.BUILTINS)
    assert len(registry.BUILTINS) >= 20


def test_all_stays_the_papers_eight_and_zoo_is_a_tag():
    from scart_bench.benchmark.selection import resolve_detectors

    every = [c.name for c in resolve_detectors(["all"], {})]  # and any entry-point plugin installed
    assert every[: len(registry.PAPER)] == list(registry.PAPER) and not set(every) & set(ZOO)
    assert [c.name for c in resolve_detectors(["zoo"], {})] == ZOO
    assert [c.name for c in resolve_detectors(["statistical,zoo,iforest"], {})] == ["statistical", *ZOO]
    assert [c.name for c in resolve_detectors(["paper"], {})] == list(registry.PAPER)


def test_a_run_file_names_the_zoo_by_its_tag_beside_names(tmp_path):
    from scart_bench.benchmark.config import read_run_file
    from scart_bench.benchmark.selection import resolve_detectors

    path = tmp_path / "run.toml"
    path.write_text('detectors = ["goad", "zoo"]\n', encoding="utf-8")
    assert [c.name for c in resolve_detectors(read_run_file(path)["detectors"], {})] == ["goad", *ZOO]


def test_detectors_command_lists_every_builtin_with_its_tag(capsys):
    from scart_bench.cli.main import main

    assert main(["detectors"]) == 0
    out = capsys.readouterr().out
    for name in registry.BUILTINS:
        tag = "zoo" if name in registry.ZOO else "paper"
        assert any(line.startswith(f"{name} ") and f"({tag})" in line for line in out.splitlines()), name
    assert main(["detectors", "--tag", "zoo"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines() if "built-in (" in line]
    assert listed == ZOO


# -- detection and equality with the libraries --------------------------------------------------------


@pytest.fixture(scope="module")
def case() -> tuple[list[pd.DataFrame], list[pd.DataFrame], pd.DataFrame, list[str]]:
    """4 training flights, 3 held-out normal flights, 1 attacked flight and the position channels."""
    from scart_bench.detectors.base import feature_columns

    train = normal_flights(4, seed=0, rows=ROWS)
    columns = [c for c in feature_columns(train)[0] if c.partition(".")[0] in POSITION_TOPICS]
    return train, normal_flights(3, seed=1, rows=ROWS), attacked_flight(seed=2, rows=ROWS), columns


_FITTED: dict[str, object] = {}


def fitted(name: str, case):
    if name not in _FITTED:
        train, _, _, columns = case
        _FITTED[name] = registry.make(name, columns=columns, **DETECTION_PARAMS.get(name, {})).fit(train)
    return _FITTED[name]


@pytest.mark.parametrize("name", ZOO)
def test_attacked_flight_scores_above_every_normal_flight(name, case):
    _, held_out, attacked, _ = case
    detector = fitted(name, case)
    attacked_score = flight_score(detector.score(attacked)[BURN_IN_ROWS:])
    normal_scores = [flight_score(detector.score(f)[BURN_IN_ROWS:]) for f in held_out]
    assert attacked_score > max(normal_scores), (attacked_score, normal_scores)


def _prepared(detector, flights: list[pd.DataFrame]) -> list[np.ndarray]:
    """The flights as the detector's ``_fit`` and ``_score`` see them (selected, standardised, filled)."""
    return [detector._standardise(detector._raw_matrix(f, detector.columns_)) for f in flights]


def _training_windows(detector, train) -> np.ndarray:
    raw = detector.train_matrix(_prepared(detector, train))
    return ((raw - detector.feature_mean_) / detector.feature_scale_).astype(np.float32)


def _sklearn_scores(name: str, detector, Ft: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The library's own scores of the windows ``F``, from a model fitted here on ``Ft``."""
    from sklearn.cluster import KMeans
    from sklearn.decomposition import PCA
    from sklearn.ensemble import IsolationForest
    from sklearn.neighbors import LocalOutlierFactor, NearestNeighbors

    p = detector.get_params()
    if name == "iforest":
        return -IsolationForest(n_estimators=p["n_estimators"], random_state=p["random_state"]).fit(Ft).score_samples(F)
    if name == "pca":
        model = PCA(n_components=p["n_components"], svd_solver="full").fit(Ft)
        return ((F.astype(np.float64) - model.inverse_transform(model.transform(F))) ** 2).sum(axis=1)
    if name == "kmeans":
        model = KMeans(n_clusters=p["n_clusters"], n_init=1, random_state=p["random_state"]).fit(Ft)
        return model.transform(F).min(axis=1)
    if name == "knn":
        return NearestNeighbors(n_neighbors=p["n_neighbors"]).fit(Ft).kneighbors(F)[0][:, -1]
    if name == "lof":
        return -LocalOutlierFactor(n_neighbors=p["n_neighbors"], novelty=True).fit(Ft).score_samples(F)
    if name == "hbos":
        from pyod.models.hbos import HBOS

        return HBOS(n_bins=p["n_bins"]).fit(Ft).decision_function(F)
    raise KeyError(name)


@pytest.mark.parametrize("name", ["iforest", "pca", "kmeans", "knn", "lof", "hbos"])
def test_window_adapter_scores_equal_the_librarys_own(name, case):
    train, _, attacked, _ = case
    detector = fitted(name, case)
    F = detector.features(_prepared(detector, [attacked])[0])
    expected = _sklearn_scores(name, detector, _training_windows(detector, train), F)
    np.testing.assert_allclose(detector.score(attacked), expected, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name", ["ecod", "copod"])
def test_empirical_tail_scores_equal_pyods_score_of_each_window_alone(name, case):
    """PyOD scores a batch transductively (the batch joins the ECDFs); one window alone is its score."""
    from pyod.models.copod import COPOD
    from pyod.models.ecod import ECOD

    train, _, attacked, _ = case
    detector = fitted(name, case)
    F = detector.features(_prepared(detector, [attacked])[0])
    model = (ECOD if name == "ecod" else COPOD)().fit(_training_windows(detector, train))
    ours = detector.score(attacked)
    rows = np.unique(np.r_[np.linspace(0, len(F) - 1, 12).astype(int), np.argmax(ours)])
    expected = [model.decision_function(F[i : i + 1])[0] for i in rows]
    np.testing.assert_allclose(ours[rows], expected, rtol=1e-6)


@pytest.mark.parametrize("name", ["tcned", "usad", "deepsvdd_ts", "dif_ts"])
def test_deepod_adapter_scores_equal_deepods_decision_function(name, case):
    """From the first full window on, a row's score is DeepOD's ``decision_function`` of the flight
    (its first 700 rows, the attack's start included, to keep the test short)."""
    attacked = case[2].iloc[:700]
    detector = fitted(name, case)
    X = _prepared(detector, [attacked])[0].astype(np.float32)
    model, L = detector.model_, detector.seq_len
    expected = np.asarray(model.decision_function(X))
    np.testing.assert_allclose(detector.score(attacked)[L - 1 :], expected[L - 1 :], rtol=1e-5, atol=1e-7)
