"""The reference results page: the benchmark over several seeds of a profile, beside the paper's printed
numbers, with single-factor experiments, written as one Markdown page with its figures.

    python -m scart_bench.reports.reference --profile paper --seeds 0,1,2 --jobs 2 \\
        --runs runs/reference --out docs/results.md

The runs (each seed's benchmark, the rescored factor experiments, the retrained configurations) are
run or resumed by :mod:`scart_bench.benchmark.reference_runs`; this module renders them. The detection
rule (in window, in window or its end transient, flagged anywhere) is in every run's metrics. The page is
rewritten as a whole; the figures go into a folder beside it (``<out stem>/``).
"""

from __future__ import annotations

import argparse
import math
import platform
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark import reference_runs
from scart_bench.benchmark.reference_runs import (  # noqa: F401 (the names reports.report and callers import here)
    PAPER,
    TRAINED,
    VARIANTS,
    Retrained,
    finished,
    protocol_variant,
    rescored,
)
from scart_bench.errors import ReportError
from scart_bench.jsonfile import read_json
from scart_bench.reports.leaderboard import leaderboard_of
from scart_bench.reports.results import RunResults, load_runs

CLASSICAL = ("telemanom", "tsbitmaps", "statistical")
#: benchmark.tables.detectability_bins's labels, weakest first
DETECTABILITY_ORDER = ("<1 sd", "1-3 sd", "3-10 sd", ">=10 sd")
DEEPOD = ("deepsvdd", "rdp", "rca", "goad", "neutral")



def wall_s(run: Path) -> float:
    """The wall time a run's wall_s.json records (bounded read; ReportError naming the file and field)."""
    path = run / "wall_s.json"
    value = read_json(path).get("wall_s")  # type: ignore[union-attr]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ReportError(f"{path}: wall_s = {value!r}: expected a number of seconds >= 0")
    return float(value)


def retrained(run: Path, name: str, jobs: int) -> Path | None:
    """:func:`scart_bench.benchmark.reference_runs.retrained` with this module's ``TRAINED[name]``."""
    return reference_runs.retrained(run, name, jobs, TRAINED[name])


def _trained_lines(board: pd.DataFrame, trained: dict[str, list[RunResults]]) -> list[str]:
    """One table per retrained configuration: ours vs it, with the pooled intervals, and whether they agree."""
    lines: list[str] = []
    for name, conf in TRAINED.items():
        detector = conf.detector
        if not trained.get(name) or detector not in board.index:
            continue
        other = _board(trained[name])
        if detector not in other.index:
            continue
        a, b = board.loc[detector], other.loc[detector]
        walls = [wall_s(r.path) for r in trained[name] if (r.path / "wall_s.json").is_file()]
        lines += ["", f"**{conf.what}** (`{conf.label()}`; "
                      f"{len(trained[name])} seeds, {sum(walls) / 60:.1f} min):", "",
                  "| Configuration | TP simulation | TP csv | TN no attack | ROC-AUC |", "|---|---|---|---|---|"]
        for label, row in ((f"{detector} (default)", a), (f"{detector} ({name})", b)):
            lines.append(f"| {label} | {_cell(row, 'tp_simulation')} | {_cell(row, 'tp_csv')} | "
                         f"{_cell(row, 'tn_no_attack')} | {row.get('roc_auc_mean', np.nan):.3f} |")
        names = {"tp_simulation": "TP simulation", "tp_csv": "TP csv", "tn_no_attack": "TN"}
        agree = [label for key, label in names.items()
                 if a.get(f"{key}_lo", np.nan) <= b.get(f"{key}_mean", np.nan) <= a.get(f"{key}_hi", np.nan)]
        lines += ["", f"Its means within the default's pooled 95 % intervals: {', '.join(agree) if agree else 'none'} "
                      f"(of {', '.join(names.values())})."]
    return lines


