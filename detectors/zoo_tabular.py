"""Classic fast baselines of the zoo on window features: scikit-learn and PyOD models, ECOD / COPOD.

Every row is scored by the window of the last ``window`` rows that ends at it, flattened as in
the DeepOD tabular adapters (:mod:`scart_bench.detectors.deepod_models`): the means of
``segments`` equal parts of the window per channel and, with ``window_stats``, each channel's
standard deviation and that of its row-to-row increments (a GPS noise attack shows in those).
Rows before a full window see the first row repeated, so the score of row ``i`` depends only on
rows ``0..i``. The features are standardised with the training windows' statistics; training
uses windows every ``stride`` rows, at most ``max_train_windows`` (a deterministic subsample).
The model then scores each window alone, so scores are causal and stream through the default
trailing window.

The models, with their papers (each the library's own estimator, default settings unless named):

- ``iforest``: Liu, Ting and Zhou, "Isolation forest", ICDM 2008 (scikit-learn ``IsolationForest``).
- ``pca``: Shyu et al., "A novel anomaly detection scheme based on principal component
  classifier", ICDM 2003 workshop (reconstruction error of scikit-learn ``PCA``).
- ``kmeans``: distance to the nearest k-means centre (scikit-learn ``KMeans``); as a detector, e.g.
  Münz, Li and Carle, "Traffic anomaly detection using k-means clustering", 2007.
- ``knn``: Ramaswamy, Rastogi and Shim, "Efficient algorithms for mining outliers from large data
  sets", SIGMOD 2000 (distance to the k-th nearest training window, scikit-learn ``NearestNeighbors``).
- ``lof``: Breunig et al., "LOF: identifying density-based local outliers", SIGMOD 2000
  (scikit-learn ``LocalOutlierFactor(novelty=True)``).
- ``ecod``: Li et al., "ECOD: unsupervised outlier detection using empirical cumulative
  distribution functions", TKDE 2022 (PyOD ``ECOD``'s score of one window alone, computed here:
  PyOD's own scores a batch transductively, see :class:`_EmpiricalTail`).
- ``copod``: Li et al., "COPOD: copula-based outlier detection", ICDM 2020 (likewise PyOD ``COPOD``).
- ``hbos``: Goldstein and Dengel, "Histogram-based outlier score (HBOS)", KI 2012 (PyOD ``HBOS``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from scart_bench.detectors._kernels import window_features
from scart_bench.detectors.base import MAX_WINDOW_ROWS, Detector, DetectorError
from scart_bench.detectors.statistical import pad_start

#: Floor of a window feature's training spread (as in the DeepOD adapters).
_MIN_FEATURE_SCALE = 0.01


def window_matrix(X: np.ndarray, window: int, segments: int, step: int = 1, stats: bool = True) -> np.ndarray:
    """Feature vectors (float32) of the windows of ``window`` rows ending at rows 0, step, 2 step, ...

    Rows before a full window see the first row repeated (causal padding).
    """
    w, k = int(window), int(segments)
    padded = np.ascontiguousarray(pad_start(np.asarray(X, dtype=np.float32), w - 1))
    bounds = np.linspace(0, w, k + 1).round().astype(np.int64)
    return window_features(padded, w, bounds, int(step), bool(stats))


class WindowFeatureDetector(Detector):
    """Base of the window-feature adapters: a tabular model scores each row's trailing window.

    Subclasses set ``name``, ``description``, ``relative_cost`` and implement ``_make_model()``
    (the library estimator, unfitted) and ``_model_scores(model, F)`` (higher = more anomalous).

    Parameters
    ----------
    window : int
        Rows per window (25 = 0.5 s at 50 Hz); the score of a row is that of the window ending at it.
    segments : int
        The window is flattened as the means of this many equal segments of it.
    stride : int
        Rows between consecutive training windows.
    max_train_windows : int
        Cap on training windows; more are subsampled deterministically with ``random_state``.
    window_stats : bool
        Append each channel's standard deviation over the window and that of its increments.
    columns : list of str or None
        Sensor columns to use; None for the feature rule's columns.
    random_state : int
        Seed of the window subsample and of the model.

    Attributes
    ----------
    model_ : estimator
        The fitted library model.
    feature_mean_, feature_scale_ : ndarray (features,)
        Standardisation of the window features, learned on the training windows.
    n_train_windows_ : int
        Windows the model was trained on.
    """

    #: parameters counted in rows: a run refuses values not shorter than its shortest flight
    window_params = ("window",)

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, columns: list[str] | None = None, random_state: int = 0):
        self.window = window
        self.segments = segments
        self.stride = stride
        self.max_train_windows = max_train_windows
        self.window_stats = window_stats
        self.columns = columns
        self.random_state = random_state

    # -- for subclasses --------------------------------------------------------------------------
    def _make_model(self) -> Any:
        raise NotImplementedError

    def _model_scores(self, model: Any, F: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    # -- features --------------------------------------------------------------------------------
    def _check_params(self) -> None:
        if not 1 <= int(self.window) <= MAX_WINDOW_ROWS:
            raise DetectorError(f"{self.name}: window must be in 1..{MAX_WINDOW_ROWS:,} rows, got {self.window!r}")
        if not 1 <= int(self.segments) <= int(self.window):
            raise DetectorError(f"{self.name}: segments must be in 1..window, got {self.segments!r}")
        for key in ("stride", "max_train_windows"):
            if int(getattr(self, key)) < 1:
                raise DetectorError(f"{self.name}: {key} must be a positive integer, got {getattr(self, key)!r}")

    def _stats(self) -> bool:
        return bool(self.window_stats) and int(self.window) >= 2

    def train_matrix(self, X_list: list[np.ndarray]) -> np.ndarray:
        """The raw training windows of prepared flights (before standardising), subsampled."""
        train = np.concatenate([window_matrix(x, self.window, self.segments, int(self.stride), self._stats())
                                for x in X_list], axis=0)
        cap = int(self.max_train_windows)
        if train.shape[0] > cap:
            train = train[np.sort(self._rng().choice(train.shape[0], size=cap, replace=False))]
        return train

    def features(self, X: np.ndarray) -> np.ndarray:
        """Standardised features (float32) of the window ending at every row of prepared ``X``."""
        raw = window_matrix(X, self.window, self.segments, 1, self._stats())
        return ((raw - self.feature_mean_) / self.feature_scale_).astype(np.float32)

    # -- Detector hooks ----------------------------------------------------------------------------
    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        train = self.train_matrix(X_list)
        self.history_rows_ = int(self.window)  # the window ending at a row decides its score
        self.feature_mean_ = train.mean(axis=0)
        self.feature_scale_ = np.maximum(train.std(axis=0), _MIN_FEATURE_SCALE)
        F = ((train - self.feature_mean_) / self.feature_scale_).astype(np.float32)
        self.model_ = self._make_model().fit(F)
        self.n_train_windows_ = int(F.shape[0])

    def _score(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(self._model_scores(self.model_, self.features(X)), dtype=np.float64)

    def _score_last(self, X: np.ndarray) -> float:
        """Only the window ending at the last row (the model scores windows one by one)."""
        return float(self._score(X[-int(self.window):])[-1])


# -- scikit-learn ----------------------------------------------------------------------------------


class IForest(WindowFeatureDetector):
    """Isolation Forest (Liu, Ting and Zhou 2008): how quickly random splits isolate a window.

    scikit-learn's ``IsolationForest``; the score is ``-score_samples`` (higher = easier to isolate).
    ``n_estimators`` and ``max_samples`` are its parameters.
    """

    name = "iforest"
    relative_cost = 28.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "Isolation Forest (Liu et al. 2008, scikit-learn) on windows: path length of random splits"

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_estimators: int = 100, max_samples: int | str = "auto",
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_estimators = n_estimators
        self.max_samples = max_samples

    def _make_model(self):
        from sklearn.ensemble import IsolationForest

        return IsolationForest(n_estimators=int(self.n_estimators), max_samples=self.max_samples,
                               random_state=int(self.random_state), n_jobs=1)

    def _model_scores(self, model, F):
        return -model.score_samples(F)


class PCAReconstruction(WindowFeatureDetector):
    """PCA reconstruction error (Shyu et al. 2003): squared distance of a window to the principal subspace.

    scikit-learn's ``PCA`` with ``n_components`` (a fraction: the explained variance kept).
    """

    name = "pca"
    relative_cost = 10.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "PCA reconstruction error (Shyu et al. 2003, scikit-learn) on windows"

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_components: float | int = 0.95,
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_components = n_components

    def _make_model(self):
        from sklearn.decomposition import PCA

        return PCA(n_components=self.n_components, svd_solver="full", random_state=int(self.random_state))

    def _model_scores(self, model, F):
        recon = model.inverse_transform(model.transform(F))
        return np.sum((F.astype(np.float64) - recon) ** 2, axis=1)


class KMeansDistance(WindowFeatureDetector):
    """Distance to the nearest k-means centre of the training windows (scikit-learn ``KMeans``)."""

    name = "kmeans"
    relative_cost = 10.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "distance to the nearest k-means centre (scikit-learn) of the training windows"

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_clusters: int = 16,
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_clusters = n_clusters

    def _check_params(self) -> None:
        super()._check_params()
        if int(self.n_clusters) < 1:
            raise DetectorError(f"{self.name}: n_clusters must be a positive integer, got {self.n_clusters!r}")

    def _make_model(self):
        from sklearn.cluster import KMeans

        return KMeans(n_clusters=int(self.n_clusters), n_init=1, random_state=int(self.random_state))

    def _model_scores(self, model, F):
        return model.transform(F).min(axis=1)


class KNNDistance(WindowFeatureDetector):
    """kNN distance (Ramaswamy et al. 2000): distance to the ``n_neighbors``-th nearest training window.

    scikit-learn's ``NearestNeighbors`` (exact search).
    """

    name = "knn"
    relative_cost = 41.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "distance to the k-th nearest training window (Ramaswamy et al. 2000, scikit-learn)"

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_neighbors: int = 5,
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_neighbors = n_neighbors

    def _check_params(self) -> None:
        super()._check_params()
        if int(self.n_neighbors) < 1:
            raise DetectorError(f"{self.name}: n_neighbors must be a positive integer, got {self.n_neighbors!r}")

    def _make_model(self):
        from sklearn.neighbors import NearestNeighbors

        return NearestNeighbors(n_neighbors=int(self.n_neighbors), algorithm="brute")

    def _model_scores(self, model, F):
        k = min(int(self.n_neighbors), self.n_train_windows_)
        return model.kneighbors(F, n_neighbors=k)[0][:, -1]


class LOF(WindowFeatureDetector):
    """Local Outlier Factor (Breunig et al. 2000): a window's density relative to its neighbours'.

    scikit-learn's ``LocalOutlierFactor(novelty=True)``; the score is ``-score_samples``.
    """

    name = "lof"
    relative_cost = 35.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "Local Outlier Factor (Breunig et al. 2000, scikit-learn) on windows"

    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_neighbors: int = 20,
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_neighbors = n_neighbors

    def _check_params(self) -> None:
        super()._check_params()
        if int(self.n_neighbors) < 1:
            raise DetectorError(f"{self.name}: n_neighbors must be a positive integer, got {self.n_neighbors!r}")

    def _make_model(self):
        from sklearn.neighbors import LocalOutlierFactor

        return LocalOutlierFactor(n_neighbors=int(self.n_neighbors), novelty=True, algorithm="brute")

    def _model_scores(self, model, F):
        return -model.score_samples(F)


# -- PyOD ------------------------------------------------------------------------------------------

#: How to install PyOD (a dependency of scart-bench; its own dependencies, numpy, scipy, scikit-learn,
#: numba, joblib and matplotlib, are scart-bench's too, and it needs no torch).
PYOD_INSTALL = "pip install pyod"


def _pyod_hbos() -> type:
    try:
        from pyod.models.hbos import HBOS as _HBOS
    except ImportError as exc:
        raise DetectorError(f"the detector hbos needs PyOD, which is not installed ({exc}): {PYOD_INSTALL}") from exc
    return _HBOS


def _tail_counts(sorted_train: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row and feature of ``F``: training values ``<=`` and ``>=`` it (columns of ``sorted_train`` sorted)."""
    below = np.empty(F.shape, dtype=np.float64)
    above = np.empty(F.shape, dtype=np.float64)
    n = sorted_train.shape[0]
    for j in range(F.shape[1]):
        below[:, j] = np.searchsorted(sorted_train[:, j], F[:, j], side="right")
        above[:, j] = n - np.searchsorted(sorted_train[:, j], F[:, j], side="left")
    return below, above


