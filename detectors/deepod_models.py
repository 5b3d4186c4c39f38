"""Adapters over the tabular models of DeepOD (Xu et al., https://github.com/xuhongzuo/DeepOD).

Each row is scored by the window of the last ``window`` rows that ends at it. The window is
flattened into one feature vector: the means of ``segments`` equal parts of it for every
channel (a piecewise aggregate approximation; ``segments = window`` keeps every row) plus, with
``window_stats``, each channel's standard deviation and that of its row-to-row increments (the
spread and noise level the means average out). Features are standardised with the training
windows' statistics, since the DeepOD networks expect comparable input scales. Rows before a
full window see the first row repeated, so the score of row ``i`` depends only on rows
``0..i``. Training uses windows every ``stride`` rows of the normal flights, at most
``max_train_windows`` of them (a deterministic subsample). DeepOD's published settings are kept
(networks, batch size 64, learning rate 1e-3) except for fewer epochs (10 instead of 100) and,
for GOAD, fewer transformations, to fit in seconds on a CPU.

The models, with their papers:

- DeepSVDD: Ruff et al., "Deep one-class classification", ICML 2018.
- RDP: Wang et al., "Unsupervised representation learning by predicting random distances",
  IJCAI 2020.
- RCA: Liu et al., "RCA: a deep collaborative autoencoder approach for anomaly detection",
  IJCAI 2021.
- GOAD: Bergman and Hoshen, "Classification-based anomaly detection for general data",
  ICLR 2020.
- NeuTraL: Qiu et al., "Neural transformation learning for deep anomaly detection beyond
  images", ICML 2021.

DeepOD 0.4.1 needs three changes to score causally and reproducibly, made in small private
subclasses: RDP is scored by the gap between the learned and the random projection of each
sample alone, as in the RDP authors' code (DeepOD also pairs each sample with a random other one
of its batch); RCA is scored without dropout (DeepOD averages random dropout masks); GOAD
computes its transformation centres once after training (DeepOD recomputes them from shuffled
batches at every call). DeepOD also reseeds the global numpy / torch / ``random`` generators;
the adapters save and restore them, and the torch thread count, around every call.

Scoring skips DeepOD's per-row data loader and, for GOAD, computes the transformations in one
float32 product (to float32 rounding of DeepOD's) and the distance step a few windows at a time
(the same bits): ``tests/test_job_threads.py`` holds every model to DeepOD's own scores.
"""

from __future__ import annotations

import contextlib
import os
import random
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
import torch
from torch.utils.data import DataLoader

from scart_bench.detectors._kernels import window_features
from scart_bench.detectors.base import Detector, DetectorError
from scart_bench.detectors.statistical import pad_start

#: How to install DeepOD: its metadata pins torch<1.13.1, so it goes in without its dependencies
#: (numpy, scipy, scikit-learn, pandas, torch and tqdm come with scart-bench).
DEEPOD_INSTALL = "pip install --no-deps deepod==0.4.1"

try:
    from deepod.core.base_model import BaseDeepAD
    from deepod.models.tabular import GOAD as _DeepODGOAD
    from deepod.models.tabular import RCA as _DeepODRCA
    from deepod.models.tabular import RDP as _DeepODRDP
    from deepod.models.tabular import DeepSVDD as _DeepODDeepSVDD
    from deepod.models.tabular import NeuTraL as _DeepODNeuTraL
except ImportError as exc:  # one clear line instead of a traceback, for every DeepOD detector
    raise DetectorError(f"the DeepOD detectors (deepsvdd, rdp, rca, goad, neutral) need deepod, which is not "
                        f"installed ({exc}): {DEEPOD_INSTALL}") from exc

#: Floor of a feature's training spread, in units of the channel's standard deviation: keeps
#: features that barely vary in training (a still channel's noise level) from exploding.
_MIN_FEATURE_SCALE = 0.01
#: Windows per step of GOAD's distance computation: 32 x 32 x 32 x 8 float32 (1 MB) stays in a
#: core's cache.
_DISTANCE_CHUNK = 32

# -- DeepOD models made causal and reproducible ------------------------------------------------