def other_profiles(runs_root: Path, profile: str) -> dict[str, list[Path]]:
    """The finished runs of the other profiles in the same runs folder (``<profile>-seed<N>`` with every
    paper detector in its metrics), for the grid comparison; profiles with none are left out."""
    found: dict[str, list[Path]] = {}
    for other in ("quick", "standard", "paper"):
        if other == profile:
            continue
        paths = sorted((p for p in runs_root.glob(f"{other}-seed*")
                        if p.name.removeprefix(f"{other}-seed").isdigit() and finished(p, PAPER)),
                       key=lambda p: int(p.name.removeprefix(f"{other}-seed")))
        if paths:
            found[other] = paths
    return found


def _profile_lines(profile: str, runs: list[RunResults], rule: pd.DataFrame,
                   others: dict[str, list[RunResults]]) -> list[str]:
    """The grid factor: the same detectors and protocol on each profile's grid and flight counts
    (``rule``: this page's rates per detector, mean over its seeds, in the order of its table)."""
    if not others:
        return []
    keys = ("tp_simulation", "tp_csv", "tn_no_attack")
    rates = {profile: (rule, runs), **{k: (_rates(v, keys), v) for k, v in others.items()}}
    order = [k for k in ("quick", "standard", "paper") if k in rates]

    def counts(rs: list[RunResults]) -> str:
        m = rs[0].metrics.iloc[0]
        return (f"{int(m['n_simulation'])}/{int(m['n_csv'])} attacked, {int(m['n_no_attack'])} normal, "
                f"{len(rs)} seed{'s' if len(rs) > 1 else ''}")

    lines = ["", "**Grid composition and flight counts** (the profile: its scenario grid, how many flights of each "
                 "kind; the detectors, their parameters and the protocol are the same). TP simulation / TP csv / "
                 "TN, mean over the seeds; per profile its attacked flights per mode (simulation/csv) and "
                 "held-out normal flights per seed:", "",
             "| Detector | " + " | ".join(f"{k} ({counts(rates[k][1])})" for k in order) + " |",
             "|---" * (len(order) + 1) + "|"]
    for det in rule.index:
        cells = [" / ".join(_pct(rates[k][0].at[det, key]) if det in rates[k][0].index else "–" for key in keys)
                 for k in order]
        lines.append(f"| {det} | " + " | ".join(cells) + " |")
    return lines


# -- the page -----------------------------------------------------------------------------------

def _pct(x: float) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{100 * x:.1f}"


def _cell(row: pd.Series, key: str) -> str:
    """mean ± std over seeds [pooled 95 % interval]."""
    mean, std = row.get(f"{key}_mean", np.nan), row.get(f"{key}_std", np.nan)
    text = _pct(mean) + (f" ± {100 * std:.1f}" if np.isfinite(std) else "")
    lo, hi = row.get(f"{key}_lo", np.nan), row.get(f"{key}_hi", np.nan)
    if np.isfinite(lo) and np.isfinite(hi):
        text += f" [{100 * lo:.0f}-{100 * hi:.0f}]"
    return text


def _board(runs: list[RunResults]) -> pd.DataFrame:
    return leaderboard_of(runs).set_index("detector")


def _rates(runs: list[RunResults], keys: tuple[str, ...]) -> pd.DataFrame:
    """Per detector, each key's mean over the runs where the detector finished OK."""
    frames = [r.metrics[r.metrics["status"] == "OK"].set_index("detector")[list(keys)] for r in runs]
    return pd.concat(frames).groupby(level=0).mean()


def pooled_tp(runs: list[RunResults], dimension: str) -> pd.DataFrame:
    """TP rate per detector, value and mode of a breakdown dimension, flights pooled over the runs."""
    parts = [r.table("breakdown.csv") for r in runs if (r.path / "breakdown.csv").is_file()]
    if not parts:
        return pd.DataFrame(columns=["detector", "value", "mode", "n", "detected", "tp_rate"])
    b = pd.concat(parts)
    b = b[b["dimension"] == dimension]
    # a value written as "n/a" (e.g. the detectability of an attack that changed no value) reads back as NaN
    return _summed(b.assign(value=b["value"].astype(object).where(b["value"].notna(), "n/a").astype(str)))


