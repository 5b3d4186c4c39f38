"""Telemanom: LSTM forecasting with nonparametric dynamic thresholding.

Hundman, Constantinou, Laporte, Colwell and Soderstrom (2018), "Detecting Spacecraft Anomalies
Using LSTMs and Nonparametric Dynamic Thresholding", KDD 2018 (arXiv:1802.04431).

An LSTM learns to forecast the next ``n_predictions`` values of the telemetry channels from the
last ``l_s`` rows of every channel. The anomaly signal is the absolute one-step-ahead prediction
error, smoothed by an exponentially weighted moving average (EWMA). ``score`` combines the
smoothed errors of all predicted channels, each divided by its normal error level; ``alarms``
applies the paper's nonparametric dynamic threshold to each channel's smoothed errors (windows of
``window_size * error_batch`` errors, threshold ``mean + z * std`` with the ``z`` that best
separates the errors, sequences grown by ``error_buffer`` rows and pruned with ``p``).

The original implementation (khundman/telemanom) is Keras 2 code; this is a PyTorch rewrite of
the published algorithm. Its defaults (``l_s=250, n_predictions=10, layers=[80, 80],
dropout=0.3, lstm_batch_size=64, epochs=35, patience=10, min_delta=0.0003``; thresholding
``batch_size=70`` (here ``error_batch``), ``window_size=30, smoothing_perc=0.05,
error_buffer=100, p=0.13``) are scaled here to 50 Hz flights of 1500-4000 rows and a CPU
budget: 1 s of history, a smaller network, fewer epochs, 0.5 s threshold batches.

Deviations from the published code, each for a stated reason:

- the network forecasts the change from the last observed value (``residual=True``): 50 Hz
  telemetry is smooth, and a few CPU epochs then suffice;
- training windows are subsampled to ``max_train_windows``, and the best validation weights are
  restored after early stopping;
- the start of a flight is padded by repeating its first row, so every row gets a forecast (and
  training sees the same padding); the EWMA is causal, without the published back-filling of
  the first ``l_s`` errors with their mean;
- ``alarms`` also requires errors beyond those seen on the normal training flights
  (``alarm_quantile``), which the paper, lacking normal reference data, could not do.

``backend="tensorflow"`` runs the same model in Keras 3 on ``tensorflow-cpu`` (the paper's own
stack, :mod:`scart_bench.detectors.telemanom_keras`; install with ``pip install
'scart-bench[tensorflow]'``), so that the published implementation's framework can be compared
with this rewrite; everything around the forecaster (windows, errors, threshold) is shared.
"""

from __future__ import annotations

import copy
import hashlib
import io
import math
from collections.abc import Sequence

import numpy as np
import torch
from scipy.signal import lfilter
from torch import nn

from scart_bench.detectors import telemanom_keras
from scart_bench.detectors.base import Detector, DetectorError, DetectorStream

#: z values tried by the dynamic threshold (published: ``np.arange(2.5, sd_lim, 0.5)``, sd_lim 12).
Z_VALUES = np.arange(2.5, 12.0, 0.5)
#: z used when no candidate threshold passes the sanity checks (published ``sd_lim``).
SD_LIM = 12.0
#: Smallest smoothed error that can be anomalous, in standardised units. The published code
#: used 0.05 on channels scaled to [-1, 1]; standardised channels have a comparable scale.
MIN_ERROR = 0.05
#: Quantile of the normal smoothed errors that a channel's errors are divided by in ``score``.
ERROR_SCALE_QUANTILE = 0.99
#: Windows forecast per LSTM call when scoring. The LSTM keeps every step's gates of the whole
#: batch; 256 windows of 50 steps stay in a core's cache where 1,024 did not (same forecasts bit
#: for bit, ~30 % less time per row on one core: tests/test_telemanom.py, perf.detector_speed).
_PREDICT_CHUNK = 256
#: Frameworks that can run the forecaster (``Telemanom(backend=...)``).
BACKENDS = ("torch", "tensorflow")
#: Fewest windows per LSTM call: a flight's last call is padded up to it by repeating its last
#: window, because calls of 1-3 windows take another kernel and round differently; so a row's
#: forecast does not depend on how many rows follow it.
_MIN_CHUNK = 8