class _RDPModel(_DeepODRDP):
    """RDP scored per sample: mean squared gap between the learned and the random projection."""

    def inference_forward(self, batch_x, net, criterion):
        x = batch_x.float().to(self.device)
        z = net(x)
        return z, torch.mean((z - criterion.rp_net(x)) ** 2, dim=1)


class _RCAModel(_DeepODRCA):
    """RCA scored with dropout off (the expectation of DeepOD's random dropout ensemble)."""

    def _inference(self):
        return BaseDeepAD._inference(self)


class _GOADModel(_DeepODGOAD):
    """GOAD whose transformation centres are computed once, right after training."""

    def training_prepare(self, X, y):
        self.rep_means = None
        return super().training_prepare(X, y)

    def inference_prepare(self, X):
        if self.rep_means is None:  # first call, inside fit: compute the centres
            return super().inference_prepare(X)
        self.net.eval()
        return DataLoader(self.transform(X), batch_size=self.batch_size, shuffle=False)

    def inference_forward(self, batch_x, net, criterion):
        """DeepOD's GOAD score of a batch, bit for bit, about 6x faster on a CPU.

        DeepOD squares the gaps between every transformation's representation and every centre
        as one (batch, n_trans, n_trans, rep) tensor: 16 MB at 512 windows, which leaves the
        core's cache, so the step is memory-bound and was most of GOAD's scoring. Here the same
        tensor operations run on ``_DISTANCE_CHUNK`` windows at a time (each window's score
        depends on its own rows only). The network's classification head is skipped: its output
        is not used for scoring, only its first step, which DeepOD applies in place to the
        representation (a LeakyReLU), is kept.
        """
        head_act = net.head[0]
        if not isinstance(head_act, torch.nn.LeakyReLU):  # another DeepOD network: its own code
            return super().inference_forward(batch_x, net, criterion)
        rep = head_act(net.enc(batch_x.float().to(self.device))).permute(0, 2, 1)
        scores = []
        for lo in range(0, rep.shape[0], _DISTANCE_CHUNK):
            diffs = rep[lo : lo + _DISTANCE_CHUNK].unsqueeze(2) - self.rep_means
            diffs = (diffs * diffs).sum(-1)  # DeepOD: ** 2, the same product
            diffs = torch.max(diffs, self.eps * torch.ones_like(diffs))
            logp = torch.nn.functional.log_softmax(-diffs, dim=2)
            s = -torch.diagonal(logp, 0, 1, 2)  # contiguous first, as DeepOD sums it
            scores.append(s.sum(1))
        return rep, torch.cat(scores)

    def transform(self, X: np.ndarray) -> torch.Tensor:
        """Every affine transformation of every row, (rows, trans_dim, n_trans) float32.

        One float32 matrix product with the transformations side by side. DeepOD multiplies in
        float64, one product per transformation, and rounds the result to float32 for its network;
        the float32 product agrees with that to float32 rounding (relative ~1e-6) and is ~7x
        faster, which makes it most of GOAD's scoring time saved. Training keeps DeepOD's products.
        """
        weights = self.__dict__.get("_stacked_weights")
        if weights is None:  # (features, n_trans * trans_dim), transformation-major columns
            weights = np.transpose(self.affine_weights, (1, 0, 2)).reshape(X.shape[1], -1)
            weights = np.ascontiguousarray(weights, dtype=np.float32)
            self.__dict__["_stacked_weights"] = weights
        x_trans = (np.asarray(X, dtype=np.float32) @ weights).reshape(X.shape[0], self.n_trans, -1)
        return torch.from_numpy(np.ascontiguousarray(x_trans.transpose(0, 2, 1)))


def _model_scores(model: BaseDeepAD, X: np.ndarray, batch_size: int) -> np.ndarray:
    """DeepOD's ``decision_function`` scores of the rows of ``X``, in batches of ``batch_size``.

    The same batches and the same ``inference_forward`` as DeepOD, without its per-row data
    loader and without collecting the representations it also returns (unused here).
    """
    data = model.inference_prepare(X).dataset  # also what the model sets up for inference
    data = data if isinstance(data, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(X))
    model.net.eval()
    out = []
    with torch.no_grad():
        for lo in range(0, data.shape[0], batch_size):
            out.append(model.inference_forward(data[lo : lo + batch_size], model.net, model.criterion)[1])
    return torch.cat(out).cpu().numpy().astype(np.float64)