def _summed(b: pd.DataFrame) -> pd.DataFrame:
    """Flights and detections summed per detector, value and mode, and their TP rate."""
    g = b.groupby(["detector", "value", "mode"], as_index=False)[["n", "detected"]].sum()
    g["tp_rate"] = g["detected"] / g["n"].where(g["n"] > 0)
    return g


def tp_by_family(runs: list[RunResults]) -> pd.DataFrame:
    """pooled_tp by attack family: a configuration of one action counts under its action; one that
    combines k actions (the paper grid's 2- and 3-scenario flights) under "k actions combined"
    (38 combinations would make a table nobody reads)."""
    fam = pooled_tp(runs, "action")
    if not len(fam):
        return fam
    k = fam["value"].astype(str).str.count(r"\+") + 1
    return _summed(fam.assign(value=fam["value"].where(k == 1, k.astype(str) + " actions combined")))


def family_order(values) -> list[str]:
    """Single actions alphabetically, then the combinations by size."""
    return sorted(set(values), key=lambda v: (v.endswith("combined"), v))


def figures(det: pd.DataFrame, fam: pd.DataFrame, folder: Path) -> list[Path]:
    """TP by detectability bin (``pooled_tp(runs, "detectability_bin")``), and TP by attack family and mode
    (``tp_by_family(runs)``), as PNG files in ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    if len(det):
        det = det[det["mode"] == "all"]
        order = [b for b in DETECTABILITY_ORDER if b in set(det["value"])]
        fig, ax = plt.subplots(figsize=(7, 4))
        for name in PAPER:
            d = det[det["detector"] == name].set_index("value").reindex(order)
            ax.plot(range(len(order)), 100 * d["tp_rate"], marker="o", label=name)
        ax.set_xticks(range(len(order)), order, rotation=20)
        ax.set_xlabel("detectability bin (attack effect in validation standard deviations)")
        ax.set_ylabel("TP, in window (%)")
        ax.set_ylim(-2, 102)
        ax.legend(fontsize=7, ncol=2)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        out.append(folder / "tp_by_detectability.png")
        fig.savefig(out[-1], dpi=110)
        plt.close(fig)
    if len(fam):
        families = family_order(fam["value"])
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        for ax, mode in zip(axes, ("simulation", "csv")):
            m = fam[fam["mode"] == mode].pivot(index="detector", columns="value", values="tp_rate")
            m = m.reindex(index=list(PAPER), columns=families)
            im = ax.imshow(100 * m.to_numpy(dtype=float), vmin=0, vmax=100, cmap="viridis", aspect="auto")
            ax.set_xticks(range(len(families)), families, rotation=45, ha="right", fontsize=7)
            ax.set_yticks(range(len(PAPER)), list(PAPER), fontsize=8)
            ax.set_title(f"TP by attack family, {mode} mode (%)", fontsize=9)
            for (i, j), v in np.ndenumerate(m.to_numpy(dtype=float)):
                if np.isfinite(v):
                    ax.text(j, i, f"{100 * v:.0f}", ha="center", va="center", fontsize=6,
                            color="white" if v < 0.6 else "black")
        fig.colorbar(im, ax=axes, shrink=0.8)
        out.append(folder / "tp_by_family.png")
        fig.savefig(out[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return out


def verdict(board: pd.DataFrame, rule: pd.DataFrame) -> list[str]:
    """The paper's findings, each checked against the runs (sentences computed from the numbers)."""
    lines = []
    ours = {d: (board.at[d, "tp_simulation_mean"], board.at[d, "tp_csv_mean"]) for d in CLASSICAL if d in board.index}
    if ours:
        gaps = {d: 100 * (c - s) for d, (s, c) in ours.items()}
        holds = all(g > 10 for g in gaps.values())
        lines.append(f"- *csv mode far above simulation mode for the classical detectors* (paper: +27 to +44 "
                     f"points): {'holds' if holds else 'does not hold'} here ("
                     + ", ".join(f"{d} {g:+.1f}" for d, g in gaps.items()) + " points, TP csv - TP simulation).")
    deep = [d for d in DEEPOD if d in board.index]
    if deep:
        tp = [100 * min(board.at[d, "tp_simulation_mean"], board.at[d, "tp_csv_mean"]) for d in deep]
        flagged = [100 * min(rule.at[d, "flagged_simulation"], rule.at[d, "flagged_csv"]) for d in deep
                   if d in rule.index]
        lines.append(f"- *The DeepOD models detect every attack* (paper: 100 % in both modes): "
                     f"{'holds' if min(tp) >= 99.5 else 'does not hold'} here (the lower of the two modes: "
                     f"{min(tp):.1f}-{max(tp):.1f} % in window"
                     + (f", {min(flagged):.1f}-{max(flagged):.1f} % flagged anywhere" if flagged else "") + ").")
        best_deep = max(deep, key=lambda d: board.at[d, "headline_mean"])
        best_classic = max((d for d in CLASSICAL if d in board.index), key=lambda d: board.at[d, "headline_mean"],
                           default=None)
        if best_classic is not None:
            above = board.at[best_deep, "headline_mean"] > board.at[best_classic, "headline_mean"]
            lines.append(f"- *The DeepOD models above the classical detectors*: {'holds' if above else 'does not hold'}"
                         f" for the best of each ({best_deep} {_pct(board.at[best_deep, 'headline_mean'])} vs "
                         f"{best_classic} {_pct(board.at[best_classic, 'headline_mean'])}, headline).")
    tn = [100 * board.at[d, "tn_no_attack_mean"] for d in board.index if d in PAPER]
    if tn:
        lines.append(f"- *TN of 90-100 % on normal flights*: here {min(tn):.1f}-{max(tn):.1f} %, by construction: "
                     "every threshold is calibrated for a 5 % false-alarm rate per flight (the paper states no "
                     "threshold rule).")
    return lines


