"""Tables: the breakdown per attack dimension, the Markdown tables of metrics.md (the paper's table
and the further metrics), the number formats, and the operating-point lines printed after a run.

They read a metrics table (one row per detector, :func:`benchmark.metrics.compute_metrics`'s
columns) or one detector's :class:`~scart_bench.benchmark.evaluation.Evaluation`; nothing here
counts or thresholds anything.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from scart_bench.benchmark.evaluation import Evaluation
from scart_bench.benchmark.intervals import wilson
from scart_bench.benchmark.protocol import ATTACK_MODES

# -- breakdown per attack dimension -------------------------------------------------------------

BREAKDOWN_DIMENSIONS = ("action", "target", "injection_point", "kind", "detectability_bin")
BREAKDOWN_COLUMNS = ["detector", "dimension", "value", "mode", "n", "detected", "tp_rate", "tp_rate_lo",
                     "tp_rate_hi", "late", "flagged", "impact_n", "max_dev_median_m", "final_dev_median_m",
                     "mission_completed", "crashed"]


def impact_summary(flights: pd.DataFrame) -> dict:
    """The attack's physical impact over a group of attacked flights (those with a twin: the
    simulation-mode ones; :mod:`scart_bench.generator.impact`): how many, median max and final
    deviation of the true path from the twin's (m), how many completed the mission, crashed."""
    if "impact_max_dev_m" not in flights.columns:
        return {"impact_n": 0, "max_dev_median_m": float("nan"), "final_dev_median_m": float("nan"),
                "mission_completed": 0, "crashed": 0}
    dev = pd.to_numeric(flights["impact_max_dev_m"], errors="coerce")
    has = flights[dev.notna()]
    flag = {c: has[c].astype(object).where(has[c].notna(), False).astype(str).str.lower().eq("true")
            if c in has.columns else pd.Series(False, index=has.index)
            for c in ("impact_mission_completed", "impact_crashed")}

    def med(col: str) -> float:
        return float(pd.to_numeric(has[col], errors="coerce").median()) if len(has) else float("nan")

    return {"impact_n": len(has), "max_dev_median_m": med("impact_max_dev_m"),
            "final_dev_median_m": med("impact_final_dev_m"),
            "mission_completed": int(flag["impact_mission_completed"].sum()),
            "crashed": int(flag["impact_crashed"].sum())}


#: Edges of the detectability bins (injected size in validation standard deviations).
DETECTABILITY_EDGES = (1.0, 3.0, 10.0)


def detectability_bins(values: pd.Series) -> pd.Series:
    """Bin labels of detectability values: ``<1 sd``, ``1-3 sd``, ``3-10 sd``, ``>=10 sd``, ``n/a``."""
    v = pd.to_numeric(values, errors="coerce").to_numpy(np.float64)
    labels = np.array(["<1 sd", "1-3 sd", "3-10 sd", ">=10 sd"], dtype=object)
    out = labels[np.searchsorted(np.array(DETECTABILITY_EDGES), np.nan_to_num(v, nan=0.0), side="right")]
    out[~np.isfinite(v)] = "n/a"
    return pd.Series(out, index=values.index, name="detectability_bin")


def breakdown(ev: Evaluation, dimensions: tuple[str, ...] = BREAKDOWN_DIMENSIONS) -> pd.DataFrame:
    """Detected (in-window) count, TP rate with its Wilson interval, late and flagged-anywhere
    counts of the attacked test flights per value of each dimension, for all modes together
    (mode "all") and per mode, with the attack's physical impact (:func:`impact_summary`)."""
    attacked = ev.test("test_attacked")
    if "detectability" in attacked.columns:
        attacked = attacked.assign(detectability_bin=detectability_bins(attacked["detectability"]))
    rows = []
    for dim in dimensions:
        if dim not in attacked.columns:
            continue
        values = attacked[dim].astype(object).where(attacked[dim].notna(), "(none)").astype(str)
        for mode in ("all", *ATTACK_MODES):
            sel = attacked if mode == "all" else attacked[attacked["mode"] == mode]
            if sel.empty:
                continue
            for value, group in sel.groupby(values.loc[sel.index], sort=True):
                k = int((group["outcome"] == "detected").sum())
                lo, hi = wilson(k, len(group))
                rows.append({"detector": ev.detector, "dimension": dim, "value": value, "mode": mode,
                             "n": len(group), "detected": k, "tp_rate": k / len(group), "tp_rate_lo": lo,
                             "tp_rate_hi": hi, "late": int((group["outcome"] == "late").sum()),
                             "flagged": int(group["flagged"].astype(bool).sum()), **impact_summary(group)})
    return pd.DataFrame(rows, columns=BREAKDOWN_COLUMNS)


# -- tables -----------------------------------------------------------------------------------

