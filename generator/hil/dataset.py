"""Flights flown in jMAVSim written in the project's dataset format.

A flight through the bridge becomes a one-flight :class:`~scart_bench.generator.engine.flight_batch.BatchResult`
(the flight controller's telemetry before the layer as the simulator view, after it as the navigator
view, jMAVSim's HIL_STATE_QUATERNION as the ``truth`` topic), so the built-in engine's record makers
and the dataset writer take it unchanged: the same topics, labels, manifest and layout.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scart_bench.dataset import DatasetWriter
from scart_bench.dataset.schema import TELEMETRY_TOPICS
from scart_bench.generator.attack_effect import attack_effect
from scart_bench.generator.attacks import csv_applicable, strip_labels
from scart_bench.generator.engine.flight_batch import BatchResult
from scart_bench.generator.hil.bridge import HilFlight
from scart_bench.generator.hil.flights import autopilot_for, fly_at, fly_jmavsim
from scart_bench.generator.modes import csv_mode, csv_record, simulation_record
from scart_bench.generator.params import MissionParams
from scart_bench.generator.plan import normal_seeds, splits, versions
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.telemetry.tables import normal_record

#: seconds without a heartbeat between flights against an already running simulator: jMAVSim puts its
#: vehicle back at home after 3 s without one
EXTERNAL_RESET_S = 4.0

#: the topics of a dataset flight (the built-in engine's: telemetry, the navigator's setpoints)
TOPICS = (*TELEMETRY_TOPICS, "setpoint")


def as_batch(flight: HilFlight, seed: int) -> BatchResult:
    """One flight through the bridge as a batch of one."""
    rec = flight.autopilot.records
    sim, nav = {}, {}
    for topic in TOPICS:
        if topic not in rec.before:
            continue
        steps, rows = rec.table(topic, after=False)
        sim[topic] = (steps, rows[None], np.ones((1, len(steps)), dtype=bool))
        steps, rows = rec.table(topic, after=True)
        nav[topic] = (steps, rows[None], rec.delivered(topic)[None])
    t = flight.truth
    landed = (t[:, 3] > -0.05) & (np.abs(t[:, 6]) < 0.1)
    truth = np.column_stack([t[:, 1:10], t[:, 11], landed.astype(float)])
    sim["truth"] = (t[:, 10].astype(np.int64), truth[None], np.ones((1, len(t)), dtype=bool))
    es = flight.autopilot.es
    return BatchResult(
        seeds=[int(seed)], simulator=sim, navigator=nav, exit_step=np.array([flight.steps - 1]),
        status=[flight.status], waypoints=flight.autopilot.waypoints[None], wind=np.full((1, 3), np.nan),
        gps_rejections=np.column_stack([es.gps_pos_rejected, es.gps_vel_rejected, es.baro_rejected]),
        n_steps=flight.steps, timing="ideal")


def generate_jmavsim(out: str | Path, jar=None, seed: int = 0, n_normal: int = 8,
                     configs: list[list[Scenario]] | None = None, fmt: str = "parquet", overwrite: bool = False,
                     log: Callable[[str], None] | None = None, physics: str = "jmavsim",
                     csv_configs: list[list[Scenario]] | None = None, sim: str | None = None,
                     lockstep: bool = True, mission: MissionParams | None = None) -> Path:
    """Fly ``n_normal`` normal flights and one simulation-mode flight per entry of ``configs`` in
    jMAVSim and write them as a dataset at ``out``; returns it.

    Normal flights split as train / validation / test (half, a quarter, the rest); attacked flights
    are test flights. Each flight starts its own jMAVSim (a fresh vehicle on the ground at home).
    ``csv_configs``: one csv-mode copy each (link scenarios), replayed in turn on two more normal
    flights reserved for it (split csv_source), as the built-in generator does.
    ``physics="builtin"`` flies the same seeds and scenarios with the built-in engine instead (one
    flight at a time, ideal timing), for the comparison of docs/jmavsim.md.
    ``sim``: fly against a simulator already running at this address (``udp:HOST:PORT``,
    ``tcp:HOST:PORT``, ...: :func:`scart_bench.generator.hil.link.open_link`) instead of starting
    jMAVSim; it must put its vehicle back on the ground at home between flights (jMAVSim does after
    3 s without a heartbeat). ``lockstep`` False: the started jMAVSim runs in real time.
    ``mission``: what each flight flies (default the jittered square; with ``mission.missions``, the
    mission files, flight seed ``s`` flying file ``s mod N`` as the built-in engine does).
    """
    if physics == "jmavsim" and sim is not None:
        from scart_bench.generator.hil.link import parse_sim_address

        parse_sim_address(sim)  # a bad address is said before anything is flown or written
        fly = _external_flyer(sim, mission)
    elif physics == "jmavsim":
        from scart_bench.generator.hil.jmavsim import find_jar, find_java

        find_java()
        jar = find_jar(jar)  # what is missing is said before anything is flown or written
        fly = _jmavsim_flyer(jar, lockstep, mission)
    elif physics == "builtin":
        fly = _builtin_flyer(mission)
    else:
        raise ValueError(f"physics {physics!r}: expected jmavsim or builtin")
    say = log or (lambda msg: None)
    configs = configs or []
    csv_configs = csv_configs or []
    n_src = 2 if csv_configs else 0
    seeds = normal_seeds(seed, n_normal + n_src)
    n_train, n_val = max(1, n_normal // 2), max(1, n_normal // 4)
    split_of = splits(n_normal + n_src, n_train, min(n_val, n_normal - n_train), n_src)
    sources: list[tuple[str, dict, int]] = []
    info = {"profile": physics, "physics": physics, "seed": int(seed), "n_normal": n_normal,
            "versions": versions(), "timing": "ideal"}
    pace = "lockstep" if lockstep else "real time"
    config = {"physics": physics, "simulator": (f"a simulator at {sim} (PX4 simulator MAVLink API)" if sim else
                                                f"jMAVSim (PX4 simulator MAVLink API, {pace})")
              if physics == "jmavsim" else "the built-in engine"}
    writer = DatasetWriter(out, fmt=fmt, info=info, overwrite=overwrite)
    try:
        for i, s in enumerate(seeds):
            say(f"{physics}: normal flight {i + 1} of {len(seeds)}")
            batch, _ = fly(s, None)
            record = normal_record(batch, 0, f"normal-{i:04d}", split_of[i], flown(config, mission, s))
            writer.write(record)
            if split_of[i] == "csv_source":
                sources.append((record.flight_id, strip_labels(record.navigator), s))
        attack_seeds = normal_seeds(seed + 1_000_003, len(configs))
        for i, (scs, s) in enumerate(zip(configs, attack_seeds)):
            say(f"{physics}: attacked flight {i + 1} of {len(configs)} ({'+'.join(sc.id for sc in scs)})")
            batch, layer = fly(s, scs)
            record = simulation_record(batch, layer, 0, f"sim-{i:04d}", scs, flown(config, mission, s))
            record.manifest.update(attack_effect(record.navigator, record.simulator, record.windows, None,
                                                 record.manifest["injection_point"]))
            writer.write(record)
        for i, scs in enumerate(csv_configs):
            sid, topics, sseed = sources[i % len(sources)]
            say(f"csv mode: copy {i + 1} of {len(csv_configs)} ({'+'.join(sc.id for sc in scs)} on {sid})")
            link = {t: df for t, df in topics.items() if t != "truth"}
            result = csv_mode([link], [scs], [sseed])[0]
            writer.write(csv_record(f"csv-{i:04d}", topics, result, scs, sseed, sid,
                                    {**flown(config, mission, sseed), "source_flight": sid}))
    except BaseException:
        writer.abort()
        raise
    return writer.close()


def flown(config: dict, mission: MissionParams | None, seed: int) -> dict:
    """A flight's recorded configuration: ``config`` and, with mission files, the file it flew."""
    if mission is None or not mission.missions:
        return config
    from scart_bench.generator.flight_software.mission_files import mission_for_seed

    return {**config, "mission_file": mission.missions[mission_for_seed(mission.missions, seed)].name}


