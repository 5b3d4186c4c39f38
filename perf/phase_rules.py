"""Counting rules for the flight's two ends compared on saved run folders (protocol v3, issue 46).

    python -m perf.phase_rules RUN [RUN ...] [--alpha 0.05]

For every run folder (each seed of a profile) and detector, from the saved scores alone (no job is
run), under each rule: the thresholds calibrated on the validation flights for ``alpha`` per flight,
TP in the attack window per mode, the false-alarm rate on the held-out normal flights, and how many
validation maxima (and the threshold-setting one) lie within 3 s of take-off or touchdown. The rules:

- ``burn-in 8``: protocol v2 (rows from 8 s after arming to the end of the recording);
- ``ends M``: airborne rows from M s after take-off to M s before touchdown (v3's phase mask);
- ``cruise``: rows from the end of the climb to the start of the final descent (both transients out);
- ``per-phase M``: the rows of ``ends M``, split into ascent (to the end of the climb), cruise and final
  descent, each with its own conformal threshold at alpha / 3 (Bonferroni: a normal flight is
  flagged by some phase with probability at most alpha); a row alarms above its phase's threshold.

Phase bounds come from the run's phases.csv (written from the dataset for runs made before v3). The
built-in rules' numbers equal ``scart-bench score RUN --phases ...`` (checked by the tests); the
per-phase rule exists only here. Prints one Markdown table (mean over the runs, per detector and
rule) and writes the per-run rows as CSV with ``--csv``.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import Protocol, ThresholdRule, counted_masks
from scart_bench.benchmark.results import ensure_phases
from scart_bench.benchmark.store import RunStore

#: Seconds from take-off or touchdown within which a validation maximum is "at an end".
NEAR_S = 3.0
SEGMENTS = ("ascent", "cruise", "descent")


@dataclass(frozen=True)
class Rule:
    """One counting rule: a protocol's counted rows, optionally split into per-phase thresholds."""

    name: str
    protocol: Protocol
    per_phase: bool = False


def default_rules(alpha: float) -> list[Rule]:
    def proto(**kw) -> Protocol:
        r = ThresholdRule(alpha=alpha)
        return Protocol(flight_rule=r, row_rule=r, **kw)

    return [Rule("burn-in 8", proto()), Rule("ends 3", proto(phases="ends", phase_margin_s=3.0)),
            Rule("ends 5", proto(phases="ends", phase_margin_s=5.0)),
            Rule("cruise", proto(phases="cruise", phase_margin_s=0.0)),
            Rule("per-phase 3", proto(phases="ends", phase_margin_s=3.0), per_phase=True)]


def segments(ts: np.ndarray, bounds: pd.Series) -> np.ndarray:
    """Per row: 0 ascent (before the end of the climb), 1 cruise, 2 final descent (from its start)."""
    ts = np.asarray(ts, dtype=np.int64)
    seg = np.ones(ts.shape, dtype=np.int8)
    climb, descent = bounds.get("climb_end_us"), bounds.get("descent_start_us")
    if climb is not None and not pd.isna(climb):
        seg[ts < int(climb)] = 0
    if descent is not None and not pd.isna(descent):
        seg[ts >= int(descent)] = 2
    return seg


def _conformal(values: np.ndarray, alpha: float) -> float:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return ThresholdRule(alpha=alpha).calibrate(v) if v.size else float("inf")


def row_alarms(rule: Rule, flights: pd.DataFrame, truth: Mapping[str, tuple[np.ndarray, np.ndarray]],
               scores: Mapping[str, np.ndarray], alpha: float) -> tuple[dict[str, np.ndarray], dict]:
    """(flight id -> counted row alarms, calibration facts) for every scored flight of a run."""
    ids = list(flights.index)
    counted = counted_masks(rule.protocol, flights, {f: truth[f][0] for f in ids})
    val = [f for f in ids if flights.at[f, "role"] == "validation"]
    if not rule.per_phase:
        maxima = {f: (scores[f][counted[f]].max() if counted[f].any() else -np.inf) for f in val}
        t = _conformal(np.array(list(maxima.values())), alpha)
        alarms = {f: (scores[f] > t) & counted[f] for f in ids}
        setter = max((f for f in val if maxima[f] <= t), key=lambda f: maxima[f], default=None)
        return alarms, {"thresholds": [t], "maxima": maxima, "setter": setter}
    seg = {f: segments(truth[f][0], flights.loc[f]) for f in ids}
    ts = []
    for k in range(len(SEGMENTS)):
        m = [scores[f][counted[f] & (seg[f] == k)] for f in val]
        ts.append(_conformal(np.array([x.max() if x.size else -np.inf for x in m]), alpha / len(SEGMENTS)))
    t_row = {f: np.asarray(ts)[seg[f]] for f in ids}
    alarms = {f: (scores[f] > t_row[f]) & counted[f] for f in ids}
    ratio = {f: (np.max(scores[f][counted[f]] - t_row[f][counted[f]]) if counted[f].any() else -np.inf)
             for f in val}
    return alarms, {"thresholds": ts, "maxima": ratio, "setter": None}


