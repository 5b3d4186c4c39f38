"""Attacked flights for a dataset: every configuration of the profile's grid, in both modes.

- simulation mode: each configuration is flown in the closed loop with a seed of its own;
- csv mode: each configuration is replayed on a recorded normal flight reserved for it (split
  ``csv_source``: never trained on, calibrated on or scored as normal), cycling through them.
  A recording holds the link telemetry only, so a configuration gets a csv copy only when one of
  its scenarios sits on the ``link`` (and only those act on the copy); sensor, command,
  environment and vehicle scenarios alone get no csv copy.

Every attacked flight records what the attack changed relative to its clean reference (the
simulator view, or the csv source) and how large it was (:mod:`generator.attack_effect`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import LABEL_COLUMNS, DatasetWriter
from scart_bench.generator.attack_effect import attack_effect
from scart_bench.generator.engine.flight_batch import flight_summaries, vehicle_groups
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.impact import TWIN_TOPIC, impact
from scart_bench.generator.modes import csv_mode, csv_record, simulation_mode, simulation_record
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.link_actions import CLOSED_LOOP_ACTIONS
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.telemetry.tables import truth_table

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
                       stds: dict[str, float] | None = None, batches: Iterable[int] | None = None,
                       advance: Callable[[str, int], None] | None = None) -> None:
    """Fly every configuration (the scenarios of one flight) in the closed loop and write the flights.

    ``batches``: only these batch numbers (a shard of a distributed generation,
    :mod:`generator.sharded`); the flights of a batch are the same whichever batches are flown.
    ``advance`` is told ``("simulation", flights)`` after each batch.

    Each attacked flight's normal twin (its seed flown without the layer) is flown too; its truth
    goes into the attacked flight's simulator view (``twin_truth``) and the attack's impact into
    the manifest (:mod:`generator.impact`). Twins are not dataset flights."""
    seeds = attack_seeds(seed, len(configs))
    order = _order(configs)
    for start in _starts(len(order), batch_size, batches):
        idx = order[start:start + batch_size]
        say(f"simulation mode: flying attacked flights {start + 1}-{start + len(idx)} of {len(order)}")
        # a layer's batch flies one airframe and payload (a profile's mixes: flight_batch.vehicle_groups)
        for sub, pos in vehicle_groups([seeds[i] for i in idx], cfg):
            part = [idx[k] for k in pos]
            batch, layer = simulation_mode([seeds[i] for i in part], [configs[i] for i in part], sub)
            twins = simulate([seeds[i] for i in part], sub)
            mixed = bool(cfg.mission.families or cfg.airframes)  # what each flew, as a normal flight records it
            flights = flight_summaries([seeds[i] for i in part], cfg) if mixed else None
            for j, i in enumerate(part):
                config = config_dict if flights is None else {**config_dict, "flight": flights[j]}
                record = simulation_record(batch, layer, j, f"sim-{config_id(configs[i])}", configs[i], config)
                points = record.manifest["injection_point"]
                if any(n in CLOSED_LOOP_ACTIONS for sc in configs[i] for n, _ in sc.actions):
                    points += "+controller"  # a forged command or mission moves the vehicle, not a message
                record.manifest.update(attack_effect(record.navigator, record.simulator, record.windows, stds, points))
                twin_truth = truth_table(twins, j)  # the twin's other topics are not used
                record.manifest.update(impact(record.simulator["truth"], twin_truth, batch.status[j]))
                record.simulator[TWIN_TOPIC] = twin_truth
                writer.write(record)
        if advance is not None:
            advance("simulation", len(idx))


def batch_count(n_flights: int, batch_size: int) -> int:
    """Batches of ``batch_size`` flights that ``n_flights`` flights make (the last may be short)."""
    return -(-int(n_flights) // int(batch_size))


def _starts(n: int, batch_size: int, batches: Iterable[int] | None) -> list[int]:
    """First flight index of every batch to fly (all of them, or only ``batches``)."""
    chosen = range(batch_count(n, batch_size)) if batches is None else sorted(set(batches))
    return [b * batch_size for b in chosen if 0 <= b * batch_size < n]


def csv_applicable(config: list[Scenario]) -> bool:
    """True when a scenario of the configuration acts on link messages (what a recording holds)."""
    return any(s.injection_point == "link" for s in config)


def csv_flights(writer: DatasetWriter, configs: list[list[Scenario]], sources: list[tuple[str, dict, int]],
                config_dict: dict, batch_size: int, say: Callable[[str], None],
                stds: dict[str, float] | None = None, batches: Iterable[int] | None = None,
                advance: Callable[[str, int], None] | None = None) -> None:
    """Replay every link configuration on a recorded normal flight (``sources``: id, topic tables,
    seed); configurations that cannot apply to a recording get no copy. ``batches``: only these
    batch numbers (see :func:`simulation_flights`); ``sources`` must then still be the full list.
    ``advance`` is told ``("csv", flights)`` after each batch."""
    skipped = [config_id(c) for c in configs if not csv_applicable(c)]
    if skipped and (batches is None or 0 in batches):
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
    for start in _starts(len(order), batch_size, batches):
        idx = order[start:start + batch_size]
        say(f"csv mode: replaying attacked flights {start + 1}-{start + len(idx)} of {len(order)}")
        src = [sources[i % len(sources)] for i in idx]
        link = [{t: df for t, df in s[1].items() if t != "truth"} for s in src]
        results = csv_mode(link, [configs[i] for i in idx], [s[2] for s in src])
        for result, i, (sid, topics, sseed) in zip(results, idx, src):
            writer.write(csv_record(f"csv-{config_id(configs[i])}", topics, result, configs[i], sseed, sid,
                                    {**config_dict, "source_flight": sid}, stds))
        if advance is not None:
            advance("csv", len(idx))


def attack_flights(writer: DatasetWriter, profile, normal_sources: list[tuple[str, dict, int]], seed: int,
                   cfg: FlightConfig, config_dict: dict, say: Callable[[str], None],
                   stds: dict[str, float] | None = None, advance: Callable[[str, int], None] | None = None) -> None:
    """Both modes for every configuration of the profile's grid (or sweep, or scenario file);
    ``normal_sources``: the csv_source flights; ``stds``: validation std per ``topic.field``.

    With a writer that writes in a worker process (dataset generation), csv mode runs in a
    process of its own while this one flies simulation mode (the two share nothing but the
    sources, so the files are the same as one after the other); its manifest rows follow the
    simulation flights', as before."""
    configs = load_configurations(grid_path(profile.scenario_grid))
    # csv mode in up to CSV_PROCESSES processes, each a run of whole batches (rows in batch order)
    nb = batch_count(sum(map(csv_applicable, configs)), profile.batch_size)
    cut = [round(nb * k / max(1, min(CSV_PROCESSES, nb))) for k in range(max(1, min(CSV_PROCESSES, nb)) + 1)]
    sides = [_CsvProcess.start(writer, profile, normal_sources, config_dict, say, stds, advance,
                               range(lo, hi) if len(cut) > 2 else None) for lo, hi in zip(cut, cut[1:])]
    sides = [s for s in sides if s is not None]
    try:
        simulation_flights(writer, configs, seed, cfg, config_dict, profile.batch_size, say, stds, advance=advance)
        if not sides:
            csv_flights(writer, configs, normal_sources, config_dict, profile.batch_size, say, stds, advance=advance)
        for side in sides:
            writer.add_written(side.rows())
    except BaseException:
        for side in sides:  # a failed one's partner writes nothing more either
            side.stop()
        raise


