"""Aggregate real-time factor of the flight generator: simulated flight-seconds per wall second.

    python -m perf.generator_speed [--batches 1,100,1000] [--seed 0]

For each batch size, flies that many default-mission flights in one vectorised batch and prints
wall time, simulated seconds, the aggregate real-time factor and peak memory. PX4 SITL + Gazebo
flies one flight at about 1x real time.
"""

from __future__ import annotations

import argparse
import resource
import time

from scart_bench.generator.simulate import STEP_US, simulate


def measure(n: int, seed: int = 0) -> dict[str, float]:
    """Fly ``n`` flights; returns wall seconds, simulated seconds and the real-time factor."""
    t0 = time.perf_counter()
    batch = simulate(list(range(seed, seed + n)))
    wall = time.perf_counter() - t0
    simulated = float(((batch.exit_step + 1) * STEP_US).sum() / 1e6)
    landed = sum(s == "landed" for s in batch.status)
    return {"flights": n, "wall_s": wall, "sim_s": simulated, "rtf": simulated / wall, "landed": landed}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batches", default="1,100,1000", help="comma-separated batch sizes")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    print(f"{'flights':>8} {'wall s':>9} {'flight-s':>10} {'real-time x':>12} {'per flight x':>13} {'landed':>7} "
          f"{'peak MiB':>9}")
    for n in (int(x) for x in args.batches.split(",")):
        r = measure(n, args.seed)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{n:>8} {r['wall_s']:>9.1f} {r['sim_s']:>10.0f} {r['rtf']:>12.0f} {r['rtf'] / n:>13.2f} "
              f"{r['landed']:>7} {peak:>9.0f}", flush=True)


if __name__ == "__main__":
    main()