def why(runs: list[RunResults], rule: pd.DataFrame, det: pd.DataFrame, fam: pd.DataFrame,
        others: dict[str, list[RunResults]] | None = None) -> list[str]:
    """Where the gap to the paper comes from, in numbers: the detection rule, the attacks' strength
    (``det``: the pooled detectability bins), the counting window, csv vs simulation mode per family
    (``fam``: ``tp_by_family``) and (with other profiles' runs) the grid."""
    lines = ["Where the differences come from (from the experiments below):", ""]
    deep = [d for d in DEEPOD if d in rule.index]
    if deep:
        r = rule.loc[deep]
        lift = 100 * ((r["flagged_simulation"] + r["flagged_csv"]) - (r["tp_simulation"] + r["tp_csv"])).mean() / 2
        lines.append(f"- The detection rule: counting a flight flagged anywhere, as the paper's numbers allow, adds "
                     f"{lift:.1f} points on average to the DeepOD models' TP (both modes).")
    if len(det):
        det = det[(det["mode"] == "all") & det["detector"].isin(list(PAPER))]
        by_bin = det.groupby("value")[["n", "detected"]].sum()
        share = by_bin["n"] / by_bin["n"].sum()
        rate = by_bin["detected"] / by_bin["n"]
        parts = [f"{b}: {100 * share.get(b, 0):.0f} % of the attacks, TP {100 * rate.get(b, np.nan):.0f} %"
                 for b in (*DETECTABILITY_ORDER, "n/a") if b in by_bin.index]
        strong = det[det["value"] == DETECTABILITY_ORDER[-1]].set_index("detector")
        full = [d for d in PAPER if d in strong.index and strong.at[d, "tp_rate"] >= 0.99]
        big = "the attacks that move a field by 10 validation standard deviations or more"
        if full:
            caught = f"{', '.join(full)} {'catch' if len(full) > 1 else 'catches'} 99 % or more of {big}"
        elif len(strong):
            best = strong["tp_rate"].idxmax()
            caught = f"no detector catches 99 % of {big} (the best, {best}: {_pct(strong.at[best, 'tp_rate'])} %)"
        else:
            caught = "no attack moves a field by 10 validation standard deviations or more"
        lines.append(f"- The attacks' strength: {caught}; TP falls with the attack's size (all detectors pooled; "
                     + "; ".join(parts) + "). The paper does not give its attacks' sizes relative to normal "
                     "variation; a grid of strong attacks alone would give every detector that catches 99 % of "
                     "them 100 %, the classical ones among them too, so it would not give the paper's ranking "
                     "(table and figure below).")
    lines.append("- The counting window: without the 8 s burn-in after arming (protocol v1's counting), the "
                 "start-up sets every threshold and TP falls (table below); the paper states no such rule.")
    if len(fam):
        fam = fam[fam["detector"].isin(list(PAPER)) & ~fam["value"].str.endswith("combined")]
        tp = fam.pivot_table(index=["detector", "value"], columns="mode", values="tp_rate")
        if {"simulation", "csv"} <= set(tp.columns):
            gap = (100 * (tp["simulation"] - tp["csv"])).groupby(level="value").mean().sort_values(ascending=False)
            top = [f"{f} {g:+.1f}" for f, g in gap.head(3).items()]
            lines.append(f"- csv mode {'below' if gap.median() > 0 else 'level with or above'} simulation mode: in "
                         "simulation mode the controller acts on the attacked "
                         "values, so the flight itself moves and other fields show it; in csv mode only the attacked "
                         "field changes. The gap (TP simulation - TP csv, mean over the detectors) is largest for "
                         + ", ".join(top) + " points, and "
                         f"{gap.median():+.1f} for the median family. The paper's csv mode coming out 27-44 points "
                         "above needs csv flights that differ in some other way; its text does not say how they "
                         "were made.")
    for other, other_runs in (others or {}).items():
        b = _rates(other_runs, ("tp_simulation", "tp_csv"))
        common = [d for d in rule.index if d in b.index]
        if not common:
            continue
        gap = 100 * ((rule.loc[common, ["tp_simulation", "tp_csv"]] - b.loc[common, ["tp_simulation", "tp_csv"]])
                     .abs().mean(axis=1))
        n_self, n_other = (int(r[0].metrics["n_simulation"].iloc[0]) for r in (runs, other_runs))
        lines.append(f"- The grid: on the {other} profile's grid ({n_other} attacked flights per mode, against "
                     f"{n_self} here) the same detectors' TP differs from this page's by {gap.median():.1f} points "
                     f"for the median detector and {gap.max():.1f} at most ({gap.idxmax()}; mean of the two modes), "
                     "so the grid's size does not explain a gap of tens of points (table below).")
    return lines


