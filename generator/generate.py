"""Dataset generation: profiles of flight counts, normal flights and (with scenarios) attacked ones."""

from __future__ import annotations

import dataclasses
import platform
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scart_bench.dataset import (
    DatasetError,
    DatasetWriter,
    check_layout,
    check_output_dir,
    replacing,
)
from scart_bench.generator.attack_effect import field_stds
from scart_bench.generator.attacks import attack_flights, batch_count, strip_labels
from scart_bench.generator.engine.flight_batch import defaults_summary
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.profiles import Profile, get_profile
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.telemetry.tables import normal_record
from scart_bench.storage import is_url, local_path


def normal_seeds(seed: int, count: int) -> list[int]:
    """Flight seeds derived from the dataset seed (stable, distinct)."""
    ss = np.random.SeedSequence(int(seed))
    return [int(x) for x in ss.generate_state(count, dtype=np.uint32)]


def splits(count: int, n_train: int, n_validation: int, n_csv_source: int = 0) -> list[str]:
    """Split of the i-th normal flight: train, then validation, then test, then csv_source (by seed
    order; the csv sources come last, so adding them leaves the other flights as they were)."""
    n_test = count - n_train - n_validation - n_csv_source
    return ["train" if i < n_train else "validation" if i < n_train + n_validation
            else "test" if i < n_train + n_validation + n_test else "csv_source" for i in range(count)]


def versions() -> dict[str, str]:
    import pandas
    import pyarrow

    from scart_bench.generator import __version__

    return {"scart-bench": __version__, "numpy": np.__version__, "pandas": pandas.__version__,
            "pyarrow": pyarrow.__version__, "python": platform.python_version()}


@dataclasses.dataclass(frozen=True)
class GenerationPlan:
    """What a generation flies: the profile, flight config, normal seeds and splits (plain data,
    the same for every executor, so a sharded generation writes the same bytes as a local one)."""

    profile: Profile
    config: FlightConfig
    config_dict: dict
    seed: int
    seeds: list[int]
    split_of: list[str]
    with_attacks: bool

    @property
    def count(self) -> int:
        return len(self.seeds)

    @property
    def attacks(self) -> bool:
        return self.with_attacks and self.profile.scenario_grid is not None

    def info(self) -> dict:
        """dataset.json's content (before format and layout)."""
        return {"profile": self.profile.name, "seed": self.seed, "n_normal": self.count, "versions": versions(),
                **defaults_summary(self.config)}


def plan_generation(profile: str, seed: int = 0, n_normal: int | None = None, with_attacks: bool = True,
                    config: FlightConfig | None = None, scenarios: str | Path | None = None,
                    uorb: bool | None = None, batch_size: int | None = None) -> GenerationPlan:
    """The flights a generation flies (validates the profile, scenarios, counts; flies nothing).

    ``batch_size``: flights flown together (default: the profile's); a batch is also the unit of
    work of a sharded generation (:mod:`generator.sharded`). The dataset depends on it: compare
    datasets made with the same batch size."""
    prof = get_profile(profile)
    if scenarios is not None:
        load_configurations(scenarios)  # bad files fail here, before any work
        prof = dataclasses.replace(prof, scenario_grid=str(Path(scenarios).resolve()))
    if batch_size is not None:
        if int(batch_size) < 1:
            raise DatasetError(f"batch size must be at least 1, got {batch_size}")
        prof = dataclasses.replace(prof, batch_size=int(batch_size))
    if n_normal is not None and n_normal < 1:
        raise DatasetError(f"flight count must be at least 1, got {n_normal}")
    cfg = config or prof.flight_config()
    if uorb is not None:
        cfg = dataclasses.replace(cfg, uorb=bool(uorb))
    count = n_normal if n_normal is not None else prof.n_normal
    frac_train = prof.n_train / prof.n_normal
    frac_val = prof.n_validation / prof.n_normal
    frac_src = prof.n_csv_source / prof.n_normal
    n_train = max(1, int(round(count * frac_train))) if count > 2 else count
    reserve = with_attacks and prof.scenario_grid is not None and prof.n_csv_source > 0
    n_src = max(1, int(round(count * frac_src))) if count > 2 and reserve else 0
    n_src = min(n_src, count - n_train)
    # a scaled-down profile keeps its csv sources (csv mode needs one): validation takes what is left
    n_val = min(int(round(count * frac_val)), count - n_train - n_src) if count > 2 else 0
    config_dict = {"flight_config": dataclasses.asdict(cfg), "versions": versions(), "profile": prof.name}
    return GenerationPlan(prof, cfg, config_dict, int(seed), normal_seeds(seed, count),
                          splits(count, n_train, n_val, n_src), with_attacks)


