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
from scart_bench.generator.attacks import attack_flights, strip_labels
from scart_bench.generator.engine.flight_batch import defaults_summary
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.profiles import Profile, get_profile
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.telemetry.tables import normal_record


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


def generate_dataset(profile: str, out: str | Path, seed: int = 0, fmt: str = "parquet",
                     n_normal: int | None = None, overwrite: bool = False, with_attacks: bool = True,
                     config: FlightConfig | None = None, log: Callable[[str], None] | None = None,
                     scenarios: str | Path | None = None, layout: str | None = None,
                     uorb: bool | None = None) -> Path:
    """Generate a complete dataset; returns its folder. The manifest is written last.

    ``layout``: "compact" (default for Parquet) or "paper" (the paper's per-topic files; the
    default for CSV); see scart_bench.dataset.

    ``scenarios``: a scenario, grid or sweep file that replaces the profile's grid for the
    attacked flights (both modes); it is validated before anything is flown. ``uorb``: also write
    each flight's uORB view (a third view, generator.telemetry.uorb); None keeps ``config``'s
    ``FlightConfig.uorb`` (False by default), whatever the profile.
    """
    prof = get_profile(profile)
    layout = check_layout(fmt, layout)
    if scenarios is not None:
        load_configurations(scenarios)  # bad files fail here, before any work
        prof = dataclasses.replace(prof, scenario_grid=str(Path(scenarios).resolve()))
    if n_normal is not None and n_normal < 1:
        raise DatasetError(f"flight count must be at least 1, got {n_normal}")
    out = Path(out)
    check_output_dir(out, overwrite=overwrite)
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
    seeds = normal_seeds(seed, count)
    split_of = splits(count, n_train, n_val, n_src)
    config_dict = {"flight_config": dataclasses.asdict(cfg), "versions": versions(), "profile": prof.name}
    # write into a hidden sibling folder and move it into place at the end: an interrupted
    # generation leaves nothing at ``out``, and an existing dataset stays until the new one is done
    with replacing(out) as partial:
        _write_all(partial, prof, cfg, config_dict, seeds, split_of, count, seed, fmt, with_attacks, log,
                   layout)
    return out


def _write_all(partial: Path, prof: Profile, cfg: FlightConfig, config_dict: dict, seeds: list[int],
               split_of: list[str], count: int, seed: int, fmt: str, with_attacks: bool, log,
               layout: str | None = None) -> None:
    # one worker process writes flights while this one simulates the next batch
    writer = DatasetWriter(partial, fmt=fmt, workers=1, layout=layout,
                           info={"profile": prof.name, "seed": seed, "n_normal": count, "versions": versions(),
                                 **defaults_summary(cfg)})
    try:
        _fly_and_write(writer, prof, cfg, config_dict, seeds, split_of, count, seed, with_attacks, log)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def _fly_and_write(writer: DatasetWriter, prof: Profile, cfg: FlightConfig, config_dict: dict, seeds: list[int],
                   split_of: list[str], count: int, seed: int, with_attacks: bool, log) -> None:
    say = log or (lambda msg: None)
    sources: dict[str, list] = {"csv_source": [], "validation": []}
    for start in range(0, count, prof.batch_size):
        chunk = seeds[start:start + prof.batch_size]
        say(f"flying normal flights {start + 1}-{start + len(chunk)} of {count}")
        batch = simulate(chunk, cfg)
        for j in range(len(chunk)):
            i = start + j
            record = normal_record(batch, j, f"normal-{i:04d}", split_of[i], config_dict)
            writer.write(record)
            if split_of[i] in sources:
                sources[split_of[i]].append((record.flight_id, strip_labels(record.navigator), seeds[i]))
    if with_attacks and prof.scenario_grid is not None:
        stds = field_stds([topics for _, topics, _ in sources["validation"]])
        attack_flights(writer, prof, sources["csv_source"], seed, cfg, config_dict, say, stds)