def _attainability(runs: list[RunResults]) -> list[str]:
    """A line saying when a variant's alpha cannot be reached with the runs' validation flights."""
    m = pd.concat([r.metrics for r in runs])
    if "alpha_attainable" not in m or not (m["alpha_attainable"] == 0).any():
        return []
    n = int(m["n_validation"].min())
    alpha = float(m["alpha"].dropna().iloc[0])
    return [f"With {n} validation flights alpha = {100 * alpha:g} % is not attainable (the conformal rank "
            f"ceil((n + 1)(1 - alpha)) = {math.ceil((n + 1) * (1 - alpha))} exceeds n): the threshold is the largest "
            f"validation score; at 5 % the rank is {math.ceil((n + 1) * 0.95)} of {n}, so the two thresholds "
            f"{'are the same and nothing moves' if math.ceil((n + 1) * 0.95) >= n else 'differ'}. "
            "100 validation flights (standard and paper profiles) reach 1 % (rank 100 of 100).", ""]


def _detectability_lines(det: pd.DataFrame) -> list[str]:
    """TP per detector and detectability bin (both modes), flights pooled over the seeds."""
    if not len(det):
        return []
    det = det[det["mode"] == "all"]
    return ["", "## Per detectability bin", "", "TP in window, both modes, flights pooled over the seeds, by how far "
            "the attack moves the attacked field in standard deviations of that field on validation flights "
            "(n attacked flights in the header; n/a: the attack changed no value the detectors see against a "
            "clean reference, e.g. it only dropped messages, or acted before the flight controller in simulation "
            "mode, where the two views agree by construction):", "", *detectability_table(det, list(PAPER))]


