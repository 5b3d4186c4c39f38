"""What ``attack --dataset`` costs per copy on all-topic ULogs: full copies (before) against copies that
store what the attack changed and share the rest with their source flight (now), in one run.

    python -m perf.attack_speed [--logs GLOB] [--grid TOML] [--actions bias,drift] [--levels 2]

Imports the logs with every topic (split auto) into a temp folder once, then attacks two copies of
that dataset with the grid (default data/scenarios/quick.toml cut to ``--actions`` x ``--levels``,
both targets and triggers, so that it runs in minutes; ``--actions all --levels all`` for the whole
grid): ``attack_dataset(full_copies=True)``, the old path, and the default. Prints per path the
copies, the wall and CPU time, copies per second and the flights' size on disk, the ratios (wall, and
CPU seconds, which a loaded shared machine disturbs less) and the load average before and after, and checks that
every copy reads back the same tables in both datasets (navigator and simulator, every topic and the
combined most_frequent table).
"""

from __future__ import annotations

import argparse
import glob
import os
import shutil
import tempfile
import time
import tomllib
from pathlib import Path

import pandas as pd
import tomli_w

from scart_bench.dataset import open_dataset, read_view
from scart_bench.generator.logs.offline import attack_dataset, import_logs

SOURCES = ("train", "validation", "test", "csv_source")


def cut_grid(grid: Path, actions: str, levels: str, out: Path) -> Path:
    """``grid`` with only ``actions`` and ``levels`` on its axes ("all": as it is)."""
    spec = tomllib.loads(grid.read_text())
    axes = spec["grid"]["axes"]
    if actions != "all":
        axes["action"] = [a for a in axes["action"] if a in actions.split(",")]
    if levels != "all":
        axes["level"] = [int(v) for v in levels.split(",")]
    out.write_bytes(tomli_w.dumps(spec).encode())
    return out


def size_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 1e6


def same_tables(a_path: Path, b_path: Path, ids: list[str]) -> int:
    """Compare every copy's topic tables and combined table between two datasets; returns tables compared."""
    a, b = open_dataset(a_path), open_dataset(b_path)
    n = 0
    for fid in ids:
        for view in ("navigator", "simulator"):
            a.verify(fid)
            b.verify(fid)
            ta, tb = read_view(a.flight_dir(fid), view), read_view(b.flight_dir(fid), view)
            assert list(ta) == list(tb), (fid, view)
            for t in ta:
                pd.testing.assert_frame_equal(ta[t], tb[t], check_exact=True)
                n += 1
            pd.testing.assert_frame_equal(a.flight(fid, view), b.flight(fid, view), check_exact=True)
            n += 1
    return n


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--logs", default="/work/shared/data/ulog/*.ulg", help="logs to import (a glob)")
    p.add_argument("--grid", type=Path, default=Path("data/scenarios/quick.toml"))
    p.add_argument("--actions", default="bias,drift", help="actions of the grid kept (or all)")
    p.add_argument("--levels", default="2", help="levels of the grid kept (or all)")
    p.add_argument("--no-check", action="store_true", help="skip the table-by-table comparison")
    args = p.parse_args(argv)
    logs = sorted(glob.glob(args.logs))
    if not logs:
        raise SystemExit(f"{args.logs}: no log")
    print("load average (1, 5, 15 min) at the start: " + ", ".join(f"{v:.2f}" for v in os.getloadavg()), flush=True)
    with tempfile.TemporaryDirectory(prefix="attack_speed_") as tmp:
        tmp = Path(tmp)
        grid = cut_grid(args.grid, args.actions, args.levels, tmp / "grid.toml")
        t0 = time.perf_counter()
        import_logs(logs, tmp / "base", split="auto")
        print(f"import: {len(logs)} logs with all topics in {time.perf_counter() - t0:.1f} s, "
              f"{size_mb(tmp / 'base'):.1f} MB")
        rates, ids, cpu = {}, {}, {}
        for name, full in (("full copies (before)", True), ("shared with the source (now)", False)):
            folder = tmp / ("full" if full else "shared")
            shutil.copytree(tmp / "base", folder)
            before = size_mb(folder)
            t0, c0 = time.perf_counter(), time.process_time()
            ids[full] = attack_dataset(folder, grid, sources=SOURCES, full_copies=full)
            secs, cpu[full] = time.perf_counter() - t0, time.process_time() - c0
            rates[full] = len(ids[full]) / secs
            print(f"{name}: {len(ids[full])} copies in {secs:.1f} s = {rates[full]:.3f} copies/s "
                  f"({cpu[full]:.1f} CPU s, {len(ids[full]) / cpu[full]:.3f} copies per CPU s), "
                  f"{(size_mb(folder) - before) / max(len(ids[full]), 1):.2f} MB per copy", flush=True)
        print(f"ratio: {rates[False] / rates[True]:.1f}x copies per second (wall), "
              f"{cpu[True] / cpu[False]:.1f}x per CPU second; load average at the end: "
              + ", ".join(f"{v:.2f}" for v in os.getloadavg()), flush=True)
        if not args.no_check:
            assert ids[True] == ids[False]
            n = same_tables(tmp / "full", tmp / "shared", ids[True])
            print(f"check: {n} tables read back identical in both datasets")


if __name__ == "__main__":
    main()
