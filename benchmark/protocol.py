"""The evaluation protocol: which flights train, calibrate and test a detector, and the operating point.

Roles, from the dataset manifest:

- ``train``: normal flights with split "train"; the only flights a detector is fitted on.
- ``validation``: normal flights with split "validation"; the only flights thresholds are
  calibrated on.
- ``test_normal``: normal flights with split "test" (held out: the TN rate and the measured
  false-alarm rate).
- ``test_attacked``: every attacked flight (mode "simulation" or "csv"; their split must be
  "test") whose attack changed something: the TP rates.
- ``no_effect``: attacked flights marked ``no_effect`` in the manifest (the attack changed no
  row relative to the simulator view or the csv source): not scored, counted in the summary.
- ``csv_source``: normal flights with split "csv_source", reserved as the recordings csv mode
  attacks; never fitted on, calibrated on or scored.

A csv-mode flight replaying a train or validation flight (``source_flight``) is refused: its
detector would have seen the very rows it is asked to flag, and its threshold would be calibrated
on them.

The operating point (protocol v3, the default since issue 46; v2 without its first item):

- **The flight's two ends** (``phases = "ends"``). Only the airborne rows from ``phase_margin_s``
  (default 3 s) after take-off to ``phase_margin_s`` before touchdown calibrate a threshold or
  raise an alarm: the ground before take-off (start-up, arming, spin-up) and after touchdown, the
  lift-off and the touchdown transients are left out by one rule at both ends. Take-off and
  touchdown are read from the flight itself with the phase detection real logs get
  (:func:`flight_phase_bounds`: the log's land detector and flight mode where it has them, else
  altitude and vertical speed); a flight without them (no altitude, never airborne) is counted by
  the burn-in below. ``"cruise"`` leaves the climb and the final descent out too; ``"burn-in"`` is
  protocol v2's rule, what run folders made before v3 keep.
- **Burn-in** (v2's rule). Rows before ``burn_in_s`` (default 8 s) after a flight's arming neither calibrate
  a threshold nor raise an alarm, on every flight and for every detector alike: the start-up on
  the ground (sensors starting, the GPS fix, a detector's first windows), the arming step and the
  motors' spin-up are the largest transients of a normal flight and would otherwise set every
  threshold. The arming time is read from the flight itself
  (:func:`arming_time_us`: the first row where an ``armed`` field is set, or PX4's
  ``arming_state`` is ARMED); a flight without one (a log that starts armed) is armed at its
  first row.
- **Flight score** = the largest score over the counted rows.
- **Threshold**: the conformal order statistic of the validation flights' scores for a target
  per-flight false-alarm rate ``alpha`` (default 0.05): with ``n`` validation flights the
  threshold is the ``k``-th smallest, ``k = ceil((n + 1) (1 - alpha))``. For a new normal flight
  exchangeable with the validation flights, P(flight score > threshold) = 1 - k / (n + 1) <= alpha
  (Vovk et al. 2005; Angelopoulos & Bates 2021), whatever the detector. With fewer than
  ``1 / alpha - 1`` validation flights no order statistic reaches alpha: the threshold is then
  the largest validation score, its rate ``1 / (n + 1)``, and the summary says so.
- **Rows** alarm when their score is above the same number (``row_rule`` conformal: calibrated on
  the same flight scores), so that "a flight is flagged" and "a flight has a row alarm" agree.
- ``alarm_rule = "own"`` uses each detector's own alarm rule where it has one
  (``Detector.alarms``, e.g. Telemanom's nonparametric dynamic threshold) instead of the common
  threshold; detectors without one keep the calibrated threshold.

Protocol v1 (run folders made before it) is ``ThresholdRule("max", margin=0.05)`` without burn-in:
``Protocol.from_dict`` reads a v1 folder's rules as they were, so old runs score as before.

Scores of test or attacked flights never enter a threshold: :meth:`Protocol.thresholds` takes
only validation scores.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from scart_bench.detectors.base import flight_score
from scart_bench.errors import ScartBenchError

__all__ = [
    "ATTACK_MODES", "NORMAL_MODE", "ROLES", "Protocol", "ProtocolError", "Splits",
    "ThresholdRule", "arming_time_us", "conformal_rank", "counted_rows", "flight_phase_bounds", "flight_score",
    "phase_counted_rows",
]

NORMAL_MODE = "normal"
ATTACK_MODES = ("simulation", "csv")
ROLES = ("train", "validation", "test_normal", "test_attacked", "no_effect", "csv_source")
NORMAL_SPLITS = ("train", "validation", "test", "csv_source")


class ProtocolError(ScartBenchError):
    """The dataset cannot be evaluated under the protocol (missing splits, bad modes)."""


@dataclass(frozen=True)
class Splits:
    """Flight ids per role, in manifest order."""

    train: tuple[str, ...]
    validation: tuple[str, ...]
    test_normal: tuple[str, ...]
    test_attacked: tuple[str, ...]
    no_effect: tuple[str, ...] = ()
    csv_source: tuple[str, ...] = ()

    @classmethod
    def from_manifest(cls, manifest: pd.DataFrame) -> Splits:
        """Assign every manifest row its role; raise ProtocolError when the splits are unusable."""
        roles = assign_roles(manifest)
        ids = manifest["flight_id"].astype(str)
        parts = {r: tuple(ids[roles == r]) for r in ROLES}
        splits = cls(**parts)
        for role in ("train", "validation"):
            if not getattr(splits, role):
                raise ProtocolError(f"the dataset has no normal flights with split {role!r}; "
                                    "the protocol needs train and validation normal flights")
        if not splits.test_normal and not splits.test_attacked:
            raise ProtocolError("the dataset has no test flights (normal split 'test' or attacked)")
        return splits

    @property
    def scored(self) -> tuple[str, ...]:
        """Flights a fitted detector scores: validation, then the test flights."""
        return self.validation + self.test_normal + self.test_attacked

def assign_roles(manifest: pd.DataFrame) -> pd.Series:
    """The role of each manifest row (see the module docstring)."""
    missing = [c for c in ("flight_id", "mode", "split") if c not in manifest.columns]
    if missing:
        raise ProtocolError(f"manifest lacks column(s) {missing}")
    if manifest["flight_id"].duplicated().any():
        dup = manifest["flight_id"][manifest["flight_id"].duplicated()].iloc[0]
        raise ProtocolError(f"manifest lists flight {dup!r} more than once")
    mode = manifest["mode"].astype(str)
    split = manifest["split"].astype(str)
    bad_mode = ~mode.isin((NORMAL_MODE, *ATTACK_MODES))
    if bad_mode.any():
        raise ProtocolError(f"manifest mode {mode[bad_mode].iloc[0]!r}: expected one of "
                            f"{(NORMAL_MODE, *ATTACK_MODES)}")
    normal = mode == NORMAL_MODE
    bad_split = normal & ~split.isin(NORMAL_SPLITS)
    if bad_split.any():
        raise ProtocolError(f"normal flight {manifest['flight_id'][bad_split].iloc[0]!r} has split "
                            f"{split[bad_split].iloc[0]!r}; expected train, validation, test or csv_source")
    leaked = ~normal & (split != "test")
    if leaked.any():
        raise ProtocolError(f"attacked flight {manifest['flight_id'][leaked].iloc[0]!r} has split "
                            f"{split[leaked].iloc[0]!r}; attacked flights must all be 'test'")
    if "source_flight" in manifest.columns:
        fitted = set(manifest["flight_id"].astype(str)[normal & split.isin(("train", "validation"))])
        source = manifest["source_flight"].astype(object).where(manifest["source_flight"].notna(), "").astype(str)
        reused = ~normal & source.isin(fitted)
        if reused.any():
            i = reused[reused].index[0]
            raise ProtocolError(f"attacked flight {manifest['flight_id'][i]!r} replays {source[i]!r}, a "
                                f"{split[manifest['flight_id'].astype(str) == source[i]].iloc[0]} flight; csv-mode "
                                "sources must be normal flights outside train and validation (split csv_source)")
    no_effect = ~normal & no_effect_mask(manifest)
    roles = np.where(normal, split.map({"train": "train", "validation": "validation", "test": "test_normal",
                                        "csv_source": "csv_source"}),
                     np.where(no_effect, "no_effect", "test_attacked"))
    return pd.Series(roles, index=manifest.index, name="role")


def no_effect_mask(manifest: pd.DataFrame) -> pd.Series:
    """True where the manifest marks a flight ``no_effect`` (bool, 0/1 or "True"/"False" text)."""
    if "no_effect" not in manifest.columns:
        return pd.Series(False, index=manifest.index)
    v = manifest["no_effect"]
    text = v.astype(object).where(v.notna(), "false").astype(str).str.strip().str.lower()
    return text.isin(("true", "1", "1.0", "yes"))


#: Default target per-flight false-alarm rate of the operating point.
DEFAULT_ALPHA = 0.05
#: Default burn-in after arming (seconds) in which rows neither calibrate nor alarm.
DEFAULT_BURN_IN_S = 8.0
#: Default end transient (seconds after the last attacked row) in which an alarm counts as "at the end".
DEFAULT_END_TRANSIENT_S = 2.0
#: The longest burn-in or end transient accepted (an hour, longer than any flight's start-up or
#: landing; 1e12 s would overflow the microsecond arithmetic and count no row at all).
MAX_PROTOCOL_S = 3600.0
#: Values of ``Protocol.alarm_rule``.
ALARM_RULES = ("calibrated", "own")
#: Rules calibrated on the validation flights' scores (one value per flight).
FLIGHT_KINDS = ("conformal",)


def conformal_rank(n: int, alpha: float) -> int:
    """The 1-based rank ``k = ceil((n + 1) (1 - alpha))`` of the conformal threshold among ``n``
    validation flight scores (may exceed ``n``: no order statistic reaches ``alpha``)."""
    # a tiny tolerance keeps exact products such as 101 * 0.95 = 95.95 from rounding up twice
    return int(math.ceil((n + 1) * (1.0 - alpha) - 1e-9))


@dataclass(frozen=True)
class ThresholdRule:
    """How a threshold is derived from validation scores.

    ``kind="conformal"``: the ``k``-th smallest validation *flight* score,
    ``k = ceil((n + 1) (1 - alpha))`` (the largest when ``k > n``); ``margin`` is not used.
    ``kind="max"``: ``m + margin * |m|`` with ``m`` the largest value (protocol v1).
    ``kind="quantile"``: the ``q`` quantile (linear interpolation) plus ``margin * |quantile|``.
    """

    kind: str = "conformal"
    margin: float = 0.05
    q: float = 0.999
    alpha: float = DEFAULT_ALPHA

    def __post_init__(self) -> None:
        if self.kind not in ("conformal", "max", "quantile"):
            raise ProtocolError(f"threshold rule {self.kind!r}: expected 'conformal', 'max' or 'quantile'")
        if not (0.0 <= self.q <= 1.0):
            raise ProtocolError(f"threshold quantile {self.q}: expected 0 <= q <= 1")
        if self.margin < 0:
            raise ProtocolError(f"threshold margin {self.margin}: expected >= 0")
        if not (0.0 < self.alpha < 1.0):
            raise ProtocolError(f"threshold alpha {self.alpha}: expected a false-alarm rate 0 < alpha < 1")

    def calibrate(self, values: np.ndarray) -> float:
        """The threshold for these validation values (all must be finite)."""
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        if v.size == 0:
            raise ProtocolError("cannot calibrate a threshold on zero validation scores")
        if not np.all(np.isfinite(v)):
            raise ProtocolError("validation scores contain NaN or inf; a threshold cannot be calibrated")
        if self.kind == "conformal":
            k = min(conformal_rank(v.size, self.alpha), v.size)
            return float(np.partition(v, k - 1)[k - 1])
        base = float(v.max()) if self.kind == "max" else float(np.quantile(v, self.q))
        return base + self.margin * abs(base)

    def calibrate_many(self, flight_scores: np.ndarray) -> np.ndarray | None:
        """The thresholds of many resampled sets of validation *flight* scores at once (one set per
        row of ``flight_scores``); None for the quantile rule, which needs the rows themselves."""
        v = np.asarray(flight_scores, dtype=np.float64)
        if self.kind == "quantile":
            return None
        if self.kind == "conformal":
            k = min(conformal_rank(v.shape[1], self.alpha), v.shape[1])
            return np.partition(v, k - 1, axis=1)[:, k - 1]
        base = v.max(axis=1)
        return base + self.margin * np.abs(base)

    def attainable(self, n: int) -> bool:
        """Whether ``n`` validation flights reach ``alpha`` (conformal rule; other rules: True)."""
        return self.kind != "conformal" or conformal_rank(n, self.alpha) <= n

    def describe(self) -> str:
        if self.kind == "conformal":
            return (f"conformal order statistic of the validation flight scores for a per-flight "
                    f"false-alarm rate alpha = {self.alpha:g} (k = ceil((n + 1)(1 - alpha)))")
        if self.kind == "max":
            return f"max of validation scores + {self.margin:g} x |max|"
        return f"{self.q:g} quantile of validation scores + {self.margin:g} x |quantile|"


#: Fields that say the vehicle is armed: ``armed`` (the navigator's arm request, on at >= 0.5) and PX4's
#: ``arming_state`` (2 = armed).
ARMING_FIELD_NAMES = ("armed", "arming_state")


def is_armed(field_name: str, value):
    """Whether ``value`` (a number or an array) of an arming field says armed."""
    return value >= 0.5 if field_name == "armed" else value == 2.0


def arming_time_us(flight: pd.DataFrame) -> tuple[int, str]:
    """When a flight was armed (its ``Timestamp``, microseconds) and the column that says so.

    The first row where a field named ``armed`` is set (>= 0.5: the navigator's arm request on
    generated flights, ``actuator_armed.armed`` in PX4 logs) or ``arming_state`` is 2 (PX4's
    ARMING_STATE_ARMED); a flight with neither (a log recorded while armed, PX4's default) is armed
    at its first row (``"first row"``).
    """
    ts = flight["Timestamp"].to_numpy(np.int64) if "Timestamp" in flight.columns else np.zeros(0, np.int64)
    first = int(ts[0]) if ts.size else 0
    for col in flight.columns:
        if not isinstance(col, str) or "." not in col:
            continue
        field_name = col.rpartition(".")[2]
        if field_name not in ARMING_FIELD_NAMES:
            continue
        v = pd.to_numeric(flight[col], errors="coerce").to_numpy(np.float64)
        on = is_armed(field_name, v)
        hit = np.flatnonzero(on)
        if hit.size:
            return int(ts[hit[0]]), col
    return first, "first row"


def counted_rows(timestamps: np.ndarray, armed_us: float | None, burn_in_s: float) -> np.ndarray:
    """Rows that calibrate and alarm: those from ``burn_in_s`` after arming on. The start-up before
    arming (sensors starting, the GPS fix, a detector's first windows) and the arming and spin-up
    transient after it are left out alike; a log recorded from arming (PX4's default) loses only
    its first ``burn_in_s``."""
    ts = np.asarray(timestamps, dtype=np.int64).reshape(-1)
    if burn_in_s <= 0 or ts.size == 0:
        return np.ones(ts.shape, dtype=bool)
    arm = int(ts[0]) if armed_us is None or pd.isna(armed_us) else int(armed_us)
    return ts >= arm + int(round(burn_in_s * 1e6))


#: Counting rules for the ends of a flight (``Protocol.phases``): ``"burn-in"`` (protocol v2: rows
#: from ``burn_in_s`` after arming on, to the end of the recording) and ``"ends"`` (v3: the airborne
#: rows from ``phase_margin_s`` after take-off to ``phase_margin_s`` before touchdown, both read
#: from the flight's own phases) and ``"cruise"`` (the rows from the end of the climb plus
#: ``phase_margin_s`` to ``phase_margin_s`` before the final descent: both transients out whole).
PHASE_RULES = ("burn-in", "ends", "cruise")
#: The default counting rule (protocol v3; a run folder that records none counts as v2's "burn-in").
DEFAULT_PHASES = "ends"
#: Default target of the small-data operating point (false alarms per flight-hour) and its window (s).
DEFAULT_HOURLY_RATE = 1.0
DEFAULT_HOURLY_WINDOW_S = 60.0
#: Default margin (seconds) after take-off and before touchdown of the "ends" rule.
DEFAULT_PHASE_MARGIN_S = 3.0
#: A flight's phase bounds (microseconds, ``Timestamp``; <NA> where the flight has none) and their source:
#: take-off (the first airborne row), the end of the climb (the first row after take-off in neither
#: the take-off nor the climb phase), the start of the final descent (the first row of the descent
#: run that ends at touchdown) and touchdown (the first landed row after the last airborne one).
PHASE_COLUMNS = ("liftoff_us", "climb_end_us", "descent_start_us", "touchdown_us", "phases_by")


#: The topics besides the altitude sources that generator.logs.phases reads: land detectors and flight modes.
PHASE_DETECTOR_TOPICS = frozenset({"vehicle_land_detected", "extended_sys_state", "ev", "vehicle_status", "mode"})


def _topic_tables(flight: pd.DataFrame, wanted: frozenset[str]) -> dict[str, pd.DataFrame]:
    """The ``wanted`` topics of a flat flight table (``topic.field`` columns on one row grid) as
    ``{topic: table}`` with its ``Timestamp``, as generator.logs.phases reads a recorded log."""
    ts = flight["Timestamp"].to_numpy(np.int64)
    topics: dict[str, dict[str, np.ndarray]] = {}
    for col in flight.columns:
        if not isinstance(col, str) or "." not in col:
            continue
        topic, _, name = col.rpartition(".")
        if topic not in wanted:  # only what the phase detector reads: the other columns cost a conversion each
            continue
        v = pd.to_numeric(flight[col], errors="coerce")
        if v.notna().any():
            topics.setdefault(topic, {"Timestamp": ts})[name] = v.to_numpy(np.float64)
    return {t: pd.DataFrame(cols) for t, cols in topics.items()}


def flight_phase_bounds(flight: pd.DataFrame) -> dict[str, object]:
    """The flight's phase bounds (:data:`PHASE_COLUMNS`), read from the flight itself with the phase
    detection real logs get (:func:`scart_bench.generator.logs.phases.flight_phases`: the log's
    land detector and flight mode where it has them, else altitude and vertical speed).

    A flight that starts in the air takes off at its first row; one that never lands touches down
    after its last row (``touchdown_us`` <NA>). ``phases_by`` names the sources, or why there are no
    bounds (no altitude in the flight, never airborne): such a flight is counted by the burn-in rule.
    """
    from scart_bench.generator.logs.phases import ALTITUDE_SOURCES, CLIMB, PHASES, TAKEOFF, flight_phases

    out: dict[str, object] = dict.fromkeys(PHASE_COLUMNS[:-1], pd.NA)
    if "Timestamp" not in flight.columns or not len(flight):
        return {**out, "phases_by": "none: empty flight"}
    try:
        wanted = frozenset(t for t, _, _ in ALTITUDE_SOURCES) | PHASE_DETECTOR_TOPICS
        ph = flight_phases(_topic_tables(flight, wanted))
    except ValueError:
        return {**out, "phases_by": "none: no altitude in the flight"}
    t = ph["Timestamp"].to_numpy(np.int64)
    code = np.array([PHASES.index(p) for p in ph["phase"]])
    air = np.flatnonzero(code != 0)
    if not air.size:
        return {**out, "phases_by": "none: never airborne"}
    lift, last = int(air[0]), int(air[-1])
    out["liftoff_us"] = int(t[lift])
    rest = np.flatnonzero((np.arange(len(t)) > lift) & (code != TAKEOFF) & (code != CLIMB))
    if rest.size:
        out["climb_end_us"] = int(t[rest[0]])
    if last + 1 < len(t):
        out["touchdown_us"] = int(t[last + 1])
    k = last
    while k > lift and code[k] == PHASES.index("descent"):
        k -= 1
    if k < last:
        out["descent_start_us"] = int(t[k + 1])
    a = ph.attrs
    out["phases_by"] = f"altitude {a.get('altitude')}; landed {a.get('landed')}" + (
        f"; mode {a['mode']}" if a.get("mode") else "")
    return out


def phase_counted_rows(timestamps: np.ndarray, liftoff_us: float | None, touchdown_us: float | None,
                       margin_s: float) -> np.ndarray:
    """Rows the "ends" rule counts: from ``margin_s`` after take-off to ``margin_s`` before
    touchdown (to the end of the recording when the flight does not land in it)."""
    ts = np.asarray(timestamps, dtype=np.int64).reshape(-1)
    m = int(round(margin_s * 1e6))
    keep = ts >= int(liftoff_us) + m
    if touchdown_us is not None and not pd.isna(touchdown_us):
        keep &= ts < int(touchdown_us) - m
    return keep


def counted_masks(protocol: Protocol, flights: pd.DataFrame,
                  timestamps: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per flight id (``flights`` indexed by it), the rows the protocol counts. Under the "ends" and
    "cruise" rules a flight without phase bounds (:data:`PHASE_COLUMNS` <NA> or absent from the table:
    no altitude, never airborne) is counted by the burn-in rule."""
    armed = (pd.to_numeric(flights["armed_us"], errors="coerce") if "armed_us" in flights.columns
             else pd.Series(np.nan, index=flights.index))
    if protocol.phases != "burn-in":
        first, last = (("liftoff_us", "touchdown_us") if protocol.phases == "ends"
                       else ("climb_end_us", "descent_start_us"))
        def bound(col: str) -> pd.Series:  # a table without the column: no flight has bounds
            return (pd.to_numeric(flights[col], errors="coerce") if col in flights.columns
                    else pd.Series(np.nan, index=flights.index))

        lo, hi = bound(first), bound(last)
        return {fid: (phase_counted_rows(timestamps[fid], lo[fid], hi[fid], protocol.phase_margin_s)
                      if not pd.isna(lo[fid]) else counted_rows(timestamps[fid], armed[fid], protocol.burn_in_s))
                for fid in flights.index}
    return {fid: counted_rows(timestamps[fid], armed[fid], protocol.burn_in_s) for fid in flights.index}


def counted_max(scores: np.ndarray, counted: np.ndarray) -> float:
    """The flight score: the largest score over the counted rows (the smallest score of the
    flight when no row is counted: such a flight is never flagged)."""
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if s.size == 0:
        return float("-inf")
    c = np.asarray(counted, dtype=bool).reshape(-1)
    return float(s[c].max()) if c.any() else float(s.min())


@dataclass(frozen=True)
class Protocol:
    """The operating point of a run: threshold rules (flight level for the paper's table, row level
    for the rest), the burn-in after arming, the end transient and which alarm rule is used."""

    flight_rule: ThresholdRule = field(default_factory=ThresholdRule)
    row_rule: ThresholdRule = field(default_factory=ThresholdRule)
    burn_in_s: float = DEFAULT_BURN_IN_S
    end_transient_s: float = DEFAULT_END_TRANSIENT_S
    alarm_rule: str = "calibrated"
    #: which rows count at the flight's ends (:data:`PHASE_RULES`) and the "ends" rule's margin
    phases: str = DEFAULT_PHASES
    phase_margin_s: float = DEFAULT_PHASE_MARGIN_S
    #: the operating point for small datasets: when the validation flights are too few for alpha, at
    #: most this many false alarms per flight-hour, calibrated on ``hourly_window_s`` windows of the
    #: validation flights (0: off, the largest validation score, as before v3)
    hourly_rate: float = DEFAULT_HOURLY_RATE
    hourly_window_s: float = DEFAULT_HOURLY_WINDOW_S

    def __post_init__(self) -> None:
        if self.phases not in PHASE_RULES:
            raise ProtocolError(f"counting rule {self.phases!r}: expected one of {', '.join(PHASE_RULES)}")
        if not (math.isfinite(self.hourly_rate) and 0 <= self.hourly_rate <= 3600):
            raise ProtocolError(f"hourly_rate {self.hourly_rate!r}: expected false alarms per flight-hour in 0..3600")
        if not (math.isfinite(self.hourly_window_s) and 1 <= self.hourly_window_s <= MAX_PROTOCOL_S):
            raise ProtocolError(f"hourly_window_s {self.hourly_window_s!r}: expected seconds in 1..{MAX_PROTOCOL_S:g}")
        for name in ("burn_in_s", "end_transient_s", "phase_margin_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and 0 <= v <= MAX_PROTOCOL_S):
                raise ProtocolError(f"{name} {v!r}: expected a finite number of seconds in 0..{MAX_PROTOCOL_S:g}")
        if self.alarm_rule not in ALARM_RULES:
            raise ProtocolError(f"alarm rule {self.alarm_rule!r}: expected one of {', '.join(ALARM_RULES)}")

    @property
    def alpha(self) -> float | None:
        """The target per-flight false-alarm rate (None for the v1 rules, which state none)."""
        return self.flight_rule.alpha if self.flight_rule.kind == "conformal" else None

    def hourly_point(self, validation_scores: dict[str, np.ndarray], masks: dict[str, np.ndarray],
                     timestamps: Mapping[str, np.ndarray]) -> dict | None:
        """The small-data operating point, or None when alpha is attainable (or it is off).

        Each validation flight's counted rows are cut into ``hourly_window_s`` windows from its
        first counted row; a window's score is its largest. The threshold is the conformal order
        statistic of the window scores for a per-window rate ``r = hourly_rate * window / 3600``,
        raised to ``1 / (m + 1)`` (the largest window score) when the m windows cannot reach it:
        a new normal window exceeds it with probability at most r, i.e. at most
        ``r * 3600 / window`` windows with an alarm per flight-hour. Returned: the threshold, the
        stated rate per flight-hour, the windows and the validation flight-hours.
        """
        n = len(validation_scores)
        if self.flight_rule.kind != "conformal" or self.flight_rule.attainable(n) or self.hourly_rate <= 0:
            return None
        w_us = int(round(self.hourly_window_s * 1e6))
        windows, seconds = [], 0.0
        for f, s in validation_scores.items():
            c = masks[f]
            if not c.any():
                continue
            t = np.asarray(timestamps[f], dtype=np.int64)[c]
            v = np.asarray(s, dtype=np.float64)[c]
            seconds += (t[-1] - t[0]) / 1e6
            k = (t - t[0]) // w_us
            starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
            windows.append(np.maximum.reduceat(v, starts))
        w = np.concatenate(windows) if windows else np.zeros(0)
        if not w.size:
            return None
        rate = max(self.hourly_rate * self.hourly_window_s / 3600.0, 1.0 / (w.size + 1))
        t = ThresholdRule("conformal", alpha=min(rate, 0.999999)).calibrate(w)
        return {"threshold": t, "rate_per_hour": rate * 3600.0 / self.hourly_window_s, "windows": int(w.size),
                "validation_hours": seconds / 3600.0, "target_per_hour": float(self.hourly_rate)}

    def thresholds(self, validation_scores: dict[str, np.ndarray],
                   counted: dict[str, np.ndarray] | None = None,
                   timestamps: Mapping[str, np.ndarray] | None = None) -> tuple[float, float]:
        """(flight threshold, row threshold) from the per-row scores of the validation flights;
        ``counted`` (flight id -> bool mask) leaves the rows outside the counting rule out. With
        ``timestamps`` (flight id -> row times) and too few validation flights for alpha, both are
        the small-data operating point's (:meth:`hourly_point`)."""
        if not validation_scores:
            raise ProtocolError("no validation flight scores to calibrate thresholds on")
        masks = {f: (counted[f] if counted is not None and f in counted else
                     np.ones(np.asarray(s).shape[0], dtype=bool)) for f, s in validation_scores.items()}
        if timestamps is not None:
            hourly = self.hourly_point(validation_scores, masks, timestamps)
            if hourly is not None:
                return hourly["threshold"], hourly["threshold"]
        flights = np.array([counted_max(s, masks[f]) for f, s in validation_scores.items()])
        t_flight = self.flight_rule.calibrate(flights)
        if self.row_rule.kind in FLIGHT_KINDS:
            return t_flight, self.row_rule.calibrate(flights)
        rows = np.concatenate([np.asarray(s, dtype=np.float64)[masks[f]] for f, s in validation_scores.items()])
        return t_flight, self.row_rule.calibrate(rows)

    def rules(self) -> dict:
        """The rules as plain data (what makes two runs' thresholds comparable)."""
        out = {"flight_rule": asdict(self.flight_rule), "row_rule": asdict(self.row_rule),
               "burn_in_s": float(self.burn_in_s), "end_transient_s": float(self.end_transient_s),
               "alarm_rule": self.alarm_rule}
        if self.phases != "burn-in":  # v2's rules read as they always did
            out.update(phases=self.phases, phase_margin_s=float(self.phase_margin_s))
        if self.hourly_rate > 0:
            out.update(hourly_rate=float(self.hourly_rate), hourly_window_s=float(self.hourly_window_s))
        return out

    def counting(self) -> str:
        """Which rows count, in a sentence."""
        if self.phases != "burn-in":
            span = ("take-off", "touchdown") if self.phases == "ends" else ("the end of the climb",
                                                                            "the final descent")
            return (f"airborne rows from {self.phase_margin_s:g} s after {span[0]} to {self.phase_margin_s:g} s "
                    f"before {span[1]} (phases read from the flight; a flight without them: rows from "
                    f"{self.burn_in_s:g} s after arming)")
        return (f"rows from {self.burn_in_s:g} s after arming (start-up, arming, spin-up left out)"
                if self.burn_in_s else "every row")

    def to_dict(self) -> dict:
        return {**self.rules(),
                "flight_score": ("max row score over the counted rows" if self.phases != "burn-in"
                                 else "max row score outside the burn-in" if self.burn_in_s else "max row score"),
                "counted_rows": self.counting(),
                "flight_threshold": self.flight_rule.describe() + " (validation flight scores)",
                "row_threshold": self.row_rule.describe() + (
                    " (the same validation flight scores)" if self.row_rule.kind in FLIGHT_KINDS
                    else " (validation row scores)"),
                "burn_in": (f"rows before {self.burn_in_s:g} s after arming (start-up, arming, spin-up) neither calibrate nor alarm"
                            if self.burn_in_s else "none"),
                "end_transient": f"{self.end_transient_s:g} s after the last attacked row",
                "alarms": ("each detector's own alarm rule where it has one, else the calibrated threshold"
                           if self.alarm_rule == "own" else "score > the calibrated threshold"),
                "decision": "flagged / alarm when score > threshold"}

    @classmethod
    def from_dict(cls, d: dict) -> Protocol:
        """A protocol from ``rules()`` / ``to_dict()`` data; keys missing from a v1 run folder keep
        v1's meaning (no burn-in, no end transient, calibrated thresholds)."""
        def rule(x: dict) -> ThresholdRule:
            return ThresholdRule(**{k: x[k] for k in ("kind", "margin", "q", "alpha") if k in x})

        return cls(rule(d["flight_rule"]), rule(d["row_rule"]), burn_in_s=float(d.get("burn_in_s", 0.0)),
                   end_transient_s=float(d.get("end_transient_s", 0.0)),
                   alarm_rule=str(d.get("alarm_rule", "calibrated")), phases=str(d.get("phases", "burn-in")),
                   phase_margin_s=float(d.get("phase_margin_s", DEFAULT_PHASE_MARGIN_S)),
                   hourly_rate=float(d.get("hourly_rate", 0.0)),
                   hourly_window_s=float(d.get("hourly_window_s", DEFAULT_HOURLY_WINDOW_S)))