def detectability_table(det: pd.DataFrame, detectors: list[str]) -> list[str]:
    """A markdown table of TP per detector (rows, in the given order) and detectability bin (columns, with
    their attacked-flight counts) from ``pooled_tp(runs, "detectability_bin")`` rows of one mode."""
    order = [b for b in (*DETECTABILITY_ORDER, "n/a") if b in set(det["value"])]
    nper = det.groupby("value")["n"].max()
    lines = ["| Detector | " + " | ".join(f"{b} ({int(nper.get(b, 0))})" for b in order) + " |",
             "|---" * (len(order) + 1) + "|"]
    for name in detectors:
        d = det[det["detector"] == name].set_index("value")["tp_rate"]
        lines.append(f"| {name} | " + " | ".join(_pct(d.get(b, np.nan)) for b in order) + " |")
    return lines



#: What the paper profile flies, said on its page (issue 47: the quick and standard profiles fly a mix)
PAPER_SQUARE = ("Every flight of the paper profile flies the paper's 30 m square on the 3DR Iris, as the paper's own "
                "flights did, so that this table compares with the paper's; the quick and standard profiles fly a mix "
                "of mission families and airframes ([missions.md](missions.md)), and what the mix does to every "
                "detector is measured beside the square in [realism.md](realism.md#mission-diversity).")