#: (header, metrics column, format) of the printed table. ``pct_ci``: a percentage with its
#: interval from ``<column>_lo`` / ``<column>_hi``; ``fN_ci``: N decimals with its interval;
#: ``prior``: AUC-PR with its interval and the AUC-PR of a random ranking.
PAPER_COLUMNS = (("TP Simulation (in window)", "tp_simulation", "pct_ci"),
                 ("TP CSV (in window)", "tp_csv", "pct_ci"),
                 ("TN No Attack", "tn_no_attack", "pct_ci"),
                 ("False alarms, normal", "far_no_attack", "pct_ci"),
                 ("TP Sim (window + end)", "tp_end_simulation", "pct_ci"),
                 ("TP CSV (window + end)", "tp_end_csv", "pct_ci"),
                 ("Late Sim", "late_simulation", "pct_ci"), ("Late CSV", "late_csv", "pct_ci"),
                 ("FA before onset Sim", "fa_before_onset_simulation", "pct_ci"),
                 ("FA before onset CSV", "fa_before_onset_csv", "pct_ci"),
                 ("Flagged anywhere Sim", "flagged_simulation", "pct_ci"),
                 ("Flagged anywhere CSV", "flagged_csv", "pct_ci"),
                 ("ROC-AUC", "roc_auc", "f3_ci"), ("AUC-PR (prior)", "auc_pr", "prior"),
                 ("Median delay (s)", "delay_median_s", "f2"))
EXTRA_COLUMNS = (("VUS-PR", "vus_pr", "f3"), ("VUS-ROC", "vus_roc", "f3"), ("Row AUC-PR", "row_auc_pr", "f3"),
                 ("Row ROC-AUC", "row_roc_auc", "f3"),
                 ("Point P", "point_precision", "f3"), ("Point R", "point_recall", "f3"),
                 ("Point F1", "point_f1", "f3"), ("R-P (TSB-AD)", "r_precision", "f3"),
                 ("R-R (TSB-AD)", "r_recall", "f3"), ("R-F1 (TSB-AD)", "r_f1", "f3"),
                 ("Range F1 (Tatbul a=0)", "rt0_f1", "f3"),
                 ("p90 delay (s)", "delay_p90_s", "f2"), ("Late delay after end (s)", "late_delay_median_s", "f2"),
                 ("False alarms / h", "false_alarms_per_hour", "f2"),
                 ("Latency (us/row)", "latency_us_per_row", "f1"), ("Fit (s)", "fit_s", "f1"))