class _Forecaster(nn.Module):
    """Stacked LSTM -> dropout -> linear head, as the published Keras model.

    With ``skip`` (the input positions of the outputs) the head forecasts the change from the last
    observed value instead of the value itself.
    """

    def __init__(
        self,
        n_inputs: int,
        n_outputs: int,
        hidden: Sequence[int],
        dropout: float,
        n_predictions: int,
        skip: Sequence[int] | None = None,
    ):
        super().__init__()
        self.register_buffer("skip", torch.as_tensor(list(skip) if skip is not None else [], dtype=torch.long))
        sizes = [n_inputs, *hidden]
        self.lstms = nn.ModuleList(nn.LSTM(a, b, batch_first=True) for a, b in zip(sizes[:-1], sizes[1:]))
        self.drop = nn.Dropout(dropout)
        self.head = nn.Linear(sizes[-1], n_outputs * n_predictions)
        self.n_outputs = n_outputs
        self.n_predictions = n_predictions

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` (batch, l_s, n_inputs) -> forecasts (batch, n_predictions, n_outputs)."""
        seq = x
        for lstm in self.lstms:
            seq, _ = lstm(seq)
            seq = self.drop(seq)
        out = self.head(seq[:, -1, :]).view(-1, self.n_predictions, self.n_outputs)
        if self.skip.numel():
            out = out + x[:, -1, self.skip][:, None, :]
        return out


def ewma(errors: np.ndarray, span: float) -> np.ndarray:
    """Causal EWMA along axis 0, equal to ``pandas.DataFrame.ewm(span=span).mean()`` (adjust=True)."""
    errors = np.asarray(errors, dtype=np.float64)
    if errors.shape[0] == 0:
        return errors.copy()
    alpha = 2.0 / (max(float(span), 1.0) + 1.0)
    decay = 1.0 - alpha
    num = lfilter([1.0], [1.0, -decay], errors, axis=0)
    den = lfilter([1.0], [1.0, -decay], np.ones(errors.shape[0]))
    if errors.ndim > 1:
        den = den.reshape((-1,) + (1,) * (errors.ndim - 1))
    return num / den


# -- nonparametric dynamic thresholding ------------------------------------------------------------
def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Rows within ``radius`` rows of a True row, along the last axis."""
    r = max(int(radius), 0)
    if r == 0:
        return mask.copy()
    n = mask.shape[-1]
    c = np.cumsum(mask, axis=-1, dtype=np.int64)
    c = np.concatenate([np.zeros(mask.shape[:-1] + (1,), dtype=np.int64), c], axis=-1)
    idx = np.arange(n)
    hi = np.minimum(idx + r + 1, n)
    lo = np.maximum(idx - r, 0)
    return (c[..., hi] - c[..., lo]) > 0


def _n_sequences(mask: np.ndarray) -> np.ndarray:
    """Number of runs of True longer than one row, along the last axis."""
    prev = np.zeros_like(mask)
    prev[..., 1:] = mask[..., :-1]
    nxt = np.zeros_like(mask)
    nxt[..., :-1] = mask[..., 1:]
    starts = mask & ~prev
    singletons = starts & ~nxt
    return starts.sum(axis=-1) - singletons.sum(axis=-1)


def find_z(e_s: np.ndarray, error_buffer: int, z_values: np.ndarray = Z_VALUES) -> float:
    """The published ``find_epsilon``: the z whose threshold ``mean + z * std`` maximises

    ``(delta_mean / mean + delta_std / std) / (n_anomalous_points + n_sequences ** 2)``

    where the deltas are the drops of mean and std when the errors above the threshold are removed
    and the anomalous points are those within ``error_buffer - 1`` rows of an error above it (the
    published ``find_epsilon`` pads by ``np.arange(1, error_buffer)``; its ``compare_to_epsilon``
    by ``error_buffer`` rows, see :func:`_window_anomalies`). Candidates
    with more than 5 sequences or half the window anomalous are skipped; ``SD_LIM`` if none fits.
    """
    e_s = np.asarray(e_s, dtype=np.float64)
    n = e_s.shape[0]
    mean, sd = float(e_s.mean()), float(e_s.std())
    if n == 0 or sd <= 0.0 or mean == 0.0:
        return SD_LIM
    eps = mean + sd * np.asarray(z_values)[:, None]  # (Z, 1)
    above = e_s[None, :] > eps
    below = e_s[None, :] < eps
    anom = _dilate(above, int(error_buffer) - 1)
    n_anom = anom.sum(axis=1)
    n_seq = _n_sequences(anom)
    n_below = np.maximum(below.sum(axis=1), 1)
    m_below = np.where(below, e_s, 0.0).sum(axis=1) / n_below
    v_below = np.where(below, (e_s[None, :] - m_below[:, None]) ** 2, 0.0).sum(axis=1) / n_below
    s = ((mean - m_below) / mean + (sd - np.sqrt(v_below)) / sd) / np.maximum(n_seq**2 + n_anom, 1)
    best_s, best_z = 0.0, SD_LIM
    for k, z in enumerate(z_values):  # ascending z, ">=" keeps the last maximum, as published
        if n_anom[k] > 0 and s[k] >= best_s and n_seq[k] <= 5 and n_anom[k] < 0.5 * n:
            best_s, best_z = float(s[k]), float(z)
    return best_z


def _runs(idx: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive runs (first, last) of sorted indices, runs of one index dropped."""
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) != 1)
    firsts = np.concatenate([[idx[0]], idx[breaks + 1]])
    lasts = np.concatenate([idx[breaks], [idx[-1]]])
    return [(int(a), int(b)) for a, b in zip(firsts, lasts) if b > a]


def _window_anomalies(
    e_s: np.ndarray,
    y: np.ndarray,
    window: int,
    offset: int,
    flagged: np.ndarray,
    *,
    error_batch: int,
    error_buffer: int,
    p: float,
    n_ignore: int,
    floor: float = -np.inf,
) -> np.ndarray:
    """Anomalous indices (window-local) of one error window above ``mean + z * std``, pruned.

    ``z`` comes from ``find_z``, computed only when some error could be anomalous at all.

    The published ``compare_to_epsilon`` + ``prune_anoms`` (Hundman et al. 2018, reference code):
    each error above the threshold is padded by ``error_buffer`` rows on each side; only the
    newest ``error_batch`` rows of a window may become anomalous (every row in the first window,
    except its first ``n_ignore``); ``flagged`` holds the rows already flagged in earlier windows
    (global indices). Errors at or below ``floor`` are never anomalous. Pruning works on the
    sequences of two rows or more; when the window has none (its anomalous rows are single rows,
    e.g. a padding cut by the batch boundary), the rows are kept unpruned, as published, and can
    join the sequences of the neighbouring windows.
    """
    n = e_s.shape[0]
    none = np.zeros(0, dtype=np.int64)
    # errors that can reach the rows this window may flag (the buffer reaches error_buffer rows)
    reach = e_s if window == 0 else e_s[max(n - error_batch - error_buffer, 0) :]
    if not e_s.max() > MIN_ERROR or not (reach > floor).any():
        return none
    mean, std = float(e_s.mean()), float(e_s.std())
    perc_high, perc_low = np.percentile(y, [95, 5])
    inter_range = perc_high - perc_low
    chan_std = float(np.std(y))
    if not (std > 0.05 * chan_std or e_s.max() > 0.05 * inter_range):
        return none
    epsilon = mean + find_z(e_s, error_buffer) * std
    hits = (e_s > epsilon) & (e_s > 0.05 * inter_range) & (e_s > floor)
    if not hits.any():
        return none
    anom = _dilate(hits, error_buffer)
    if window > 0:
        anom[: max(n - error_batch, 0)] = False
    else:
        anom[:n_ignore] = False
    idx = np.flatnonzero(anom)
    seqs = _runs(idx)
    if not seqs:
        return idx  # single rows only: nothing to prune, kept (the published prune_anoms returns early)
    normal = ~anom
    earlier = flagged[(flagged >= offset) & (flagged < offset + n)] - offset
    normal[earlier] = False
    non_anom_max = float(e_s[normal].max()) if normal.any() else 0.0
    # prune: sort sequence maxima (plus the largest normal error); keep the sequences before the
    # last drop of at least p, reclassify those after it as normal
    seq_max = np.array([e_s[a : b + 1].max() for a, b in seqs])
    order = np.argsort(-seq_max, kind="stable")
    values = list(seq_max[order]) + ([non_anom_max] if non_anom_max > 0 else [])
    remove: list[int] = []
    for i in range(len(values) - 1):
        if values[i] <= 0 or (values[i] - values[i + 1]) / values[i] < p:
            remove.append(int(order[i]))
        else:
            remove = []
    keep = [s for k, s in enumerate(seqs) if k not in set(remove)]
    if not keep:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.arange(a, b + 1) for a, b in keep])


def dynamic_threshold(
    e_s: np.ndarray,
    y: np.ndarray,
    *,
    error_batch: int = 25,
    window_size: int = 30,
    error_buffer: int = 25,
    p: float = 0.13,
    n_ignore: int = 0,
    inverse: bool = True,
    high: float = -np.inf,
    low: float = np.inf,
) -> np.ndarray:
    """Boolean anomaly mask of one channel's smoothed errors ``e_s`` (the published ``process_errors``).

    Windows of ``window_size * error_batch`` errors advance by ``error_batch`` rows; each gets its
    own threshold from ``find_z`` and flags sequences among its newest rows, pruned with ``p``.
    ``y`` are the channel's values (for the published minimum-magnitude check). With ``inverse``
    the errors mirrored around their window mean are thresholded too (dips in the error, e.g. a
    frozen sensor, are anomalous as well), as the published code does. Beyond the published
    checks, a high error must also exceed ``high`` and a dip fall below ``low`` (e.g. quantiles of
    the errors on normal flights).
    """
    e_s = np.asarray(e_s, dtype=np.float64).reshape(-1)
    y = np.asarray(y, dtype=np.float64).reshape(-1)
    n = e_s.shape[0]
    mask = np.zeros(n, dtype=bool)
    if n < 2:
        return mask
    batch = max(int(error_batch), 1)
    ws = max(int(window_size), 1)
    while ws > 1 and n - batch * ws < 0:  # fewer errors than one full window: shrink it
        ws -= 1
    n_windows = max((n - batch * ws) // batch, 0)
    flagged = np.zeros(0, dtype=np.int64)
    for w in range(n_windows + 1):
        lo = w * batch
        hi = n if w == n_windows else ws * batch + w * batch
        win, win_y = e_s[lo:hi], y[lo:hi]
        if win.shape[0] < 2:
            continue
        kw = dict(error_batch=batch, error_buffer=error_buffer, p=p, n_ignore=n_ignore)
        found = [_window_anomalies(win, win_y, w, lo, flagged, floor=high, **kw)]
        if inverse:
            inv = 2.0 * win.mean() - win
            floor_inv = 2.0 * win.mean() - low
            found.append(_window_anomalies(inv, win_y, w, lo, flagged, floor=floor_inv, **kw))
        new = np.unique(np.concatenate(found)) + lo
        if new.size:
            flagged = np.union1d(flagged, new)
    for a, b in _runs(flagged):
        mask[a : b + 1] = True
    return mask


# -- the detector ---------------------------------------------------------------------------------
class Telemanom(Detector):
    """LSTM forecaster + nonparametric dynamic threshold (Hundman et al. 2018).

    Parameters
    ----------
    columns : list of str or None
        Input columns (``topic.field``); None for every sensor column.
    random_state : int
        Seed of weight initialisation, dropout, window subsampling and shuffling.
    l_s : int
        History rows fed to the LSTM (published 250; 50 = 1 s at 50 Hz).
    n_predictions : int
        Steps ahead the LSTM forecasts in training (published 10).
    hidden : tuple of int
        Units of the stacked LSTM layers (published (80, 80)).
    dropout : float
        Dropout after each LSTM layer (published 0.3).
    epochs, batch_size, lr : int, int, float
        Adam training: maximum epochs (published 35), minibatch size (64), learning rate.
    patience, min_delta : int, float
        Early stopping on the validation loss (published 10 and 0.0003).
    validation_split : float
        Fraction of training windows (the last ones, in time order) used for early stopping.
    max_train_windows : int or None
        Training windows are subsampled to at most this many (None: use all).
    smoothing_perc : float
        EWMA span as a fraction of the thresholding window: ``span = smoothing_perc *
        window_size * error_batch`` (published 0.05 * 30 * 70 = 105 rows).
    error_batch, window_size : int
        Dynamic threshold: each window holds ``window_size`` batches of ``error_batch`` rows and
        advances by one batch (published 70 and 30; 25 rows = 0.5 s here).
    error_buffer : int
        Rows around an anomalous error added to its sequence (published 100).
    p : float
        Minimum percent decrease between sorted sequence maxima to keep an anomaly (0.13).
    alarm_quantile : float or None
        Not in the paper (it had no normal reference flights): ``alarms`` only flags a high error
        above this quantile of the channel's smoothed errors on the training flights, and a dip
        below the complementary quantile. This keeps noise-dominated channels (IMU at hover)
        from raising alarms on ordinary fluctuations. None: the published thresholding alone.
    residual : bool
        True: the network forecasts the change from the last observed value (a skip connection,
        not in the paper: at 50 Hz the persistence forecast is already close, and the LSTM
        learns the correction much faster than the value). False: the value, as published.
    per_channel : bool
        False: one multi-output model predicts every target channel from all inputs. True: one
        model per target channel fed with that channel's own history, as the paper did.
    target_columns : list of str or None
        Channels to predict (a subset of ``columns``); None for all of them.
    aggregate : {"first", "mean"}
        Forecast of row t: the one-step-ahead forecast ("first", published default) or the mean
        of the forecasts of row t made 1..n_predictions steps earlier ("mean").
    combine : {"max", "mean"}
        How ``score`` combines the channels' normalised smoothed errors.
    device : str
        "auto" (CUDA when available, else CPU), "cpu" or "cuda[:i]". The tensorflow backend runs
        on the CPU ("auto" or "cpu").
    backend : {"torch", "tensorflow"}
        Framework of the LSTM forecaster. "torch" (default): this module's PyTorch model.
        "tensorflow": the same model in Keras 3 on ``tensorflow-cpu``, as the original
        implementation (stacked ``LSTM`` + ``Dropout``, ``Dense`` output, Adam on the MSE,
        ``EarlyStopping`` on the validation loss), with the same parameters above and the same
        outputs; seeded with ``keras.utils.set_random_seed`` under TensorFlow's op determinism,
        so the same ``random_state`` gives the same scores. Needs the optional extra:
        ``pip install 'scart-bench[tensorflow]'`` (TensorFlow is imported only for this backend).

    Attributes
    ----------
    target_idx_ : ndarray of int
        Positions of the predicted channels in ``columns_``.
    model_states_ : list of bytes, or list of list of ndarray
        Trained weights, one per model: ``torch.save`` of each state dict (CPU tensors), or with
        the tensorflow backend the Keras model's ``get_weights()`` as numpy arrays (a fitted
        detector pickles without TensorFlow objects).
    error_scale_ : ndarray
        Per target channel, the 99th percentile of its smoothed error on the training flights;
        ``score`` divides the channel's smoothed errors by it.
    alarm_high_, alarm_low_ : ndarray
        Per target channel, the ``alarm_quantile`` and ``1 - alarm_quantile`` quantiles of its
        smoothed error on the training flights (-inf / inf when ``alarm_quantile`` is None).
    span_ : float
        EWMA span in rows.
    history_rows_ : int
        Trailing rows enough to reproduce the last row's score when streaming.
    epochs_run_ : list of int
        Epochs trained per model before early stopping.
    """

    name = "telemanom"
    relative_cost = 20.0  # us per row, paper flights (scheduling hint)
    description = "LSTM forecaster with nonparametric dynamic thresholding (Hundman et al. 2018)"
    has_alarms = True

    def __init__(
        self,
        columns: list[str] | None = None,
        random_state: int = 0,
        l_s: int = 50,
        n_predictions: int = 10,
        hidden: tuple[int, ...] = (32, 32),
        dropout: float = 0.3,
        epochs: int = 10,
        batch_size: int = 64,
        lr: float = 1e-3,
        patience: int = 3,
        min_delta: float = 3e-4,
        validation_split: float = 0.2,
        max_train_windows: int | None = 20000,
        smoothing_perc: float = 0.05,
        error_batch: int = 25,
        window_size: int = 30,
        error_buffer: int = 25,
        p: float = 0.13,
        alarm_quantile: float | None = 1.0,
        residual: bool = True,
        per_channel: bool = False,
        target_columns: list[str] | None = None,
        aggregate: str = "first",
        combine: str = "max",
        device: str = "auto",
        backend: str = "torch",
    ):
        self.columns = columns
        self.random_state = random_state
        self.l_s = l_s
        self.n_predictions = n_predictions
        self.hidden = hidden
        self.dropout = dropout
        self.epochs = epochs
        self.batch_size = batch_size
        self.lr = lr
        self.patience = patience
        self.min_delta = min_delta
        self.validation_split = validation_split
        self.max_train_windows = max_train_windows
        self.smoothing_perc = smoothing_perc
        self.error_batch = error_batch
        self.window_size = window_size
        self.error_buffer = error_buffer
        self.p = p
        self.alarm_quantile = alarm_quantile
        self.residual = residual
        self.per_channel = per_channel
        self.target_columns = target_columns
        self.aggregate = aggregate
        self.combine = combine
        self.device = device
        self.backend = backend

    # -- public ------------------------------------------------------------------------------
    def smoothed_errors(self, flight) -> np.ndarray:
        """Per target channel, the EWMA-smoothed absolute one-step-ahead error (rows, targets)."""
        X = self._transform(flight)
        return self._smoothed(X).copy()  # the cached array is read-only

    def alarms(self, flight) -> np.ndarray:
        """Boolean alarm per row: the dynamic threshold on each target channel, OR-ed.

        As in the paper's batch-wise setting, a row can only be flagged by the first threshold
        window or by the window whose newest ``error_batch`` rows contain it, so its alarm depends
        on the rows up to the end of that batch (the last window reaches the end of the flight).
        The first ``l_s`` rows, whose forecast history is padded, are never flagged.
        """
        X = self._transform(flight)
        out = np.zeros(X.shape[0], dtype=bool)
        if X.shape[0] == 0:
            return out
        e_s = self._smoothed(X)
        kw = dict(
            error_batch=self.error_batch,
            window_size=self.window_size,
            error_buffer=self.error_buffer,
            p=self.p,
            n_ignore=self.l_s,
        )
        for k, c in enumerate(self.target_idx_):
            out |= dynamic_threshold(
                e_s[:, k], X[:, c], high=self.alarm_high_[k], low=self.alarm_low_[k], **kw
            )
        return out

    # -- Detector hooks ----------------------------------------------------------------------
    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        self.target_idx_ = self._target_indices()
        self.span_ = max(float(self.smoothing_perc) * self.window_size * self.error_batch, 1.0)
        alpha = 2.0 / (self.span_ + 1.0)
        memory = math.ceil(math.log(1e-3) / math.log(1.0 - alpha)) if alpha < 1.0 else 1
        extra = self.n_predictions if self.aggregate == "mean" else 1
        self.history_rows_ = int(self.l_s + extra + memory)
        device = self._torch_device()
        padded = [self._pad(x).astype(np.float32) for x in X_list]
        starts = self._training_windows(X_list)
        if starts.size < 2:
            raise DetectorError(
                f"{self.name}: training flights too short for n_predictions={self.n_predictions}"
            )
        offsets = np.concatenate([[0], np.cumsum([p.shape[0] for p in padded])[:-1]])
        flat = np.concatenate(padded, axis=0)
        glob = offsets[starts[:, 0]] + starts[:, 1]  # window start in ``flat``
        rng = np.random.default_rng(self.random_state)
        if self.max_train_windows is not None and glob.size > self.max_train_windows:
            glob = np.sort(rng.choice(glob, size=int(self.max_train_windows), replace=False))
        models = self._model_specs()
        seed = int(rng.integers(0, 2**31 - 1))
        states, epochs_run = [], []
        devices = [device.index or 0] if device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(seed)
            for k, (inputs, outputs) in enumerate(models):
                if self.backend == "tensorflow":
                    state, n_ep = self._train_keras(flat, glob, inputs, outputs, seed + k)
                else:
                    net, n_ep = self._train_one(flat, glob, inputs, outputs, device, seed + k)
                    state = self._state_bytes(net)
                states.append(state)
                epochs_run.append(n_ep)
        self.model_states_ = states
        self.epochs_run_ = epochs_run
        self.__dict__.pop("_nets_cache", None)
        self.__dict__.pop("_smoothed_cache", None)
        # the normal error level of every channel, from the training flights
        errs = np.concatenate([self._smoothed(x) for x in X_list], axis=0)
        scale = np.quantile(errs, ERROR_SCALE_QUANTILE, axis=0)
        floor = max(float(np.median(scale)) * 1e-2, 1e-6)
        self.error_scale_ = np.maximum(scale, floor)
        if self.alarm_quantile is None:
            self.alarm_high_ = np.full(len(self.target_idx_), -np.inf)
            self.alarm_low_ = np.full(len(self.target_idx_), np.inf)
        else:
            self.alarm_high_ = np.quantile(errs, float(self.alarm_quantile), axis=0)
            self.alarm_low_ = np.quantile(errs, 1.0 - float(self.alarm_quantile), axis=0)

    def _score(self, X: np.ndarray) -> np.ndarray:
        z = self._smoothed(X) / self.error_scale_
        return z.max(axis=1) if self.combine == "max" else z.mean(axis=1)

    # -- internals ---------------------------------------------------------------------------
    def _check_params(self) -> None:
        bad = []
        if int(self.l_s) < 1:
            bad.append("l_s >= 1")
        if int(self.n_predictions) < 1:
            bad.append("n_predictions >= 1")
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            bad.append("hidden: one or more positive sizes")
        if not 0.0 <= float(self.dropout) < 1.0:
            bad.append("0 <= dropout < 1")
        if int(self.epochs) < 1 or int(self.batch_size) < 1:
            bad.append("epochs >= 1 and batch_size >= 1")
        if not 0.0 <= float(self.validation_split) < 1.0:
            bad.append("0 <= validation_split < 1")
        if self.aggregate not in ("first", "mean"):
            bad.append("aggregate in {'first', 'mean'}")
        if self.combine not in ("max", "mean"):
            bad.append("combine in {'max', 'mean'}")
        if self.alarm_quantile is not None and not 0.5 <= float(self.alarm_quantile) <= 1.0:
            bad.append("alarm_quantile None or in [0.5, 1]")
        if int(self.error_batch) < 1 or int(self.window_size) < 1 or int(self.error_buffer) < 1:
            bad.append("error_batch, window_size, error_buffer >= 1")
        if self.backend not in BACKENDS:
            bad.append("backend in {'torch', 'tensorflow'}")
        elif self.backend == "tensorflow" and self.device not in ("auto", "cpu"):
            bad.append("device 'auto' or 'cpu' with backend 'tensorflow' (tensorflow-cpu)")
        if bad:
            raise DetectorError(f"{self.name}: invalid parameters, need " + "; ".join(bad))

    def _target_indices(self) -> np.ndarray:
        if self.target_columns is None:
            return np.arange(len(self.columns_))
        pos = {c: i for i, c in enumerate(self.columns_)}
        missing = [c for c in self.target_columns if c not in pos]
        if missing:
            raise DetectorError(f"{self.name}: target_columns not among the input columns: {missing[:5]}")
        if not self.target_columns:
            raise DetectorError(f"{self.name}: target_columns is empty")
        return np.array([pos[c] for c in self.target_columns], dtype=np.int64)

    def _torch_device(self) -> torch.device:
        if getattr(self, "backend", "torch") == "tensorflow":
            return torch.device("cpu")  # windows are cut in torch on the CPU, forecast by Keras
        if self.device == "auto":
            return torch.device("cuda" if torch.cuda.is_available() else "cpu")
        return torch.device(self.device)

    def _model_specs(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(input channels, output channels) of each model."""
        n = len(self.columns_)
        if self.per_channel:
            return [(np.array([c]), np.array([c])) for c in self.target_idx_]
        return [(np.arange(n), self.target_idx_)]

    def _new_net(self, inputs: np.ndarray, outputs: np.ndarray) -> _Forecaster:
        hidden = [int(h) for h in self.hidden]
        skip = np.searchsorted(inputs, outputs) if self.residual else None
        return _Forecaster(len(inputs), len(outputs), hidden, float(self.dropout), int(self.n_predictions), skip)

    def _pad(self, x: np.ndarray) -> np.ndarray:
        """Prepend ``l_s`` copies of the first row, so that row t's history is ``pad[t:t+l_s]``."""
        return np.concatenate([np.repeat(x[:1], self.l_s, axis=0), x], axis=0)

    def _training_windows(self, X_list: list[np.ndarray]) -> np.ndarray:
        """(flight, t) of every window whose ``n_predictions`` targets lie inside its flight."""
        rows = []
        for f, x in enumerate(X_list):
            n_win = x.shape[0] - self.n_predictions + 1
            if n_win > 0:
                t = np.arange(n_win)
                rows.append(np.stack([np.full(n_win, f), t], axis=1))
        return np.concatenate(rows, axis=0) if rows else np.zeros((0, 2), dtype=np.int64)

    def _train_one(
        self,
        flat: np.ndarray,
        glob: np.ndarray,
        inputs: np.ndarray,
        outputs: np.ndarray,
        device: torch.device,
        seed: int,
    ) -> tuple[_Forecaster, int]:
        l_s, n_pred = int(self.l_s), int(self.n_predictions)
        data = torch.from_numpy(np.ascontiguousarray(flat[:, inputs])).to(device)
        target = torch.from_numpy(np.ascontiguousarray(flat[:, outputs])).to(device)
        steps_in = torch.arange(l_s, device=device)
        steps_out = torch.arange(l_s, l_s + n_pred, device=device)
        starts = torch.from_numpy(glob.astype(np.int64)).to(device)
        n_val = int(round(len(glob) * float(self.validation_split)))
        n_val = min(n_val, len(glob) - 1)
        train_idx, val_idx = starts[: len(glob) - n_val], starts[len(glob) - n_val :]

        def batch(idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            return data[idx[:, None] + steps_in], target[idx[:, None] + steps_out]

        net = self._new_net(inputs, outputs).to(device)
        opt = torch.optim.Adam(net.parameters(), lr=float(self.lr))
        gen = torch.Generator(device="cpu").manual_seed(seed)
        bs = int(self.batch_size)
        best, best_state, bad_epochs, epochs_run = math.inf, None, 0, 0
        for _ in range(int(self.epochs)):
            epochs_run += 1
            net.train()
            order = torch.randperm(len(train_idx), generator=gen).to(device)
            for i in range(0, len(order), bs):
                xb, yb = batch(train_idx[order[i : i + bs]])
                opt.zero_grad(set_to_none=True)
                loss = torch.mean((net(xb) - yb) ** 2)
                loss.backward()
                opt.step()
            if n_val == 0:
                continue
            net.eval()
            with torch.no_grad():
                total = 0.0
                for i in range(0, n_val, 1024):
                    xb, yb = batch(val_idx[i : i + 1024])
                    total += float(torch.sum((net(xb) - yb) ** 2))
                val_loss = total / (n_val * n_pred * len(outputs))
            if val_loss < best - float(self.min_delta):
                best, best_state, bad_epochs = val_loss, copy.deepcopy(net.state_dict()), 0
            else:
                bad_epochs += 1
                if bad_epochs >= int(self.patience):
                    break
        if best_state is not None:
            net.load_state_dict(best_state)
        net.eval()
        return net, epochs_run

    def _keras_model_args(self, inputs: np.ndarray, outputs: np.ndarray) -> dict:
        skip = np.searchsorted(inputs, outputs) if self.residual else None
        return dict(
            l_s=int(self.l_s),
            n_predictions=int(self.n_predictions),
            hidden=[int(h) for h in self.hidden],
            dropout=float(self.dropout),
            skip=skip,
        )

    def _train_keras(
        self, flat: np.ndarray, glob: np.ndarray, inputs: np.ndarray, outputs: np.ndarray, seed: int
    ) -> tuple[list[np.ndarray], int]:
        """``_train_one`` in Keras (the tensorflow backend): weights as numpy arrays, epochs run."""
        return telemanom_keras.train(
            flat,
            glob,
            inputs,
            outputs,
            seed,
            epochs=int(self.epochs),
            batch_size=int(self.batch_size),
            lr=float(self.lr),
            patience=int(self.patience),
            min_delta=float(self.min_delta),
            validation_split=float(self.validation_split),
            **self._keras_model_args(inputs, outputs),
        )

    @staticmethod
    def _state_bytes(net: nn.Module) -> bytes:
        buf = io.BytesIO()
        torch.save({k: v.detach().cpu() for k, v in net.state_dict().items()}, buf)
        return buf.getvalue()

    def _nets(self) -> list[_Forecaster]:
        """The trained models on the compute device (rebuilt from ``model_states_`` once; with the
        tensorflow backend, Keras models called like the torch ones)."""
        device = self._torch_device()
        cache = self.__dict__.get("_nets_cache")
        if cache is not None and cache[0] == str(device):
            return cache[1]
        nets = []
        for (inputs, outputs), state in zip(self._model_specs(), self.model_states_):
            if getattr(self, "backend", "torch") == "tensorflow":
                args = self._keras_model_args(inputs, outputs)
                nets.append(telemanom_keras.load(state, n_inputs=len(inputs), n_outputs=len(outputs), **args))
                continue
            with torch.random.fork_rng(devices=[]):  # initialisation draws from the global RNG
                net = self._new_net(inputs, outputs)
            net.load_state_dict(torch.load(io.BytesIO(state), map_location="cpu", weights_only=True))
            nets.append(net.to(device).eval())
        self.__dict__["_nets_cache"] = (str(device), nets)
        return nets

    def __getstate__(self):
        state = dict(super().__getstate__())  # a copy: the live object keeps its cache
        state.pop("_nets_cache", None)  # rebuilt from model_states_ on first use
        state.pop("_smoothed_cache", None)
        return state

    def _predict(self, X: np.ndarray) -> np.ndarray:
        """Forecast of every row (rows, targets) from the rows before it (start padded)."""
        l_s, n_pred, T = int(self.l_s), int(self.n_predictions), X.shape[0]
        device = self._torch_device()
        padded = torch.from_numpy(self._pad(X).astype(np.float32))
        pred = np.zeros((T, len(self.target_idx_)))
        # window w = padded[w : w + l_s] forecasts rows w .. w + n_pred - 1
        n_steps = 1 if self.aggregate == "first" else n_pred
        chunk = _PREDICT_CHUNK
        steps = torch.arange(l_s)
        for k, ((inputs, outputs), net) in enumerate(zip(self._model_specs(), self._nets())):
            cols = [k] if self.per_channel else slice(None)
            series = padded[:, torch.from_numpy(inputs)]
            out = np.empty((T, n_steps, len(outputs)))
            with torch.inference_mode():
                for lo in range(0, T, chunk):
                    hi = min(lo + chunk, T)
                    ends = torch.arange(lo, max(hi, lo + _MIN_CHUNK)).clamp_(max=hi - 1)  # pad: last window
                    xb = series[ends[:, None] + steps].to(device)
                    out[lo:hi] = net(xb)[: hi - lo, :n_steps, :].double().cpu().numpy()
            if n_steps == 1:
                agg = out[:, 0, :]
            else:
                acc = np.zeros((T, len(outputs)))
                cnt = np.zeros((T, 1))
                for step in range(min(n_steps, T)):  # forecast of row w + step made by window w
                    acc[step:] += out[: T - step, step, :]
                    cnt[step:] += 1.0
                agg = acc / cnt
            pred[:, cols] = agg
        return pred

    def stream(self) -> TelemanomStream:
        """Incremental live scorer: one forecast window per new row and the EWMA carried over."""
        self._check_fitted()
        return TelemanomStream(self)

    def _smoothed(self, X: np.ndarray) -> np.ndarray:
        """Smoothed forecast errors (rows, targets). The last flight's are kept (keyed by its bytes), so
        ``alarms`` after ``score`` on the same flight, as a run with the own alarm rule calls them, does
        not forecast the flight a second time."""
        if X.shape[0] == 0:
            return np.zeros((0, len(self.target_idx_)))
        key = (X.shape, X.dtype.str, hashlib.blake2b(np.ascontiguousarray(X).tobytes(), digest_size=16).digest())
        cached = self.__dict__.get("_smoothed_cache")
        if cached is not None and cached[0] == key:
            return cached[1]
        err = np.abs(self._predict(X) - X[:, self.target_idx_])
        e_s = ewma(err, self.span_)
        e_s.flags.writeable = False
        self.__dict__["_smoothed_cache"] = (key, e_s)
        return e_s


class TelemanomStream(DetectorStream):
    """Telemanom fed one row at a time: the same scores as ``score`` on the rows seen so far.

    Each row is forecast once from the ``l_s`` rows before it (one window through each model,
    instead of the whole trailing history), the forecasts of the last ``n_predictions`` windows
    are kept for ``aggregate="mean"``, and the error EWMA is carried from row to row (exact, where
    a trailing window truncates its memory). Equal to batch scores up to float32 rounding.
    """

    def __init__(self, detector: Telemanom):
        super().__init__(detector)
        d = detector
        self._hist: np.ndarray | None = None  # (l_s, inputs) prepared rows before the current one
        self._last: np.ndarray | None = None
        self._n_steps = 1 if d.aggregate == "first" else int(d.n_predictions)
        self._outs: list[np.ndarray] = []  # forecasts of the newest windows, newest last
        self._decay = 1.0 - 2.0 / (max(float(d.span_), 1.0) + 1.0)
        self._num = np.zeros(len(d.target_idx_))
        self._den = 0.0
        self._specs = d._model_specs()
        self._device = d._torch_device()

    def update(self, row: np.ndarray) -> float:
        d = self.detector
        z = d._prepare_row(row, self._last)
        self._last = z
        if self._hist is None:
            self._hist = np.repeat(z[None].astype(np.float32), int(d.l_s), axis=0)
        window = torch.from_numpy(self._hist)
        out = np.empty((self._n_steps, len(d.target_idx_)))
        with torch.inference_mode():
            for k, ((inputs, _), net) in enumerate(zip(self._specs, d._nets())):
                cols = [k] if d.per_channel else slice(None)
                xb = window[:, torch.from_numpy(inputs)][None].to(self._device)
                out[:, cols] = net(xb)[0, : self._n_steps, :].double().cpu().numpy()
        self._outs = (self._outs + [out])[-self._n_steps:]
        acc = np.zeros(len(d.target_idx_))
        count = 0
        for step in range(len(self._outs)):  # forecast of this row made `step` windows ago
            acc += self._outs[-1 - step][step]
            count += 1
        err = np.abs(acc / count - z[d.target_idx_])
        self._num = err + self._decay * self._num
        self._den = 1.0 + self._decay * self._den
        self._hist[:-1] = self._hist[1:]
        self._hist[-1] = z
        self.n_rows += 1
        zs = (self._num / self._den) / d.error_scale_
        return d._checked_last(float(zs.max() if d.combine == "max" else zs.mean()))
