"""The leaderboard: one row per detector over one or many runs, ranked by a headline score.

Headline score (per detector and run): the mean of the paper's three rates, TP Simulation, TP CSV
and TN No Attack (fractions 0..1). A rate that is undefined in a run (no attacked flight of that
mode) is left out of the mean; the other detectors of the run share the same flights, so they
are compared on the same terms. Detectors are ranked by the mean headline score over the runs in
which they finished OK.

Several runs of the same configuration (e.g. seeds) give, per metric, the mean over the runs where
the detector finished OK, the sample standard deviation (``ddof=1``; NaN with a single run) and
the number of those runs. A detector missing from a run, or whose job failed there, contributes
nothing to the mean: it is shown by its status in that run (``missing``, ``ERROR``, ``TIMEOUT``,
``UNFINISHED``), never as zero.

Intervals: every rate (TP, late, flagged anywhere, TN) carries, for a single run, that run's own
interval (protocol v2: a cluster bootstrap that re-calibrates the threshold), and over several runs
the 95 % Wilson interval of the flights pooled over the OK runs (``<rate>_lo`` / ``<rate>_hi``,
resting on ``<rate>_n`` flights);
ROC-AUC and AUC-PR carry the run's bootstrap interval when the detector finished OK in one run
(with several runs their spread is the standard deviation).

Columns of :func:`build_leaderboard`'s table: ``rank``, ``rank_certainty`` (share of paired cluster-bootstrap
resamples of the test flights in which the detector keeps its rank: :func:`rank_certainty`), ``detector``, ``n_runs`` (OK runs),
``runs`` (runs given), ``headline_mean``, ``headline_std``, then per run ``status[<run>]`` and
``headline[<run>]``, then ``<metric>_mean`` / ``<metric>_std`` for every metric of
:data:`METRICS`, then ``<metric>_lo`` / ``<metric>_hi`` (and ``<rate>_n``) where it has an interval.
"""

from __future__ import annotations

import html
import os
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pandas as pd

from scart_bench.benchmark.intervals import cluster_weights, wilson
from scart_bench.benchmark.results import transfer_summary
from scart_bench.reports.results import RunResults, load_runs

#: The three rates averaged into the headline score.
HEADLINE_PARTS = ("tp_simulation", "tp_csv", "tn_no_attack")
MISSING = "missing"

#: (column, label, format) of the metrics shown and aggregated: ``pct`` = percent of a fraction,
#: ``fN`` = N decimals.
METRICS: tuple[tuple[str, str, str], ...] = (
    ("headline", "Headline", "pct"),
    ("tp_simulation", "TP Simulation (in window)", "pct"),
    ("tp_csv", "TP CSV (in window)", "pct"),
    ("tn_no_attack", "TN No Attack", "pct"),
    ("late_simulation", "Late Sim", "pct"),
    ("late_csv", "Late CSV", "pct"),
    ("flagged_simulation", "Flagged anywhere Sim", "pct"),
    ("flagged_csv", "Flagged anywhere CSV", "pct"),
    ("roc_auc", "ROC-AUC", "f3"),
    ("auc_pr", "AUC-PR", "f3"),
    ("vus_pr", "VUS-PR", "f3"),
    ("vus_roc", "VUS-ROC", "f3"),
    ("point_f1", "Point F1", "f3"),
    ("r_f1", "R-F1 (TSB-AD)", "f3"),
    ("delay_median_s", "Median delay (s)", "f2"),
    ("false_alarms_per_hour", "False alarms / h", "f2"),
    ("latency_us_per_row", "Latency (us/row)", "f1"),
    ("fit_s", "Fit (s)", "f1"),
)
#: Metrics shown in the Markdown and HTML tables (all of METRICS are in the CSV).
SHOWN = ("tp_simulation", "tp_csv", "tn_no_attack", "flagged_simulation", "flagged_csv", "roc_auc", "auc_pr",
         "vus_pr", "r_f1", "delay_median_s", "false_alarms_per_hour")
