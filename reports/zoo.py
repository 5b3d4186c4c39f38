"""The zoo leaderboard: every detector (the paper's eight and the zoo) on one profile over several seeds,
under protocol v3, ranked with rank certainty, per attack family and detectability bin, with each
detector's fit and score cost per row, written as one Markdown page by one command:

    python -m scart_bench.reports.zoo --profile standard --seeds 0,1,2 --detectors paper,zoo \\
        --jobs 2 --runs runs/zoo --out docs/results-zoo-standard.md

Each seed's run (``<runs>/<profile>-seed<N>``, on the profile's dataset under ``--data``, generated
when missing) is run or resumed by :func:`scart_bench.benchmark.reference_runs.run_seeds`: finished jobs
are kept, so the command can be stopped and started again, and a run that has every detector is not
touched. The page is then written from the run folders alone (``--render-only`` skips the runs), the
same folders giving the same page byte for byte: its date is the runs' last update, its rank certainty
a seeded bootstrap.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import Protocol
from scart_bench.errors import ReportError, RunError, ScartBenchError
from scart_bench.jsonfile import read_json
from scart_bench.reports.leaderboard import (
    RANK_BOOTSTRAP,
    RANK_SEED,
    bootstrap_headlines,
    bootstrap_ranks,
    failures,
    leaderboard_of,
)
from scart_bench.reports.reference import detectability_table, family_order, pooled_tp, tp_by_family
from scart_bench.reports.results import RunResults, load_run, read_table

#: The counting rule a run must be scored under to stand on this page: protocol v3 (the default).
V3 = Protocol()
#: Where ``scart-bench score RUN --phases ends`` writes a pre-v3 run's v3 evaluation.
V3_EVALUATION = Path("evaluations") / "phases-ends"


def detector_names(names: list[str]) -> list[str]:
    """``--detectors`` items (names and tags such as ``paper``, ``zoo``) as built-in names, in order
    (RunError naming an unknown one)."""
    from scart_bench.benchmark.selection import resolve_detectors

    return [c.name for c in resolve_detectors(names, {})]


def is_v3(protocol: Protocol) -> bool:
    """``protocol`` counts flights as v3 does: airborne rows from the margin after take-off to the
    margin before touchdown, thresholds calibrated at v3's alpha, v3's end transient."""
    return (protocol.phases == V3.phases and protocol.phase_margin_s == V3.phase_margin_s
            and protocol.alarm_rule == V3.alarm_rule and protocol.alpha == V3.alpha
            and protocol.end_transient_s == V3.end_transient_s)


@dataclass
class ZooRun:
    """One seed's run as the page reads it: its tables under v3 (the run's own, or its v3 evaluation
    for a run made before v3), and the rows its detectors trained on."""

    results: RunResults
    folder: Path
    train_rows: int
    evaluation: bool  # the tables come from evaluations/phases-ends


def load_v3(path: Path) -> ZooRun:
    """A run folder's v3 tables (ReportError naming the folder when it has none)."""
    run = load_run(path)
    flights = run.table("flights.csv")
    if "rows" not in flights.columns or "role" not in flights.columns:
        raise ReportError(f"{path / 'flights.csv'}: expected columns 'role' and 'rows'")
    train_rows = int(pd.to_numeric(flights.loc[flights["role"] == "train", "rows"], errors="coerce").sum())
    if is_v3(Protocol.from_dict(run.config.get("protocol") or {})):
        return ZooRun(run, path, train_rows, False)
    ev = path / V3_EVALUATION
    if (ev / "metrics.csv").is_file() and (ev / "evaluation.json").is_file():
        info = read_json(ev / "evaluation.json")
        if not isinstance(info, dict) or not isinstance(info.get("protocol"), dict):
            raise ReportError(f"{ev / 'evaluation.json'}: field 'protocol': expected the evaluation's protocol")
        if is_v3(Protocol.from_dict(info["protocol"])):
            metrics = read_table(ev / "metrics.csv")
            return ZooRun(RunResults(ev, run.label, run.config, metrics), path, train_rows, True)
    raise ReportError(f"{path}: scored under phases = {run.config.get('protocol', {}).get('phases', 'burn-in')!r}, "
                      f"not protocol v3 (phases = {V3.phases!r}); evaluate it with "
                      f"`scart-bench score {path} --phases ends` or resume it with `scart-bench run --resume`")