def write_page(out: Path, profile: str, seeds: list[int], runs: list[RunResults],
               variants: dict[str, list[RunResults]], wall_s: float, command: str,
               trained: dict[str, list[RunResults]] | None = None,
               others: dict[str, list[RunResults]] | None = None) -> list[Path]:
    """docs/results.md and its figures; ``others``: other profiles' runs for the grid comparison."""
    board = _board(runs)
    rule_keys = ("tp_simulation", "tp_csv", "tp_end_simulation", "tp_end_csv", "flagged_simulation", "flagged_csv",
                 "far_no_attack", "tn_no_attack")
    rule = _rates(runs, rule_keys)
    bins, fam = pooled_tp(runs, "detectability_bin"), tp_by_family(runs)
    figs = figures(bins, fam, out.parent / out.stem)
    n = board.iloc[0] if len(board) else None
    first = runs[0].metrics.set_index("detector")
    counts = (f"{int(first['n_simulation'].iloc[0])} simulation-mode and {int(first['n_csv'].iloc[0])} csv-mode "
              f"attacked flights, {int(first['n_no_attack'].iloc[0])} held-out normal flights and "
              f"{int(first['n_validation'].iloc[0])} validation flights per seed") if n is not None else ""
    run_walls = [wall_s(r.path) for r in runs if (r.path / "wall_s.json").is_file()]
    lines = [
        "# Reference results",
        "",
        f"The {profile} profile, {'seeds' if len(seeds) > 1 else 'seed'} {', '.join(map(str, seeds))}: {counts}. "
        "Regenerate this page (runs are resumed, finished ones reused) with",
        "",
        f"```\n{command}\n```",
        "",
        f"Made on {datetime.now(UTC):%Y-%m-%d} on {platform.machine()} with {_cpus()} CPUs"
        + (f"; the {len(run_walls)} benchmark run{'s' if len(run_walls) > 1 else ''} (dataset generation "
           f"included) took {sum(run_walls) / 60:.1f} min" if run_walls else "") + f"; the command's last invocation took {wall_s / 60:.1f} min (runs and "
        "retrained configurations it found finished are reused, not timed again).",
        "",
        *([f"Not the paper profile: its 2048 configurations per mode and 100 held-out normal flights per "
           f"seed give intervals of a few points where the {profile} profile's are ten. The same command with "
           "`--profile paper --out docs/results.md` makes its page: [results.md](results.md).", ""]
          if profile != "paper" else [PAPER_SQUARE, ""]),
        "Protocol v2 (docs/protocol.md): thresholds calibrated on validation normal flights for a 5 % false-alarm "
        "rate per flight, 8 s burn-in after arming, TP = an alarm inside the attack window. "
        + ("Cells: mean ± standard deviation over the seeds [95 % interval of the flights pooled over the seeds]. "
           if len(seeds) > 1 else
           "Cells: the rate [its 95 % interval]. One seed: the seed-to-seed spread is on the quick profile's "
           "three-seed page ([results-quick.md](results-quick.md)). ")
        + "*Rank held*: the share of paired bootstrap resamples of the test flights in which the detector keeps "
        "its rank.",
        "",
        "## The paper's table and ours",
        "",
        "| Rank | Rank held | Detector | Paper TP sim / TP csv / TN | TP simulation | TP csv | TN no attack | "
        "False alarms | ROC-AUC |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for det, row in board.iterrows():
        paper = PAPER.get(det)
        held = row.get("rank_certainty", np.nan)
        lines.append(f"| {'–' if pd.isna(row['rank']) else int(row['rank'])} | "
                     f"{'–' if pd.isna(held) else f'{100 * held:.0f} %'} | {det} | "
                     f"{' / '.join(f'{p:g}' for p in paper) if paper else '–'} | {_cell(row, 'tp_simulation')} | "
                     f"{_cell(row, 'tp_csv')} | {_cell(row, 'tn_no_attack')} | "
                     f"{_pct(1 - row.get('tn_no_attack_mean', np.nan))} | "
                     f"{row.get('roc_auc_mean', np.nan):.3f} |")
    lines += ["", "## What the paper found, checked here", "", *verdict(board, rule), "",
              *why(runs, rule, bins, fam, others), ""]
    lines += ["## Factor by factor", "",
              "Each experiment changes one factor. The detection rule, alpha and the burn-in rescore the saved scores "
              "of the same runs; the grid comparison reads the other profiles' runs in the same runs folder; a "
              "retrained configuration trains one detector again on the same datasets with the same seeds.", "",
              "**Detection rule** (TP simulation / TP csv, mean over seeds): in the attack window (ours), in the "
              "window or its 2 s end transient, flagged anywhere in the flight (the paper's lenient reading).", "",
              "| Detector | in window | window + end | flagged anywhere | paper |", "|---|---|---|---|---|"]
    for det in board.index:
        if det not in rule.index:
            continue
        r = rule.loc[det]
        paper = PAPER.get(det)
        lines.append(f"| {det} | {_pct(r['tp_simulation'])} / {_pct(r['tp_csv'])} | {_pct(r['tp_end_simulation'])} / "
                     f"{_pct(r['tp_end_csv'])} | {_pct(r['flagged_simulation'])} / {_pct(r['flagged_csv'])} | "
                     f"{f'{paper[0]:g} / {paper[1]:g}' if paper else '–'} |")
    for name, (what, _) in VARIANTS.items():
        if not variants.get(name):
            continue
        other = _rates(variants[name], ("tp_simulation", "tp_csv", "tn_no_attack", "far_no_attack"))
        lines += ["", f"**{what}** instead of the default (TP simulation / TP csv / false alarms on normal flights, "
                      "default -> variant):", ""]
        lines += _attainability(variants[name])
        lines += ["| Detector | TP simulation | TP csv | False alarms |", "|---|---|---|---|"]
        for det in board.index:
            if det not in other.index or det not in rule.index:
                continue
            a, b = rule.loc[det], other.loc[det]
            lines.append(f"| {det} | {_pct(a['tp_simulation'])} -> {_pct(b['tp_simulation'])} | "
                         f"{_pct(a['tp_csv'])} -> {_pct(b['tp_csv'])} | {_pct(a['far_no_attack'])} -> "
                         f"{_pct(b['far_no_attack'])} |")
    lines += _profile_lines(profile, runs, rule.reindex([d for d in board.index if d in rule.index]),
                            others or {})
    lines += _trained_lines(board, trained or {})
    if not trained and profile != "quick":
        lines += ["", "Retrained configurations (" + "; ".join(c.short or c.what for c in TRAINED.values())
                  + ") train a detector again on every seed's dataset; they are on the quick profile's page "
                  "([results-quick.md](results-quick.md)), made with the same command without `--no-retrained`."]
    if len(fam):
        lines += ["", "## Per attack family", "", "TP in window, flights pooled over the seeds (simulation / csv; "
                  "n flights per mode in the header; a flight that combines several actions counts under "
                  "\"k actions combined\").", ""]
        families = family_order(fam["value"])
        nper = fam[fam["detector"] == fam["detector"].iloc[0]].set_index(["value", "mode"])["n"]
        head = [f"{f} ({int(nper.get((f, 'simulation'), 0))}/{int(nper.get((f, 'csv'), 0))})" for f in families]
        lines += ["| Detector | " + " | ".join(head) + " |", "|---" * (len(families) + 1) + "|"]
        for det in PAPER:
            d = fam[fam["detector"] == det].set_index(["value", "mode"])["tp_rate"]
            cells = [f"{_pct(d.get((f, 'simulation'), np.nan))} / {_pct(d.get((f, 'csv'), np.nan))}" for f in families]
            lines.append(f"| {det} | " + " | ".join(cells) + " |")
    lines += _detectability_lines(bins)
    if figs:
        lines += ["", "## Figures", ""] + [f"![{p.stem}]({p.parent.name}/{p.name})" for p in figs]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    return [out, *figs]


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scart_bench.reports.reference", description=__doc__.split("\n")[0])
    p.add_argument("--profile", default="paper", choices=("quick", "standard", "paper"))
    p.add_argument("--seeds", default="0,1,2", help="comma-separated dataset and detector seeds (default 0,1,2)")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--runs", type=Path, default=Path("runs/reference"), help="folder of the run folders")
    p.add_argument("--data", type=Path, default=Path("data/datasets"), help="folder of the datasets")
    p.add_argument("--out", type=Path, default=Path("docs/results.md"))
    p.add_argument("--no-retrained", action="store_true",
                   help="leave out the retrained configurations (Telemanom on TensorFlow)")
    args = p.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    t0 = time.perf_counter()
    done = reference_runs.reference_runs(args.profile, seeds, args.jobs, args.runs, args.data,
                                         {} if args.no_retrained else TRAINED)
    runs = load_runs(done.runs)
    variants = {name: load_runs(folders) for name, folders in done.variants.items()}
    trained = {name: load_runs(folders) for name, folders in done.trained.items()}
    command = (f"python -m scart_bench.reports.reference --profile {args.profile} --seeds {args.seeds} "
               f"--jobs {args.jobs} --runs {args.runs}{' --no-retrained' if args.no_retrained else ''} "
               f"--out {args.out}")
    others = {k: load_runs(v) for k, v in other_profiles(args.runs, args.profile).items()}
    for f in write_page(args.out, args.profile, seeds, runs, variants, time.perf_counter() - t0, command,
                        trained, others):
        print(f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
