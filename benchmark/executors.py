"""How jobs run: each job in its own worker process, locally or on dask workers.

A job always runs in a fresh ``python -m scart_bench.benchmark.executors SPEC RESULT`` process (its own
session, so it can be killed with everything it started). Why a subprocess rather than a
``ProcessPoolExecutor``: a pool cannot kill one hanging task, and dask worker processes are
daemonic (``multiprocessing`` refuses to start children there) while ``subprocess`` works in both.

- ``local``: up to ``--jobs`` worker processes at once; a worker past ``--timeout`` is killed
  (SIGKILL to its process group) and the job becomes TIMEOUT. The timeout counts from the moment
  the worker has started Python and imported the benchmark (at most ``STARTUP_GRACE_S`` later).
- ``dask``: one dask task per job, each running the same isolated worker process on a dask worker
  (``dask.distributed.Client(ADDRESS)``, or a ``LocalCluster`` with ``--jobs`` single-threaded
  worker processes). The scheduler must see the dataset path.

Workers get the same thread limits and hash seed everywhere, so both executors give identical
scores. A worker whose parent dies exits by itself.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from scart_bench.benchmark.jobs import JobResult, run_job
from scart_bench.cluster import CONNECT_TIMEOUT_S
from scart_bench.dataset.locks import exit_with_parent
from scart_bench.errors import RunError
from scart_bench.progress import duration, progress_every_s
from scart_bench.storage import claim_tempdir, release_tempdir

#: Seconds a worker may take to start Python and import the benchmark before its job begins; the
#: job's own ``--timeout`` is counted from then, so a loaded machine does not time out fast jobs.
STARTUP_GRACE_S = 120.0
#: Largest part of a worker's log kept in the run folder.
LOG_LIMIT = 256 * 1024
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS",
                "VECLIB_MAXIMUM_THREADS")

#: Called with (spec, result) as each job ends; may return more specs to run (a sharded job's
#: scoring shards once its fit is done), which the executor runs like the first ones.
OnDone = Callable[[object, object], "list | None"]
#: Called with (spec, progress) while a job runs: flights scored, total, rows, score seconds.
OnProgress = Callable[[object, dict], None]
#: The dask topic on which workers publish the progress of their jobs.
PROGRESS_TOPIC = "scart-bench-job-progress"


@dataclass
class _Worker:
    spec: object
    proc: subprocess.Popen
    folder: Path
    log: object
    started: float
    timeout: float
    owner: object = None  # the folder's owner file (scart_bench.storage.claim_tempdir)
    job_started: float | None = None

    last_report: float = 0.0

    def progress(self) -> dict | None:
        """The job's latest progress (flights, total, rows, score_s), None before its first flight."""
        import json

        try:
            return json.loads((self.folder / "progress.json").read_text())
        except (OSError, ValueError):
            return None

    def due(self, every_s: float) -> dict | None:
        """The progress to report now (every ``every_s`` seconds), else None."""
        now = time.monotonic()
        if now - max(self.last_report, self.started) < every_s:
            return None
        self.last_report = now
        return self.progress()

    def expired(self) -> bool:
        """True when the job has run past its timeout (counted from the worker's start marker)."""
        now = time.monotonic()
        if self.job_started is None and (self.folder / "started").exists():
            self.job_started = now
        if self.job_started is None:
            return now > self.started + self.timeout + STARTUP_GRACE_S
        return now > self.job_started + self.timeout


def _launch(spec, timeout: float) -> _Worker:
    # owned by this process: a run killed -9 leaves it behind, and the next command's start removes it
    folder, owner = claim_tempdir("scart-job-")
    try:
        (folder / "spec.pkl").write_bytes(pickle.dumps(spec))
    except BaseException:
        release_tempdir(folder, owner)
        raise
    env = dict(os.environ)
    env.update(dict.fromkeys(_THREAD_VARS, str(spec.threads)))
    # OpenMP threads that wait by spinning make torch 5-7x slower when another process holds one of
    # the job's cores (issue 15: Telemanom's fit 52 s with 2 spinning threads, 9 s passive, 7 s with
    # one thread on a loaded 2-core machine); waiting passively costs nothing measurable. Results do
    # not depend on it.
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    env["PYTHONHASHSEED"] = "0"
    log = open(folder / "log.txt", "wb")  # closed by _read_log
    proc = subprocess.Popen(
        [sys.executable, "-m", "scart_bench.benchmark.executors", str(folder / "spec.pkl"), str(folder / "result.pkl")],
        stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
    )
    return _Worker(spec, proc, folder, log, time.monotonic(), timeout, owner)