def load_zoo_runs(folders: list[Path]) -> list[ZooRun]:
    """:func:`load_v3` of each folder, each given a distinct label (``name``, ``name #2``, ...)."""
    runs = [load_v3(f) for f in folders]
    seen: dict[str, int] = {}
    for run in runs:
        label = run.results.label
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            run.results.label = f"{label} #{seen[label]}"
    return runs


def _only(run: ZooRun, names: list[str]) -> RunResults:
    """The run's results restricted to ``names`` (other detectors the folder holds are not on the page)."""
    r = run.results
    return RunResults(r.path, r.label, r.config, r.metrics[r.metrics["detector"].isin(names)].reset_index(drop=True))


# -- the numbers -------------------------------------------------------------------------------------

def costs(runs: list[ZooRun], names: list[str]) -> pd.DataFrame:
    """Per detector, mean over the runs where it finished OK: fit microseconds per training row
    (``fit_s`` / the train flights' rows) and score microseconds per scored row (``score_s`` / ``rows``)."""
    rows = []
    for run in runs:
        m = run.results.metrics
        for _, x in m[(m["status"] == "OK") & m["detector"].isin(names)].iterrows():
            rows.append({"detector": x["detector"],
                         "fit_us": 1e6 * float(x["fit_s"]) / run.train_rows if run.train_rows else np.nan,
                         "score_us": 1e6 * float(x["score_s"]) / float(x["rows"]) if x["rows"] else np.nan,
                         "fit_s": float(x["fit_s"]), "score_s": float(x["score_s"])})
    if not rows:
        return pd.DataFrame(columns=["fit_us", "score_us", "fit_s", "score_s"])
    return pd.DataFrame(rows).groupby("detector").mean()


def rank_table(runs: list[RunResults], ranked: list[str], n_boot: int = RANK_BOOTSTRAP,
               seed: int = RANK_SEED) -> pd.DataFrame:
    """Rank certainty of ``ranked`` (best first) from paired bootstrap replicates of the test flights
    (:func:`scart_bench.reports.leaderboard.bootstrap_headlines`): ``held`` (share of replicates in which
    the detector keeps its rank), ``lo`` / ``hi`` (its rank's 2.5 and 97.5 % quantiles) and ``above_next``
    (share of replicates in which its headline is above the next-ranked detector's; NaN for the last)."""
    out = pd.DataFrame(index=pd.Index(ranked, name="detector"),
                       columns=["held", "lo", "hi", "above_next"], dtype=float)
    if not ranked:
        return out
    heads = bootstrap_headlines(runs, ranked, n_boot, seed)
    if not np.isfinite(heads).any():
        return out
    ranks = bootstrap_ranks(heads)
    out["held"] = (ranks == np.arange(1, len(ranked) + 1)[None, :]).mean(axis=0)
    out["lo"] = np.quantile(ranks, 0.025, axis=0, method="lower")
    out["hi"] = np.quantile(ranks, 0.975, axis=0, method="higher")
    above = np.full(len(ranked), np.nan)
    above[:-1] = (heads[:, :-1] > heads[:, 1:]).mean(axis=0)
    out["above_next"] = above
    return out


# -- the page ---------------------------------------------------------------------------------------

def _pct(x) -> str:
    return "–" if x is None or pd.isna(x) else f"{100 * float(x):.1f}"


