"""``scart-bench report``: the leaderboard of one or many runs as Markdown, CSV and a self-contained
HTML page, with the figures (``<out>/figures/*.png``, also embedded in the HTML).

Figures: the headline score per detector; per run, flight-level ROC curves, the TP-rate heatmap and
each detector's operating characteristic (TP in window against false alarms on held-out normal flights
over a range of alpha, from the saved scores, with the spread of the realised false-alarm rate and the
paper's point);
for the first run, one example attacked flight (flagged by the top-ranked detector when possible,
simulation mode first): its path, a sensor trace and that detector's score. The flight's path and
trace need the run's dataset (``config.json`` ``dataset.path``); when it is gone they are skipped
with a note.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.metrics import OC_ALPHAS
from scart_bench.benchmark.protocol import Protocol
from scart_bench.benchmark.reference_runs import PAPER
from scart_bench.benchmark.results import operating_characteristics
from scart_bench.benchmark.store import atomic_write_text
from scart_bench.dataset import is_dataset, open_dataset
from scart_bench.errors import ReportError, ScartBenchError
from scart_bench.reports import figures as fg
from scart_bench.reports import html as html_page
from scart_bench.reports.leaderboard import (
    config_differences,
    leaderboard_of,
    md_text,
    terminal_table,
    to_csv,
    to_markdown,
)
from scart_bench.reports.results import RunResults, load_runs


@dataclass
class ReportFiles:
    """What :func:`write_report` wrote."""

    markdown: Path
    csv: Path
    html: Path
    figures: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    board: pd.DataFrame | None = None  # the leaderboard (reports.leaderboard.leaderboard_of)
    runs: list[RunResults] = field(default_factory=list)  # the runs it ranks

    def terminal(self, wide: bool = False) -> str:
        """The leaderboard for a terminal (reports.leaderboard.terminal_table): at most 120 characters a row,
        ``wide``: every column of leaderboard.md."""
        return terminal_table(self.board, self.runs, wide)


def example_flight(run: RunResults, board: pd.DataFrame) -> tuple[str | None, str | None]:
    """(detector, flight id) for the example figures: the best-ranked detector that finished OK in the
    run and an attacked test flight it detected inside the attack window (simulation mode first),
    else any attacked flight."""
    ok = set(run.metrics.loc[run.metrics["status"] == "OK", "detector"].astype(str))
    ranked = [d for d in board["detector"].astype(str) if d in ok]
    if not ranked or not (run.path / "flight_scores.csv").exists():
        return None, None
    fs = run.table("flight_scores.csv")
    att = fs[(fs["detector"] == ranked[0]) & (fs["role"] == "test_attacked")]
    if att.empty:
        return ranked[0], None
    hit = att["outcome"] == "detected" if "outcome" in att.columns else att["flagged"].astype(bool)
    att = att.assign(order=~hit.astype(bool), sim=att["mode"] != "simulation")
    return ranked[0], str(att.sort_values(["order", "sim"], kind="stable")["flight_id"].iloc[0])


def _flight_figures(run: RunResults, board: pd.DataFrame, out: Path) -> tuple[list[tuple[str, Path]], list[str]]:
    det, fid = example_flight(run, board)
    if fid is None:
        return [], [f"{run.label}: no attacked test flight scored by a detector; no flight figures"]
    figs, notes = [], []
    ds_path = Path(str((run.config.get("dataset") or {}).get("path", "")))
    if is_dataset(ds_path):
        ds = open_dataset(ds_path)
        figs.append((f"Flight path of attacked flight {fid} ({run.label})", fg.flight_path(ds, fid, out)))
        figs.append((f"Sensor trace of {fid}, navigator vs simulator view, attack window shaded",
                     fg.sensor_trace(ds, fid, out)))
    else:
        notes.append(f"{run.label}: dataset {ds_path} is not available; flight path and sensor trace skipped")
    try:
        figs.append((f"Score of {det} on {fid} with its row threshold, alarms and the attack window shaded",
                     fg.score_trace(run, det, fid, out)))
    except ReportError as exc:  # e.g. the job folder was removed: the tables still make a report
        notes.append(f"{run.label}: score figure of {det} skipped: {exc}")
    return figs, notes


def _oc_figures(run: RunResults, out: Path) -> tuple[list[tuple[str, Path]], list[str]]:
    """Each OK detector's operating characteristic, from the run's saved scores (notes for what is skipped)."""
    try:
        oc = operating_characteristics(run.path)
    except (ScartBenchError, ValueError, OSError) as exc:  # e.g. the job folders were removed: the tables still report
        return [], [f"{run.label}: operating characteristics skipped: {exc}"]
    run_alpha = Protocol.from_dict(run.config["identity"]["protocol"]).alpha
    figs, notes = [], []
    for det in run.metrics.loc[run.metrics["status"] == "OK", "detector"].astype(str):
        if not (oc["detector"] == det).any():
            notes.append(f"{run.label}: no saved scores of {det}; its operating characteristic is skipped")
            continue
        n_val = int(oc.loc[oc["detector"] == det, "n_validation"].iloc[0])
        figs.append((f"Operating characteristic of {det} ({run.label}): TP in window against false alarms on "
                     f"held-out normal flights for target alpha {', '.join(f'{100 * a:g}' for a in OC_ALPHAS)} %"
                     f" (the run's alpha circled, the paper's point starred where it reports one); bars: 95 % "
                     f"spread of the false-alarm rate realised with {n_val} validation flights",
                     fg.operating_characteristic(oc, det, run.label, out, run_alpha, PAPER.get(det))))
    return figs, notes


def draw_figures(board: pd.DataFrame, runs: list[RunResults], out: Path) -> tuple[list[tuple[str, Path]], list[str]]:
    """Every report figure as (caption, PNG path), and notes on what was skipped."""
    figs: list[tuple[str, Path]] = []
    notes: list[str] = []
    if board["headline_mean"].notna().any():
        figs.append(("Headline score per detector (mean ± std over runs)", fg.headline_bars(board, out)))
    for run in runs:
        if not (run.path / "flight_scores.csv").exists():
            notes.append(f"{run.label}: no flight_scores.csv; ROC and heatmap skipped")
            continue
        figs.append((f"Flight-level ROC curves: {run.label}", fg.roc_curves(run, out)))
        figs.append((f"TP rate by action x target: {run.label}", fg.tp_heatmap(run, out)))
        more, why = _oc_figures(run, out)
        figs += more
        notes += why
    more, why = _flight_figures(runs[0], board, out)
    return figs + more, notes + why


def write_report(run_paths: list[str | Path], out: str | Path, figures: bool = True,
                 defense: list[str | Path] = ()) -> ReportFiles:
    """Write leaderboard.md, leaderboard.csv, leaderboard.html and figures/ into ``out``.

    ``defense``: folders ``scart-bench defend`` wrote, shown beside the leaderboard with those found in the run
    folders (reports.defense)."""
    from scart_bench.reports import defense as defense_section

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ReportError(f"--out {out}: exists and is not a folder")
    runs = load_runs(list(run_paths))
    defended = defense_section.find_defense(list(run_paths), list(defense))
    board = leaderboard_of(runs)
    out.mkdir(parents=True, exist_ok=True)
    figs, notes = draw_figures(board, runs, out / "figures") if figures else ([], [])
    defense_figs = defense_section.figures(defended, out / "figures") if figures else {}
    md = to_markdown(board, runs, out, notes) + defense_section.markdown(defended, defense_figs, out)
    figs += [(defense_section._caption(f), p) for f, p in defense_figs.items()]
    if figs:
        md += "\n## Figures\n\n" + "".join(f"![{md_text(cap)}]({p.relative_to(out).as_posix()})\n\n"
                                           for cap, p in figs)
    diffs = config_differences(runs)
    if diffs:
        notes.insert(0, f"The runs differ in: {', '.join(diffs)}; their mean mixes configurations.")
    files = ReportFiles(out / "leaderboard.md", out / "leaderboard.csv", out / "leaderboard.html",
                        [p for _, p in figs], notes, board, runs)
    for path, text in ((files.markdown, md), (files.csv, to_csv(board)),
                       (files.html, html_page.page(board, runs, figs, out, notes, defense_section.html(defended)))):
        atomic_write_text(path, text)
        os.chmod(path, 0o644)  # a report is meant to be shared (the temp file was private)
    return files