# -- window features ---------------------------------------------------------------------------


# -- isolation of global state ---------------------------------------------------------------


def _job_threads() -> int:
    """The job's share of the cores: ``OMP_NUM_THREADS`` as the benchmark sets it for each job
    (``cpu count // --jobs``), else every core."""
    try:
        return max(1, int(os.environ.get("OMP_NUM_THREADS", "")))
    except ValueError:
        return max(1, os.cpu_count() or 1)



@contextlib.contextmanager
def isolated_global_state(n_threads: int) -> Iterator[None]:
    """Run DeepOD code with ``n_threads`` torch threads (0: as the process is set, i.e. the job's share
    of the cores) and restore every global RNG afterwards."""
    np_state = np.random.get_state()
    py_state = random.getstate()
    torch_state = torch.get_rng_state()
    cuda_states = torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None
    threads = torch.get_num_threads()
    torch.set_num_threads(n_threads if n_threads > 0 else _job_threads())
    try:
        yield
    finally:
        torch.set_num_threads(threads)
        np.random.set_state(np_state)
        random.setstate(py_state)
        torch.set_rng_state(torch_state)
        if cuda_states is not None:
            torch.cuda.set_rng_state_all(cuda_states)


# -- the shared adapter ------------------------------------------------------------------------


class _DeepODDetector(Detector):
    """Windowed adapter over a DeepOD tabular model (shared by the five built-ins).

    Parameters
    ----------
    window : int
        Rows per window (25 = 0.5 s at 50 Hz); the score of a row is that of the window ending at it.
    segments : int
        The window is flattened as the means of this many equal segments of it (piecewise
        aggregate approximation); ``segments = window`` flattens every row.
    stride : int
        Rows between consecutive training windows.
    epochs : int
        Training epochs.
    batch_size : int
        Mini-batch size for training and scoring.
    lr : float
        Adam learning rate.
    max_train_windows : int
        Cap on training windows; more are subsampled deterministically with ``random_state``.
    window_stats : bool
        Append each channel's standard deviation over the window and that of its row-to-row
        increments (the spread and the noise level that the segment means average out).
    model_params : dict or None
        Extra keyword arguments of the DeepOD model, over the adapter's defaults (see the class).
    device : str or None
        Torch device; None for "cuda" when available, else "cpu".
    score_batch_size : int
        Windows per batch when scoring (training keeps ``batch_size``). Larger batches cost less
        per window (~4-9 % on 2 cores, more on a GPU); a flight is padded to whole batches, so a
        window's score never depends on the flight's length.
    n_threads : int
        Torch CPU threads while fitting and scoring; 0 for the job's share of the cores (the
        benchmark runs each job with ``cpu count // --jobs`` threads). Default 1: on 2 shared
        cores, 2 threads made GOAD 3-8x and DeepSVDD 5x slower (measured for issue 15: the
        threads spin and wait for each other when another process holds a core).
    columns : list of str or None
        Sensor columns to use; None for every ``topic.field`` column.
    random_state : int
        Seed of the model initialisation, the training shuffles and the window subsample.

    Attributes
    ----------
    model_ : deepod model
        The fitted DeepOD model (training data stripped).
    feature_mean_, feature_scale_ : ndarray (features,)
        Standardisation of the window features, learned on the training windows.
    n_train_windows_ : int
        Windows the model was trained on.
    """

    #: The DeepOD model class (a module-level class, so that fitted detectors pickle).
    _model_class: ClassVar[type]
    #: Model keyword arguments that differ from DeepOD's defaults.
    _model_defaults: ClassVar[dict[str, Any]] = {}

    def __init__(
        self,
        window: int = 25,
        segments: int = 5,
        stride: int = 5,
        epochs: int = 10,
        batch_size: int = 64,
        score_batch_size: int = 512,
        lr: float = 1e-3,
        max_train_windows: int = 2000,
        window_stats: bool = True,
        model_params: dict[str, Any] | None = None,
        device: str | None = None,
        n_threads: int = 1,
        columns: list[str] | None = None,
        random_state: int = 0,
    ):
        self.window = window
        self.segments = segments
        self.stride = stride
        self.epochs = epochs
        self.batch_size = batch_size
        self.score_batch_size = score_batch_size
        self.lr = lr
        self.max_train_windows = max_train_windows
        self.window_stats = window_stats
        self.model_params = model_params
        self.device = device
        self.n_threads = n_threads
        self.columns = columns
        self.random_state = random_state

    # -- features --------------------------------------------------------------------------------
    def _windows(self, X: np.ndarray, step: int = 1) -> np.ndarray:
        """Raw feature vectors (float32) of the windows ending at rows 0, step, 2 step, ..."""
        w, k = int(self.window), int(self.segments)
        X = np.ascontiguousarray(pad_start(X.astype(np.float32), w - 1))
        bounds = np.linspace(0, w, k + 1).round().astype(np.int64)
        return window_features(X, w, bounds, int(step), bool(self.window_stats))

    def _features(self, X: np.ndarray, step: int = 1) -> np.ndarray:
        """Window features standardised with the training windows' mean and spread."""
        return ((self._windows(X, step) - self.feature_mean_) / self.feature_scale_).astype(np.float32)

    def _check_params(self) -> None:
        if int(self.window) < 2:
            raise DetectorError(f"{self.name}: window must be at least 2 rows, got {self.window!r}")
        if not 1 <= int(self.segments) <= int(self.window):
            raise DetectorError(f"{self.name}: segments must be in 1..window, got {self.segments!r}")
        if int(self.n_threads) < 0:
            raise DetectorError(f"{self.name}: n_threads must be 0 (the job's share of the cores) or more, "
                                f"got {self.n_threads!r}")
        for key in ("stride", "epochs", "batch_size", "score_batch_size", "max_train_windows"):
            if int(getattr(self, key)) < 1:
                raise DetectorError(
                    f"{self.name}: {key} must be a positive integer, got {getattr(self, key)!r}"
                )

    # -- Detector hooks ----------------------------------------------------------------------------
    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        train = np.concatenate([self._windows(x, int(self.stride)) for x in X_list], axis=0)
        cap = int(self.max_train_windows)
        if train.shape[0] > cap:
            train = train[np.sort(self._rng().choice(train.shape[0], size=cap, replace=False))]
        self.history_rows_ = int(self.window)  # the window ending at a row decides its score
        self.feature_mean_ = train.mean(axis=0)
        self.feature_scale_ = np.maximum(train.std(axis=0), _MIN_FEATURE_SCALE)
        train = ((train - self.feature_mean_) / self.feature_scale_).astype(np.float32)
        device = self.device or ("cuda" if torch.cuda.is_available() else "cpu")
        kwargs = {
            "epochs": int(self.epochs),
            "batch_size": int(self.batch_size),
            "lr": float(self.lr),
            "device": device,
            "verbose": 0,
            "random_state": int(self.random_state),
            **self._model_defaults,
            **(self.model_params or {}),
        }
        with isolated_global_state(int(self.n_threads)):
            try:
                model = self._model_class(**kwargs)
            except TypeError as exc:
                raise DetectorError(
                    f"{self.name}: invalid model_params {self.model_params!r}: {exc}"
                ) from exc
            model.fit(train)
        # Drop what only training needs: the data (it would be pickled with the detector).
        model.train_data = model.train_loader = model.test_loader = None
        model.decision_scores_ = model.labels_ = None
        self.model_ = model
        self.n_train_windows_ = int(train.shape[0])

    def _score(self, X: np.ndarray) -> np.ndarray:
        feats = self._features(X)
        n = feats.shape[0]
        # Score in full batches only, so a window's float32 result never depends on how many
        # windows follow it (batch shapes change the kernels' rounding): pad with the last window.
        b = int(getattr(self, "score_batch_size", self.batch_size))  # detectors pickled before it
        padded = np.concatenate([feats, np.repeat(feats[-1:], (-n) % b, axis=0)], axis=0)
        with isolated_global_state(int(self.n_threads)):
            scores = _model_scores(self.model_, padded, b)
        return scores[:n]

    def _score_last(self, X: np.ndarray) -> float:
        """Only the window ending at the last row, scored alone (for streaming).

        A batch of one window takes ~1/64 of the compute of a full batch; its float32 result
        equals the batch score up to rounding (relative ~1e-6; exactly for GOAD here).
        """
        feats = self._features(X[-int(self.window):])[-1:]
        with isolated_global_state(int(self.n_threads)):
            scores = _model_scores(self.model_, feats, 1)
        return float(scores[0])

