"""What a generation flies (:class:`GenerationPlan`: profile, flight config, normal seeds and splits)
and the flying of one batch of normal flights: shared by the local generation
(:mod:`generator.generate`) and the sharded one on Dask (:mod:`generator.sharded`)."""

from __future__ import annotations

import dataclasses
import platform
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scart_bench.dataset import (
    DatasetError,
)
from scart_bench.generator.attacks import csv_applicable, grid_path, strip_labels
from scart_bench.generator.engine.flight_batch import defaults_summary, flight_summaries
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.mission_files import mission_for_seed
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

    def totals(self) -> dict[str, int]:
        """Flights the generation writes per kind: normal, and with attacks simulation (one per
        configuration) and csv (one per configuration with a link scenario, when a csv source is
        reserved); what its progress counts towards."""
        out = {"normal": self.count}
        if self.attacks:
            configs = load_configurations(grid_path(self.profile.scenario_grid))
            out["simulation"] = len(configs)
            if "csv_source" in self.split_of:
                out["csv"] = sum(csv_applicable(c) for c in configs)
        return out

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
    flight_config = dataclasses.asdict(cfg)
    if not cfg.mission.missions:  # the square: the flights' config as it was before mission files
        del flight_config["mission"]["missions"]
    if not cfg.mission.families:  # ... and before mission families and airframes (the paper profile)
        del flight_config["mission"]["families"], flight_config["mission"]["duration_range"]
    if not cfg.airframes:
        del flight_config["airframes"]
    if not cfg.timing_table:  # the realistic table as it is: the config as before per-topic timing
        del flight_config["timing_table"]
    for key in ("accel_noise_cutoff_hz", "gyro_noise_cutoff_hz", "baro_noise_cutoff_hz"):  # white: as before coloured noise
        if not flight_config["sensors"][key]:
            del flight_config["sensors"][key]
    if not any(cfg.sensors.imu_offset_m) and not cfg.sensors.baro_downwash_pa:  # as before the lever arm and downwash
        del flight_config["sensors"]["imu_offset_m"], flight_config["sensors"]["baro_downwash_pa"]
    if not cfg.sensors.baro_wander_pa:  # as before the baro's wander
        del flight_config["sensors"]["baro_wander_pa"], flight_config["sensors"]["baro_wander_tau_s"]
    if not cfg.sensors.baro_speed_pa:  # as before the baro's noise in forward flight
        del flight_config["sensors"]["baro_speed_pa"], flight_config["sensors"]["baro_speed_full_m_s"]
    if not cfg.sensors.vibration_levels:  # every vehicle alike: as before the vibration levels
        del flight_config["sensors"]["vibration_levels"]
    if not cfg.mission.rocking_levels:  # no vehicle rocks: as before the rocking
        del flight_config["mission"]["rocking_levels"]
    if not cfg.mission.rocking_flow_levels:  # no vehicle rocks in forward flight: as before it
        for key in ("rocking_flow_levels", "rocking_flow_hz", "rocking_flow_full_m_s", "rocking_flow_from_m_s"):
            del flight_config["mission"][key]
    if not max(cfg.mission.pilot_stick_deg, cfg.mission.pilot_yaw_deg, cfg.mission.pilot_throttle):
        for key in [k for k in flight_config["mission"] if k.startswith("pilot_")]:  # no pilot: as before it
            del flight_config["mission"][key]
    config_dict = {"flight_config": flight_config, "versions": versions(), "profile": prof.name}
    return GenerationPlan(prof, cfg, config_dict, int(seed), normal_seeds(seed, count),
                          splits(count, n_train, n_val, n_src), with_attacks)


Sources = dict[str, list[tuple[str, dict, int]]]


def fly_normal_batch(writer, plan: GenerationPlan, batch: int, say: Callable[[str], None],
                     advance: Callable[[str, int], None] | None = None) -> Sources:
    """Fly and write the ``batch``-th batch of normal flights; returns its validation and csv_source
    flights (id, link topics without labels, seed): the attacked flights' references. ``advance``
    is told ``("normal", flights)`` once the batch is written (:class:`scart_bench.progress.Progress`)."""
    size, count = plan.profile.batch_size, plan.count
    start = batch * size
    chunk = plan.seeds[start:start + size]
    sources: Sources = {"csv_source": [], "validation": []}
    say(f"flying normal flights {start + 1}-{start + len(chunk)} of {count}")
    flown = simulate(chunk, plan.config)
    missions = plan.config.mission.missions
    mixed = bool(plan.config.mission.families or plan.config.airframes)
    flights = flight_summaries(chunk, plan.config) if mixed else None
    for j in range(len(chunk)):
        i = start + j
        config = plan.config_dict
        if missions:  # which file the flight flew (generator.mission_files.mission_for_seed)
            config = {**config, "mission_file": missions[mission_for_seed(missions, plan.seeds[i])].name}
        if flights is not None:  # what the flight flew under the profile's mixes (flight_batch.flight_summaries)
            config = {**config, "flight": flights[j]}
        record = normal_record(flown, j, f"normal-{i:04d}", plan.split_of[i], config)
        if flights is not None:  # its own items, not padded to its batch's longest mission
            record.config["waypoints_ned"] = record.config["waypoints_ned"][:flights[j].get("items")]
        writer.write(record)
        if plan.split_of[i] in sources:
            sources[plan.split_of[i]].append((record.flight_id, strip_labels(record.navigator), plan.seeds[i]))
    if advance is not None:
        advance("normal", len(chunk))
    return sources
