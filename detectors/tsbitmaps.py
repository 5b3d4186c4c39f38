"""Time-series bitmaps: SAX subword frequencies in a lag and a lead window, compared.

Implements the anomaly score of Wei, Kumar, Lolla, Keogh, Lonardi and Ratanamahatana,
"Assumption-free anomaly detection in time series" (SSDBM 2005), built on the bitmaps of
Kumar, Lolla, Keogh, Lonardi, Ratanamahatana and Wei, "Time-series bitmaps: a practical
visualization tool for working with large time series databases" (SDM 2005):

1. each channel is discretised with SAX: a subsequence is z-normalised, reduced by the
   piecewise aggregate approximation (PAA, the mean of ``feature_window_size`` points per
   symbol) and each mean mapped to one of ``alphabet_size`` symbols by the breakpoints that cut
   a standard normal into equiprobable regions;
2. the frequencies of the words of ``level_size`` symbols in a window form the window's bitmap
   (``alphabet_size ** level_size`` cells), each cell normalised by the largest one;
3. two adjacent windows slide along the series, the lag window (the recent past) and the lead
   window; the anomaly score is the squared Euclidean distance between their bitmaps.

Here the lead window ends at the current row and the lag window precedes it, so the score is
causal. A word is computed at every row from the ``level_size * feature_window_size`` rows
ending at it (z-normalised over that span, one PAA symbol per ``feature_window_size`` rows);
window counts are differences of cumulative counts, so scoring is a few vectorised numpy
operations per channel. Each channel's distances are divided by their ``q``-th percentile on
the training flights, then channels are combined by ``max`` or ``mean``.

Published settings: the papers use an alphabet of 4 (square bitmaps) and levels up to 3-4;
open implementations default to ``level_size=3`` (binhmop/tsbitmaps, TimeEval), and TimeEval's
adapter uses lag/lead windows of 300/200 points. The defaults here are 4 symbols, level 3, one
symbol per 5 rows (0.1 s at 50 Hz) and lag/lead windows of 300/100 rows (6 s / 2 s).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.stats import norm

from scart_bench.detectors._kernels import bitmap_distances
from scart_bench.detectors.base import MAX_WINDOW_ROWS, Detector, DetectorError, DetectorStream
from scart_bench.detectors.statistical import pad_start

#: Smallest per-channel unit of distance: one bitmap cell entirely different. Keeps channels that
#: barely move in training (their training percentile is ~0) from turning noise into huge scores.
_MIN_UNIT = 1.0


def sax_breakpoints(alphabet_size: int) -> np.ndarray:
    """The ``alphabet_size - 1`` cut points of a standard normal into equiprobable regions."""
    return norm.ppf(np.arange(1, alphabet_size) / alphabet_size)


#: The most bitmap cells (alphabet_size ** level_size) accepted: each channel keeps two such count arrays.
MAX_CELLS = 65_536

class TSBitmaps(Detector):
    """Time-series bitmaps (Wei et al. 2005): distance between lag and lead SAX bitmaps.

    Parameters
    ----------
    feature_window_size : int
        Rows averaged into one SAX symbol (the PAA segment length).
    alphabet_size : int
        SAX symbols; 4 gives the papers' square bitmaps.
    level_size : int
        Length of the counted subwords (the bitmap level); the bitmap has ``alphabet_size **
        level_size`` cells.
    lag_window_size : int
        Rows in the lag window (the reference), immediately before the lead window.
    lead_window_size : int
        Rows in the lead window, ending at the scored row.
    min_std : float
        Word spans whose standard deviation (in units of the channel's training standard
        deviation) is below this are flat: they are centred but not scaled, so sensor noise on a
        still channel does not turn into random symbols.
    q : float
        Percentile (0..100) of each channel's training distances used as its unit.
    combine : {"max", "mean"}
        How the calibrated channel distances are combined into the row score.
    columns : list of str or None
        Sensor columns to use; None for every ``topic.field`` column.
    random_state : int
        Unused (the method is deterministic); kept for the common interface.

    Attributes
    ----------
    breakpoints_ : ndarray (alphabet_size - 1,)
        SAX cut points on the standardised channels.
    unit_ : ndarray (channels,)
        Per-channel calibration divisor (training percentile ``q``, at least 1).

    Before ``lag_window_size + lead_window_size`` rows are available, the history seen so far is
    split between lag and lead in the same proportion and the distance is weighted by the share
    of the full history seen (bitmaps of a few counts are noisy); the first row scores 0.
    """

    name = "tsbitmaps"
    relative_cost = 7.0  # us per row, paper flights (scheduling hint)
    description = "time-series bitmaps (Wei et al. 2005): SAX subword bitmaps of lag vs lead window"

    def __init__(
        self,
        feature_window_size: int = 5,
        alphabet_size: int = 4,
        level_size: int = 3,
        lag_window_size: int = 300,
        lead_window_size: int = 100,
        min_std: float = 0.01,
        q: float = 99.0,
        combine: str = "max",
        columns: list[str] | None = None,
        random_state: int = 0,
    ):
        self.feature_window_size = feature_window_size
        self.alphabet_size = alphabet_size
        self.level_size = level_size
        self.lag_window_size = lag_window_size
        self.lead_window_size = lead_window_size
        self.min_std = min_std
        self.q = q
        self.combine = combine
        self.columns = columns
        self.random_state = random_state

    # -- the method ------------------------------------------------------------------------------
    def _check_params(self) -> None:
        checks = {
            "feature_window_size": 1 <= int(self.feature_window_size) <= MAX_WINDOW_ROWS,
            "alphabet_size": 2 <= int(self.alphabet_size) <= MAX_CELLS,
            "level_size": 1 <= int(self.level_size) <= 16,
            "lag_window_size": 1 <= int(self.lag_window_size) <= MAX_WINDOW_ROWS,
            "lead_window_size": 1 <= int(self.lead_window_size) <= MAX_WINDOW_ROWS,
            "min_std": float(self.min_std) > 0.0,
            "q": 0.0 < float(self.q) <= 100.0,
            "combine": self.combine in ("max", "mean"),
        }
        bad = ", ".join(f"{k}={getattr(self, k)!r}" for k, ok in checks.items() if not ok)
        if not bad and int(self.alphabet_size) ** int(self.level_size) > MAX_CELLS:
            bad = (f"alphabet_size={self.alphabet_size!r} and level_size={self.level_size!r} "
                   f"(alphabet_size ** level_size cells, at most {MAX_CELLS:,})")
        if bad:
            raise DetectorError(f"{self.name}: invalid parameter(s) {bad}; expected windows of 1..{MAX_WINDOW_ROWS:,} "
                                f"rows, alphabet_size >= 2, level_size 1..16 with alphabet_size ** level_size <= "
                                f"{MAX_CELLS:,}, min_std > 0, 0 < q <= 100 and combine max or mean")

    def _subword_codes(self, X: np.ndarray) -> np.ndarray:
        """Integer code (rows, channels) of the SAX word ending at each row.

        The word spans ``level_size * feature_window_size`` rows, z-normalised over that span
        (flat spans, std below ``min_std``, are only centred), one PAA symbol per
        ``feature_window_size`` rows. Rows before a full span see the first row repeated. Each
        code is computed from its own span alone (:meth:`_span_codes`), so streaming gives
        bit-identical codes.
        """
        if X.shape[0] == 0:
            return np.zeros(X.shape, dtype=np.int64)
        span = int(self.feature_window_size) * int(self.level_size)
        view = sliding_window_view(pad_start(np.asarray(X, dtype=np.float64), span - 1), span, axis=0)
        return self._span_codes(view)

    def _span_codes(self, view: np.ndarray) -> np.ndarray:
        """SAX word codes of spans ``view`` (words, channels, span rows), summed in a fixed order."""
        w, a, level = int(self.feature_window_size), int(self.alphabet_size), int(self.level_size)
        span = w * level
        seg_sums = []
        total = sq = None
        for k in range(level):  # oldest segment first
            acc = None
            for i in range(k * w, (k + 1) * w):
                col = view[..., i]
                acc = col.copy() if acc is None else acc + col
                sq = col * col if sq is None else sq + col * col
            seg_sums.append(acc)
            total = acc.copy() if total is None else total + acc
        span_mean = total / span
        span_std = np.sqrt(np.maximum(sq / span - span_mean * span_mean, 0.0))
        span_std = np.where(span_std >= float(self.min_std), span_std, np.inf)
        codes = np.zeros(span_mean.shape, dtype=np.int64)
        for acc in seg_sums:
            symbol = np.searchsorted(self.breakpoints_, ((acc / w - span_mean) / span_std).ravel(), side="right")
            codes = codes * a + symbol.reshape(span_mean.shape)
        return codes

    def _window_bounds(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Start of the lag window, start of the lead window and end (exclusive) per row."""
        return self._window_bounds_at(np.arange(1, n + 1))

    def _window_bounds_at(self, end: np.ndarray | int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Window bounds of the rows whose windows end (exclusive) at ``end``."""
        lag, lead = int(self.lag_window_size), int(self.lead_window_size)
        end = np.atleast_1d(np.asarray(end, dtype=np.int64))
        lead_len = np.where(end >= lag + lead, lead, np.maximum(1, np.rint(end * lead / (lag + lead))))
        lead_len = lead_len.astype(np.int64)
        lag_len = np.minimum(end - lead_len, lag)
        return end - lead_len - lag_len, end - lead_len, end

    @staticmethod
    def _bitmap_distance(
        codes: np.ndarray, bounds: tuple[np.ndarray, np.ndarray, np.ndarray], full_history: int
    ) -> np.ndarray:
        """Squared distance between the max-normalised lag and lead bitmaps of one channel.

        Warm-up: bitmaps of a few counts are noisy, so the distance is weighed by the share of
        history available; with no lag window yet (the first row) there is nothing to compare with.
        """
        if codes.size == 0:
            return np.zeros(0)
        _, compact = np.unique(codes, return_inverse=True)  # only the subwords that occur
        lag_start, lead_start, end = (np.asarray(b, dtype=np.int64) for b in bounds)
        return bitmap_distances(compact.astype(np.int64).reshape(-1), int(compact.max()) + 1,
                                 lag_start, lead_start, end, float(full_history))

    def _channel_distances(self, X: np.ndarray) -> np.ndarray:
        """Raw lag/lead bitmap distance (rows, channels) of standardised ``X``."""
        codes = self._subword_codes(X)
        bounds = self._window_bounds(X.shape[0])
        full = int(self.lag_window_size) + int(self.lead_window_size)
        return np.stack([self._bitmap_distance(codes[:, j], bounds, full) for j in range(X.shape[1])], axis=1)

    # -- Detector hooks ----------------------------------------------------------------------------
    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        self.breakpoints_ = sax_breakpoints(int(self.alphabet_size))
        # rows a live monitor keeps; symbols are aligned to the start of the series, so a trailing
        # window reproduces the batch score only approximately (within ~10 % here)
        self.history_rows_ = int(self.lag_window_size) + int(self.lead_window_size) + int(self.feature_window_size)
        train = np.concatenate([self._channel_distances(x) for x in X_list], axis=0)
        self.unit_ = np.maximum(np.percentile(train, float(self.q), axis=0), _MIN_UNIT)

    def _score(self, X: np.ndarray) -> np.ndarray:
        calibrated = self._channel_distances(X) / self.unit_
        return calibrated.max(axis=1) if self.combine == "max" else calibrated.mean(axis=1)

    def stream(self) -> BitmapStream:
        """Incremental live scorer: one new word per channel and a few bitmap cell updates per row."""
        self._check_fitted()
        return BitmapStream(self)


class BitmapStream(DetectorStream):
    """TSBitmaps fed one row at a time: the same scores as ``score`` on the rows seen so far.

    Keeps the last word span of prepared rows, the words of the lag and lead windows and their
    per-channel cell counts; each row adds one word to the lead window, moves the words that
    leave it to the lag window and drops those that leave the lag window.
    """

    def __init__(self, detector: TSBitmaps):
        super().__init__(detector)
        d = detector
        self.span = int(d.feature_window_size) * int(d.level_size)
        self.full = int(d.lag_window_size) + int(d.lead_window_size)
        n_ch = d.mean_.shape[0]
        cells = int(d.alphabet_size) ** int(d.level_size)
        self._buf: np.ndarray | None = None  # (span, channels) prepared rows, oldest first
        self._last: np.ndarray | None = None
        self._codes = np.zeros((self.full + 2, n_ch), dtype=np.int64)  # ring of words by row
        self._lag = np.zeros((n_ch, cells), dtype=np.int64)
        self._lead = np.zeros((n_ch, cells), dtype=np.int64)
        self._ch = np.arange(n_ch)
        self._lag_start = self._lead_start = 0

    def update(self, row: np.ndarray) -> float:
        d = self.detector
        z = d._prepare_row(row, self._last)
        self._last = z
        if self._buf is None:
            self._buf = np.repeat(z[None], self.span, axis=0)
        else:
            self._buf[:-1] = self._buf[1:]
            self._buf[-1] = z
        code = d._span_codes(self._buf.T[None])[0]
        ring = self._codes.shape[0]
        self._codes[self.n_rows % ring] = code
        self.n_rows += 1
        end = self.n_rows
        self._lead[self._ch, code] += 1
        lag_start, lead_start, _ = (int(b[0]) for b in d._window_bounds_at(end))
        while self._lead_start < lead_start:
            moved = self._codes[self._lead_start % ring]
            self._lead[self._ch, moved] -= 1
            self._lag[self._ch, moved] += 1
            self._lead_start += 1
        while self._lag_start < lag_start:
            self._lag[self._ch, self._codes[self._lag_start % ring]] -= 1
            self._lag_start += 1
        maps = []
        for counts in (self._lag, self._lead):
            c = counts.astype(np.float64)
            peak = c.max(axis=1, keepdims=True)
            maps.append(np.divide(c, peak, out=np.zeros_like(c), where=peak > 0))
        dist = np.sum((maps[1] - maps[0]) ** 2, axis=1)
        weight = min(1.0, (end - lag_start) / self.full) if lead_start > lag_start else 0.0
        calibrated = dist * weight / d.unit_
        return d._checked_last(float(calibrated.max() if d.combine == "max" else calibrated.mean()))