# -- the five built-ins ------------------------------------------------------------------------


class DeepSVDD(_DeepODDetector):
    """Deep SVDD (Ruff et al. 2018): distance of a window's embedding to a hypersphere centre.

    Parameters: see ``_DeepODDetector``; ``model_params`` are DeepOD ``DeepSVDD`` arguments
    (``rep_dim``, ``hidden_dims``, ``act``, ``bias``).
    """

    name = "deepsvdd"
    relative_cost = 3.8  # us per row, paper flights (scheduling hint)
    description = (
        "Deep SVDD (Ruff et al. 2018) on flattened windows: distance to a learned hypersphere centre"
    )
    _model_class = _DeepODDeepSVDD


class RDP(_DeepODDetector):
    """RDP (Wang et al. 2020): error in predicting a random projection of a window.

    Parameters: see ``_DeepODDetector``; ``model_params`` are DeepOD ``RDP`` arguments
    (``rep_dim``, ``hidden_dims``, ``act``, ``bias``).
    """

    name = "rdp"
    relative_cost = 5.3  # us per row, paper flights (scheduling hint)
    description = "RDP (Wang et al. 2020) on flattened windows: random-distance prediction error"
    _model_class = _RDPModel


class RCA(_DeepODDetector):
    """RCA (Liu et al. 2021): reconstruction error of two collaborative autoencoders.

    Parameters: see ``_DeepODDetector``; ``model_params`` are DeepOD ``RCA`` arguments
    (``rep_dim``, ``hidden_dims``, ``act``, ``alpha``, ``anom_ratio``, ``dropout``).
    """

    name = "rca"
    relative_cost = 8.3  # us per row, paper flights (scheduling hint)
    description = (
        "RCA (Liu et al. 2021) on flattened windows: collaborative autoencoders' reconstruction error"
    )
    _model_class = _RCAModel


