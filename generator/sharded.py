"""Generation sharded over a dask cluster: the same dataset, byte for byte, flown by many workers.

The unit of work (a shard) is one batch of flights as a local generation flies it
(``Profile.batch_size`` flights, see :func:`generator.plan.plan_generation`), so every flight is
computed from the same inputs in the same batch as locally. Two phases, as locally:

1. the normal flights, one shard per batch; the shards return their validation and csv-source
   flights (the attacked flights' references) with their manifest rows;
2. the attacked flights: one shard per simulation-mode batch and per csv-mode batch.

A worker flies its shard in its own folder (its dask ``local_directory``), then delivers the
flight folders: to an object-store URL directly (``target``), or back to this process, which
writes them into the dataset folder (no disk shared with the workers either way). Only this
process writes ``dataset.json`` and, last, the manifest, in the order a local generation writes
its rows; a failed shard cancels the rest and raises :class:`~scart_bench.errors.ClusterError`
naming the shard, with no manifest written.
"""

from __future__ import annotations

import shutil
import tempfile
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from scart_bench.dataset import DatasetWriter
from scart_bench.errors import ClusterError
from scart_bench.generator.attack_effect import field_stds
from scart_bench.generator.attacks import (
    RowWriter,
    batch_count,
    csv_flights,
    grid_path,
    simulation_flights,
)
from scart_bench.generator.plan import GenerationPlan, Sources, fly_normal_batch
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.names import join_inside


@dataclass(frozen=True)
class Shard:
    """One batch of one kind of flight: ``normal``, ``simulation`` (attacked) or ``csv`` (attacked)."""

    kind: str
    batch: int

    def __str__(self) -> str:
        return f"{self.kind} batch {self.batch}"


@dataclass
class ShardResult:
    """What a shard sends back: manifest rows (in writing order), the flight files when they come
    back here (relative path under ``flights/`` -> bytes), and the normal references."""

    rows: list[dict]
    files: dict[str, bytes] = field(default_factory=dict)
    sources: Sources = field(default_factory=dict)


def plan_shards(plan: GenerationPlan) -> tuple[list[Shard], list[Shard]]:
    """The shards of both phases (normal flights; attacked flights in simulation, then csv mode)."""
    size, totals = plan.profile.batch_size, plan.totals()
    normal = [Shard("normal", b) for b in range(batch_count(totals["normal"], size))]
    attacked = [Shard(kind, b) for kind in ("simulation", "csv") for b in range(batch_count(totals.get(kind, 0), size))]
    return normal, attacked


def fly_shard(plan: GenerationPlan, shard: Shard, fmt: str, layout: str, target: str | None = None,
              csv_sources: list | None = None, stds: dict | None = None) -> ShardResult:
    """Fly and write one shard in a folder of this worker's own; deliver it to ``target`` (an
    object-store URL of the dataset) or return its files. Runs on a dask worker."""
    from scart_bench.cluster import worker_temp_root

    folder = Path(tempfile.mkdtemp(prefix="scart-shard-", dir=worker_temp_root()))
    try:
        writer = RowWriter(folder, fmt, layout)
        (folder / "flights").mkdir()
        sources: Sources = {}
        say = _quiet
        if shard.kind == "normal":
            sources = fly_normal_batch(writer, plan, shard.batch, say)
        else:
            configs = load_configurations(grid_path(plan.profile.scenario_grid))
            size = plan.profile.batch_size
            if shard.kind == "simulation":
                simulation_flights(writer, configs, plan.seed, plan.config, plan.config_dict, size, say, stds,
                                   batches=[shard.batch])
            else:
                csv_flights(writer, configs, csv_sources or [], plan.config_dict, size, say, stds,
                            batches=[shard.batch])
        files: dict[str, bytes] = {}
        if target is None:
            files = {p.relative_to(folder).as_posix(): p.read_bytes()
                     for p in sorted((folder / "flights").rglob("*")) if p.is_file()}
        else:
            from scart_bench.storage import upload_folder

            upload_folder(folder / "flights", f"{target.rstrip('/')}/flights")
        return ShardResult(writer.rows, files, sources)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _quiet(msg: str) -> None:
    """Progress lines of a shard stay on its worker; the client reports shards as they finish."""


def generate_sharded(plan: GenerationPlan, out: Path, fmt: str, layout: str, scheduler: str | None = None,
                     jobs: int = 1, log: Callable[[str], None] | None = None, target: str | None = None,
                     advance: Callable[[str, int], None] | None = None) -> None:
    """Fly ``plan`` on a dask cluster and write the dataset into the (new, empty) folder ``out``:
    flight files, ``dataset.json`` and, last, the manifest. ``target``: the dataset's object-store
    URL, where workers upload their flights themselves (``out`` then receives no flight files).
    ``advance`` is told ``(kind, flights)`` as each shard comes back."""
    from scart_bench.cluster import connect

    say = log or _quiet
    normal, attacked = plan_shards(plan)
    writer = DatasetWriter(out, fmt=fmt, layout=layout, info=plan.info())
    try:
        with connect(scheduler, jobs) as cluster:
            say(f"dask: {len(normal)} normal and {len(attacked)} attacked shard(s) of up to "
                f"{plan.profile.batch_size} flights on {len(cluster.client.scheduler_info()['workers'])} worker(s)")
            done = _run(cluster.client, normal, lambda s: (plan, s, fmt, writer.layout, target), out, say, advance)
            refs: Sources = {"csv_source": [], "validation": []}
            for res in done:
                for k, v in res.sources.items():
                    refs[k].extend(v)
            if attacked:
                stds = field_stds([topics for _, topics, _ in refs["validation"]])
                sources = cluster.client.scatter(refs["csv_source"], broadcast=False, hash=False) \
                    if any(s.kind == "csv" for s in attacked) else None
                done += _run(cluster.client, attacked,
                             lambda s: (plan, s, fmt, writer.layout, target, sources if s.kind == "csv" else None,
                                        stds), out, say, advance)
        for res in done:
            writer.add_written(res.rows)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def _run(client, shards: list[Shard], args: Callable[[Shard], tuple], out: Path,
         say: Callable[[str], None], advance: Callable[[str, int], None] | None = None) -> list[ShardResult]:
    """Run ``shards`` on the cluster; write returned files into ``out``; results in shard order."""
    from distributed import as_completed

    tag = uuid.uuid4().hex[:8]
    futures = {client.submit(fly_shard, *args(s), key=f"scart-shard-{s.kind}-{s.batch}-{tag}", pure=False): i
               for i, s in enumerate(shards)}
    results: list[ShardResult | None] = [None] * len(shards)
    try:
        for n, fut in enumerate(as_completed(futures, loop=client.loop), 1):
            shard = shards[futures[fut]]
            try:
                res = fut.result()
            except Exception as exc:
                raise ClusterError(f"generate --executor dask: shard {shard} failed ({type(exc).__name__}: "
                                   f"{exc}); nothing was committed") from exc
            for rel, data in res.files.items():  # names a worker sent back: kept inside the dataset
                path = join_inside(out, rel, f"generate --executor dask: shard {shard}: file")
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)
            res.files = {}
            results[futures[fut]] = res
            say(f"[{n}/{len(shards)}] shard {shard}: {len(res.rows)} flight(s) written")
            if advance is not None:
                advance(shard.kind, len(res.rows))
    finally:
        for fut in futures:
            fut.cancel()
    return results  # type: ignore[return-value]
