"""An LSTM autoencoder of windows, written here in torch (no installed library ships one for series).

Malhotra et al., "LSTM-based encoder-decoder for multi-sensor anomaly detection", ICML 2016
anomaly-detection workshop: an LSTM encodes the window of the last ``window`` rows into its
final hidden state, a second LSTM decodes the window back from that state (fed the hidden state
at every step), and the score of a row is the mean squared reconstruction error of the window
ending at it. Rows before a full window see the first row repeated, so the score of row ``i``
depends only on rows ``0..i``; windows are scored in whole batches (the end padded with the last
row) so that a window's float32 score never depends on how many rows follow it.

Determinism: the weights come from ``torch.manual_seed(random_state)`` inside
``torch.random.fork_rng`` (the global generator is restored) and the training shuffles from a
numpy Generator seeded with ``random_state``.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import numpy as np
import torch
from torch import nn

from scart_bench.detectors.base import MAX_WINDOW_ROWS, Detector, DetectorError
from scart_bench.detectors.statistical import pad_start


@contextlib.contextmanager
def _torch_threads(n_threads: int) -> Iterator[None]:
    """Run with ``n_threads`` torch threads (0: the job's share of the cores, ``OMP_NUM_THREADS``)."""
    before = torch.get_num_threads()
    if n_threads <= 0:
        try:
            n_threads = max(1, int(os.environ.get("OMP_NUM_THREADS", "")))
        except ValueError:
            n_threads = max(1, os.cpu_count() or 1)
    torch.set_num_threads(n_threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class _LSTMAutoencoder(nn.Module):
    """Encoder LSTM -> last hidden state -> decoder LSTM (the state at every step) -> linear output."""

    def __init__(self, n_features: int, hidden: int):
        super().__init__()
        self.encoder = nn.LSTM(n_features, hidden, batch_first=True)
        self.decoder = nn.LSTM(hidden, hidden, batch_first=True)
        self.output = nn.Linear(hidden, n_features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _, (h, _) = self.encoder(x)
        z = h[-1].unsqueeze(1).expand(-1, x.shape[1], -1)
        out, _ = self.decoder(z)
        return self.output(out)


class LSTMAutoencoder(Detector):
    """LSTM encoder-decoder (Malhotra et al. 2016): reconstruction error of the window ending at a row.

    Parameters
    ----------
    window : int
        Rows per window (25 = 0.5 s at 50 Hz).
    hidden : int
        Units of the encoder's and the decoder's LSTM (the code size).
    epochs : int
        Training epochs (Adam, mean squared error).
    batch_size : int
        Mini-batch size for training and scoring.
    lr : float
        Adam learning rate.
    stride : int
        Rows between consecutive training windows.
    max_train_windows : int
        Cap on training windows; more are subsampled deterministically with ``random_state``.
    device : str or None
        Torch device; None for "cuda" when available, else "cpu".
    n_threads : int
        Torch CPU threads while fitting and scoring; 0 for the job's share of the cores.
    columns : list of str or None
        Sensor columns to use; None for the feature rule's columns.
    random_state : int
        Seed of the weights, the training shuffles and the window subsample.

    Attributes
    ----------
    net_ : torch module
        The trained autoencoder (on the CPU).
    n_train_windows_ : int
        Windows it was trained on.
    """

    name = "lstm_ae"
    window_params = ("window",)
    relative_cost = 81.0  # us per row (perf.detector_speed, scaled to statistical's 3.6)
    description = "LSTM encoder-decoder (Malhotra et al. 2016) on windows: reconstruction error"

    def __init__(self, window: int = 25, hidden: int = 32, epochs: int = 5, batch_size: int = 64, lr: float = 1e-3,
                 stride: int = 5, max_train_windows: int = 2000, device: str | None = None, n_threads: int = 1,
                 columns: list[str] | None = None, random_state: int = 0):
        self.window = window
        self.hidden = hidden
        self.epochs = epochs
        self.batch_size = batch_size
        self.lr = lr
        self.stride = stride
        self.max_train_windows = max_train_windows
        self.device = device
        self.n_threads = n_threads
        self.columns = columns
        self.random_state = random_state

    def _check_params(self) -> None:
        if not 2 <= int(self.window) <= MAX_WINDOW_ROWS:
            raise DetectorError(f"{self.name}: window must be in 2..{MAX_WINDOW_ROWS:,} rows, got {self.window!r}")
        for key in ("hidden", "epochs", "batch_size", "stride", "max_train_windows"):
            if int(getattr(self, key)) < 1:
                raise DetectorError(f"{self.name}: {key} must be a positive integer, got {getattr(self, key)!r}")
        if int(self.n_threads) < 0:
            raise DetectorError(f"{self.name}: n_threads must be 0 (the job's share of the cores) or more, "
                                f"got {self.n_threads!r}")

    def windows(self, X: np.ndarray, step: int = 1) -> np.ndarray:
        """The windows (float32, windows x rows x channels) ending at rows 0, step, 2 step, ... of ``X``."""
        w = int(self.window)
        padded = np.ascontiguousarray(pad_start(np.asarray(X, dtype=np.float32), w - 1))
        view = np.lib.stride_tricks.sliding_window_view(padded, w, axis=0)  # (windows, channels, rows)
        return np.ascontiguousarray(view[::step].transpose(0, 2, 1))

    def _device(self) -> torch.device:
        return torch.device(self.device or ("cuda" if torch.cuda.is_available() else "cpu"))

    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        train = np.concatenate([self.windows(x, int(self.stride)) for x in X_list], axis=0)
        rng = self._rng()
        cap = int(self.max_train_windows)
        if train.shape[0] > cap:
            train = train[np.sort(rng.choice(train.shape[0], size=cap, replace=False))]
        device = self._device()
        cuda = [device.index or 0] if device.type == "cuda" else []
        with _torch_threads(int(self.n_threads)), torch.random.fork_rng(devices=cuda):
            torch.manual_seed(int(self.random_state))
            net = _LSTMAutoencoder(train.shape[2], int(self.hidden)).to(device)
            opt = torch.optim.Adam(net.parameters(), lr=float(self.lr))
            data = torch.from_numpy(train).to(device)
            b = int(self.batch_size)
            net.train()
            for _ in range(int(self.epochs)):
                order = torch.from_numpy(rng.permutation(train.shape[0]))
                for lo in range(0, train.shape[0], b):
                    batch = data[order[lo : lo + b]]
                    loss = torch.mean((net(batch) - batch) ** 2)
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
        self.net_ = net.cpu().eval()
        self.history_rows_ = int(self.window)
        self.n_train_windows_ = int(train.shape[0])

    def _score(self, X: np.ndarray) -> np.ndarray:
        wins = self.windows(X)
        n, b = wins.shape[0], int(self.batch_size)
        wins = np.concatenate([wins, np.repeat(wins[-1:], (-n) % b, axis=0)], axis=0)  # whole batches
        device = self._device()
        net = self.net_.to(device)
        out = []
        with _torch_threads(int(self.n_threads)), torch.no_grad():
            for lo in range(0, wins.shape[0], b):
                batch = torch.from_numpy(wins[lo : lo + b]).to(device)
                out.append(torch.mean((net(batch) - batch) ** 2, dim=(1, 2)).cpu())
        self.net_ = net.cpu()
        return torch.cat(out).numpy().astype(np.float64)[:n]

    def _score_last(self, X: np.ndarray) -> float:
        """The window ending at the last row, scored in a batch as :meth:`_score` scores it."""
        return float(self._score(X[-int(self.window):])[-1])