#: Rates and the count of flights each rests on (a Wilson interval over the flights of the OK runs).
RATE_COUNTS = {"tp_simulation": "n_simulation", "tp_csv": "n_csv", "tn_no_attack": "n_no_attack",
               "late_simulation": "n_simulation", "late_csv": "n_csv", "flagged_simulation": "n_simulation",
               "flagged_csv": "n_csv"}
#: Threshold-free scores with a bootstrap interval in each run's metrics.
BOOTSTRAPPED = ("roc_auc", "auc_pr")
HEADLINE_DOC = ("Headline score = mean of TP Simulation, TP CSV and TN No Attack at each run's operating point "
                "(the threshold calibrated to its alpha; a rate undefined in a run is left out); detectors are "
                "ranked by its mean over the runs where they finished OK. 'Rank held' is the share of paired "
                "bootstrap resamples of the test flights (clusters resampled, the same for every detector) in "
                "which the detector keeps that rank. "
                "TP counts an attacked flight only when a row alarms inside its attack window; 'flagged anywhere' "
                "is the paper's lenient rule. Rates show [95 % Wilson interval] over the flights of the OK runs; "
                "ROC-AUC and AUC-PR of a single run show their bootstrap interval. "
                "With several runs a cell shows mean ± sample standard deviation; n = runs where the detector "
                "finished OK. A detector that is missing or failed in a run shows that status, never 0.")


RULES_DOC = ("Scoring rules: an attacked flight is detected (TP) only when one of its rows alarms inside an "
             "attack window [start, end) of its event log; alarms only after the window make it 'late' "
             "(reported apart), and 'flagged anywhere' is the paper's lenient rule, shown as its own column. "
             "Attacked flights whose attack changed nothing relative to their simulator view or csv source "
             "(no_effect) are left out of every rate; csv-mode copies replay normal flights reserved for them, "
             "never train or validation flights. Rates rest on few flights: read them with their interval. "
             "VUS-PR, AUC-PR and R-F1 follow TSB-AD's definitions.")


#: Paired bootstrap replicates behind each rank's certainty.
RANK_BOOTSTRAP = 1000
RANK_SEED = 20240705


def _run_indicators(run: RunResults, detectors: list[str]) -> tuple[np.ndarray, np.ndarray, dict] | None:
    """One run's test flights as the rank bootstrap needs them: clusters, roles and, per detector, the
    (3, n) indicators of TP Simulation, TP CSV and TN No Attack (NaN where a flight is not in that rate)."""
    path = run.path / "flight_scores.csv"
    if not path.is_file():
        return None
    fs = run.table("flight_scores.csv")
    fs = fs[fs["role"].isin(("test_normal", "test_attacked")) & fs["detector"].isin(detectors)]
    if fs.empty:
        return None
    flights = fs.drop_duplicates("flight_id").set_index("flight_id")
    order = flights.index
    groups = [(flights["role"] == "test_attacked") & (flights["mode"] == m) for m in ("simulation", "csv")]
    groups.append(flights["role"] == "test_normal")
    out = {}
    for det, f in fs.groupby("detector", sort=False):
        f = f.set_index("flight_id").reindex(order)
        hits = [(f["outcome"] == "detected").to_numpy(), (f["outcome"] == "detected").to_numpy(),
                ~f["flagged"].astype(bool).to_numpy()]
        out[det] = np.stack([np.where(g.to_numpy() & f["role"].notna().to_numpy(), h, np.nan)
                             for g, h in zip(groups, hits)])
    return flights["cluster"].astype(str).to_numpy(), flights["role"].to_numpy(), out