def _rate(row: pd.Series, key: str, flip: bool = False) -> str:
    """mean (± std over seeds) [95 % interval of the flights pooled over the seeds], in percent;
    ``flip``: the complement (false alarms from TN)."""
    mean, std = row.get(f"{key}_mean", np.nan), row.get(f"{key}_std", np.nan)
    lo, hi = row.get(f"{key}_lo", np.nan), row.get(f"{key}_hi", np.nan)
    if pd.isna(mean):
        return "–"
    if flip:
        mean, lo, hi = 1 - mean, 1 - hi, 1 - lo
    text = _pct(mean) + ("" if pd.isna(std) else f" ± {100 * std:.1f}")
    return text + ("" if pd.isna(lo) or pd.isna(hi) else f" [{100 * lo:.0f}-{100 * hi:.0f}]")


def _num(x, fmt: str) -> str:
    return "–" if x is None or pd.isna(x) else format(float(x), fmt)


def _tag(name: str) -> str:
    from scart_bench.detectors.registry import tag_of

    return tag_of(name) or "plugin"


def page_lines(runs: list[ZooRun], names: list[str], profile: str, seeds: list[int], command: str) -> list[str]:
    """The page's Markdown lines (deterministic for the same run folders)."""
    results = [_only(r, names) for r in runs]
    board = leaderboard_of(results)
    ranked = [d for d, rank in zip(board["detector"], board["rank"]) if not pd.isna(rank)]
    certainty = rank_table(results, ranked)
    cost = costs(runs, names)
    first = results[0].metrics.iloc[0] if len(results[0].metrics) else None
    counts = ("" if first is None else
              f"{int(first['n_simulation'])} simulation-mode and {int(first['n_csv'])} csv-mode attacked flights, "
              f"{int(first['n_no_attack'])} held-out normal flights and {int(first['n_validation'])} validation "
              f"flights per seed (the first seed's counts), ")
    updated = max(str(r.results.config.get("updated", ""))[:10] for r in runs)
    jobs = sorted({int((r.results.config.get("run") or {}).get("jobs", 1)) for r in runs})
    evaluated = [r.folder.name for r in runs if r.evaluation]
    not_run = [d for d in names if d not in set(board["detector"])]
    lines = [
        f"# Detector leaderboard: {profile} profile, {len(seeds)} seed{'s' if len(seeds) > 1 else ''}",
        "",
        f"Every detector asked for ({len(names)}: {', '.join(names)}) on the {profile} profile, seed"
        f"{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}: {counts}under protocol v3 "
        f"(docs/protocol.md: only the airborne rows from {V3.phase_margin_s:g} s after take-off to "
        f"{V3.phase_margin_s:g} s before touchdown calibrate or alarm; thresholds for a "
        f"{100 * V3.alpha:g} % false-alarm rate per flight on the validation normal flights; TP = an alarm "
        "inside the attack window). Written by this command from the run folders (runs are resumed, "
        "finished jobs reused, missing datasets generated):",
        "",
        f"```\n{command}\n```",
        "",
        f"Runs last updated {updated}, {' or '.join(map(str, jobs))} parallel job{'s' if jobs != [1] else ''} "
        "each."
        + (f" {', '.join(evaluated)}: made before v3, read from its v3 evaluation "
           f"(`{V3_EVALUATION.as_posix()}/`, `scart-bench score RUN --phases ends`)." if evaluated else ""),
        "",
        "## Ranking",
        "",
        "Ranked by the headline (mean of TP simulation, TP csv and TN; its mean over the seeds). Cells: mean ± "
        "standard deviation over the seeds [95 % interval of the flights pooled over the seeds], in percent; "
        "*False alarms*: held-out normal flights flagged. *Rank held*: the share of "
        f"{RANK_BOOTSTRAP} paired bootstrap resamples of the test flights (clusters resampled within each seed's "
        "normal and attacked flights, the same resample for every detector, seeds averaged) in which the "
        "detector keeps its rank; *Rank 95 %*: its rank's 2.5-97.5 % range over the resamples; *Above next*: "
        "the share in which it scores above the detector ranked just below it. *Fit*: microseconds per "
        "training row (fit seconds / the train flights' rows); *Score*: microseconds per scored row; both the "
        "jobs' own wall times, mean over the seeds.",
        "",
        "| Rank | Rank held | Rank 95 % | Above next | Detector | Tag | Headline | TP simulation | TP csv | "
        "False alarms | ROC-AUC | Fit (us/row) | Score (us/row) | Seeds OK |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, row in board.iterrows():
        det = row["detector"]
        c = certainty.loc[det] if det in certainty.index else pd.Series(dtype=float)
        rng = ("–" if pd.isna(c.get("lo", np.nan)) else
               f"{int(c['lo'])}" if c["lo"] == c["hi"] else f"{int(c['lo'])}-{int(c['hi'])}")
        held = "–" if pd.isna(c.get("held", np.nan)) else f"{100 * c['held']:.0f} %"
        above = "–" if pd.isna(c.get("above_next", np.nan)) else f"{100 * c['above_next']:.0f} %"
        roc = _num(row.get("roc_auc_mean"), ".3f") + ("" if pd.isna(row.get("roc_auc_std")) else
                                                     f" ± {row['roc_auc_std']:.3f}")
        lines.append(
            f"| {'–' if pd.isna(row['rank']) else int(row['rank'])} | "
            f"{held} | {rng} | {above} | {det} | "
            f"{_tag(det)} | {_pct(row['headline_mean'])} | {_rate(row, 'tp_simulation')} | "
            f"{_rate(row, 'tp_csv')} | {_rate(row, 'tn_no_attack', flip=True)} | {roc} | "
            f"{_num(cost['fit_us'].get(det, np.nan), '.1f')} | {_num(cost['score_us'].get(det, np.nan), '.1f')} | "
            f"{int(row['n_runs'])}/{int(row['runs'])} |")
    fewer = [f"{d} ({int(n)})" for d, n, total in zip(board["detector"], board["n_runs"], board["runs"])
             if 0 < n < total]
    if fewer:
        lines += ["", f"Ranked on fewer seeds than the others (seeds where the job finished OK): {', '.join(fewer)}; "
                      "its mean and rank rest on those seeds' flights only."]
    if not_run:
        lines += ["", f"Not in any run folder yet (no job has finished): {', '.join(not_run)}."]
    fails = failures(results)
    if fails:
        lines += ["", "Jobs that did not finish OK (left out of the means, never counted as 0):", ""]
        lines += [f"- {run}: **{det}** {status}: {msg.splitlines()[0] if msg else ''}" for run, det, status, msg in fails]
    order = list(board["detector"])
    lines += _family_lines(results, order) + _bin_lines(results, order) + _cost_lines(cost, order)
    return lines


def _family_lines(results: list[RunResults], order: list[str]) -> list[str]:
    """TP per detector and attack family, simulation / csv, flights pooled over the seeds."""
    fam = tp_by_family(results)
    if not len(fam):
        return []
    families = family_order(fam["value"])
    nper = fam.groupby(["value", "mode"])["n"].max()
    head = [f"{f} ({int(nper.get((f, 'simulation'), 0))}/{int(nper.get((f, 'csv'), 0))})" for f in families]
    lines = ["", "## Per attack family", "",
             "TP in window, simulation / csv, flights pooled over the seeds (n attacked flights per mode in the "
             "header, over all seeds; a flight that combines several actions counts under \"k actions "
             "combined\"); rows in the ranking's order.", "",
             "| Detector | " + " | ".join(head) + " |", "|---" * (len(families) + 1) + "|"]
    for det in order:
        d = fam[fam["detector"] == det].set_index(["value", "mode"])["tp_rate"]
        lines.append(f"| {det} | " + " | ".join(f"{_pct(d.get((f, 'simulation'), np.nan))} / "
                                                f"{_pct(d.get((f, 'csv'), np.nan))}" for f in families) + " |")
    return lines


def _bin_lines(results: list[RunResults], order: list[str]) -> list[str]:
    """TP per detector and detectability bin, both modes, flights pooled over the seeds."""
    bins = pooled_tp(results, "detectability_bin")
    bins = bins[bins["mode"] == "all"]
    if not len(bins):
        return []
    return ["", "## Per detectability bin", "",
            "TP in window, both modes, flights pooled over the seeds, by how far the attack moves the attacked "
            "field in standard deviations of that field on validation flights (n attacked flights in the "
            "header; n/a: the attack changed no value the detectors see against a clean reference).", "",
            *detectability_table(bins, order)]


def _cost_lines(cost: pd.DataFrame, order: list[str]) -> list[str]:
    """Fit and score seconds per seed (the per-row figures' numerators)."""
    known = [d for d in order if d in cost.index]
    if not known:
        return []
    lines = ["", "## Cost", "",
             "Seconds per seed (mean over the seeds where the job finished OK): fitting on the train flights and "
             "scoring every scored flight (validation, held-out normal, attacked), each the job's own wall time "
             "(the run's jobs in parallel share the machine).", "",
             "| Detector | Fit (s) | Score (s) | Fit (us/training row) | Score (us/row) |", "|---|---|---|---|---|"]
    for det in known:
        c = cost.loc[det]
        lines.append(f"| {det} | {_num(c['fit_s'], '.1f')} | {_num(c['score_s'], '.1f')} | "
                     f"{_num(c['fit_us'], '.1f')} | {_num(c['score_us'], '.1f')} |")
    return lines


def write_page(out: Path, runs: list[ZooRun], names: list[str], profile: str, seeds: list[int],
               command: str) -> Path:
    """Write the page as a whole (a temp file renamed over ``out``: a failure leaves the old page)."""
    text = "\n".join(page_lines(runs, names, profile, seeds, command)) + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return out


def command_line(args: argparse.Namespace) -> str:
    """The command that regenerates the page (the options given, in a fixed order)."""
    return (f"python -m scart_bench.reports.zoo --profile {args.profile} --seeds {args.seeds} "
            f"--detectors {args.detectors} --jobs {args.jobs}"
            + ("" if args.timeout is None else f" --timeout {args.timeout:g}")
            + f" --runs {args.runs} --data {args.data} --out {args.out}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scart_bench.reports.zoo", description=__doc__.split("\n")[0])
    p.add_argument("--profile", default="standard", choices=("quick", "standard", "paper"))
    p.add_argument("--seeds", default="0,1,2", help="comma-separated dataset and detector seeds (default 0,1,2)")
    p.add_argument("--detectors", default="paper,zoo",
                   help="names and tags, comma-separated (default paper,zoo: all 21 built-ins)")
    p.add_argument("--jobs", type=int, default=1, help="parallel jobs of each run (default 1)")
    p.add_argument("--timeout", type=float, default=None,
                   help="each job's time limit in seconds (default: the profile's; a job past it is a TIMEOUT row)")
    p.add_argument("--runs", type=Path, default=Path("runs/zoo"), help="folder of the run folders")
    p.add_argument("--data", type=Path, default=Path("data/datasets"), help="folder of the datasets")
    p.add_argument("--out", type=Path, default=Path("docs/results-zoo-standard.md"))
    p.add_argument("--render-only", action="store_true",
                   help="run nothing: write the page from the run folders there are (each seed's must exist)")
    args = p.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        print(f"zoo: --seeds {args.seeds!r}: expected comma-separated integers", file=sys.stderr)
        return 2
    try:
        if not seeds:
            raise RunError(f"--seeds {args.seeds!r}: expected at least one seed")
        names = detector_names([args.detectors])
        t0 = time.perf_counter()
        if args.render_only:
            folders = [args.runs / f"{args.profile}-seed{s}" for s in seeds]
        else:
            from scart_bench.benchmark.reference_runs import run_seeds

            folders = run_seeds(args.profile, seeds, args.jobs, args.runs, args.data, names, args.timeout)
        runs = load_zoo_runs(folders)
        out = write_page(args.out, runs, names, args.profile, seeds, command_line(args))
    except ScartBenchError as exc:
        print(f"zoo: {exc}", file=sys.stderr)
        return 2
    print(f"{out} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