#: processes csv mode runs in beside the simulation-mode flights (issue 51: one was the long pole)
CSV_PROCESSES = 2


class RowWriter:
    """Writes flights in the calling process and keeps their manifest rows (the csv-mode process)."""

    def __init__(self, out: Path, fmt: str, layout: str):
        self.out, self.fmt, self.layout = out, fmt, layout
        self.rows: list[dict] = []
        self.ids: set[str] = set()

    def write(self, record) -> None:
        from scart_bench.dataset import DatasetError, write_flight

        if record.flight_id in self.ids:
            raise DatasetError(f"{self.out}: a flight {record.flight_id!r} is already in the dataset; "
                               "flight ids must be unique")
        self.ids.add(record.flight_id)
        self.rows.append(write_flight(self.out, self.fmt, record, self.layout))


def _csv_main(conn, parent: int, out: Path, fmt: str, layout: str, grid: str, sources, config_dict: dict,
              batch_size: int, stds, batches: range | None = None) -> None:
    """Entry of the csv-mode process: replay every configuration, write the flights, send the rows."""
    from scart_bench.dataset import exit_with_parent

    exit_with_parent(parent)
    try:
        w = RowWriter(out, fmt, layout)
        csv_flights(w, load_configurations(grid_path(grid)), sources, config_dict, batch_size,
                    lambda msg: conn.send(("say", msg)), stds,
                    batches=batches, advance=lambda part, n: conn.send(("progress", (part, n))))
        conn.send(("rows", w.rows))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
        try:
            conn.send(("error", exc))  # raised again as it is in the parent
        except Exception:  # noqa: BLE001 - an exception that does not pickle goes as text
            import traceback

            conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    finally:
        conn.close()


