"""Wall time and peak memory of generating a profile's dataset (normal + attacked in both modes).

    python -m perf.generate_speed [--profile paper] [--out DIR] [--seed 0] [--layout compact|paper]

Prints the time of each phase as it goes and, at the end, total wall time, peak resident memory
(this process and, separately, its largest child: the writer process) and the number of flights,
files and bytes written, per flight too. The goal for ``paper`` (100 normal flights + 2048
configurations x 2 modes) is under 10 minutes [5], 6 GB peak and 5 GB [2] on disk on 2 cores.

``--timing-ratio``: the same generation with realistic and with ideal message timing, one after the
other in one run (issue 51 acceptance 1: realistic at most 1.3x ideal), wall and CPU seconds of each
(this process and its children: the csv-mode process and the writer) and the ratios::

    python -m perf.generate_speed --profile paper --flights 16 --timing-ratio

``--csv-mode N``: csv mode alone, CPU seconds per flight and a hash of its output, on ``N`` paper-grid
configurations from ``--skip`` (the generator's order) replayed on the csv-source flights of the first
16 normal flights of ``--flights 16`` (11 recordings, ``--timing``), as csv mode's batch replays them;
run it with two versions for speed and same output::

    python -m perf.generate_speed --csv-mode 128 --skip 0 --timing realistic
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

from scart_bench.dataset import open_dataset
from scart_bench.generator.generate import generate_dataset


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--profile", default="paper")
    p.add_argument("--out", default=None, help="dataset folder (default: a temporary folder, removed after)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--format", default="parquet")
    p.add_argument("--layout", default=None, help="compact | paper (default: compact for Parquet)")
    p.add_argument("--flights", type=int, default=None, help="normal flights (default: the profile's)")
    p.add_argument("--scenarios", default=None, help="a scenario, grid or sweep file instead of the profile's grid")
    p.add_argument("--timing-ratio", action="store_true", help="realistic against ideal timing, in one run")
    p.add_argument("--csv-mode", type=int, default=0, metavar="N", help="csv mode alone on N paper configurations")
    p.add_argument("--skip", type=int, default=0, help="with --csv-mode: configurations skipped first")
    p.add_argument("--timing", default="realistic", help="with --csv-mode: the recordings' timing")
    args = p.parse_args(argv)
    if args.csv_mode:
        csv_mode_speed(args.csv_mode, args.skip, args.timing)
        return
    if args.timing_ratio:
        timing_ratio(args)
        return
    tmp = None
    out = Path(args.out) if args.out else Path(tmp := tempfile.mkdtemp()) / args.profile
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:8.1f} s] {msg}", file=sys.stderr, flush=True)

    generate_dataset(args.profile, out, seed=args.seed, fmt=args.format, overwrite=True, log=log,
                     layout=args.layout)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    ds = open_dataset(out)
    files = [f for f in out.rglob("*") if f.is_file()]
    size = sum(f.stat().st_size for f in files)
    counts = ds.manifest["mode"].value_counts().to_dict()
    print(f"profile {args.profile} ({ds.info.get('layout')} layout): {len(ds)} flights {counts}; wall {wall:.1f} s "
          f"({wall / 60:.1f} min); peak memory {peak:.0f} MiB (+ writer {child:.0f} MiB); "
          f"{size / 2**20:.0f} MiB on disk in {len(files)} files ({size / len(ds) / 2**20:.2f} MiB and "
          f"{len(files) / len(ds):.1f} files per flight)")
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)


def cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (the csv-mode process, the writer)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def csv_mode_speed(n: int, skip: int, timing: str) -> None:
    """CPU seconds per flight of csv mode on ``n`` paper configurations and a sha256 of what it returns."""
    import dataclasses

    from perf.layer_speed import hash_csv
    from scart_bench.generator.attacks import RowWriter, _order, csv_applicable, grid_path
    from scart_bench.generator.modes import csv_mode
    from scart_bench.generator.plan import fly_normal_batch, plan_generation
    from scart_bench.generator.profiles import get_profile
    from scart_bench.generator.scart.grid import load_configurations

    cfg = dataclasses.replace(get_profile("paper"), timing=timing).flight_config()
    plan = plan_generation("paper", 0, 16, True, cfg, None, None, 16)
    with tempfile.TemporaryDirectory(prefix="generate_speed_") as tmp:
        (Path(tmp) / "flights").mkdir()
        sources = fly_normal_batch(RowWriter(Path(tmp), "parquet", "compact"), plan, 0, lambda m: None)["csv_source"]
    configs = [c for c in load_configurations(grid_path("paper.toml")) if csv_applicable(c)]
    idx = _order(configs)[skip:skip + n]
    src = [sources[i % len(sources)] for i in idx]
    link = [{t: df for t, df in s[1].items() if t != "truth"} for s in src]
    own = resource.getrusage(resource.RUSAGE_SELF)
    c0 = own.ru_utime + own.ru_stime
    results = csv_mode(link, [configs[i] for i in idx], [s[2] for s in src])
    own = resource.getrusage(resource.RUSAGE_SELF)
    cpu = own.ru_utime + own.ru_stime - c0
    digest = hash_csv(results)
    print(f"csv mode, {timing} timing: {len(idx)} configurations from {skip} on {len(sources)} recordings: "
          f"{cpu:.1f} CPU s, {cpu / len(idx):.3f} per flight; output sha256 {digest[:16]}")


def timing_ratio(args) -> None:
    """Generate with realistic, then ideal timing (same seed, flights and grid); print wall and CPU."""
    import dataclasses

    from scart_bench.generator.profiles import get_profile

    res = {}
    with tempfile.TemporaryDirectory(prefix="generate_speed_") as tmp:
        for timing in ("realistic", "ideal"):
            cfg = dataclasses.replace(get_profile(args.profile), timing=timing).flight_config()
            t0, c0 = time.perf_counter(), cpu_seconds()
            generate_dataset(args.profile, Path(tmp) / timing, seed=args.seed, fmt=args.format, n_normal=args.flights,
                             config=cfg, scenarios=args.scenarios, layout=args.layout)
            res[timing] = (time.perf_counter() - t0, cpu_seconds() - c0)
            counts = open_dataset(Path(tmp) / timing).manifest["mode"].value_counts().to_dict()
            print(f"{timing} timing: {counts}, wall {res[timing][0]:.1f} s, CPU {res[timing][1]:.1f} s", flush=True)
            shutil.rmtree(Path(tmp) / timing)
    (wr, cr), (wi, ci) = res["realistic"], res["ideal"]
    print(f"realistic / ideal: {wr / wi:.2f}x wall, {cr / ci:.2f}x CPU (issue 51 asks at most 1.3x)")


if __name__ == "__main__":
    main()
