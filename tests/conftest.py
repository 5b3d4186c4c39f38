"""Shared fixtures: flights are expensive, so each batch is flown once per test session."""

from __future__ import annotations

import numpy as np
import pytest

from scart_bench.generator.scart.scenario import load_scenarios

SCENARIOS = "data/scenarios"


@pytest.fixture(scope="session")
def normal_fleet():
    """20 normal flights with different seeds (and so different winds), flown as one batch."""
    from scart_bench.generator.engine.simulate import simulate

    return simulate(list(range(100, 120)))


@pytest.fixture(scope="session")
def attacked_fleet():
    """One seed flown four times in one batch: normal, link GPS spoofing, sensor GPS jump, sensor drift."""
    from scart_bench.generator.modes import simulation_mode

    spoof = load_scenarios(f"{SCENARIOS}/gps_spoof.toml")
    jump = load_scenarios(f"{SCENARIOS}/sensor_gps_jump.toml")
    drift = load_scenarios(f"{SCENARIOS}/sensor_gps_drift.toml")
    batch, layer = simulation_mode([5, 5, 5, 5], [[], spoof, jump, drift])
    return batch, layer, {"normal": 0, "spoof": 1, "jump": 2, "drift": 3}


@pytest.fixture(scope="session")
def quick_dataset(tmp_path_factory):
    """A small dataset of the quick profile: 6 normal flights and the quick grid in both modes."""
    from scart_bench.generator.generate import generate_dataset

    out = tmp_path_factory.mktemp("datasets") / "quick"
    return generate_dataset("quick", out, seed=3, n_normal=6)


def truth(batch, i):
    """(steps, truth table) of flight ``i`` up to its end."""
    steps, vals, _ = batch.simulator["truth"]
    keep = steps <= batch.exit_step[i]
    return steps[keep], vals[i][keep]


def distance_to_path(points_ne: np.ndarray, waypoints_ne: np.ndarray) -> np.ndarray:
    """Distance of each point to the polyline through the waypoints (m)."""
    best = np.full(points_ne.shape[0], np.inf)
    for a, b in zip(waypoints_ne[:-1], waypoints_ne[1:]):
        ab = b - a
        denom = max(float(ab @ ab), 1e-9)
        t = np.clip(((points_ne - a) @ ab) / denom, 0.0, 1.0)
        proj = a + t[:, None] * ab
        best = np.minimum(best, np.linalg.norm(points_ne - proj, axis=1))
    return best
