"""Adapters over DeepOD's time-series models (Xu et al., https://github.com/xuhongzuo/DeepOD).

DeepOD's time-series models take a series (rows, channels), cut it into windows of ``seq_len``
rows and score each window with the model; ``decision_function`` gives the row that ends a
window that window's score (and 0 to the first ``seq_len - 1`` rows). The adapters keep that and
make it causal from the first row: a flight is scored with ``seq_len - 1`` copies of its first
row in front (as the other built-ins pad their windows), so the score of row ``i`` is the
model's score of the window ending at ``i``. Each window is scored alone (the models score
windows independently), and a flight is scored in whole batches (the end padded with its last
row), so a window's float32 score does not depend on how many rows follow it.
``tests/test_zoo.py`` holds every adapter to the model's own ``decision_function``.

Training: the training flights, each padded the same way, are joined end to end and the model is
fitted on that series with DeepOD's ``stride`` chosen so that at most ``max_train_windows``
windows are used (the few windows across a join mix two flights). DeepOD's settings are kept
except where they do not run on a CPU in seconds: fewer epochs and smaller networks (each class
says which), and DeepSVDD-TS uses DeepOD's TCN network (its default Transformer network fails
with torch 2.x: DeepOD's layer lacks the ``is_causal`` argument). DeepOD reseeds the global
numpy / torch / ``random`` generators; the adapters restore them and the torch thread count
around every call (:func:`scart_bench.detectors.deepod_models.isolated_global_state`).

The models, with their papers:

- ``tcned``: TCN encoder-decoder, Bai, Kolter and Koltun, "An empirical evaluation of generic
  convolutional and recurrent networks for sequence modeling", 2018, as a reconstruction
  detector in Garg et al., "An evaluation of anomaly detection and diagnosis in multivariate time
  series", IEEE TNNLS 2021.
- ``usad``: Audibert et al., "USAD: unsupervised anomaly detection on multivariate time series",
  KDD 2020.
- ``deepsvdd_ts``: Ruff et al., "Deep one-class classification", ICML 2018, on windows through a
  temporal convolutional network.
- ``dif_ts``: Xu et al., "Deep isolation forest for anomaly detection", IEEE TKDE 2023.

Left out, measured on 2 CPU cores for issue 50: TimesNet (it picks its periods from the spectrum
averaged over a batch, so a window's score depends on the windows batched with it; scored one
window per batch to stay causal, it was by far the slowest here: one check scoring an 800-row
flight with DeepOD took 9 min on the shared 2 cores), AnomalyTransformer (its fixed 512-wide network
took 56 s for one epoch of 20 batches), TranAD (fails with torch 2.x: its encoder layer lacks
``is_causal``), COUTA (uses ``np.NAN``, gone in numpy 2).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
import torch

from scart_bench.detectors.base import MAX_WINDOW_ROWS, Detector, DetectorError
from scart_bench.detectors.deepod_models import DEEPOD_INSTALL, isolated_global_state
from scart_bench.detectors.statistical import pad_start

try:
    from deepod.models.time_series import USAD as _USAD
    from deepod.models.time_series import DeepIsolationForestTS as _DIF
    from deepod.models.time_series import DeepSVDDTS as _DeepSVDDTS
    from deepod.models.time_series import TcnED as _TcnED
except ImportError as exc:  # one clear line instead of a traceback
    raise DetectorError(f"the DeepOD time-series detectors (tcned, usad, deepsvdd_ts, dif_ts) need deepod, "
                        f"which is not installed ({exc}): {DEEPOD_INSTALL}") from exc

#: Windows per scoring call: a long flight is scored in chunks of about this many windows (whole
#: batches), which bounds the memory of DeepOD's window copies (windows x seq_len x channels).
_CHUNK_WINDOWS = 4096
#: What only training needs, dropped after fit so that it is not pickled with the detector.
_TRAINING_ATTRIBUTES = ("train_data", "train_label", "train_loader", "test_loader", "decision_scores_",
                        "labels_", "x_reduced_lst", "score_lst")


class _DeepODSeriesDetector(Detector):
    """Causal adapter over a DeepOD time-series model (shared by the zoo's DeepOD built-ins).

    Parameters
    ----------
    seq_len : int
        Rows per window (25 = 0.5 s at 50 Hz); the score of a row is that of the window ending at it.
    epochs : int
        Training epochs.
    batch_size : int
        Mini-batch size for training and scoring.
    lr : float
        Learning rate.
    max_train_windows : int
        Cap on training windows (DeepOD's ``stride`` is raised to keep under it).
    model_params : dict or None
        Extra keyword arguments of the DeepOD model, over the adapter's defaults (see the class).
    device : str or None
        Torch device; None for "cuda" when available, else "cpu".
    n_threads : int
        Torch CPU threads while fitting and scoring; 0 for the job's share of the cores.
    columns : list of str or None
        Sensor columns to use; None for the feature rule's columns.
    random_state : int
        Seed of the model initialisation and the training shuffles.

    Attributes
    ----------
    model_ : deepod model
        The fitted DeepOD model (training data stripped).
    n_train_windows_ : int
        Windows the model was trained on.
    """

    #: parameters counted in rows: a run refuses values not shorter than its shortest flight
    window_params = ("seq_len",)
    #: The DeepOD model class.
    _model_class: ClassVar[type]
    #: Model keyword arguments that differ from DeepOD's defaults.
    _model_defaults: ClassVar[dict[str, Any]] = {}
    #: Whether the model has a learning rate and epochs (DIF's networks are random, not trained).
    _trained: ClassVar[bool] = True

    def __init__(self, seq_len: int = 25, epochs: int = 5, batch_size: int = 64, lr: float = 1e-3,
                 max_train_windows: int = 2000, model_params: dict[str, Any] | None = None,
                 device: str | None = None, n_threads: int = 1, columns: list[str] | None = None,
                 random_state: int = 0):
        self.seq_len = seq_len
        self.epochs = epochs
        self.batch_size = batch_size
        self.lr = lr
        self.max_train_windows = max_train_windows
        self.model_params = model_params
        self.device = device
        self.n_threads = n_threads
        self.columns = columns
        self.random_state = random_state

    def _check_params(self) -> None:
        if not 2 <= int(self.seq_len) <= MAX_WINDOW_ROWS:
            raise DetectorError(f"{self.name}: seq_len must be in 2..{MAX_WINDOW_ROWS:,} rows, got {self.seq_len!r}")
        for key in ("epochs", "batch_size", "max_train_windows"):
            if int(getattr(self, key)) < 1:
                raise DetectorError(f"{self.name}: {key} must be a positive integer, got {getattr(self, key)!r}")
        if int(self.n_threads) < 0:
            raise DetectorError(f"{self.name}: n_threads must be 0 (the job's share of the cores) or more, "
                                f"got {self.n_threads!r}")

    def _padded(self, X: np.ndarray) -> np.ndarray:
        """``X`` as float32 with ``seq_len - 1`` copies of its first row in front."""
        return np.ascontiguousarray(pad_start(np.asarray(X, dtype=np.float32), int(self.seq_len) - 1))

    def training_series(self, X_list: list[np.ndarray]) -> np.ndarray:
        """The series the model is fitted on: every prepared flight padded, joined end to end."""
        return np.concatenate([self._padded(x) for x in X_list], axis=0)

    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        series = self.training_series(X_list)
        L = int(self.seq_len)
        n_windows = series.shape[0] - L + 1
        stride = max(1, math.ceil(n_windows / int(self.max_train_windows)))
        device = self.device or ("cuda" if torch.cuda.is_available() else "cpu")
        kwargs = {"seq_len": L, "stride": stride, "batch_size": int(self.batch_size), "device": device,
                  "verbose": 0, "random_state": int(self.random_state)}
        if self._trained:
            kwargs.update(epochs=int(self.epochs), lr=float(self.lr))
        kwargs.update({**self._model_defaults, **(self.model_params or {})})
        with isolated_global_state(int(self.n_threads)):
            try:
                model = self._model_class(**kwargs)
            except TypeError as exc:
                raise DetectorError(f"{self.name}: invalid model_params {self.model_params!r}: {exc}") from exc
            model.fit(series)
        for attr in _TRAINING_ATTRIBUTES:
            if hasattr(model, attr):
                setattr(model, attr, [] if attr in ("x_reduced_lst", "score_lst") else None)
        self.model_ = model
        self.history_rows_ = L
        self.n_train_windows_ = int(len(range(0, n_windows, stride)))

    def library_scores(self, series: np.ndarray) -> np.ndarray:
        """The model's own scores of the windows of ``series`` (one per window, in order)."""
        return np.asarray(self.model_.decision_function(series), dtype=np.float64)[int(self.seq_len) - 1:]

    def _scoring_batch(self) -> int:
        return int(getattr(self.model_, "batch_size", self.batch_size))

    def _score(self, X: np.ndarray) -> np.ndarray:
        L, n = int(self.seq_len), X.shape[0]
        b = self._scoring_batch()
        series = self._padded(X)
        series = np.concatenate([series, np.repeat(series[-1:], (-n) % b, axis=0)], axis=0)  # whole batches
        chunk = b * max(1, _CHUNK_WINDOWS // b)
        out = []
        with isolated_global_state(int(self.n_threads)), torch.no_grad():
            for lo in range(0, series.shape[0] - L + 1, chunk):
                out.append(self.library_scores(series[lo : lo + chunk + L - 1]))
        return np.concatenate(out)[:n]

    def _score_last(self, X: np.ndarray) -> float:
        """The window ending at the last row, scored in a batch as :meth:`_score` scores it."""
        return float(self._score(X[-int(self.seq_len):])[-1])


class TcnED(_DeepODSeriesDetector):
    """TCN encoder-decoder (Bai et al. 2018; Garg et al. 2021): error reconstructing a window's last row.

    DeepOD ``TcnED`` with its defaults (``model_params``: ``rep_dim``, ``hidden_dims``,
    ``kernel_size``, ``dropout``); 5 epochs instead of 10.
    """

    name = "tcned"
    relative_cost = 222.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "TCN encoder-decoder (Bai et al. 2018, DeepOD TcnED): last-row reconstruction error"
    _model_class = _TcnED


class USADModel(_USAD):
    """DeepOD's USAD, scoring one batch as well as several (DeepOD stacks all batches but the last,
    which fails when there is only one); the same per-window arithmetic."""

    def decision_function(self, x, labels=None):
        from deepod.utils.utility import get_sub_seqs
        from torch.utils.data import DataLoader, TensorDataset

        seqs = get_sub_seqs(x, seq_len=self.seq_len, stride=1)
        loader = DataLoader(TensorDataset(torch.from_numpy(seqs).float().view([seqs.shape[0], self.w_size])),
                            batch_size=self.batch_size, shuffle=False, num_workers=0)
        scores = torch.cat([r.flatten() for r in self.testing(loader)]).detach().cpu().numpy()
        return np.hstack([np.zeros(x.shape[0] - scores.shape[0]), scores])


class USAD(_DeepODSeriesDetector):
    """USAD (Audibert et al. 2020): reconstruction errors of two adversarially trained autoencoders.

    DeepOD ``USAD``; ``hidden_dims`` 4 (DeepOD: 100; the latent size is ``seq_len * hidden_dims``,
    2,500 at 25 rows with DeepOD's value) and no validation split (DeepOD holds out 20 % only
    to print a loss).
    """

    name = "usad"
    relative_cost = 176.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "USAD (Audibert et al. 2020, DeepOD): adversarial autoencoders' reconstruction error"
    _model_class = USADModel
    _model_defaults = {"hidden_dims": 4, "train_val_pc": 0.0}


class DeepSVDDTS(_DeepODSeriesDetector):
    """Deep SVDD on windows (Ruff et al. 2018): distance of a window's TCN embedding to a centre.

    DeepOD ``DeepSVDDTS`` with ``network="TCN"``, ``hidden_dims="32"`` and ``rep_dim`` 32 (DeepOD:
    a Transformer, which fails with torch 2.x) and the adapter's learning rate (1e-3; DeepOD 1e-5
    over 100 epochs).
    """

    name = "deepsvdd_ts"
    relative_cost = 46.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "Deep SVDD (Ruff et al. 2018, DeepOD DeepSVDDTS) on windows through a TCN"
    _model_class = _DeepSVDDTS
    _model_defaults = {"network": "TCN", "hidden_dims": "32", "rep_dim": 32}


class DIFTS(_DeepODSeriesDetector):
    """Deep Isolation Forest (Xu et al. 2023): isolation forests on random dilated-convolution embeddings.

    DeepOD ``DeepIsolationForestTS``; 8 ensemble members instead of 50 and ``hidden_dims="32"``,
    ``rep_dim`` 32 (DeepOD: "100,50", 128). Its networks are random, not trained: ``epochs`` and
    ``lr`` are unused.
    """

    name = "dif_ts"
    relative_cost = 515.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "Deep Isolation Forest (Xu et al. 2023, DeepOD) on windows: forests on random conv embeddings"
    _model_class = _DIF
    _model_defaults = {"n_ensemble": 8, "hidden_dims": "32", "rep_dim": 32}
    _trained = False
