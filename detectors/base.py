"""The Detector protocol shared by every built-in adapter and every plugin.

A detector learns what normal flights look like from a list of combined navigator-view tables
(one ``pandas.DataFrame`` per flight, rows in time order, columns ``topic.field``) and then
gives one anomaly score per row of a new flight: higher means more anomalous. Scores must be
causal (the score of row ``i`` depends only on rows ``0..i``), so that a detector can run on a
live stream and batch scores equal streaming scores.

Modelled on scikit-learn estimators: constructor arguments are plain parameters stored unchanged,
``__init__`` does no work, fitted state lives in attributes ending in ``_``.
"""

from __future__ import annotations

import fnmatch
import re
from collections import deque
from functools import lru_cache

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator

from scart_bench.dataset.schema import TOPICS, sensor_columns
from scart_bench.errors import ScartBenchError

#: Field names that are not sensor values (the feature rule, matched on the part after ``topic.``):
#: timestamps, counters, ids and reset counters/deltas. Constant columns go too (see feature_columns).
#: Clocks, ids and counters of imported logs, by ArduPilot DataFlash, MAVLink tlog and ROS names (field
#: names as the importers give them): GPS time of week and week (``TimeMS``, ``Week``, ``GMS``,
#: ``GWk``), boot clocks (``TimeUS``, ``T``, ``SampleUS``, ``time_boot_ms``, ``tc1``/``ts1``), message
#: stamps and sequence numbers (``header_stamp_sec``, ``header_seq``), instance and event ids (``Id``,
#: ``I``, ``Instance``), loop and error counters (``NLon``, ``NLoop``, ``I2CErr``, ``errors_count1``).
#: None is a field of a generated flight (tests/test_log_features.py checks it), so generated datasets'
#: features are unchanged.
LOG_NON_FEATURE_PATTERN = (
    r"^(TimeMS|TimeUS|Week|GMS|GWk|T|SampleUS|GPSTime|TimeMsec|time_boot_ms|tc1|ts1)$|"  # clocks
    r"(^|_)stamp_(sec|nanosec|nsec)$|^header_seq$|"  # ROS message stamps
    r"^(Id|I|Inst|Instance|Subsys|ECode|Seq)$|"  # instance, event and error ids
    r"^(NLon|NLoop|MaxT|LogDrop|NFail)$|Err$|^errors_count\d+$|^errors_comm$|^drop_rate_comm$"  # counters
)

NON_FEATURE_FIELDS = re.compile(
    r"(^|_)timestamp(_|$)|^time_utc_usec$|_time_relative$|^time_|"  # clocks
    r"(^|_)(device_)?id$|_ids?$|^serial_number$|_device_id$|"  # identifiers
    r"_reset_counter$|(^|_)delta_.*reset|_reset(_\d+)?$|"  # estimator resets and their deltas
    r"_counter$|_count$|^count$|"  # counters
    + LOG_NON_FEATURE_PATTERN
)


#: Control and state flags (matched on the field name): what the vehicle or its operator *decided*
#: (armed, arming and navigation state, flight mode, the current mission item, landed and in-air
#: flags), not what a sensor or estimator *measured*. They change in steps at arming, take-off and
#: every waypoint of every normal flight (the arm request's 0 -> 1 step is a 7-sd jump), so a
#: detector that uses them learns the mission's script; attacks on the control link show in the
#: measured state they change. A run can still use them: ``--features`` names columns outright.
#: The same flags under ArduPilot's and MAVLink's names (flight mode and its reason, the landed state,
#: the system status and the sensor-health bitmasks of SYS_STATUS); none is a generated flight's field.
LOG_CONTROL_STATE_PATTERN = (
    r"^(Mode|ModeNum|Rsn|ThrCrs)$|^landed_state$|^vtol_state$|^system_status$|^onboard_control_sensors_|"
    r"^mavlink_version$|^autopilot$|^type$"
)

