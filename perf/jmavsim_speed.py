"""The same missions flown by the built-in engine and by jMAVSim (lockstep) with the project's flight software.

    python -m perf.jmavsim_speed [--jmavsim JAR_OR_BUILD | --build ../shared/sim/jmavsim] [--flights 3]

Per flight and engine: simulated time, wall time and speed (multiple of real time), the worst and
mean distance of the true track from each leg's line outside turns (5 m from either end of a leg),
the distance from home at touchdown, and the accelerometer's z noise while hovering at the take-off
point (HIGHRES_IMU telemetry, 50 Hz, both engines). jMAVSim comes from ``--jmavsim`` / ``$SCART_JMAVSIM`` or is built from ``--build`` into a
temporary folder.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np


def leg_errors(xy: np.ndarray, phase: np.ndarray, item: np.ndarray, wps: np.ndarray) -> tuple[float, float]:
    """(worst, mean) distance (m) of the track from the line of the leg it flies, outside turns."""
    worst, parts = 0.0, []
    for k in range(1, len(wps)):
        a, b = wps[k - 1, :2], wps[k, :2]
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        along, cross = (xy - a) @ u, (xy - a) @ np.array([-u[1], u[0]])
        on = (phase == 2) & (item == k) & (along > 5.0) & (along < length - 5.0)
        if on.any():
            worst = max(worst, float(np.abs(cross[on]).max()))
            parts.append(np.abs(cross[on]))
    return worst, float(np.concatenate(parts).mean()) if parts else float("nan")


def builtin(seed: int) -> dict:
    from scart_bench.generator.engine.simulate import simulate

    t0 = time.perf_counter()
    r = simulate([seed], engine="numpy")
    wall = time.perf_counter() - t0
    st, truth, _ = r.simulator["truth"]
    ss, sp, _ = r.simulator["setpoint"]
    keep = st <= r.exit_step[0]
    st, truth = st[keep], truth[0][keep]
    idx = np.clip(np.searchsorted(ss, st, side="right") - 1, 0, None)
    item = sp[0, idx, 4].astype(int)
    phase = np.where((item >= 1) & (item < r.waypoints.shape[1]) & (truth[:, 2] < -5.0), 2, 0)
    worst, mean = leg_errors(truth[:, :2], phase, item, r.waypoints[0])
    sim_s = (int(r.exit_step[0]) + 1) * 0.004
    hs, imu, _ = r.simulator["highres_imu"]
    return {"engine": "built-in (numpy step)", "sim_s": sim_s, "wall_s": wall, "worst": worst, "mean": mean,
            "home": float(np.linalg.norm(truth[-1, :2])), "status": r.status[0],
            "hover_acc_z": _hover_std(hs, imu[0][:, 2], st, item, truth[:, 2], truth[:, 5])}


def jmavsim(seed: int, jar) -> dict:
    from scart_bench.generator.hil.flights import fly_jmavsim

    f = fly_jmavsim(jar, seed=seed)
    est = f.estimate
    idx = np.clip(np.searchsorted(est[:, 0], f.truth[:, 10], side="right") - 1, 0, None)
    phase, item = est[idx, 4].astype(int), est[idx, 5].astype(int)
    worst, mean = leg_errors(f.truth[:, 1:3], phase, item, f.autopilot.waypoints)
    steps, acc = f.autopilot.records.table("highres_imu", after=False)
    return {"engine": "jMAVSim (lockstep)", "sim_s": f.sim_s, "wall_s": f.wall_s, "worst": worst, "mean": mean,
            "home": float(np.linalg.norm(f.truth[-1, 1:3])), "status": f.status,
            "hover_acc_z": _hover_std(steps, acc[:, 2], f.truth[:, 10], item, f.truth[:, 3], f.truth[:, 6])}


def _hover_std(steps, acc_z, truth_steps, item, z, vz) -> float:
    """Std of the accelerometer's z axis while hovering at the take-off point (item 0, above 9 m,
    climbing or sinking slower than 0.1 m/s)."""
    hover = truth_steps[(item == 0) & (z < -9.0) & (np.abs(vz) < 0.1)]
    if len(hover) < 50:
        return float("nan")
    sel = (steps >= hover[10]) & (steps <= hover[-10])
    return float(np.std(acc_z[sel]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.jmavsim_speed", description=__doc__.split("\n")[0])
    p.add_argument("--jmavsim", default=None, help="jmavsim_run.jar or its build folder (default $SCART_JMAVSIM)")
    p.add_argument("--build", default=None, help="a jMAVSim source folder to build into a temporary folder first")
    p.add_argument("--flights", type=int, default=3)
    args = p.parse_args(argv)
    jar = args.jmavsim
    with tempfile.TemporaryDirectory() as tmp:
        if args.build:
            from scart_bench.generator.hil.jmavsim import build

            jar = build(args.build, tmp)
        print("| seed | engine | status | simulated s | wall s | x real time | worst off line m | mean off line m "
              "| touchdown from home m | accel z std at hover m/s^2 |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for seed in range(args.flights):
            for row in (builtin(seed), jmavsim(seed, jar)):
                print(f"| {seed} | {row['engine']} | {row['status']} | {row['sim_s']:.1f} | {row['wall_s']:.1f} | "
                      f"{row['sim_s'] / row['wall_s']:.1f} | {row['worst']:.2f} | {row['mean']:.2f} | "
                      f"{row['home']:.2f} | {row['hover_acc_z']:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