class _EmpiricalTail(WindowFeatureDetector):
    """ECOD / COPOD scored inductively: each window against the training windows' empirical tails.

    PyOD's ``ECOD`` and ``COPOD`` are transductive: ``decision_function(X)`` builds the empirical
    CDFs from the training windows *and every row of X*, so a row's score depends on the rows
    scored with it (later rows too: not causal) and costs a sort of all of them. This class gives
    every window the score PyOD gives it when scored alone, ``decision_function(x[None])``: the
    tail probabilities count the training windows and the window itself, and the skewness whose
    sign picks the tail is that of the training windows plus it (its third central moment, from
    the training sums). ``tests/test_zoo.py`` holds it to PyOD's own scores window by window.
    One difference: a feature constant in training and in the window has a skewness of 0 here,
    where PyOD's is NaN (a NaN score).

    Attributes: ``sorted_train_`` (training windows, each feature sorted) and ``power_sums_``
    (sums of the training values to the powers 1, 2, 3, per feature) beside the base's.
    """

    #: "ecod" or "copod": how the tails are combined.
    _rule: str = "ecod"

    def _make_model(self):  # no library model: the training tails are the model
        return None

    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        train = self.train_matrix(X_list)
        self.history_rows_ = int(self.window)
        self.feature_mean_ = train.mean(axis=0)
        self.feature_scale_ = np.maximum(train.std(axis=0), _MIN_FEATURE_SCALE)
        F = ((train - self.feature_mean_) / self.feature_scale_).astype(np.float32).astype(np.float64)
        self.sorted_train_ = np.sort(F, axis=0)
        self.power_sums_ = np.stack([F.sum(axis=0), (F * F).sum(axis=0), (F * F * F).sum(axis=0)])
        self.n_train_windows_ = int(F.shape[0])
        self.model_ = None

    def _skew_sign(self, F: np.ndarray) -> np.ndarray:
        """Sign of the skewness of each feature over the training windows plus the row's window."""
        n = self.n_train_windows_ + 1
        s1, s2, s3 = (self.power_sums_[i] + F ** (i + 1) for i in range(3))
        mu = s1 / n
        m2 = s2 / n - mu * mu
        m3 = s3 / n - 3 * mu * s2 / n + 2 * mu ** 3
        return np.where(m2 > 1e-12, np.sign(m3), 0.0)

    def _score(self, X: np.ndarray) -> np.ndarray:
        F = self.features(X).astype(np.float64)
        n = self.n_train_windows_ + 1
        below, above = _tail_counts(self.sorted_train_, F)
        u_l = -np.log((below + 1) / n)
        u_r = -np.log((above + 1) / n)
        skew = self._skew_sign(F)
        u_skew = u_l * -1 * np.sign(skew - 1) + u_r * np.sign(skew + 1)
        if self._rule == "ecod":
            o = np.maximum(np.maximum(u_l, u_r), u_skew)
        else:
            o = np.maximum(u_skew, (u_l + u_r) / 2)
        return o.sum(axis=1)


