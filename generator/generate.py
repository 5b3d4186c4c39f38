"""Dataset generation: profiles of flight counts, normal flights and (with scenarios) attacked ones."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from scart_bench.dataset import (
    DatasetError,
    DatasetWriter,
    check_layout,
    check_output_dir,
    replacing,
)
from scart_bench.generator.attack_effect import field_stds
from scart_bench.generator.attacks import attack_flights, batch_count
from scart_bench.generator.engine.simulate import FlightConfig
from scart_bench.generator.plan import GenerationPlan, Sources, fly_normal_batch, plan_generation
from scart_bench.progress import Progress
from scart_bench.storage import is_url, local_path

#: Most normal flights of one dataset. Flights are flown and written a batch at a time, but the plan
#: holds a seed and a split per flight (~50 bytes: 0.5 GB here) and the attack stage keeps the
#: validation and csv-source flights; ten million quick-profile flights are also ~5 TB on disk.
MAX_FLIGHTS = 10_000_000
#: Most flights flown together: a batch is simulated in memory at once, about 2 MB a flight of the
#: quick profile (the default 256: ~0.5 GB; this maximum: ~8 GB, what a large machine holds).
MAX_BATCH_SIZE = 4096


def check_counts(n_normal: int | None, batch_size: int | None) -> None:
    """DatasetError stating the maximum and why when a count cannot be generated (before anything
    is allocated: ``--flights 10**12`` would ask numpy for 3.6 TiB of seeds)."""
    if n_normal is not None and not 1 <= int(n_normal) <= MAX_FLIGHTS:
        raise DatasetError(f"flight count {n_normal}: expected 1 to {MAX_FLIGHTS:,} normal flights (the plan holds "
                           "a seed and a split per flight, and ten million flights are terabytes on disk)")
    if batch_size is not None and not 1 <= int(batch_size) <= MAX_BATCH_SIZE:
        raise DatasetError(f"batch size {batch_size}: expected 1 to {MAX_BATCH_SIZE:,} flights (a batch is "
                           "simulated in memory at once)")


def generate_dataset(profile: str, out: str | Path, seed: int = 0, fmt: str = "parquet",
                     n_normal: int | None = None, overwrite: bool = False, with_attacks: bool = True,
                     config: FlightConfig | None = None, log: Callable[[str], None] | None = None,
                     scenarios: str | Path | None = None, layout: str | None = None,
                     uorb: bool | None = None, batch_size: int | None = None, executor: str = "local",
                     scheduler: str | None = None, jobs: int = 1, progress: Progress | None = None) -> Path | str:
    """Generate a complete dataset; returns its folder (or URL). The manifest is written last.

    ``out``: a folder, or an fsspec URL (``s3://bucket/prefix``; :mod:`scart_bench.storage`).

    ``layout``: "compact" (default for Parquet) or "paper" (the paper's per-topic files; the
    default for CSV); see scart_bench.dataset.

    ``scenarios``: a scenario, grid or sweep file that replaces the profile's grid for the
    attacked flights (both modes); it is validated before anything is flown. ``uorb``: also write
    each flight's uORB view (a third view, generator.telemetry.uorb); None keeps ``config``'s
    ``FlightConfig.uorb`` (False by default), whatever the profile.

    ``executor="dask"``: the batches are flown and written as shards on a dask cluster
    (``scheduler``: its address, or None for a LocalCluster of ``jobs`` workers) and the manifest
    is committed here; the dataset is byte-identical to a local one (:mod:`generator.sharded`).

    ``progress``: counts the flights written per kind (normal, simulation, csv) against the plan's
    totals, whichever executor flies them (:mod:`scart_bench.progress`).

    A dataset for a URL is written in a temp folder this process owns (``scart-generate-<pid>-*``,
    :func:`scart_bench.storage.owned_tempdir`): one a killed generate left is removed by the next command.
    """
    check_counts(n_normal, batch_size)
    plan = plan_generation(profile, seed, n_normal, with_attacks, config, scenarios, uorb, batch_size)
    layout = check_layout(fmt, layout)
    if executor not in ("local", "dask"):
        raise DatasetError(f"executor {executor!r}: expected local or dask")
    advance = None
    if progress is not None:
        for kind, total in plan.totals().items():
            progress.expect(kind, total)
        advance = progress.add
    if is_url(out):
        _generate_to_url(plan, str(out), fmt, layout, overwrite, executor, scheduler, jobs, log, advance)
        return out
    out = local_path(out)
    check_output_dir(out, overwrite=overwrite)
    # write into a hidden sibling folder and move it into place at the end: an interrupted
    # generation leaves nothing at ``out``, and an existing dataset stays until the new one is done
    with replacing(out) as partial:
        if executor == "dask":
            from scart_bench.generator.sharded import generate_sharded

            generate_sharded(plan, partial, fmt, layout, scheduler=scheduler, jobs=jobs, log=log, advance=advance)
        else:
            _write_all(partial, plan, fmt, log, layout, advance)
    return out


def _generate_to_url(plan: GenerationPlan, url: str, fmt: str, layout: str, overwrite: bool, executor: str,
                     scheduler: str | None, jobs: int, log, advance: Callable[[str, int], None] | None = None) -> None:
    """A dataset at an object-store URL (scart_bench.storage): written here and uploaded with its
    manifest last; with dask, the workers upload their flights and this process the manifest.
    An old dataset there is removed, manifest first, just before the new one is uploaded."""
    from scart_bench.storage import (
        check_writable,
        clear,
        has_manifest,
        has_objects,
        owned_tempdir,
        publish_dataset,
    )

    check_writable(url)
    old = has_manifest(url)
    if old and not overwrite:
        raise DatasetError(f"{url}: a dataset is already there; pass --overwrite to replace it")
    if not old and not overwrite and has_objects(url):  # a half-uploaded dataset: replaced only when asked
        raise DatasetError(f"{url}: holds objects but no manifest (not a complete scart-bench dataset); "
                           "choose a new prefix, or pass --overwrite to replace them")
    with owned_tempdir("scart-generate-") as tmp:  # a killed generate's is removed by the next command
        local = Path(tmp) / "dataset"
        if executor == "dask":
            from scart_bench.generator.sharded import generate_sharded

            clear(url)
            try:
                generate_sharded(plan, local, fmt, layout, scheduler=scheduler, jobs=jobs, log=log, target=url,
                                 advance=advance)
                publish_dataset(local, url, flights_uploaded=True)
            except BaseException:
                clear(url)  # what the workers uploaded: no manifest was written
                raise
            return
        _write_all(local, plan, fmt, log, layout, advance)
        clear(url)
        try:
            publish_dataset(local, url)
        except BaseException:
            clear(url)
            raise


def _write_all(partial: Path, plan: GenerationPlan, fmt: str, log, layout: str | None = None,
               advance: Callable[[str, int], None] | None = None) -> None:
    # one worker process writes flights while this one simulates the next batch
    writer = DatasetWriter(partial, fmt=fmt, workers=1, layout=layout, info=plan.info())
    try:
        _fly_and_write(writer, plan, log, advance)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def _fly_and_write(writer: DatasetWriter, plan: GenerationPlan, log,
                   advance: Callable[[str, int], None] | None = None) -> None:
    say = log or (lambda msg: None)
    sources: Sources = {"csv_source": [], "validation": []}
    for b in range(batch_count(plan.count, plan.profile.batch_size)):
        for k, v in fly_normal_batch(writer, plan, b, say, advance).items():
            sources[k].extend(v)
    if plan.attacks:
        stds = field_stds([topics for _, topics, _ in sources["validation"]])
        attack_flights(writer, plan.profile, sources["csv_source"], plan.seed, plan.config, plan.config_dict, say,
                       stds, advance)
