"""The phase table of a profile's end-to-end run: generate, read the flights, fit and score per
detector, metrics, report; wall total and peak memory of the whole process tree.

    python -m perf.paper_phases --profile quick|standard|paper [--detectors all] [--jobs 1]
                                [--dataset DIR] [--data DIR] [--out RUN] [--no-figures]

``--dataset`` skips the generate phase (an existing dataset); otherwise the profile's dataset is
generated into ``--data`` (default: a temporary folder, removed at the end). The run goes into a
fresh folder (``--out``, default ``runs/perf/phases-<profile>-<time>``). Per detector, fit and score
are the job's own timings (results.csv), job wall includes the worker's start and its reads, and
job peak is the worker's own peak RSS. Peak memory of the tree is the largest sum of the proportional
set sizes (PSS: a page shared by k processes counts 1/k in each, so the flight cache that every job
maps counts once; RSS where the system has no PSS) of this process and all its descendants, sampled
every 0.2 s. The acceptance goal for ``paper`` is under 45 min [30] and 8 GB.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path

import pandas as pd
import psutil

from scart_bench.benchmark import executors, runner
from scart_bench.cli.main import main as cli_main
from scart_bench.cli.run import PROFILES


def _role(p: psutil.Process) -> str:
    """What a process of the tree is, from its command line: a job, a spawned worker (reader), other."""
    try:
        cmd = p.cmdline()
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return "gone"
    text = " ".join(cmd)
    if "scart_bench.benchmark.executors" in text:
        return "job"
    if "spawn_main" in text or "multiprocessing" in text:
        return "spawned"
    return "other"


class TreeMemory:
    """Samples the PSS sum of this process and its descendants in a thread; keeps the peak overall and
    per phase (``phase(name)`` starts a new one), and, with ``log``, a timeline: one CSV row per
    process and sample (seconds, phase, pid, role, PSS MiB), to see what makes up a peak."""

    def __init__(self, period_s: float = 0.2, log: Path | None = None):
        self.period_s, self.peak, self.phase_peak = period_s, 0, {}
        self.current: str | None = None
        self._log = open(log, "w", encoding="utf-8") if log else None  # noqa: SIM115 (closed in __exit__)
        if self._log:
            self._log.write("seconds,phase,pid,role,pss_mib\n")
        self._t0 = time.perf_counter()
        self._roles: dict[int, str] = {}
        self._stop = threading.Event()
        self._me = psutil.Process()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="rss-sampler")

    def sample(self) -> int:
        total = 0
        t = time.perf_counter() - self._t0
        for p in [self._me, *self._me.children(recursive=True)]:
            try:  # PSS: pages shared between processes (the jobs map one flight cache) count once
                info = p.memory_full_info()
                pss = getattr(info, "pss", info.rss)
            except (psutil.NoSuchProcess, psutil.AccessDenied):
                continue
            total += pss
            if self._log:
                role = self._roles.get(p.pid) or self._roles.setdefault(p.pid, "main" if p is self._me else _role(p))
                self._log.write(f"{t:.2f},{self.current},{p.pid},{role},{pss / 2**20:.1f}\n")
        self.peak = max(self.peak, total)
        if self.current is not None:
            self.phase_peak[self.current] = max(self.phase_peak.get(self.current, 0), total)
        return total

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self.sample()

    def phase(self, name: str) -> None:
        self.current = name
        self.sample()

    def __enter__(self) -> TreeMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()
        if self._log:
            self._log.close()


def _timed(module, name: str, seconds: dict[str, float], key: str):
    """Wrap ``module.name`` so that its calls add their wall time to ``seconds[key]``."""
    original = getattr(module, name)

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - t0

    setattr(module, name, wrapper)
    return original


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.paper_phases", description=__doc__.split("\n")[0])
    p.add_argument("--profile", choices=PROFILES, default="paper")
    p.add_argument("--detectors", default="all")
    p.add_argument("--dataset", type=Path, help="an existing dataset (skips the generate phase)")
    p.add_argument("--data", type=Path, help="where to generate the dataset (default: a temporary folder, removed)")
    p.add_argument("--out", type=Path, help="run folder (default: a new runs/perf/phases-<profile>-<time>)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--executor", choices=("local", "dask"), default="local")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-figures", action="store_true", help="report tables only")
    p.add_argument("--memory-log", type=Path, help="write the memory timeline (CSV: seconds, phase, pid, role, PSS MiB)")
    args = p.parse_args(argv)

    from scart_bench.generator.generate import generate_dataset
    from scart_bench.reports.report import write_report

    seconds: dict[str, float] = {}
    tmp = None
    t_start = time.perf_counter()
    with TreeMemory(log=args.memory_log) as mem:
        dataset = args.dataset
        if dataset is None:
            mem.phase("generate")
            dataset = args.data or Path(tmp := tempfile.mkdtemp(prefix="phases-")) / args.profile
            t0 = time.perf_counter()
            generate_dataset(args.profile, dataset, seed=args.seed, overwrite=True)
            seconds["generate"] = time.perf_counter() - t0
        mem.phase("run")
        out = args.out or Path("runs/perf") / f"phases-{args.profile}-seed{args.seed}-{datetime.now():%Y%m%d-%H%M%S}"
        originals = {"build_cache": _timed(runner, "build_cache", seconds, "read flights (cache)"),
                     "write_results": _timed(runner, "write_results", seconds, "metrics"),
                     "score_run": _timed(runner, "score_run", seconds, "metrics"),
                     "dataset_fingerprint": _timed(runner, "dataset_fingerprint", seconds, "fingerprint")}
        make_executor = executors.make_executor

        def timed_executor(*a, **kw):  # the jobs' wall: from the first job's start to the last one's end
            ex = make_executor(*a, **kw)
            _timed(ex, "run", seconds, "jobs")
            return ex

        executors.make_executor = timed_executor
        t0 = time.perf_counter()
        try:
            rc = cli_main(["run", "--detectors", args.detectors, "--profile", args.profile, "--dataset", str(dataset),
                           "--out", str(out), "--jobs", str(args.jobs), "--executor", args.executor,
                           "--seed", str(args.seed)])
        finally:
            for name, fn in originals.items():
                setattr(runner, name, fn)
            executors.make_executor = make_executor
        seconds["run"] = time.perf_counter() - t0
        mem.phase("report")
        t0 = time.perf_counter()
        write_report([out], out / "report", figures=not args.no_figures)
        seconds["report"] = time.perf_counter() - t0
    wall = time.perf_counter() - t_start
    if rc == 0:  # the reference page's wall time of the run (dataset generation included)
        (out / "wall_s.json").write_text(json.dumps({"wall_s": wall}))
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)

    gib = 2.0 ** 30
    print(f"\nprofile {args.profile}, seed {args.seed}, {args.jobs} job(s), executor {args.executor}: run exit {rc}")
    print(f"  run folder {out}; dataset {dataset}{' (generated, removed)' if tmp else ''}")
    rows = []
    if "generate" in seconds:
        rows.append(("generate", seconds["generate"], mem.phase_peak.get("generate", 0) / gib))
    rows.append(("dataset fingerprint", seconds.get("fingerprint", float("nan")), float("nan")))
    rows.append(("read flights (cache)", seconds.get("read flights (cache)", float("nan")), float("nan")))
    results = out / "results.csv"
    res = pd.read_csv(results) if results.exists() else pd.DataFrame()
    for _, r in res.iterrows():
        rows.append((f"{r['detector']}: fit", r["fit_s"], r["max_rss_mb"] / 1024))
        rows.append((f"{r['detector']}: score", r["score_s"], float("nan")))
        rows.append((f"{r['detector']}: job wall ({r['status']})", r["wall_s"], float("nan")))
    rows.append((f"jobs, {args.jobs} at a time (wall)", seconds.get("jobs", float("nan")), float("nan")))
    rows.append(("metrics (run tables)", seconds.get("metrics", float("nan")), float("nan")))
    known = sum(seconds.get(k, 0.0) for k in ("fingerprint", "read flights (cache)", "jobs", "metrics"))
    rows.append(("run: everything else", seconds["run"] - known, float("nan")))
    rows.append(("run total", seconds["run"], mem.phase_peak.get("run", 0) / gib))
    rows.append(("report" + (" (tables)" if args.no_figures else " (tables + figures)"), seconds["report"],
                 mem.phase_peak.get("report", 0) / gib))
    rows.append(("wall total", wall, mem.peak / gib))
    table = pd.DataFrame(rows, columns=["phase", "seconds", "peak GiB"])
    with pd.option_context("display.width", 160, "display.float_format", "{:.2f}".format):
        print(table.to_string(index=False, na_rep=""))
    print(f"wall {wall / 60:.1f} min; peak memory (PSS) of the process tree {mem.peak / gib:.2f} GiB "
          "(per detector: the job process's own peak)")
    return rc


if __name__ == "__main__":
    sys.exit(main())