class _CsvProcess:
    """csv mode in a process of its own; relays its progress messages to ``say`` and its counts
    to ``advance``."""

    def __init__(self, proc, conn, say: Callable[[str], None], advance: Callable[[str, int], None] | None = None):
        import threading

        self.proc, self.conn, self.say, self.advance = proc, conn, say, advance
        self.result: tuple[str, object] | None = None
        self.thread = threading.Thread(target=self._relay, daemon=True, name="csv-mode-relay")
        self.thread.start()

    @classmethod
    def start(cls, writer: DatasetWriter, profile, sources, config_dict: dict, say: Callable[[str], None],
              stds, advance: Callable[[str, int], None] | None = None, batches: range | None = None
              ) -> _CsvProcess | None:
        if getattr(writer, "_pool", None) is None:  # no worker process: stay in this one
            return None
        import multiprocessing
        import os

        ctx = multiprocessing.get_context("spawn")
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_csv_main, name="scart-bench-csv-mode", daemon=True,
                           args=(send, os.getpid(), writer.out, writer.fmt, writer.layout,
                                 str(profile.scenario_grid), sources, config_dict, profile.batch_size, stds,
                                 batches))
        proc.start()
        send.close()
        return cls(proc, recv, say, advance)

    def _relay(self) -> None:
        try:
            while True:
                kind, payload = self.conn.recv()
                if kind == "say":
                    self.say(payload)
                elif kind == "progress":
                    if self.advance is not None:
                        self.advance(*payload)
                else:
                    self.result = (kind, payload)
                    return
        except (EOFError, OSError):
            return

    def rows(self) -> list[dict]:
        """Wait for the process; its flights' manifest rows (RuntimeError if it failed)."""
        self.thread.join()
        self.proc.join()
        if self.result is not None and isinstance(self.result[1], BaseException):
            raise self.result[1]
        if self.result is None or self.result[0] != "rows":
            detail = self.result[1] if self.result else f"it ended with exit code {self.proc.exitcode}"
            raise RuntimeError(f"csv mode failed: {detail}")
        return self.result[1]

    def stop(self) -> None:
        """End the process (nothing more is written) before the caller cleans up."""
        if self.proc.is_alive():
            self.proc.terminate()
        self.proc.join()
        self.thread.join(timeout=5)


def strip_labels(topics: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    return {t: df.drop(columns=list(LABEL_COLUMNS), errors="ignore") for t, df in topics.items()}
