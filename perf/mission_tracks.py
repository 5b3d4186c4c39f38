"""How closely mission files are flown: the test missions in the kernel (one batch) and in the sitl.

    python -m perf.mission_tracks

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


if __name__ == "__main__":
    main()
