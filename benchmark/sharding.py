"""Sharded scoring: one detector's job split into a fit and several scoring shards.

With ``--score-shards N`` (N > 1) a job runs as one "fit" job (fit on the train flights, return the
fitted detector pickled) and then N "score" jobs, each scoring a contiguous slice of the scored
flights with that same fitted detector, in parallel on the run's executor (local or dask). The
shards' scores are merged in the flights' order into one result, which is saved exactly as the
unsharded job's would be: same scores, same metrics (a fitted detector scores the same after a
pickle round trip, which the conformance kit checks for every detector, and every shard runs with
the job's thread count). A job's status is written once, when every shard is back, so ``--resume``
sees a job as finished or not, never half-scored; the first failed stage (fit or a shard) is the
job's status and its other shards' results are dropped.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from scart_bench.benchmark.jobs import JobResult, JobSpec


def split_flights(flights: Sequence[str], rows: dict[str, int], n: int) -> list[tuple[str, ...]]:
    """``flights`` in at most ``n`` contiguous slices of about equal rows (every slice non-empty)."""
    flights = list(flights)
    n = max(1, min(int(n), len(flights)))
    weight = np.array([max(1, int(rows.get(f, 1))) for f in flights], dtype=np.float64)
    ends = np.concatenate([[0.0], np.cumsum(weight)])  # rows before flight i
    cuts = [int(np.argmin(np.abs(ends - ends[-1] * k / n))) for k in range(1, n)]  # nearest boundary
    bounds = [0]
    for c in cuts:  # strictly increasing, leaving at least one flight for every later slice
        bounds.append(min(max(c, bounds[-1] + 1), len(flights) - (n - len(bounds))))
    bounds.append(len(flights))
    return [tuple(flights[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]


@dataclasses.dataclass
class _Job:
    spec: JobSpec
    shards: list[tuple[str, ...]]
    fit: JobResult | None = None
    results: dict[int, JobResult] = dataclasses.field(default_factory=dict)
    failed: bool = False


class ShardedScoring:
    """Turns jobs into fit + scoring shards and merges them back (an executor's ``on_done``).

    ``plan(spec)`` gives the spec to submit for a job; pass the instance as the executor's
    ``on_done``: it returns the scoring shards when a fit ends and calls ``on_done(spec, result)``
    once per job, with the merged result, as an unsharded job would.
    """

    def __init__(self, shards: int, rows: dict[str, int], on_done: Callable[[JobSpec, JobResult], None],
                 note: Callable[[str], None] | None = None):
        self.shards, self.rows, self.on_done = int(shards), rows, on_done
        self.note = note or (lambda line: None)
        self.jobs: dict[str, _Job] = {}

    def plan(self, spec: JobSpec) -> JobSpec:
        """The spec to run for ``spec``: itself, or its fit stage when it is scored in shards."""
        parts = split_flights(spec.scored, self.rows, self.shards) if self.shards > 1 and spec.scored else []
        if len(parts) < 2:
            return spec
        self.jobs[spec.detector] = _Job(spec, parts)
        return dataclasses.replace(spec, stage="fit", scored=())

    def __call__(self, spec: JobSpec, res: JobResult) -> list[JobSpec] | None:
        job = self.jobs.get(spec.detector)
        if job is None:  # an unsharded job
            self.on_done(spec, res)
            return None
        if job.failed:
            return None
        if res.status != "OK":  # the first failure is the job's status
            job.failed = True
            stage = "fit" if spec.stage == "fit" else f"scoring shard {spec.shard[0] + 1}/{spec.shard[1]}"
            self.on_done(job.spec, dataclasses.replace(res, message=f"{stage}: {res.message}"))
            return None
        if spec.stage == "fit":
            job.fit = res
            n = len(job.shards)
            self.note(f"{spec.detector}: fitted in {res.fit_seconds:.1f} s; scoring {len(job.spec.scored)} "
                      f"flights in {n} shards")
            return [dataclasses.replace(job.spec, stage="score", model=res.model, train=(), scored=part,
                                        shard=(i, n)) for i, part in enumerate(job.shards)]
        job.results[spec.shard[0]] = res
        self.note(f"{spec.detector}: scoring shard {spec.shard[0] + 1}/{spec.shard[1]} done "
                  f"({res.rows_scored} rows, {res.score_seconds:.1f} s)")
        if len(job.results) == len(job.shards):
            self.on_done(job.spec, merge(job.fit, [job.results[i] for i in range(len(job.shards))]))
        return None


def merge(fit: JobResult, shards: list[JobResult]) -> JobResult:
    """One job's result from its fit and its scoring shards (in the flights' order)."""
    scores: dict[str, np.ndarray] = {}
    alarms: dict[str, np.ndarray] | None = {} if any(r.alarms is not None for r in shards) else None
    for r in shards:
        scores.update(r.scores or {})
        if alarms is not None:
            alarms.update(r.alarms or {})
    logs = [f"--- fit ---\n{fit.log}"] + [f"--- scoring shard {i + 1}/{len(shards)} ---\n{r.log}"
                                          for i, r in enumerate(shards)]
    return JobResult("OK", "", fit.fit_seconds, float(sum(r.score_seconds for r in shards)),
                     int(sum(r.rows_scored for r in shards)), scores, alarms,
                     max_rss_mb=float(max([fit.max_rss_mb, *(r.max_rss_mb for r in shards)])),
                     wall_seconds=float(fit.wall_seconds + max(r.wall_seconds for r in shards)),
                     log="".join(logs))
