"""How closely mission files are flown: the test missions in the kernel (one batch) and in the sitl;
and what the quick profile's mission mix flies.

    python -m perf.mission_tracks
    python -m perf.mission_tracks --mix [--tracks 20] [--flights 200] [--seed 0]

``--mix``: the first ``--tracks`` flights of a quick dataset of ``--seed`` (their seeds as
``generate`` draws them) flown by the kernel with the quick profile's mixes, drawn in
docs/missions_quick_mix.png, and the distributions of path length, altitude, speed and duration over
``--flights`` of them, per family and overall (a markdown table, docs/missions.md).

For tests/data/missions/inspection.plan and delivery.waypoints: the largest and mean distance of
the true track from the legs more than 5 m from any item, each hold's stated time and the time the
vehicle stayed within 1.5 m of its item, where it landed and how long the flight took
(docs/missions.md). The sitl flights are flown by the test's pymavlink ground station, in lockstep.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def metrics(t: np.ndarray, truth: np.ndarray, items: np.ndarray) -> str:
    from test_mission_files import TURN_M, _longest_run, _segment_distance

    pos = truth[:, :3]
    ne = pos[pos[:, 2] < -1.0, :2]
    near = np.min([np.hypot(*(ne - it[:2]).T) for it in items], axis=0)
    legs = [(items[k - 1, :2], items[k, :2]) for k in range(1, len(items))
            if np.hypot(*(items[k, :2] - items[k - 1, :2])) > 2 * TURN_M]
    off = np.min([_segment_distance(ne, a, b) for a, b in legs], axis=0)[near > TURN_M]
    holds = []
    for k in np.flatnonzero(items[:, 4] > 0):
        at = (np.hypot(*(pos[:, :2] - items[k, :2]).T) < 1.5) & (np.abs(pos[:, 2] - items[k, 2]) < 1.0)
        holds.append(f"{items[k, 4]:g} s -> {_longest_run(at, t):.1f} s")
    return (f"off the legs max {off.max():.2f} m (mean {off.mean():.2f} m); holds {', '.join(holds)}; "
            f"landed {np.hypot(*(pos[-1, :2] - items[-1, :2])):.2f} m from its spot; flight {t[-1]:.1f} s")


def main() -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_mission_files import CRUISE, PLAN, SEEDS, WPL, _fly_in_sitl

    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.flight_software.mission_files import read_missions, with_missions
    from scart_bench.generator.params import DT, MissionParams

    missions = read_missions([PLAN, WPL])
    cfg = with_missions(FlightConfig(mission=MissionParams(ground_phase=False)), missions)
    r = simulate(SEEDS, cfg, engine="kernel")
    steps, vals, _ = r.simulator["truth"]
    for i, seed in enumerate(SEEDS):
        m = missions[seed % len(missions)]
        n = int(np.searchsorted(steps, r.exit_step[i], side="right"))
        print(f"kernel {m.name}: {metrics(steps[:n] * DT, vals[i, :n], m.navigator_items(CRUISE))}", flush=True)
    for path, m in zip((PLAN, WPL), missions):
        t, truth, home, _ = _fly_in_sitl(path, seed=3)
        rel = truth.copy()
        rel[:, :3] -= home
        print(f"sitl {m.name}: {metrics(t, rel, m.navigator_items(CRUISE))}", flush=True)


def flown_figures(truth: np.ndarray, t: np.ndarray) -> dict[str, float]:
    """Path length (m, horizontal), highest altitude (m), mean speed while moving (m/s, faster than
    0.5 m/s) and duration (s, boot to the end of the log) of one flight's true track."""
    pos = truth[:, :3]
    step = np.hypot(*np.diff(pos[:, :2], axis=0).T)
    speed = np.hypot(truth[:, 3], truth[:, 4])
    moving = speed > 0.5
    return {"path_m": float(step.sum()), "altitude_m": float(-pos[:, 2].min()),
            "speed_ms": float(speed[moving].mean()) if moving.any() else 0.0, "duration_s": float(t[-1])}


def mix_report(tracks: int = 20, flights: int = 200, seed: int = 0,
               figure: Path = ROOT / "docs" / "missions_quick_mix.png") -> str:
    import time

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scart_bench.generator.engine.flight_batch import flight_summaries
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.params import DT
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.profiles import PROFILES

    cfg = PROFILES["quick"].flight_config()
    seeds = normal_seeds(seed, max(tracks, flights))
    t0 = time.perf_counter()
    r = simulate(seeds, cfg, engine="kernel")
    wall = time.perf_counter() - t0
    info = flight_summaries(seeds, cfg)
    steps, vals, _ = r.simulator["truth"]
    rows = []
    for i in range(len(seeds)):
        n = int(np.searchsorted(steps, r.exit_step[i], side="right"))
        rows.append({**flown_figures(vals[i, :n], steps[:n] * DT), "family": info[i]["family"],
                     "airframe": info[i]["airframe"], "status": r.status[i], "n": n})
    cols = 5
    fig, axes = plt.subplots(-(-tracks // cols), cols, figsize=(3.2 * cols, 3.2 * -(-tracks // cols)))
    for i, ax in enumerate(np.ravel(axes)):
        if i >= tracks:
            ax.axis("off")
            continue
        n = rows[i]["n"]
        ax.plot(vals[i, :n, 1], vals[i, :n, 0], lw=0.8)
        ax.plot(0, 0, "k^", ms=5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{rows[i]['family']} / {rows[i]['airframe']}\n{rows[i]['altitude_m']:.0f} m up, "
                     f"{rows[i]['duration_s']:.0f} s", fontsize=8)
        ax.tick_params(labelsize=6)
    fig.suptitle(f"20 flights of the quick profile's mix (seed {seed}): true tracks, east (x) / north (y) in m; "
                 "home at the triangle", fontsize=10)
    fig.tight_layout()
    fig.savefig(figure, dpi=80)
    stats = rows[:flights]
    keys = (("path_m", "path length (m)"), ("altitude_m", "altitude (m)"), ("speed_ms", "speed (m/s)"),
            ("duration_s", "duration (s)"))
    status = ", ".join(f"{s} {sum(x['status'] == s for x in stats)}" for s in ("landed", "timeout", "crashed"))
    out = [f"{len(stats)} flights, seed {seed}; kernel wall {wall:.1f} s for {len(seeds)} flights; status: {status}",
           "", "| flights | n | " + " | ".join(k[1] + ": median [5-95 %]" for k in keys) + " |",
           "|---|---|" + "---|" * len(keys)]
    groups = [("all", stats)] + [(f, [x for x in stats if x["family"] == f]) for f in sorted({x["family"] for x in stats})]
    groups += [(f"airframe {a}", [x for x in stats if x["airframe"] == a]) for a in sorted({x["airframe"] for x in stats})]
    for name, g in groups:
        cells = []
        for k, _ in keys:
            v = np.array([x[k] for x in g])
            lo, med, hi = np.percentile(v, [5, 50, 95])
            cells.append(f"{med:.0f} [{lo:.0f}-{hi:.0f}]" if k != "speed_ms" else f"{med:.1f} [{lo:.1f}-{hi:.1f}]")
        out.append(f"| {name} | {len(g)} | " + " | ".join(cells) + " |")
    return "\n".join(out)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mix", action="store_true", help="the quick profile's mix: tracks figure and distributions")
    ap.add_argument("--tracks", type=int, default=20)
    ap.add_argument("--flights", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    if a.mix:
        print(mix_report(a.tracks, a.flights, a.seed))
    else:
        main()