def bootstrap_headlines(runs: list[RunResults], detectors: list[str], n_boot: int = RANK_BOOTSTRAP,
                        seed: int = RANK_SEED) -> np.ndarray:
    """Each detector's headline in ``n_boot`` paired bootstrap replicates, shape (n_boot, len(detectors)).

    Each replicate resamples every run's test flights by cluster within normal and attacked flights,
    the same resample for every detector (paired), recomputes each detector's headline from the
    per-flight outcomes at the run's threshold and averages it over the runs. Runs without
    ``flight_scores.csv`` are left out; a column is NaN where no run has the detector.
    """
    rng = np.random.default_rng(seed)
    total = np.zeros((n_boot, len(detectors)))
    used = np.zeros(len(detectors))
    for run in runs:
        data = _run_indicators(run, detectors)
        if data is None:
            continue
        clusters, roles, indicators = data
        w = cluster_weights(clusters, roles, n_boot, rng)
        for j, det in enumerate(detectors):
            if det not in indicators:
                continue
            rates = []
            for ind in indicators[det]:
                valid = np.isfinite(ind)
                den = w[:, valid].sum(axis=1)
                num = (w[:, valid] * ind[valid]).sum(axis=1)
                rates.append(np.divide(num, den, out=np.full(n_boot, np.nan), where=den > 0))
            total[:, j] += np.nanmean(np.stack(rates), axis=0)
            used[j] += 1
    return total / np.where(used > 0, used, np.nan)


def bootstrap_ranks(headlines: np.ndarray) -> np.ndarray:
    """Ranks (1 = best) within each bootstrap replicate of :func:`bootstrap_headlines`; ties keep the
    columns' order (the table's)."""
    n_boot, k = headlines.shape
    order = np.argsort(-np.nan_to_num(headlines, nan=-np.inf), axis=1, kind="stable")
    ranks = np.empty_like(order)
    np.put_along_axis(ranks, order, np.arange(1, k + 1)[None, :].repeat(n_boot, 0), axis=1)
    return ranks


def rank_certainty(runs: list[RunResults], ranked: list[str], n_boot: int = RANK_BOOTSTRAP,
                   seed: int = RANK_SEED) -> dict[str, float]:
    """Per ranked detector (best first), the share of bootstrap resamples in which it keeps its rank
    (:func:`bootstrap_headlines`, ranked again in each replicate). NaN when no run has
    ``flight_scores.csv``.
    """
    if len(ranked) < 2:
        return {d: (1.0 if d in ranked else float("nan")) for d in ranked}
    mean = bootstrap_headlines(runs, ranked, n_boot, seed)
    used = np.isfinite(mean).any(axis=0)
    if not used.any():
        return {d: float("nan") for d in ranked}
    held = (bootstrap_ranks(mean) == np.arange(1, len(ranked) + 1)[None, :]).mean(axis=0)
    return {d: (float(held[j]) if used[j] else float("nan")) for j, d in enumerate(ranked)}


def headline(metrics: pd.DataFrame) -> pd.Series:
    """The headline score of each row of a metrics table (NaN for a detector that did not finish OK)."""
    parts = metrics.reindex(columns=list(HEADLINE_PARTS)).astype(float)
    return parts.mean(axis=1, skipna=True).where(metrics["status"] == "OK")


def status_column(label: str) -> str:
    return f"status[{label}]"


def headline_column(label: str) -> str:
    return f"headline[{label}]"


def _per_run(run: RunResults) -> pd.DataFrame:
    """One run's metrics indexed by detector, with the headline score; failed rows hold NaN values."""
    m = run.metrics.drop_duplicates("detector", keep="last").set_index("detector")
    m = m.assign(headline=headline(m.reset_index()).to_numpy())
    keys = [k for k, _, _ in METRICS] + _extra_keys()
    values = m.reindex(columns=keys).astype(float)
    values[m["status"] != "OK"] = np.nan
    values["status"] = m["status"]
    return values


def _extra_keys() -> list[str]:
    """Per-run columns read besides METRICS: flight counts and bootstrap bounds."""
    return (sorted(set(RATE_COUNTS.values())) + [f"{k}_{b}" for k in BOOTSTRAPPED for b in ("lo", "hi")]
            + [f"{r}_{b}" for r in RATE_COUNTS for b in ("lo", "hi", "wilson_lo")])