class ECOD(_EmpiricalTail):
    """ECOD (Li et al. 2022): how far out in the empirical tails of the training windows each feature lies.

    The sum over features of the negative log tail probability (left, right, or the one the
    skewness points to, whichever is largest), as PyOD's ``ECOD`` scores one window alone.
    """

    name = "ecod"
    relative_cost = 115.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "ECOD (Li et al. 2022) on windows: empirical tail probability of every feature, as PyOD scores one"
    _rule = "ecod"


class COPOD(_EmpiricalTail):
    """COPOD (Li et al. 2020): empirical-copula tail probability of a window, as PyOD's ``COPOD`` scores one."""

    name = "copod"
    relative_cost = 102.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "COPOD (Li et al. 2020) on windows: empirical-copula tail probability, as PyOD scores one"
    _rule = "copod"


class HBOS(WindowFeatureDetector):
    """HBOS (Goldstein and Dengel 2012): negative log density of per-feature histograms (PyOD ``HBOS``)."""

    name = "hbos"
    relative_cost = 12.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "HBOS (Goldstein & Dengel 2012, PyOD) on windows: per-feature histogram density"
    def __init__(self, window: int = 25, segments: int = 5, stride: int = 5, max_train_windows: int = 5000,
                 window_stats: bool = True, n_bins: int = 10,
                 columns: list[str] | None = None, random_state: int = 0):
        super().__init__(window, segments, stride, max_train_windows, window_stats, columns, random_state)
        self.n_bins = n_bins

    def _make_model(self):
        return _pyod_hbos()(n_bins=int(self.n_bins))

    def _model_scores(self, model, F):
        return model.decision_function(F)