def _kill(w: _Worker) -> None:
    try:
        os.killpg(w.proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    w.proc.wait()


def _read_log(w: _Worker) -> str:
    w.log.close()
    data = (w.folder / "log.txt").read_bytes()
    if len(data) > LOG_LIMIT:
        data = b"[... log truncated ...]\n" + data[-LOG_LIMIT:]
    return data.decode("utf-8", errors="replace")


def _collect(w: _Worker, timed_out: bool = False, timeout: float = 0.0):
    """The JobResult of a finished or killed worker; removes its temp folder."""

    try:
        log = _read_log(w)
        result_path = w.folder / "result.pkl"
        if timed_out:
            res = JobResult("TIMEOUT", f"exceeded the {timeout:g} s timeout; the worker process was killed")
        elif result_path.exists():
            res = pickle.loads(result_path.read_bytes())
        else:
            rc = w.proc.returncode
            why = f"killed by signal {-rc}" if rc is not None and rc < 0 else f"exit code {rc}"
            res = JobResult("ERROR", f"the worker process ended without a result ({why}; see log.txt)")
        res.log = log
        res.wall_seconds = time.monotonic() - w.started
        return res
    finally:
        release_tempdir(w.folder, w.owner)


def run_isolated(spec, timeout: float):
    """Run one job in its own worker process and wait (at most ``timeout`` s); used by dask tasks.

    A dataset given by URL is downloaded first, once per worker and dataset, into the worker's own
    folder (scart_bench.storage.fetch_dataset)."""
    from scart_bench.storage import is_url

    if is_url(spec.dataset):
        import dataclasses

        from scart_bench.cluster import worker_temp_root
        from scart_bench.storage import default_cache, fetch_dataset

        root = worker_temp_root()
        local = fetch_dataset(spec.dataset, Path(root) / "scart-bench" if root else default_cache())
        spec = dataclasses.replace(spec, dataset=str(local))
    w = _launch(spec, timeout)
    every, worker = progress_every_s(), _dask_worker()
    try:
        while w.proc.poll() is None:
            info = w.due(every) if worker is not None else None
            if info:
                worker.log_event(PROGRESS_TOPIC, {"detector": spec.detector, "shard": spec.shard, **info})
            if w.expired():
                _kill(w)
                return _collect(w, timed_out=True, timeout=timeout)
            time.sleep(0.1)
        return _collect(w)
    except BaseException:
        _kill(w)
        release_tempdir(w.folder, w.owner)
        raise


def _dask_worker():
    """The dask worker running this task (None outside one)."""
    try:
        from distributed import get_worker

        return get_worker()
    except (ImportError, ValueError):
        return None


class LocalExecutor:
    """Up to ``jobs`` worker processes on this machine."""

    def __init__(self, jobs: int = 1):
        self.jobs = max(1, int(jobs))

    def run(self, specs: list, timeout: float, on_done: OnDone, on_progress: OnProgress | None = None) -> None:
        pending, running = deque(specs), []
        every = progress_every_s()
        try:
            while pending or running:
                while pending and len(running) < self.jobs:
                    running.append(_launch(pending.popleft(), timeout))
                time.sleep(0.05)
                for w in running if on_progress is not None else ():
                    info = w.due(every)
                    if info:
                        on_progress(w.spec, info)
                for w in list(running):
                    if w.proc.poll() is not None:
                        running.remove(w)
                        pending.extendleft(reversed(on_done(w.spec, _collect(w)) or []))
                    elif w.expired():
                        _kill(w)
                        running.remove(w)
                        pending.extendleft(reversed(on_done(w.spec, _collect(w, timed_out=True, timeout=timeout)) or []))
        finally:
            for w in running:  # interrupted: no unfinished job leaves a process or a status
                _kill(w)
                w.log.close()
                release_tempdir(w.folder, w.owner)

    def check_dataset(self, path: str) -> None:
        """Local workers read the dataset where this process does: nothing to check."""

    def close(self) -> None:
        pass


class DaskExecutor:
    """One dask task per job; each task runs the job in an isolated worker process."""

    def __init__(self, scheduler: str | None = None, jobs: int = 1, connect_timeout: float = CONNECT_TIMEOUT_S):
        from scart_bench.cluster import connect

        self._cluster = connect(scheduler, jobs, connect_timeout, error=RunError)
        self.client, self.cluster = self._cluster.client, self._cluster.local

    def run(self, specs: list, timeout: float, on_done: OnDone, on_progress: OnProgress | None = None) -> None:
        import uuid

        from distributed import as_completed

        by_name = {(s.detector, s.shard): s for s in specs}
        if on_progress is not None:
            def relay(event) -> None:  # (time, message) from a worker's log_event
                msg = event[1]
                shard = tuple(msg["shard"]) if msg.get("shard") else None
                spec = by_name.get((msg["detector"], shard))
                if spec is not None:
                    on_progress(spec, msg)

            self.client.subscribe_topic(PROGRESS_TOPIC, relay)

        def submit(spec):
            return self.client.submit(run_isolated, spec, timeout, pure=False,
                                      key=f"scart-job-{spec.detector}-{uuid.uuid4().hex[:8]}")

        futures = {submit(spec): spec for spec in specs}
        done = as_completed(list(futures), loop=self.client.loop)
        try:
            for fut in done:
                spec = futures[fut]
                try:
                    res = fut.result()
                except Exception as exc:
                    res = JobResult("ERROR", f"the dask task failed: {type(exc).__name__}: {exc}")
                for more in on_done(spec, res) or []:
                    by_name[(more.detector, more.shard)] = more
                    f = submit(more)
                    futures[f] = more
                    done.add(f)
        finally:
            if on_progress is not None:
                self.client.unsubscribe_topic(PROGRESS_TOPIC)
            for fut in futures:
                fut.cancel()

    def check_dataset(self, path: str) -> None:
        """Refuse (RunError) when a worker cannot read the dataset at ``path``: workers open it by path,
        so a cluster needs the dataset on a shared file system or a copy at the same path on every host."""
        answers = self.client.run(_dataset_readable, str(path))
        bad = {worker: why for worker, why in answers.items() if why}
        if bad:
            worker, why = next(iter(bad.items()))
            raise RunError(f"--executor dask: {len(bad)} of {len(answers)} worker(s) cannot read the dataset "
                           f"{path} (e.g. {worker}: {why}); put the dataset on a file system every worker "
                           "mounts at the same path, copy it there on each host, or give it as a URL every "
                           "worker can read (s3://...; docs/scaling.md)")

    def close(self) -> None:
        self._cluster.close()


def _dataset_readable(path: str) -> str:
    """Why this process cannot read the dataset's manifest at ``path`` ("" when it can)."""
    from scart_bench.storage import has_manifest, is_url

    if is_url(path):
        try:
            return "" if has_manifest(path) else f"no manifest.parquet or manifest.csv at {path}"
        except Exception as exc:  # a StorageError naming the URL, or a backend's own error
            return str(exc)
    folder = Path(path)
    for name in ("manifest.parquet", "manifest.csv"):
        f = folder / name
        if f.is_file():
            try:
                with f.open("rb") as fh:
                    fh.read(1)
            except OSError as exc:
                return f"{f}: {exc.strerror or exc}"
            return ""
    return f"no manifest.parquet or manifest.csv in {folder}"


def make_executor(kind: str, scheduler: str | None = None, jobs: int = 1):
    """A LocalExecutor or a connected DaskExecutor (RunError when the scheduler is unreachable)."""
    if kind == "local":
        return LocalExecutor(jobs)
    if kind == "dask":
        return DaskExecutor(scheduler, jobs)
    raise RunError(f"--executor {kind!r}: expected local or dask")


class JobProgress:
    """A run's progress: a tqdm bar over jobs on a terminal (plain lines when stderr is not a TTY), and
    the running jobs' own lines (flights scored, rows per second, time left)."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.count, self.enabled = total, 0, enabled
        self.bar = None
        if enabled and total and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="job", desc="jobs", file=sys.stderr)

    def note(self, line: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    def job(self, spec, info: dict) -> None:
        """A line on a running job: flights scored, rows per second of scoring, time left (a guess
        from the flights' pace so far)."""
        done, total, rows, secs = info["flights"], info["total"], info["rows"], info["score_s"]
        name = spec.detector + (f" [shard {spec.shard[0] + 1}/{spec.shard[1]}]" if spec.shard else "")
        rate = f", {rows / secs:,.0f} rows/s" if secs > 0 else ""
        left = secs / done * (total - done) if done else float("nan")
        eta = f", about {duration(left)} left" if done and total > done else ""
        self.note(f"{name}: {done}/{total} flights scored{rate}{eta}")

    def done(self, name: str, res) -> None:
        self.count += 1
        detail = f"fit {res.fit_seconds:.1f} s, score {res.score_seconds:.1f} s" if res.status == "OK" else res.message
        line = f"[{self.count}/{self.total}] {name}: {res.status} ({detail})"
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(f"{name} {res.status}")
            if res.status != "OK":
                self.bar.write(line, file=sys.stderr)
        else:
            self.note(line)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _progress_writer(path: Path, every_s: float = 0.5):
    """A run_job ``report`` that keeps ``path`` (JSON) up to date, at most every ``every_s`` seconds."""
    import json

    last = [0.0]

    def report(done: int, total: int, rows: int, score_s: float) -> None:
        now = time.monotonic()
        if now - last[0] < every_s and done < total:
            return
        last[0] = now
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"flights": done, "total": total, "rows": rows, "score_s": score_s}))
        os.replace(tmp, path)

    return report


def _worker_main(argv: list[str]) -> int:
    spec_path, result_path = argv
    exit_with_parent(os.getppid(), period_s=1.0)  # an orphaned job never runs on
    spec = pickle.loads(Path(spec_path).read_bytes())

    Path(spec_path).with_name("started").touch()  # the job's timeout counts from here
    res = run_job(spec, _progress_writer(Path(spec_path).with_name("progress.json")))
    tmp = Path(result_path + ".tmp")
    tmp.write_bytes(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
    os.replace(tmp, result_path)
    return 0


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1:]))
