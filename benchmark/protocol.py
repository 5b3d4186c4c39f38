"""The evaluation protocol: which flights train, calibrate and test a detector, and the thresholds.

Roles, from the dataset manifest:

- ``train``: normal flights with split "train"; the only flights a detector is fitted on.
- ``validation``: normal flights with split "validation"; the only flights thresholds are
  calibrated on.
- ``test_normal``: normal flights with split "test" (held out: the TN rate).
- ``test_attacked``: every attacked flight (mode "simulation" or "csv"; their split must be
  "test") whose attack changed something: the TP rates.
- ``no_effect``: attacked flights marked ``no_effect`` in the manifest (the attack changed no
  row relative to the simulator view or the csv source): not scored, counted in the summary.
- ``csv_source``: normal flights with split "csv_source", reserved as the recordings csv mode
  attacks; never fitted on, calibrated on or scored.

A csv-mode flight replaying a train or validation flight (``source_flight``) is refused: its
detector would have seen the very rows it is asked to flag, and its threshold would be calibrated
on them.

Thresholds (a flight is flagged, a row alarms, when its score is strictly above the threshold):

- flight level: ``max`` rule on the validation flight scores (flight score = max row score,
  :func:`scart_bench.detectors.base.flight_score`): ``t = m + margin * |m|`` where ``m`` is the largest
  validation flight score; with the default margin 0.05 this is ``m * 1.05`` for positive scores.
  No validation flight is flagged, and a test flight must beat every validation flight by 5 %.
- row level (point-wise, range-based, delay and false-alarm metrics): the same ``max`` rule on
  the validation row scores. Since the flight score is the maximum row score, both thresholds are
  the same number by default, so "a flight is flagged" and "a flight has at least one row alarm"
  agree, and delays and false alarms describe the operating point of the paper's table.
  ``ThresholdRule("quantile", q=0.999)`` gives the alternative 99.9th-percentile rule.

Scores of test or attacked flights never enter a threshold: :meth:`Protocol.thresholds` takes
only validation scores.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from scart_bench.detectors.base import flight_score
from scart_bench.errors import ScartBenchError

__all__ = [
    "ATTACK_MODES", "NORMAL_MODE", "ROLES", "Protocol", "ProtocolError", "Splits",
    "ThresholdRule", "flight_score",
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

    def role_of(self) -> dict[str, str]:
        return {fid: role for role in ROLES for fid in getattr(self, role)}


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


@dataclass(frozen=True)
class ThresholdRule:
    """How a threshold is derived from validation scores.

    ``kind="max"``: ``m + margin * |m|`` with ``m`` the largest value. ``kind="quantile"``: the
    ``q`` quantile (linear interpolation) plus ``margin * |quantile|``.
    """

    kind: str = "max"
    margin: float = 0.05
    q: float = 0.999

    def __post_init__(self) -> None:
        if self.kind not in ("max", "quantile"):
            raise ProtocolError(f"threshold rule {self.kind!r}: expected 'max' or 'quantile'")
        if not (0.0 <= self.q <= 1.0):
            raise ProtocolError(f"threshold quantile {self.q}: expected 0 <= q <= 1")
        if self.margin < 0:
            raise ProtocolError(f"threshold margin {self.margin}: expected >= 0")

    def calibrate(self, values: np.ndarray) -> float:
        """The threshold for these validation values (all must be finite)."""
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        if v.size == 0:
            raise ProtocolError("cannot calibrate a threshold on zero validation scores")
        if not np.all(np.isfinite(v)):
            raise ProtocolError("validation scores contain NaN or inf; a threshold cannot be calibrated")
        base = float(v.max()) if self.kind == "max" else float(np.quantile(v, self.q))
        return base + self.margin * abs(base)

    def describe(self) -> str:
        if self.kind == "max":
            return f"max of validation scores + {self.margin:g} x |max|"
        return f"{self.q:g} quantile of validation scores + {self.margin:g} x |quantile|"


@dataclass(frozen=True)
class Protocol:
    """Threshold rules of a run (flight level for the paper's table, row level for the rest)."""

    flight_rule: ThresholdRule = field(default_factory=ThresholdRule)
    row_rule: ThresholdRule = field(default_factory=ThresholdRule)

    def thresholds(self, validation_scores: dict[str, np.ndarray]) -> tuple[float, float]:
        """(flight threshold, row threshold) from the per-row scores of the validation flights."""
        if not validation_scores:
            raise ProtocolError("no validation flight scores to calibrate thresholds on")
        flights = np.array([flight_score(s) for s in validation_scores.values()])
        rows = np.concatenate([np.asarray(s, dtype=np.float64) for s in validation_scores.values()])
        return self.flight_rule.calibrate(flights), self.row_rule.calibrate(rows)

    def rules(self) -> dict:
        """The two rules as plain data (what makes two runs' thresholds comparable)."""
        return {"flight_rule": asdict(self.flight_rule), "row_rule": asdict(self.row_rule)}

    def to_dict(self) -> dict:
        return {**self.rules(),
                "flight_score": "max row score",
                "flight_threshold": self.flight_rule.describe() + " (validation flight scores)",
                "row_threshold": self.row_rule.describe() + " (validation row scores)",
                "decision": "flagged / alarm when score > threshold"}

    @classmethod
    def from_dict(cls, d: dict) -> Protocol:
        return cls(ThresholdRule(**d["flight_rule"]), ThresholdRule(**d["row_rule"]))