def _jmavsim_flyer(jar, lockstep: bool = True, mission: MissionParams | None = None):
    def fly(seed: int, scenarios: list[Scenario] | None):
        flight = fly_jmavsim(jar, seed=seed, scenarios=scenarios, lockstep=lockstep, mission=mission)
        return as_batch(flight, seed), flight.autopilot.layer
    return fly


def _external_flyer(address: str, mission: MissionParams | None = None):
    mp = mission or MissionParams()

    def fly(seed: int, scenarios: list[Scenario] | None):
        flight = fly_at(address, autopilot_for(seed, scenarios, mp), max_s=mp.max_duration_s)
        time.sleep(EXTERNAL_RESET_S)  # no heartbeat: jMAVSim puts its vehicle back at home
        return as_batch(flight, seed), flight.autopilot.layer
    return fly


def _builtin_flyer(mission: MissionParams | None = None):
    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.modes import simulation_mode

    cfg = FlightConfig(timing="ideal") if mission is None else FlightConfig(timing="ideal", mission=mission)

    def fly(seed: int, scenarios: list[Scenario] | None):
        if not scenarios:
            return simulate([seed], cfg), None
        return simulation_mode([seed], [list(scenarios)], cfg)
    return fly


#: the attacks flown when none are given: a sensor-point GPS drift and jump (data/scenarios), and
#: the quick profile's grid of link attacks (position and attitude; noise, bias, drift, replay,
#: sinusoid, GPS spoofing), evenly spaced over the grid
DEFAULT_SCENARIOS = ("sensor_gps_drift.toml", "sensor_gps_jump.toml")
DEFAULT_GRID = "quick.toml"


def attack_configs(scenarios: str | Path | None, count: int, link_only: bool = False) -> list[list[Scenario]]:
    """``count`` attacked flights' scenarios: the configurations of ``scenarios`` (a scenario, grid
    or sweep file) in turn, or by default the two sensor attacks of :data:`DEFAULT_SCENARIOS` and
    link attacks spread over :data:`DEFAULT_GRID`. ``link_only``: only configurations a recording
    can replay (csv mode)."""
    from scart_bench.generator.attacks import grid_path
    from scart_bench.generator.scart.grid import load_configurations

    if count <= 0:
        return []
    if scenarios is not None:
        base = [c for c in load_configurations(scenarios) if csv_applicable(c) or not link_only]
        return [base[i % len(base)] for i in range(count)] if base else []
    sensor = [] if link_only else [load_configurations(grid_path(name))[0] for name in DEFAULT_SCENARIOS]
    grid = load_configurations(grid_path(DEFAULT_GRID))
    k = max(count - len(sensor), 1)
    link = [grid[int(j)] for j in np.linspace(0, len(grid) - 1, min(k, len(grid))).round()]
    base = sensor + link
    return [base[i % len(base)] for i in range(count)]