class GOAD(_DeepODDetector):
    """GOAD (Bergman and Hoshen 2020): how badly random affine transformations are recognised.

    Parameters: see ``_DeepODDetector``; ``model_params`` are DeepOD ``GOAD`` arguments
    (``n_trans``, ``trans_dim``, ``alpha``, ``margin``, ``hidden_dim``, ``n_layers``). The
    adapter uses 32 transformations instead of DeepOD's 256: the training loss grows with the
    square of their number.
    """

    name = "goad"
    relative_cost = 19.0  # us per row, paper flights (scheduling hint)
    description = "GOAD (Bergman & Hoshen 2020) on flattened windows: transformation-classification error"
    _model_class = _GOADModel
    _model_defaults = {"n_trans": 32}


class NeuTraL(_DeepODDetector):
    """NeuTraL AD (Qiu et al. 2021): contrastive loss of learned neural transformations.

    Parameters: see ``_DeepODDetector``; ``model_params`` are DeepOD ``NeuTraL`` arguments
    (``n_trans``, ``trans_type``, ``temp``, ``rep_dim``, ``hidden_dims``, ``trans_hidden_dims``).
    """

    name = "neutral"
    relative_cost = 42.0  # us per row, paper flights (scheduling hint)
    description = "NeuTraL AD (Qiu et al. 2021) on windows: contrastive loss of learned transformations"
    _model_class = _DeepODNeuTraL