CONTROL_STATE_FIELDS = re.compile(
    r"^armed$|^arming_state$|^nav_state|^main_state$|(^|_)mode$|^flight_mode|^seq$|^mission_seq$|"
    r"^current_seq$|^landed$|^maybe_landed$|^ground_contact$|^in_air$|^freefall$|^failsafe|"
    + LOG_CONTROL_STATE_PATTERN
)


#: The longest window, in rows, a built-in detector accepts (5.5 h at 50 Hz): a bound on the memory a
#: parameter can ask for before any flight is read (the run also checks windows against its flights).
MAX_WINDOW_ROWS = 1_000_000


def is_feature_name(column: str) -> bool:
    """False for a ``topic.field`` column whose field is a timestamp, counter, id or reset counter,
    or a control or state flag (:data:`CONTROL_STATE_FIELDS`)."""
    name = column.partition(".")[2]
    return not (NON_FEATURE_FIELDS.search(name) or CONTROL_STATE_FIELDS.search(name))


def feature_columns(flights: list[pd.DataFrame], include: list[str] | None = None,
                    exclude: list[str] | None = None) -> tuple[list[str], dict[str, list[str]]]:
    """The feature rule: which columns of the training flights a detector uses, and why others not.

    A feature is a ``topic.field`` column present in every training flight that is not a
    timestamp, counter, id or reset counter (:data:`NON_FEATURE_FIELDS`), not a control or state
    flag (:data:`CONTROL_STATE_FIELDS`: armed, modes, mission item) and is not constant over the
    training flights (constant or all missing; +/-inf counts as missing).
    ``include`` (glob patterns, e.g. ``vehicle_gps_position.*``) keeps only matching columns and
    overrides the name rule; ``exclude`` drops matching columns. Returns (features, dropped) with
    ``dropped`` mapping each reason to its columns.
    """
    common = [c for c in sensor_columns(flights[0].columns) if all(c in f.columns for f in flights[1:])]
    dropped: dict[str, list[str]] = {"not in every training flight": sorted(
        {c for f in flights for c in sensor_columns(f.columns)} - set(common))}
    if include:
        keep = [c for c in common if any(fnmatch.fnmatchcase(c, p) for p in include)]
        dropped["not in --features"] = [c for c in common if c not in keep]
    else:
        keep = [c for c in common if is_feature_name(c)]
        dropped["timestamp, counter, id or reset"] = [
            c for c in common if NON_FEATURE_FIELDS.search(c.partition(".")[2])]
        dropped["control or state flag"] = [
            c for c in common if c not in keep and not NON_FEATURE_FIELDS.search(c.partition(".")[2])]
    if exclude:
        dropped["--exclude"] = [c for c in keep if any(fnmatch.fnmatchcase(c, p) for p in exclude)]
        keep = [c for c in keep if c not in dropped["--exclude"]]
    constant = []
    for c in keep:
        lo, hi = np.inf, -np.inf
        for f in flights:
            v = pd.to_numeric(f[c], errors="coerce").to_numpy(dtype=np.float64)
            v = v[np.isfinite(v)]
            if v.size:
                lo, hi = min(lo, float(v.min())), max(hi, float(v.max()))
        if not hi > lo:
            constant.append(c)
    dropped["constant or missing"] = constant
    return [c for c in keep if c not in constant], {k: v for k, v in dropped.items() if v}


class DetectorError(ScartBenchError):
    """A detector was used wrongly: no training flights, not fitted, missing columns."""


class NotFittedError(DetectorError):
    """``score`` was called before ``fit``."""


