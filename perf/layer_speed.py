"""Speed of the SCART attack layer: simulation mode and csv mode on paper configurations.

Runs ``simulation_mode`` and ``csv_mode`` on the first ``--n`` configurations of a grid in the
generator's order (``generator.attacks._order``), prints the wall time of each and a hash of every
output (BatchResult arrays, event logs, csv tables, windows), so two versions of the layer can be
compared for speed and byte-identical output::

    python -m perf.layer_speed --n 256 --out before.json
    python -m perf.layer_speed --n 256 --out after.json --compare before.json

``--csv-paths per-message,replay`` runs csv mode through both replays of generator.scart.replay in one
run (the call at every message time, as before issue 51, and the replay that calls the layer only
where a call can matter) and prints CPU seconds per flight, the ratio and whether the outputs match.
The sources are flown with ``--timing`` (realistic by default: every flight its own schedule).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time

import numpy as np


def _hash_batch(batch, layer) -> str:
    h = hashlib.sha256()
    for view in (batch.simulator, batch.navigator):
        for topic in sorted(view):
            h.update(topic.encode())
            for arr in view[topic]:
                h.update(np.ascontiguousarray(arr).tobytes())
    for name in ("exit_step", "waypoints", "wind", "gps_rejections"):
        h.update(np.ascontiguousarray(getattr(batch, name)).tobytes())
    h.update(repr(batch.status).encode())
    h.update(repr([(e.flight, e.timestamp_us, e.event, e.scenario_id, e.kind) for e in layer.events]).encode())
    return h.hexdigest()


def hash_csv(results) -> str:
    """sha256 of what csv mode returns (every topic table, windows and events), to compare two versions."""
    h = hashlib.sha256()
    for nav, windows, events in results:
        for topic in sorted(nav):
            df = nav[topic]
            h.update(topic.encode() + repr(list(df.columns)).encode())
            for c in df.columns:
                arr = df[c].to_numpy()
                h.update(repr(arr.tolist()).encode() if arr.dtype == object else np.ascontiguousarray(arr).tobytes())
        h.update(repr(windows).encode() + repr(events).encode())
    return h.hexdigest()


def main(argv: list[str] | None = None) -> None:
    from scart_bench.generator.attacks import _order, attack_seeds, grid_path, strip_labels
    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.modes import csv_mode, simulation_mode
    from scart_bench.generator.scart.grid import load_configurations
    from scart_bench.generator.telemetry.tables import normal_record

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="paper.toml")
    ap.add_argument("--n", type=int, default=256, help="configurations (first n in the generator's order)")
    ap.add_argument("--skip", type=int, default=0, help="configurations skipped first")
    ap.add_argument("--sources", type=int, default=4, help="normal flights used as csv sources")
    ap.add_argument("--modes", default="simulation,csv", help="comma-separated: simulation, csv")
    ap.add_argument("--out", help="write times and hashes here (JSON)")
    ap.add_argument("--compare", help="a JSON of an earlier run: print the speedup and whether outputs match")
    ap.add_argument("--csv-paths", default="", help="csv mode through these replays in one run: per-message,replay")
    ap.add_argument("--timing", default=None, help="the sources' message timing (default: the generator's)")
    args = ap.parse_args(argv)

    configs = load_configurations(grid_path(args.grid))
    seeds = attack_seeds(0, len(configs))
    order = _order(configs)[args.skip:args.skip + args.n]
    cfg = FlightConfig() if args.timing is None else FlightConfig(timing=args.timing)
    simulate([1], cfg)  # compile / warm up the kernel
    modes = args.modes.split(",")
    t_sim, sim_hash, t_csv, csv_hash = float("nan"), "", float("nan"), ""
    if "simulation" in modes:
        t0 = time.perf_counter()
        batch, layer = simulation_mode([seeds[i] for i in order], [configs[i] for i in order], cfg)
        t_sim = time.perf_counter() - t0
        sim_hash = _hash_batch(batch, layer)

    link_idx = [i for i in order if any(s.injection_point == "link" for s in configs[i])]
    if "csv" in modes:
        src_seeds = [10_000 + k for k in range(args.sources)]
        normal = simulate(src_seeds, cfg)
        sources = [strip_labels(normal_record(normal, j, f"normal-{j}", "csv_source", {}).navigator)
                   for j in range(len(src_seeds))]
        link = [{t: df for t, df in sources[k % len(sources)].items() if t != "truth"} for k in range(len(link_idx))]
        t0 = time.perf_counter()
        results = csv_mode(link, [configs[i] for i in link_idx],
                           [src_seeds[k % len(sources)] for k in range(len(link_idx))])
        t_csv = time.perf_counter() - t0
        csv_hash = hash_csv(results)
    if args.csv_paths:
        _csv_paths(args.csv_paths.split(","), link, [configs[i] for i in link_idx],
                   [src_seeds[k % len(sources)] for k in range(len(link_idx))], args.timing or cfg.timing)
        return
    res = {"n": len(order), "n_csv": len(link_idx), "sim_s": round(t_sim, 2), "csv_s": round(t_csv, 2),
           "sim_hash": sim_hash, "csv_hash": csv_hash}
    print(json.dumps(res))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f)
    if args.compare:
        with open(args.compare) as f:
            ref = json.load(f)
        if "simulation" in modes:
            print(f"simulation mode: {ref['sim_s']:.1f} s -> {t_sim:.1f} s ({ref['sim_s'] / t_sim:.2f}x), "
                  f"identical: {ref['sim_hash'] == sim_hash}")
        if "csv" in modes:
            print(f"csv mode: {ref['csv_s']:.1f} s -> {t_csv:.1f} s ({ref['csv_s'] / t_csv:.2f}x), "
                  f"identical: {ref['csv_hash'] == csv_hash}")


def _csv_paths(paths: list[str], link: list, configs: list, seeds: list, timing: str) -> None:
    """csv mode on the same flights through each replay path, CPU seconds per flight and output hashes."""
    import os

    from scart_bench.generator.modes import csv_mode

    cpu, hashes = {}, {}
    for path in paths:
        if path not in ("per-message", "replay"):
            raise SystemExit(f"--csv-paths: {path!r}: expected per-message or replay")
        os.environ["SCART_BENCH_CSV_REPLAY"] = path
        t0, c0 = time.perf_counter(), time.process_time()
        results = csv_mode(link, configs, seeds)
        cpu[path], wall = time.process_time() - c0, time.perf_counter() - t0
        hashes[path] = hash_csv(results)
        print(f"csv mode, {path} replay: {len(link)} flights ({timing} timing) in {cpu[path]:.1f} CPU s "
              f"({cpu[path] / len(link):.3f} per flight), wall {wall:.1f} s", flush=True)
    os.environ.pop("SCART_BENCH_CSV_REPLAY", None)
    if len(paths) == 2:
        a, b = paths
        print(f"ratio {a}/{b}: {cpu[a] / cpu[b]:.2f}x CPU; identical outputs: {hashes[a] == hashes[b]}")


if __name__ == "__main__":
    main()