def _intervals(ok: pd.DataFrame) -> dict:
    """Rate intervals: a single run's own (protocol v2: cluster bootstrap with the threshold's
    uncertainty), else Wilson intervals over the flights of the OK runs pooled; bootstrap intervals
    of a single run for the threshold-free scores."""
    out: dict = {}
    for rate, n_col in RATE_COUNTS.items():
        pairs = ok[[rate, n_col]].dropna()
        n = float(pairs[n_col].sum())
        k = float(np.round(pairs[rate] * pairs[n_col]).sum())
        own = len(ok) == 1 and pd.notna(ok[f"{rate}_wilson_lo"].iloc[0]) and pd.notna(ok[f"{rate}_lo"].iloc[0])
        if own:
            out[f"{rate}_lo"], out[f"{rate}_hi"] = float(ok[f"{rate}_lo"].iloc[0]), float(ok[f"{rate}_hi"].iloc[0])
        else:
            out[f"{rate}_lo"], out[f"{rate}_hi"] = wilson(k, n) if n > 0 else (np.nan, np.nan)
        out[f"{rate}_n"] = int(n)
    for key in BOOTSTRAPPED:
        one = len(ok) == 1
        out[f"{key}_lo"] = float(ok[f"{key}_lo"].iloc[0]) if one else np.nan
        out[f"{key}_hi"] = float(ok[f"{key}_hi"].iloc[0]) if one else np.nan
    return out


def leaderboard_of(runs: list[RunResults]) -> pd.DataFrame:
    """The leaderboard of already loaded runs (see the module docstring for its columns)."""
    tables = [_per_run(r) for r in runs]
    detectors = list(dict.fromkeys(d for t in tables for d in t.index))
    keys = [k for k, _, _ in METRICS]
    rows = []
    for det in detectors:
        row: dict = {"detector": det}
        per_run = []
        for run, table in zip(runs, tables):
            present = det in table.index
            row[status_column(run.label)] = table.at[det, "status"] if present else MISSING
            row[headline_column(run.label)] = table.at[det, "headline"] if present else np.nan
            if present and table.at[det, "status"] == "OK":
                per_run.append(table.loc[det, keys + _extra_keys()].astype(float))
        ok = pd.DataFrame(per_run, columns=keys + _extra_keys())
        row["n_runs"] = len(ok)
        row["runs"] = len(runs)
        for k in keys:
            row[f"{k}_mean"] = ok[k].mean() if len(ok) else np.nan
            row[f"{k}_std"] = ok[k].std(ddof=1) if len(ok) > 1 else np.nan
        row.update(_intervals(ok))
        rows.append(row)
    per_run_cols = [c for r in runs for c in (status_column(r.label), headline_column(r.label))]
    interval_cols = [c for r in RATE_COUNTS for c in (f"{r}_lo", f"{r}_hi", f"{r}_n")]
    interval_cols += [f"{k}_{b}" for k in BOOTSTRAPPED for b in ("lo", "hi")]
    columns = ["detector", "n_runs", "runs", *per_run_cols, *(f"{k}_{s}" for k in keys for s in ("mean", "std")),
               *interval_cols]
    board = pd.DataFrame(rows, columns=columns)
    board = board.sort_values("headline_mean", ascending=False, na_position="last", kind="stable")
    scored = board["headline_mean"].notna().to_numpy()
    board.insert(0, "rank", pd.array(np.where(scored, np.cumsum(scored), 0), dtype="Int64"))
    board.loc[~scored, "rank"] = pd.NA
    certainty = rank_certainty(runs, list(board.loc[scored, "detector"]))
    board.insert(1, "rank_certainty", [certainty.get(d, np.nan) for d in board["detector"]])
    lead = ["rank", "rank_certainty", "detector", "n_runs", "runs", "headline_mean", "headline_std"]
    rest = [c for c in board.columns if c not in lead and c not in per_run_cols]
    return board[lead + per_run_cols + rest].reset_index(drop=True)


def build_leaderboard(runs: list[Path]) -> pd.DataFrame:
    """One row per detector over the given run folders, ranked by the headline score."""
    return leaderboard_of(load_runs(list(runs)))


# -- formatting -------------------------------------------------------------------------------

def fmt(value, kind: str) -> str:
    """A number as shown in the tables (``n/a`` for NaN)."""
    if value is None or pd.isna(value):
        return "n/a"
    v = float(value)
    return f"{100 * v:.1f} %" if kind == "pct" else f"{v:.{kind[1:]}f}"