def _nan(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or bool(pd.isna(value))


def format_value(value, kind: str, lo=None, hi=None) -> str:
    """A number as the tables show it: ``pct`` -> ``81.8 %``, ``pct_ci`` -> ``81.8 % [52-95]``,
    ``fN`` -> N decimals, ``fN_ci`` -> ``0.812 [0.700-0.900]``; ``n/a`` for NaN."""
    if _nan(value):
        return "n/a"
    v = float(value)
    base, _, ci = kind.partition("_")
    text = f"{100 * v:.1f} %" if base == "pct" else f"{v:.{base[1:]}f}"
    if ci and not _nan(lo) and not _nan(hi):
        if base == "pct":
            text += f" [{100 * float(lo):.0f}-{100 * float(hi):.0f}]"
        else:
            text += f" [{float(lo):.{base[1:]}f}-{float(hi):.{base[1:]}f}]"
    return text


def _cell(row, key: str, kind: str) -> str:
    if kind == "prior":
        text = format_value(row.get(key), "f3_ci", row.get(f"{key}_lo"), row.get(f"{key}_hi"))
        prior = row.get(f"{key}_prior")
        return text if _nan(prior) or text == "n/a" else f"{text} ({float(prior):.3f})"
    return format_value(row.get(key), kind, row.get(f"{key}_lo"), row.get(f"{key}_hi"))


def markdown_table(metrics: pd.DataFrame, columns=PAPER_COLUMNS, status: bool = True) -> str:
    """A Markdown table, one row per detector; a failed job shows its status, not numbers."""
    head = ["Detector", *(c[0] for c in columns)] + (["Status"] if status else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for _, r in metrics.iterrows():
        ok = r.get("status") == "OK"
        cells = [str(r["detector"])]
        cells += [_cell(r, key, kind) if ok else str(r.get("status")) for _, key, kind in columns]
        if status:
            cells.append(str(r.get("status")))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


DETECTION_RULE = (
    "detection rule: an attacked flight is detected (TP, the headline) when at least one row alarms inside an "
    "attack window [start, end) of its event log; 'window + end' also counts a first alarm within the end "
    "transient after the window (the attacked value snapping back is the attack's own effect); late when its "
    "first alarm comes after that; missed otherwise. 'Flagged anywhere' (flight score above the flight "
    "threshold, any row) is the paper's lenient rule, shown beside it. 'FA before onset': attacked flights with "
    "a row alarm before the attack started (false alarms the TN column does not see). TN: held-out normal test "
    "flights not flagged; 'False alarms, normal' = 1 - TN, to compare with the target alpha. Attacked flights "
    "whose attack changed nothing (no_effect) are excluded from every rate.")

#: How the rates' intervals are computed (metrics.md, the README).
INTERVAL_METHOD = (
    "intervals: 95 %, cluster bootstrap (1,000 seeded replicates): csv copies of one source recording and the "
    "flights of one configuration flown in both modes form one cluster; clusters are resampled within normal "
    "and within attacked flights, and every replicate re-calibrates the threshold on validation flights resampled "
    "with replacement (the threshold's own uncertainty). The interval shown is the hull of the bootstrap's "
    "percentile interval and the Wilson interval at its effective sample size (at the number of independent "
    "units when a rate is 0 or 100 %); the plain Wilson interval is in metrics.csv (*_wilson_lo/_hi). ROC-AUC "
    "and AUC-PR: bootstrap over flights; AUC-PR in brackets after it is the prior (a random ranking).")


def rate_summary(metrics: pd.DataFrame, no_effect: list[str] = ()) -> list[str]:
    """Markdown lines: how many flights each rate rests on, the operating point (target alpha
    against the measured false-alarm rate, per detector), and the attacked flights left out."""
    ok = metrics[metrics["status"] == "OK"] if "status" in metrics else metrics.iloc[:0]
    lines = ["## Flights behind each rate", ""]
    if len(ok):
        r = ok.iloc[0]
        units = r.get("n_units_csv")
        lines.append(f"- TP / late / flagged Simulation: {int(r['n_simulation'])} attacked simulation-mode test "
                     f"flights; TP / late / flagged CSV: {int(r['n_csv'])} csv-mode flights"
                     + ("" if _nan(units) else f" replaying {int(units)} source recordings")
                     + f"; TN No Attack: {int(r['n_no_attack'])} held-out normal test flights"
                     + ("" if _nan(r.get("n_validation")) else
                        f"; thresholds calibrated on {int(r['n_validation'])} validation normal flights") + ".")
        if not _nan(r.get("n_onset_in_burn_in")) and int(r["n_onset_in_burn_in"]):
            lines.append(f"- **{int(r['n_onset_in_burn_in'])} attacked flights start their attack inside the burn-in "
                         "after arming**: their first attacked rows cannot alarm (see docs/protocol.md).")
        lines += ["", "## Operating point", ""]
        for _, d in ok.iterrows():
            lines.append("- " + operating_point_line(d))
    no_effect = list(no_effect)
    shown = ", ".join(no_effect[:20]) + (" ..." if len(no_effect) > 20 else "")
    lines.append(f"- attacked flights whose attack changed nothing (no_effect, excluded from every rate): "
                 f"{len(no_effect)}" + (f": {shown}" if no_effect else ""))
    lines.append("")
    return lines


def operating_point_line(d) -> str:
    """One detector's operating point in words: its target alpha, the measured false-alarm rate on
    held-out normal flights with its interval, and whether the interval holds alpha."""
    far, lo, hi = d.get("far_no_attack"), d.get("far_no_attack_lo"), d.get("far_no_attack_hi")
    measured = format_value(far, "pct_ci", lo, hi)
    alpha = d.get("alpha")
    if _nan(alpha):
        text = f"**{d['detector']}**: its own alarm rule (no target rate); false alarms on normal flights {measured}"
    else:
        text = (f"**{d['detector']}**: target alpha {100 * float(alpha):g} % per flight; measured on held-out "
                f"normal flights {measured}")
        if not _nan(d.get("hourly_rate")):
            text += (f" (**alpha not attainable** with {int(d['n_validation'])} validation flights; the operating "
                     f"point is per flight-hour instead: at most {float(d['hourly_rate']):.2g} false alarms per "
                     f"flight-hour, calibrated on {int(d['n_windows'])} windows of "
                     f"{60 * float(d['validation_hours']):.0f} min of validation flight)")
        elif not _nan(d.get("alpha_attainable")) and not bool(d.get("alpha_attainable")):
            text += (f" (**alpha not attainable** with {int(d['n_validation'])} validation flights: the threshold "
                     "is the largest validation score)")
        elif not _nan(lo) and not _nan(hi) and not (float(lo) <= float(alpha) <= float(hi)):
            text += " (**the interval does not contain alpha**)"
    fa = [f"{m} {format_value(d.get(f'fa_before_onset_{m}'), 'pct')}" for m in ATTACK_MODES
          if not _nan(d.get(f"fa_before_onset_{m}"))]
    if fa:
        text += "; attacked flights with a false alarm before onset: " + ", ".join(fa)
    after = [int(d.get(f"detected_after_fa_{m}") or 0) for m in ATTACK_MODES]
    if any(after):
        text += (f" ({after[0]} simulation / {after[1]} csv detections follow such a false alarm)")
    fph = d.get("false_alarms_per_hour")
    if not _nan(fph):
        text += f"; {float(fph):.2f} false alarm events per flight-hour"
    return text + "."
