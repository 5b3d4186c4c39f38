"""Attacked flights for a dataset: every configuration of the profile's grid, in both modes.

- simulation mode: each configuration is flown in the closed loop with a seed of its own;
- csv mode: each configuration is replayed on a recorded normal flight reserved for it (split
  ``csv_source``: never trained on, calibrated on or scored as normal), cycling through them.
  A recording holds the link telemetry only, so a configuration gets a csv copy only when one of
  its scenarios sits on the ``link`` (and only those act on the copy); sensor, command,
  environment and vehicle scenarios alone get no csv copy.

Every attacked flight records what the attack changed relative to its clean reference (the
simulator view, or the csv source) and how large it was (:mod:`generator.effect`).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.generator.dataset import LABEL_COLUMNS, DatasetWriter
from scart_bench.generator.effect import attack_effect
from scart_bench.generator.impact import TWIN_TOPIC, impact
from scart_bench.generator.modes import csv_mode, csv_record, simulation_mode, simulation_record
from scart_bench.generator.records import truth_table
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.link_actions import CLOSED_LOOP_ACTIONS
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.simulate import FlightConfig, simulate

#: the shipped scenario grids and examples (package data of scart_bench.data)
SCENARIO_DIR = Path(str(resources.files("scart_bench.data").joinpath("scenarios")))


def grid_path(name: str) -> Path:
    p = Path(name)
    return p if p.is_file() else SCENARIO_DIR / name


def attack_seeds(seed: int, count: int) -> list[int]:
    """Seeds of the simulation-mode attacked flights (a stream apart from the normal flights')."""
    ss = np.random.SeedSequence(int(seed), spawn_key=(1,))
    return [int(x) for x in ss.generate_state(count, dtype=np.uint32)]


def _order(configs: list[list[Scenario]]) -> list[int]:
    """Configurations of one structure next to each other, so they share scenario groups."""
    return sorted(range(len(configs)), key=lambda i: ([s.structure_key() for s in configs[i]], i))


def config_id(config: list[Scenario]) -> str:
    return "+".join(s.id for s in config)


def simulation_flights(writer: DatasetWriter, configs: list[list[Scenario]], seed: int, cfg: FlightConfig,
                       config_dict: dict, batch_size: int, say: Callable[[str], None],
                       stds: dict[str, float] | None = None) -> None:
    """Fly every configuration (the scenarios of one flight) in the closed loop and write the flights.

    Each attacked flight's normal twin (its seed flown without the layer) is flown too; its truth
    goes into the attacked flight's simulator view (``twin_truth``) and the attack's impact into
    the manifest (:mod:`generator.impact`). Twins are not dataset flights."""
    seeds = attack_seeds(seed, len(configs))
    order = _order(configs)
    for start in range(0, len(order), batch_size):
        idx = order[start:start + batch_size]
        say(f"simulation mode: flying attacked flights {start + 1}-{start + len(idx)} of {len(order)}")
        batch, layer = simulation_mode([seeds[i] for i in idx], [configs[i] for i in idx], cfg)
        twins = simulate([seeds[i] for i in idx], cfg)
        for j, i in enumerate(idx):
            record = simulation_record(batch, layer, j, f"sim-{config_id(configs[i])}", configs[i], config_dict)
            points = record.manifest["injection_point"]
            if any(n in CLOSED_LOOP_ACTIONS for sc in configs[i] for n, _ in sc.actions):
                points += "+controller"  # a forged command or mission moves the vehicle, not a message
            record.manifest.update(attack_effect(record.navigator, record.simulator, record.windows, stds, points))
            twin_truth = truth_table(twins, j)  # the twin's other topics are not used
            record.manifest.update(impact(record.simulator["truth"], twin_truth, batch.status[j]))
            record.simulator[TWIN_TOPIC] = twin_truth
            writer.write(record)


def csv_applicable(config: list[Scenario]) -> bool:
    """True when a scenario of the configuration acts on link messages (what a recording holds)."""
    return any(s.injection_point == "link" for s in config)


def csv_flights(writer: DatasetWriter, configs: list[list[Scenario]], sources: list[tuple[str, dict, int]],
                config_dict: dict, batch_size: int, say: Callable[[str], None],
                stds: dict[str, float] | None = None) -> None:
    """Replay every link configuration on a recorded normal flight (``sources``: id, topic tables,
    seed); configurations that cannot apply to a recording get no copy."""
    skipped = [config_id(c) for c in configs if not csv_applicable(c)]
    if skipped:
        say(f"csv mode: no copy of {len(skipped)} configuration(s) with no link scenario (sensor, command, "
            f"environment, vehicle), which a recording cannot replay: {', '.join(skipped[:5])}"
            + (" ..." if len(skipped) > 5 else ""))
    configs = [c for c in configs if csv_applicable(c)]
    if not configs:
        return
    if not sources:
        say("csv mode: skipped, the dataset has no normal flight reserved as a csv source (split csv_source)")
        return
    order = _order(configs)
    for start in range(0, len(order), batch_size):
        idx = order[start:start + batch_size]
        say(f"csv mode: replaying attacked flights {start + 1}-{start + len(idx)} of {len(order)}")
        src = [sources[i % len(sources)] for i in idx]
        link = [{t: df for t, df in s[1].items() if t != "truth"} for s in src]
        results = csv_mode(link, [configs[i] for i in idx], [s[2] for s in src])
        for result, i, (sid, topics, sseed) in zip(results, idx, src):
            writer.write(csv_record(f"csv-{config_id(configs[i])}", topics, result, configs[i], sseed, sid,
                                    {**config_dict, "source_flight": sid}, stds))


def attack_flights(writer: DatasetWriter, profile, normal_sources: list[tuple[str, dict, int]], seed: int,
                   cfg: FlightConfig, config_dict: dict, say: Callable[[str], None],
                   stds: dict[str, float] | None = None) -> None:
    """Both modes for every configuration of the profile's grid (or sweep, or scenario file);
    ``normal_sources``: the csv_source flights; ``stds``: validation std per ``topic.field``."""
    configs = load_configurations(grid_path(profile.scenario_grid))
    simulation_flights(writer, configs, seed, cfg, config_dict, profile.batch_size, say, stds)
    csv_flights(writer, configs, normal_sources, config_dict, profile.batch_size, say, stds)


def strip_labels(topics: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    return {t: df.drop(columns=list(LABEL_COLUMNS), errors="ignore") for t, df in topics.items()}