def generate_dataset(profile: str, out: str | Path, seed: int = 0, fmt: str = "parquet",
                     n_normal: int | None = None, overwrite: bool = False, with_attacks: bool = True,
                     config: FlightConfig | None = None, log: Callable[[str], None] | None = None,
                     scenarios: str | Path | None = None, layout: str | None = None,
                     uorb: bool | None = None, batch_size: int | None = None, executor: str = "local",
                     scheduler: str | None = None, jobs: int = 1) -> Path | str:
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
    """
    plan = plan_generation(profile, seed, n_normal, with_attacks, config, scenarios, uorb, batch_size)
    layout = check_layout(fmt, layout)
    if executor not in ("local", "dask"):
        raise DatasetError(f"executor {executor!r}: expected local or dask")
    if is_url(out):
        _generate_to_url(plan, str(out), fmt, layout, overwrite, executor, scheduler, jobs, log)
        return out
    out = local_path(out)
    check_output_dir(out, overwrite=overwrite)
    # write into a hidden sibling folder and move it into place at the end: an interrupted
    # generation leaves nothing at ``out``, and an existing dataset stays until the new one is done
    with replacing(out) as partial:
        if executor == "dask":
            from scart_bench.generator.sharded import generate_sharded

            generate_sharded(plan, partial, fmt, layout, scheduler=scheduler, jobs=jobs, log=log)
        else:
            _write_all(partial, plan, fmt, log, layout)
    return out


def _generate_to_url(plan: GenerationPlan, url: str, fmt: str, layout: str, overwrite: bool, executor: str,
                     scheduler: str | None, jobs: int, log) -> None:
    """A dataset at an object-store URL (scart_bench.storage): written here and uploaded with its
    manifest last; with dask, the workers upload their flights and this process the manifest.
    An old dataset there is removed, manifest first, just before the new one is uploaded."""
    import tempfile

    from scart_bench.storage import check_writable, clear, has_manifest, has_objects, publish_dataset

    check_writable(url)
    old = has_manifest(url)
    if old and not overwrite:
        raise DatasetError(f"{url}: a dataset is already there; pass --overwrite to replace it")
    if not old and has_objects(url):
        raise DatasetError(f"{url}: holds objects but no manifest (not a complete scart-bench dataset); "
                           "choose a new prefix")
    with tempfile.TemporaryDirectory(prefix="scart-generate-") as tmp:
        local = Path(tmp) / "dataset"
        if executor == "dask":
            from scart_bench.generator.sharded import generate_sharded

            clear(url)
            try:
                generate_sharded(plan, local, fmt, layout, scheduler=scheduler, jobs=jobs, log=log, target=url)
                publish_dataset(local, url, flights_uploaded=True)
            except BaseException:
                clear(url)  # what the workers uploaded: no manifest was written
                raise
            return
        _write_all(local, plan, fmt, log, layout)
        clear(url)
        try:
            publish_dataset(local, url)
        except BaseException:
            clear(url)
            raise


def _write_all(partial: Path, plan: GenerationPlan, fmt: str, log, layout: str | None = None) -> None:
    # one worker process writes flights while this one simulates the next batch
    writer = DatasetWriter(partial, fmt=fmt, workers=1, layout=layout, info=plan.info())
    try:
        _fly_and_write(writer, plan, log)
    except BaseException:
        writer.abort()
        raise
    writer.close()


Sources = dict[str, list[tuple[str, dict, int]]]


def fly_normal_batch(writer, plan: GenerationPlan, batch: int, say: Callable[[str], None]) -> Sources:
    """Fly and write the ``batch``-th batch of normal flights; returns its validation and csv_source
    flights (id, link topics without labels, seed): the attacked flights' references."""
    size, count = plan.profile.batch_size, plan.count
    start = batch * size
    chunk = plan.seeds[start:start + size]
    sources: Sources = {"csv_source": [], "validation": []}
    say(f"flying normal flights {start + 1}-{start + len(chunk)} of {count}")
    flown = simulate(chunk, plan.config)
    for j in range(len(chunk)):
        i = start + j
        record = normal_record(flown, j, f"normal-{i:04d}", plan.split_of[i], plan.config_dict)
        writer.write(record)
        if plan.split_of[i] in sources:
            sources[plan.split_of[i]].append((record.flight_id, strip_labels(record.navigator), plan.seeds[i]))
    return sources


def _fly_and_write(writer: DatasetWriter, plan: GenerationPlan, log) -> None:
    say = log or (lambda msg: None)
    sources: Sources = {"csv_source": [], "validation": []}
    for b in range(batch_count(plan.count, plan.profile.batch_size)):
        for k, v in fly_normal_batch(writer, plan, b, say).items():
            sources[k].extend(v)
    if plan.attacks:
        stds = field_stds([topics for _, topics, _ in sources["validation"]])
        attack_flights(writer, plan.profile, sources["csv_source"], plan.seed, plan.config, plan.config_dict, say,
                       stds)