def fmt_spread(mean, std, kind: str) -> str:
    """``mean ± std`` (just the mean when there is no spread)."""
    if pd.isna(mean):
        return "n/a"
    if std is None or pd.isna(std):
        return fmt(mean, kind)
    return f"{fmt(mean, kind)} ± {fmt(std, kind)}"


def fmt_interval(lo, hi, kind: str) -> str:
    """`` [lo-hi]`` (percent without decimals for rates), empty when there is no interval."""
    if lo is None or hi is None or pd.isna(lo) or pd.isna(hi):
        return ""
    if kind == "pct":
        return f" [{100 * float(lo):.0f}-{100 * float(hi):.0f}]"
    return f" [{fmt(lo, kind)}-{fmt(hi, kind)}]"


def metric_cell(row: pd.Series, key: str, kind: str) -> str:
    """A metric's cell: mean (± std over runs) and its 95 % interval where it has one."""
    text = fmt_spread(row[f"{key}_mean"], row[f"{key}_std"], kind)
    if text == "n/a":
        return text
    return text + fmt_interval(row.get(f"{key}_lo"), row.get(f"{key}_hi"), kind)


def run_cell(row: pd.Series, label: str) -> str:
    """A detector's headline score in one run, or its status there (missing / ERROR / ...)."""
    status = row[status_column(label)]
    if status != "OK":
        return str(status)
    return fmt(row[headline_column(label)], "pct")


def display_table(board: pd.DataFrame, runs: list[RunResults]) -> tuple[list[str], list[list[str]]]:
    """Header and text cells of the leaderboard as shown in Markdown and HTML (not escaped)."""
    labels = dict((k, (lab, kind)) for k, lab, kind in METRICS)
    head = ["Rank", "Rank held", "Detector", "Headline", "n runs", *(f"Headline [{r.label}]" for r in runs),
            *(labels[k][0] for k in SHOWN)]
    body = []
    for _, row in board.iterrows():
        cells = ["–" if pd.isna(row["rank"]) else str(int(row["rank"])),
                 "–" if pd.isna(row["rank_certainty"]) else f"{100 * row['rank_certainty']:.0f} %", str(row["detector"]),
                 fmt_spread(row["headline_mean"], row["headline_std"], "pct"), f"{row['n_runs']}/{row['runs']}"]
        cells += [run_cell(row, r.label) for r in runs]
        cells += [metric_cell(row, k, labels[k][1]) for k in SHOWN]
        body.append(cells)
    return head, body


#: The leaderboard's columns in a terminal (``scart-bench report``): at most 120 characters a row.
TERMINAL_COLUMNS = (("TP Simulation", "tp_simulation", "pct_ci"), ("TP CSV", "tp_csv", "pct_ci"),
                    ("TN No Attack", "tn_no_attack", "pct_ci"), ("ROC-AUC", "roc_auc", "f3"))


def terminal_table(board: pd.DataFrame, runs: list[RunResults], wide: bool = False) -> str:
    """The leaderboard as ``scart-bench report`` prints it: rank, detector, headline, the paper's three rates
    (mean over the runs, pooled interval) and ROC-AUC; ``wide``: every column of leaderboard.md. Markdown."""
    from scart_bench.benchmark.tables import format_value

    if wide:
        head, body = display_table(board, runs)
    else:
        head = ["Rank", "Detector", "Headline", *(label for label, _, _ in TERMINAL_COLUMNS)]
        body = [["–" if pd.isna(row["rank"]) else str(int(row["rank"])), str(row["detector"]),
                 format_value(row["headline_mean"], "pct"),
                 *(format_value(row[f"{key}_mean"], kind, row.get(f"{key}_lo"), row.get(f"{key}_hi"))
                   for _, key, kind in TERMINAL_COLUMNS)] for _, row in board.iterrows()]
    def text(cell) -> str:  # a terminal shows brackets as they are; a pipe would cut the row
        return str(cell).replace("\n", " ").replace("|", "\\|")

    lines = ["| " + " | ".join(map(text, head)) + " |", "|" + "|".join("---" for _ in head) + "|"]
    return "\n".join(lines + ["| " + " | ".join(map(text, cells)) + " |" for cells in body])