class Detector(BaseEstimator):
    """Base class of all detectors.

    Subclasses set ``name`` and ``description``, take their parameters as keyword arguments of
    ``__init__`` (stored unchanged, no other work) and implement ``_fit(X_list)`` and
    ``_score(X)`` on float64 arrays of the selected, standardised columns. The base class
    handles column selection, missing-value filling, standardisation and input checks.

    What a run passes a detector, and nothing else (the conformance kit checks it):

    - constructor parameters (define them in the subclass ``__init__``): ``random_state`` (the run's
      ``--seed``), ``columns`` (list of column names, or None for the features chosen by
      :func:`feature_columns`), ``device`` for torch detectors (``--device``), and the detector's own
      parameters (``--param NAME.KEY=VALUE``);
    - arguments of :meth:`fit`: ``features`` / ``exclude``, the run's feature rule (glob patterns of
      ``scart-bench run --features/--exclude``), used when ``columns`` is None.

    Feature preparation, the same for every detector: +/-inf is missing (NaN); mean and scale
    are NaN-aware statistics of the training rows; missing values are filled *after*
    standardising and causally (the last value of the column, then 0, its training mean).

    Fitted attributes set by the base class (reserved names): ``columns_``, ``mean_``,
    ``scale_``, ``n_features_in_``, ``dropped_columns_``. A detector may also set ``history_rows_``: how many trailing
    rows reproduce the score of the last row when streaming (used by the latency benchmark and
    the live proxy).
    """

    name: str = "detector"
    description: str = ""
    #: True when the detector implements ``alarms`` with its own threshold.
    has_alarms: bool = False
    #: Rough scoring cost per row relative to the others (microseconds per row on one core, as
    #: ``perf.detector_speed`` measures it). Only a scheduling hint: a run starts its costliest
    #: jobs first, so that two long jobs do not end up last on the same worker.
    relative_cost: float = 10.0

    # -- public API -------------------------------------------------------------------------
    def fit(self, flights: list[pd.DataFrame], *, features: list[str] | None = None,
            exclude: list[str] | None = None) -> Detector:
        """Learn normal behaviour from a list of normal flights (combined tables).

        ``features`` keeps only the columns matching these glob patterns and ``exclude`` drops the
        matching ones (the run's ``--features`` / ``--exclude``); both apply when ``columns`` is None.
        """
        if isinstance(flights, pd.DataFrame):
            flights = [flights]
        flights = list(flights)
        if not flights:
            raise DetectorError(f"{self.name}: fit needs at least one training flight, got none")
        cols = getattr(self, "columns", None)
        self.dropped_columns_: dict[str, list[str]] = {}
        if cols is None:
            cols, self.dropped_columns_ = feature_columns(flights, features, exclude)
        cols = list(cols)
        if not cols:
            raise DetectorError(f"{self.name}: the training flights have no usable sensor columns (topic.field); "
                                f"dropped: { {k: v[:5] for k, v in self.dropped_columns_.items()} }")
        for i, f in enumerate(flights):
            missing = [c for c in cols if c not in f.columns]
            if missing:
                raise DetectorError(f"{self.name}: training flight {i} lacks columns {missing[:5]}")
        raw = [self._raw_matrix(f, cols) for f in flights]
        stacked = np.concatenate(raw, axis=0)
        if stacked.shape[0] == 0:
            raise DetectorError(f"{self.name}: the training flights have no rows")
        self.columns_ = cols
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: mean 0, scale 1
                mean = np.nanmean(stacked, axis=0)
                std = np.nanstd(stacked, axis=0)
        self.mean_ = np.where(np.isfinite(mean), mean, 0.0)
        self.scale_ = np.where(np.isfinite(std) & (std > 1e-12), std, 1.0)
        self._fit([self._standardise(x) for x in raw])
        self.n_features_in_ = len(cols)
        return self

    def score(self, flight: pd.DataFrame) -> np.ndarray:
        """One anomaly score per row of ``flight`` (higher = more anomalous), float64."""
        X = self._transform(flight)
        if X.shape[0] == 0:
            return np.zeros(0)
        s = np.asarray(self._score(X), dtype=np.float64).reshape(-1)
        if s.shape[0] != X.shape[0]:
            raise DetectorError(f"{self.name}: produced {s.shape[0]} scores for {X.shape[0]} rows")
        if not np.all(np.isfinite(s)):
            bad = int(np.flatnonzero(~np.isfinite(s))[0])
            j = int(np.argmax(np.abs(np.nan_to_num(X[bad], nan=np.inf))))
            names = self._feature_names()
            raw = self._raw_matrix(flight.iloc[: bad + 1], self.columns_)[bad, j]
            raise DetectorError(f"{self.name}: non-finite score {s[bad]} at row {bad}: column {names[j]!r} is the "
                                f"most extreme there (value {raw:g}, standardised {X[bad, j]:g}); "
                                "NaN is a failure, not a 0")
        return s

    def score_last(self, history: pd.DataFrame) -> float:
        """Score of the last row of ``history``, equal to ``score(history)[-1]``.

        For a live monitor that keeps the trailing ``history_rows_`` rows of a stream; detectors
        may override ``_score_last`` to score only the last row instead of all of them.
        """
        X = self._transform(history)
        if X.shape[0] == 0:
            raise DetectorError(f"{self.name}: score_last needs at least one row")
        return self._checked_last(float(self._score_last(X)))

    def stream(self) -> DetectorStream:
        """A live scorer fed one raw row at a time (``update(row)``, values in ``columns_`` order).

        Gives the same scores as :meth:`score` on the rows seen so far. The default keeps the
        trailing ``history_rows_`` rows (500 when unset) and calls :meth:`score_last`; detectors
        with incremental state (TSBitmaps) return their own.
        """
        self._check_fitted()
        return TrailingStream(self)

    def _checked_last(self, score: float) -> float:
        if not np.isfinite(score):
            raise DetectorError(f"{self.name}: non-finite score {score} on the last row; NaN is a failure, not a 0")
        return score

    def _feature_names(self) -> list[str]:
        """Names of the prepared matrix's columns (angles become ``col:sin`` and ``col:cos`` at the end)."""
        angles = _angle_columns(tuple(self.columns_))
        rest = [c for i, c in enumerate(self.columns_) if i not in angles]
        return rest + [f"{self.columns_[i]}:sin" for i in angles] + [f"{self.columns_[i]}:cos" for i in angles]

    def alarms(self, flight: pd.DataFrame) -> np.ndarray:  # pragma: no cover - optional
        """Boolean alarm per row, for detectors with their own thresholding."""
        raise NotImplementedError(f"{self.name} has no thresholding of its own")

    # -- for subclasses -----------------------------------------------------------------------
    def _check_params(self) -> None:
        """Raise DetectorError naming a parameter whose value is out of range (no data needed).

        Called by the benchmark before a run starts, so a bad ``--param`` is refused up front;
        subclasses call it at the start of ``_fit`` too.
        """

    def _fit(self, X_list: list[np.ndarray]) -> None:
        raise NotImplementedError

    def _score(self, X: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _score_last(self, X: np.ndarray) -> float:
        """Score of the last row of prepared ``X`` (default: all rows scored, the last kept)."""
        return float(np.asarray(self._score(X), dtype=np.float64).reshape(-1)[-1])

    def _rng(self) -> np.random.Generator:
        return np.random.default_rng(getattr(self, "random_state", 0))

    # -- helpers ------------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "columns_"):
            raise NotFittedError(f"{self.name}: call fit(flights) before score(flight)")

    def _transform(self, flight: pd.DataFrame) -> np.ndarray:
        self._check_fitted()
        if not isinstance(flight, pd.DataFrame):
            raise DetectorError(f"{self.name}: score expects a pandas DataFrame, got {type(flight).__name__}")
        missing = [c for c in self.columns_ if c not in flight.columns]
        if missing:
            raise DetectorError(
                f"{self.name}: the flight lacks {len(missing)} column(s) it was trained on, "
                f"e.g. {missing[:5]}"
            )
        return self._standardise(self._raw_matrix(flight, self.columns_))

    def _standardise(self, raw: np.ndarray) -> np.ndarray:
        """Standardise, then fill missing values causally: the column's last value, else 0 (its mean)."""
        z = (raw - self.mean_) / self.scale_
        if np.isnan(z).any():
            z = pd.DataFrame(z).ffill().fillna(0.0).to_numpy()
        return z

    def _prepare_row(self, row: np.ndarray, last: np.ndarray | None) -> np.ndarray:
        """One raw row (``columns_`` order) prepared like :meth:`_transform` prepares a flight.

        ``last`` is the previous prepared row (None at the start): missing values take its value,
        else 0, as the causal fill of :meth:`_standardise`.
        """
        arr = np.array(row, dtype=np.float64).reshape(-1)
        arr[np.isinf(arr)] = np.nan
        angles = _angle_columns(tuple(self.columns_))
        if angles:
            a = arr[angles]
            arr = np.concatenate([np.delete(arr, angles), np.sin(a), np.cos(a)])
        z = (arr - self.mean_) / self.scale_
        gap = np.isnan(z)
        if gap.any():
            z[gap] = 0.0 if last is None else last[gap]
        return z

    @staticmethod
    def _raw_matrix(flight: pd.DataFrame, cols: list[str]) -> np.ndarray:
        """Selected columns as float64 with +/-inf as missing (NaN; filled after standardising).

        Angle fields (yaw, heading, course: ``quantity == "angle"`` in scart_bench.dataset.schema) wrap
        around; each is replaced by its sine and cosine so that a wrap is not a jump.
        """
        block = flight[cols]
        if all(pd.api.types.is_numeric_dtype(d) for d in block.dtypes):
            arr = block.to_numpy(dtype=np.float64, copy=True)
        else:
            arr = block.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
        arr[np.isinf(arr)] = np.nan
        angles = _angle_columns(tuple(cols))
        if angles:
            a = arr[:, angles]
            arr = np.concatenate([np.delete(arr, angles, axis=1), np.sin(a), np.cos(a)], axis=1)
        return arr


@lru_cache(maxsize=64)
def _angle_columns(cols: tuple[str, ...]) -> list[int]:
    """Indices of the columns whose field is an angle that wraps (yaw, hdg, cog)."""
    out = []
    for i, c in enumerate(cols):
        topic, _, field = c.partition(".")
        t = TOPICS.get(topic)
        if t is not None and field in t.field_names:
            if t.fields[t.field_names.index(field)].quantity == "angle" and field in WRAPPING_ANGLES:
                out.append(i)
    return out


#: Angle fields that wrap around (roll and pitch stay far from +-pi in flight).
WRAPPING_ANGLES = ("yaw", "hdg", "cog")


class DetectorStream:
    """Scores a live stream one row at a time; ``update(row)`` returns the new row's score.

    ``row`` holds the raw values of the detector's ``columns_`` in order (NaN where missing).
    """

    def __init__(self, detector: Detector):
        self.detector = detector
        self.n_rows = 0

    def update(self, row: np.ndarray) -> float:
        raise NotImplementedError


#: Rows a trailing stream keeps when the detector does not set ``history_rows_`` (10 s at 50 Hz).
DEFAULT_HISTORY_ROWS = 500


class TrailingStream(DetectorStream):
    """The default stream: the trailing ``history_rows_`` rows, the last one scored.

    Rows are prepared one by one as they arrive (:meth:`Detector._prepare_row`) and the
    detector's ``_score_last`` scores the prepared window, so no table is built per sample. A
    detector that overrides ``score`` or ``_transform`` is called through ``score_last`` on a
    table of the trailing raw rows instead.
    """

    def __init__(self, detector: Detector):
        super().__init__(detector)
        self.history = int(getattr(detector, "history_rows_", 0) or DEFAULT_HISTORY_ROWS)
        self._rows: deque[np.ndarray] = deque(maxlen=self.history)
        cls = type(detector)
        self._prepared = cls.score is Detector.score and cls._transform is Detector._transform
        self._last: np.ndarray | None = None

    def update(self, row: np.ndarray) -> float:
        self.n_rows += 1
        d = self.detector
        if self._prepared:
            self._last = d._prepare_row(row, self._last)
            self._rows.append(self._last)
            return d._checked_last(float(d._score_last(np.vstack(self._rows))))
        self._rows.append(np.asarray(row, dtype=np.float64).reshape(-1))
        return d.score_last(pd.DataFrame(np.vstack(self._rows), columns=d.columns_))


def flight_score(row_scores: np.ndarray) -> float:
    """Flight-level score: the maximum row score (NaN propagates so that it is reported)."""
    row_scores = np.asarray(row_scores, dtype=np.float64)
    if row_scores.size == 0:
        return float("nan")
    return float(np.max(row_scores))