def near_ends(flights: pd.DataFrame, truth, scores, counted_alarms_info, rule: Rule) -> tuple[int, bool]:
    """(validation maxima within NEAR_S of take-off or touchdown, whether the threshold-setting one is)."""
    counted = counted_masks(rule.protocol, flights, {f: truth[f][0] for f in flights.index})
    n, setter_near = 0, False
    for f in flights.index[flights["role"] == "validation"]:
        c = counted[f]
        if not c.any():
            continue
        at = truth[f][0][np.flatnonzero(c)[np.argmax(scores[f][c])]]
        lift, down = flights.at[f, "liftoff_us"], flights.at[f, "touchdown_us"]
        near = ((not pd.isna(lift) and abs(at - lift) < NEAR_S * 1e6)
                or (not pd.isna(down) and abs(down - at) < NEAR_S * 1e6))
        n += bool(near)
        setter_near |= bool(near and f == counted_alarms_info["setter"])
    return n, setter_near


def scored_flights(store: RunStore) -> pd.DataFrame:
    """The run's scored flights (validation and test) by flight id, with their arming time and phase
    bounds (read from the run's dataset first for a run made before v3)."""
    ensure_phases(store, store.read_config())
    flights = store.read_flights()
    flights["flight_id"] = flights["flight_id"].astype(str)
    return flights[flights["role"].isin(("validation", "test_normal", "test_attacked"))].set_index(
        "flight_id", drop=False)


def evaluate(run: Path, rules: list[Rule], alpha: float, detectors: list[str] | None = None) -> pd.DataFrame:
    """One row per (detector, rule) of one run folder."""
    store = RunStore(run)
    flights = scored_flights(store)
    truth = store.read_truth()
    rows = []
    for det in store.job_names():
        if detectors and det not in detectors:
            continue
        status = store.read_status(det) or {}
        if status.get("status") != "OK":
            continue
        scores = {f: np.asarray(s, dtype=np.float64) for f, s in store.read_scores(det).items()}
        for rule in rules:
            alarms, info = row_alarms(rule, flights, truth, scores, alpha)
            near, setter_near = near_ends(flights, truth, scores, info, rule)
            row = {"run": run.name, "detector": det, "rule": rule.name, "val_max_near_ends": near,
                   "threshold_near_ends": setter_near}
            normal = flights.index[flights["role"] == "test_normal"]
            row["false_alarms"] = 100.0 * np.mean([alarms[f].any() for f in normal])
            for mode in ("simulation", "csv"):
                att = flights.index[(flights["role"] == "test_attacked") & (flights["mode"] == mode)]
                row[f"tp_{mode}"] = 100.0 * np.mean([(alarms[f] & (truth[f][1] == 1)).any() for f in att])
            rows.append(row)
    return pd.DataFrame(rows)


def summary(table: pd.DataFrame) -> str:
    """Markdown: per detector and rule, TP sim / TP csv / false alarms (mean and range over the runs) and the
    validation maxima near the ends (sum over the runs) with the runs whose threshold sits there."""
    lines = ["| Detector | Rule | TP simulation | TP csv | False alarms | Val. maxima within 3 s of an end | "
             "Thresholds set there |", "|---|---|---|---|---|---|---|"]

    def cell(s: pd.Series) -> str:
        return f"{s.mean():.1f} ({s.min():.1f}-{s.max():.1f})" if len(s) > 1 else f"{s.mean():.1f}"

    order = list(dict.fromkeys(table["rule"]))
    for det, g in table.groupby("detector", sort=False):
        for rule in order:
            r = g[g["rule"] == rule]
            lines.append(f"| {det} | {rule} | {cell(r['tp_simulation'])} | {cell(r['tp_csv'])} | "
                         f"{cell(r['false_alarms'])} | {int(r['val_max_near_ends'].sum())} | "
                         f"{int(r['threshold_near_ends'].sum())} of {len(r)} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.phase_rules", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--alpha", type=float, default=0.05)
    p.add_argument("--detectors", help="comma-separated (default: every OK job)")
    p.add_argument("--csv", type=Path, help="also write the per-run rows here")
    args = p.parse_args(argv)
    rules = default_rules(args.alpha)
    dets = args.detectors.split(",") if args.detectors else None
    table = pd.concat([evaluate(r, rules, args.alpha, dets) for r in args.runs], ignore_index=True)
    if args.csv:
        table.to_csv(args.csv, index=False)
    print(f"alpha {args.alpha:g}; runs: {', '.join(r.name for r in args.runs)}; cells: mean (min-max) over the runs")
    print(summary(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