def md_text(text: str) -> str:
    """Text safe in Markdown: HTML-escaped (renderers show it as text), pipes and brackets escaped."""
    text = html.escape(str(text), quote=False).replace("\n", " ")
    return "".join("\\" + ch if ch in "|[]" else ch for ch in text)


def to_markdown(board: pd.DataFrame, runs: list[RunResults], out: Path | None = None,
                notes: list[str] = ()) -> str:
    """leaderboard.md: the ranked table, the runs (with links to their configs), failures and notes."""
    head, body = display_table(board, runs)
    lines = ["# scart-bench leaderboard", "", HEADLINE_DOC, "", RULES_DOC, "",
             "| " + " | ".join(md_text(h) for h in head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(md_text(c) for c in cells) + " |" for cells in body]
    lines += ["", "## Runs", "", "| Run | Profile | Seed | Dataset | Detectors | Config |", "|---|---|---|---|---|---|"]
    for r in runs:
        link = config_link(r, out)
        ds = r.config.get("dataset", {}) or {}
        lines.append(f"| {md_text(r.label)} | {md_text(r.config.get('profile', ''))} | {md_text(r.config.get('seed', ''))} | "
                     f"{md_text(ds.get('path', ''))} | {len(r.metrics)} | [config.json]({link}) |")
    lines += transfer_lines(runs)
    fails = failures(runs)
    if fails:
        lines += ["", "## Failed or unfinished jobs", ""]
        lines += [f"- {md_text(run)}: **{md_text(det)}** {md_text(status)}: {md_text(msg)}" for run, det, status, msg in fails]
    diffs = config_differences(runs)
    notes = ([f"The runs differ in: {', '.join(diffs)}; their mean mixes configurations."] if diffs else []) + list(notes)
    if notes:
        lines += ["", "## Notes", ""] + [f"- {md_text(n)}" for n in notes]
    return "\n".join(lines) + "\n"


def transfer_lines(runs: list[RunResults]) -> list[str]:
    """Per transfer run (``--train-dataset``): where its numbers come from, the false-alarm rate on the
    test dataset's normal flights and the TP on its attacked flights, per detector (Markdown lines)."""
    out: list[str] = []
    for r in runs:
        lines = transfer_summary(r.config, r.metrics)
        if lines:
            out += ["", f"{lines[0]}: {md_text(r.label)}", *lines[1:]]
    return out


def config_link(run: RunResults, out: Path | None) -> str:
    """URL of the run's config.json relative to the report folder (percent-encoded, POSIX separators)."""
    target = run.config_path.resolve()
    rel = target if out is None else Path(os.path.relpath(target, Path(out).resolve()))
    return quote(rel.as_posix())


def failures(runs: list[RunResults]) -> list[tuple[str, str, str, str]]:
    """(run, detector, status, message) of every job that did not finish OK."""
    out = []
    for r in runs:
        bad = r.metrics[r.metrics["status"] != "OK"]
        out += [(r.label, str(x["detector"]), str(x["status"]), str(x.get("message", ""))) for _, x in bad.iterrows()]
    return out


def config_differences(runs: list[RunResults]) -> list[str]:
    """Settings that differ between the runs besides the seed and dataset (empty for repeats)."""
    keys = {"profile": lambda c: c.get("profile"),
            "protocol": lambda c: (c.get("identity") or {}).get("protocol"),
            "detector parameters": lambda c: {k: (v or {}).get("params") for k, v in (c.get("jobs") or {}).items()}}
    out = []
    for name, get in keys.items():
        values = [get(r.config) for r in runs]
        if name == "detector parameters":  # compare only detectors present in several runs
            common = [set(v) for v in values]
            shared = set.intersection(*common) if common else set()
            values = [{k: v[k] for k in shared} for v in values]
        if any(v != values[0] for v in values[1:]):
            out.append(name)
    return out


def to_csv(board: pd.DataFrame) -> str:
    """leaderboard.csv: the full table (fractions 0..1, every metric's mean and std)."""
    return board.to_csv(index=False)
