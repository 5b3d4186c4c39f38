"""Aggregate real-time factor of the flight generator: simulated flight-seconds per wall second.

    python -m perf.generator_speed [--batches 1,100,1000] [--seed 0] [--engine auto]
                                             [--scenarios quick.toml]

For each batch size, flies that many default-mission flights in one batch and prints wall time,
simulated seconds, the aggregate real-time factor, CPU seconds (all threads), the real-time factor
per CPU second and peak memory. The first line is the kernel's start-up (loading or, on a fresh
machine, compiling the numba kernel), which a dataset run pays once. The machine's load average is
printed before and after: on a shared machine wall figures understate the speed, the CPU-second
figures much less so. With ``--scenarios`` (a scenario, grid or sweep file), one more line flies
every configuration of it in simulation mode, as one batch (the SCART layer in the loop).
PX4 SITL + Gazebo flies one flight at about 1x real time.
"""

from __future__ import annotations

import argparse
import os
import resource
import time

from scart_bench.generator.engine.simulate import ENGINES, STEP_US, FlightConfig, simulate


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def measure(n: int, seed: int = 0, engine: str = "auto") -> dict[str, float]:
    """Fly ``n`` flights; returns wall and CPU seconds, simulated seconds and the real-time factor."""
    c0, t0 = _cpu(), time.perf_counter()
    batch = simulate(list(range(seed, seed + n)), engine=engine)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    simulated = float(((batch.exit_step + 1) * STEP_US).sum() / 1e6)
    landed = sum(s == "landed" for s in batch.status)
    return {"flights": n, "wall_s": wall, "cpu_s": cpu, "sim_s": simulated, "rtf": simulated / wall,
            "rtf_cpu": simulated / max(cpu, 1e-9), "landed": landed}


def measure_attacked(path: str, seed: int = 0, engine: str = "auto") -> dict[str, float]:
    """Fly every configuration of a scenario file in simulation mode, as one batch."""
    from scart_bench.generator.attacks import attack_seeds, grid_path
    from scart_bench.generator.modes import _builtin_rates
    from scart_bench.generator.scart.grid import load_configurations
    from scart_bench.generator.scart.layer import AttackLayer

    configs = load_configurations(grid_path(path))
    seeds = attack_seeds(seed, len(configs))
    c0, t0 = _cpu(), time.perf_counter()
    layer = AttackLayer(configs, seeds, rates=_builtin_rates())
    batch = simulate(seeds, layer=layer, engine=engine)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    simulated = float(((batch.exit_step + 1) * STEP_US).sum() / 1e6)
    return {"flights": len(configs), "wall_s": wall, "cpu_s": cpu, "sim_s": simulated, "rtf": simulated / wall,
            "rtf_cpu": simulated / max(cpu, 1e-9), "landed": sum(s == "landed" for s in batch.status)}


def warm_up(engine: str) -> float:
    """Seconds to load (or compile) the kernel: one 0.1 s flight."""
    from scart_bench.generator.params import MissionParams

    t0 = time.perf_counter()
    simulate([0], FlightConfig(mission=MissionParams(max_duration_s=0.1)), engine=engine)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batches", default="1,100,1000", help="comma-separated batch sizes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--engine", default="auto", choices=ENGINES, help="kernel (compiled) or numpy (reference)")
    p.add_argument("--scenarios", default=None, help="also fly this scenario/grid file's configurations")
    args = p.parse_args(argv)
    print(f"engine {args.engine}; {os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f}; kernel start-up {warm_up(args.engine):.2f} s", flush=True)
    print(f"{'flights':>8} {'wall s':>9} {'flight-s':>10} {'real-time x':>12} {'per flight x':>13} {'CPU s':>8} "
          f"{'x per CPU-s':>12} {'landed':>7} {'peak MiB':>9}")
    runs = [(str(int(x)), lambda n=int(x): measure(n, args.seed, args.engine)) for x in args.batches.split(",") if x]
    if args.scenarios:
        runs.append(("attacked", lambda: measure_attacked(args.scenarios, args.seed, args.engine)))
    for label, run in runs:
        r = run()
        n = r["flights"]
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{label:>8} {r['wall_s']:>9.2f} {r['sim_s']:>10.0f} {r['rtf']:>12.0f} {r['rtf'] / n:>13.2f} "
              f"{r['cpu_s']:>8.2f} {r['rtf_cpu']:>12.0f} {r['landed']:>7} {peak:>9.0f}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
