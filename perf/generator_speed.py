"""Throughput of the flight generator: flight-steps per second, per core and per thread count.

    python -m perf.generator_speed [--batches 1,100,1000] [--threads 1,2] [--seed 0] [--engine auto]
                                   [--scenarios quick.toml] [--crazyflow PYTHON] [--repeat 1]

For each batch size and thread count (numba's worker threads, which also draw the flights' noise),
flies that many default-mission flights in one batch and prints wall time, simulated seconds, the
aggregate real-time factor, flight-steps per wall second, CPU seconds (all threads), flight-steps
per CPU second (the per-core figure: what one core gives; on a shared machine it is much steadier
than the wall figures), the speed-up over the first thread count and peak memory. The first line
is the kernel's start-up (loading or, on a fresh machine, compiling the numba kernel), which a
dataset run pays once. The machine's load average is printed before and after.

With ``--scenarios`` (a scenario, grid or sweep file), one more line flies every configuration of
it in simulation mode, as one batch (the SCART layer in the loop).

With ``--crazyflow PYTHON`` (a Python that has crazyflow installed, e.g. a side venv; the default
is ``$SCART_CRAZYFLOW_PYTHON`` or ``/tmp/cfvenv/bin/python`` when it exists), crazyflow's
simulator flies the same number of drones for the same simulated seconds in that interpreter, on
one thread, in the same run; its flight-steps and real-time factor per CPU second are printed and
our per-core figures are given as ratios to it (crazyflow steps dynamics only, in float32; we step
sensors, the estimator, control and the navigator too). PX4 SITL + Gazebo flies one flight at about
1x real time.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import time
from pathlib import Path

from scart_bench.generator.engine.simulate import ENGINES, STEP_US, FlightConfig, simulate


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _figures(n: int, wall: float, cpu: float, batch) -> dict[str, float]:
    steps = float((batch.exit_step + 1).sum())
    simulated = steps * STEP_US / 1e6
    return {"flights": n, "wall_s": wall, "cpu_s": cpu, "sim_s": simulated, "steps": steps,
            "rtf": simulated / wall, "rtf_cpu": simulated / max(cpu, 1e-9), "steps_per_s": steps / wall,
            "steps_per_cpu_s": steps / max(cpu, 1e-9), "landed": sum(s == "landed" for s in batch.status)}


def measure(n: int, seed: int = 0, engine: str = "auto") -> dict[str, float]:
    """Fly ``n`` flights; returns wall and CPU seconds, simulated seconds, flight-steps and rates."""
    c0, t0 = _cpu(), time.perf_counter()
    batch = simulate(list(range(seed, seed + n)), engine=engine)
    return _figures(n, time.perf_counter() - t0, _cpu() - c0, batch)


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
    return _figures(len(configs), time.perf_counter() - t0, _cpu() - c0, batch)


def warm_up(engine: str) -> float:
    """Seconds to load (or compile) the kernel: one 0.1 s flight."""
    from scart_bench.generator.params import MissionParams

    t0 = time.perf_counter()
    simulate([0], FlightConfig(mission=MissionParams(max_duration_s=0.1)), engine=engine)
    return time.perf_counter() - t0


def set_threads(n: int) -> int:
    """Use ``n`` numba worker threads (at most numba's pool); returns the number set."""
    import numba

    n = max(1, min(int(n), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


# One thread for XLA before jax is imported; crazyflow's own simulator, its default physics.
_CRAZYFLOW = r"""
import json, os, resource, sys, time
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
os.environ.setdefault("JAX_PLATFORMS", "cpu")
import jax
from crazyflow.sim import Sim
n, seconds = int(sys.argv[1]), float(sys.argv[2])
sim = Sim(n_worlds=n, n_drones=1)
chunk = sim.freq  # one simulated second per call: compiled once (the warm-up), then reused
calls = max(1, int(round(seconds)))
steps = chunk * calls
sim.step(chunk)
jax.block_until_ready(sim.data.states.pos)
r0 = resource.getrusage(resource.RUSAGE_SELF); t0 = time.perf_counter()
for _ in range(calls):
    sim.step(chunk)
jax.block_until_ready(sim.data.states.pos)
r1 = resource.getrusage(resource.RUSAGE_SELF)
cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
print(json.dumps({"wall_s": time.perf_counter() - t0, "cpu_s": cpu, "steps": float(n * steps), "freq": sim.freq,
                  "sim_s": n * steps / sim.freq}))
"""


def crazyflow_python(arg: str | None) -> str | None:
    """The interpreter with crazyflow: ``arg``, $SCART_CRAZYFLOW_PYTHON, or /tmp/cfvenv/bin/python if present."""
    cand = arg or os.environ.get("SCART_CRAZYFLOW_PYTHON") or "/tmp/cfvenv/bin/python"
    return cand if cand and Path(cand).exists() else None


def measure_crazyflow(python: str, n: int, seconds: float) -> dict[str, float] | None:
    """crazyflow flying ``n`` drones for ``seconds`` simulated seconds each, one thread (None if it fails)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    try:
        out = subprocess.run([python, "-c", _CRAZYFLOW, str(n), str(seconds)], capture_output=True, text=True,
                             env=env, timeout=1800, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
    except (subprocess.SubprocessError, OSError, ValueError, IndexError) as exc:
        print(f"crazyflow: not measured ({type(exc).__name__}: {str(exc).strip()[-300:]})")
        return None
    r["steps_per_cpu_s"] = r["steps"] / max(r["cpu_s"], 1e-9)
    r["rtf_cpu"] = r["sim_s"] / max(r["cpu_s"], 1e-9)
    return r


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batches", default="1,100,1000", help="comma-separated batch sizes")
    p.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    p.add_argument("--repeat", type=int, default=1, help="runs of each line (on a shared machine: the spread)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--engine", default="auto", choices=ENGINES, help="kernel (compiled) or numpy (reference)")
    p.add_argument("--scenarios", default=None, help="also fly this scenario/grid file's configurations")
    p.add_argument("--crazyflow", default=None, help="a Python with crazyflow installed (side venv)")
    args = p.parse_args(argv)
    threads = [int(t) for t in args.threads.split(",") if t]
    print(f"engine {args.engine}; {os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f}; kernel start-up {warm_up(args.engine):.2f} s", flush=True)
    print(f"{'flights':>8} {'threads':>7} {'wall s':>8} {'flight-s':>9} {'real-time x':>11} {'steps/s':>10} "
          f"{'CPU s':>7} {'steps/CPU-s':>11} {'x per CPU-s':>11} {'speed-up':>8} {'landed':>6} {'peak MiB':>8}")
    per_core: dict[int, float] = {}
    sim_seconds: dict[int, float] = {}
    for n in (int(x) for x in args.batches.split(",") if x):
        first = None
        for t in threads:
            used = set_threads(t)
            for _ in range(max(1, args.repeat)):
                r = measure(n, args.seed, args.engine)
                first = first or r["steps_per_s"]
                per_core[n] = max(per_core.get(n, 0.0), r["steps_per_cpu_s"])
                sim_seconds[n] = r["sim_s"] / n
                peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
                print(f"{n:>8} {used:>7} {r['wall_s']:>8.2f} {r['sim_s']:>9.0f} {r['rtf']:>11.0f} "
                      f"{r['steps_per_s']:>10.3g} {r['cpu_s']:>7.2f} {r['steps_per_cpu_s']:>11.3g} "
                      f"{r['rtf_cpu']:>11.0f} {r['steps_per_s'] / first:>7.2f}x {r['landed']:>6} {peak:>8.0f}",
                      flush=True)
    set_threads(max(threads))
    if args.scenarios:
        r = measure_attacked(args.scenarios, args.seed, args.engine)
        print(f"attacked {r['flights']} flights ({max(threads)} threads): wall {r['wall_s']:.2f} s, "
              f"{r['steps_per_s']:.3g} steps/s, {r['steps_per_cpu_s']:.3g} steps/CPU-s, landed {r['landed']}")
    python = crazyflow_python(args.crazyflow)
    if python is None:
        print("crazyflow: not installed (python3 -m venv /tmp/cfvenv && /tmp/cfvenv/bin/pip install crazyflow)")
    else:
        for n, ours in per_core.items():
            cf = measure_crazyflow(python, n, sim_seconds[n])
            if cf is None:
                break
            print(f"crazyflow {n:>5} drones, {cf['sim_s'] / n:.0f} s at {cf['freq']:.0f} Hz, 1 thread: "
                  f"{cf['steps_per_cpu_s']:.3g} steps/CPU-s ({1e6 / cf['steps_per_cpu_s']:.2f} us per flight-step), "
                  f"{cf['rtf_cpu']:.0f}x real time per CPU-s; ours/crazyflow per core: "
                  f"{ours / cf['steps_per_cpu_s']:.2f} (flight-steps), "
                  f"{ours * STEP_US / 1e6 / cf['rtf_cpu']:.2f} (simulated seconds)", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
