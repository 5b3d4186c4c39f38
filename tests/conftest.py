"""Shared fixtures: flights are expensive, so each batch is flown once per test session."""

from __future__ import annotations

import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock

from scart_bench.generator.scart.scenario import load_scenarios

SCENARIOS = "data/scenarios"


def _shared_root(tmp_path_factory) -> Path:
    """A folder of this test session that every xdist worker sees (the workers' base temp's parent)."""
    root = tmp_path_factory.getbasetemp()
    return root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root


def _flown_once(tmp_path_factory, name: str, fly):
    """``fly()``'s result, computed by the first xdist worker that asks and pickled for the others
    (each worker used to fly the same batch again: 30-60 s each on a loaded 2-core machine)."""
    root = _shared_root(tmp_path_factory)
    path = root / f"{name}.pkl"
    with FileLock(str(root / f"{name}.lock")):
        if path.exists():
            return pickle.loads(path.read_bytes())
        result = fly()
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        tmp.replace(path)  # complete or absent: a worker that dies while writing leaves no half file
        return result


@pytest.fixture(scope="session")
def normal_fleet(tmp_path_factory):
    """20 normal flights with different seeds (and so different winds), flown as one batch."""
    from scart_bench.generator.engine.simulate import simulate

    return _flown_once(tmp_path_factory, "normal-fleet", lambda: simulate(list(range(100, 120))))


def _attacked_fleet():
    from scart_bench.generator.modes import simulation_mode

    spoof = load_scenarios(f"{SCENARIOS}/gps_spoof.toml")
    jump = load_scenarios(f"{SCENARIOS}/sensor_gps_jump.toml")
    drift = load_scenarios(f"{SCENARIOS}/sensor_gps_drift.toml")
    return simulation_mode([5, 5, 5, 5], [[], spoof, jump, drift])


@pytest.fixture(scope="session")
def attacked_fleet(tmp_path_factory):
    """One seed flown four times in one batch: normal, link GPS spoofing, sensor GPS jump, sensor drift."""
    batch, layer = _flown_once(tmp_path_factory, "attacked-fleet", _attacked_fleet)
    return batch, layer, {"normal": 0, "spoof": 1, "jump": 2, "drift": 3}


@pytest.fixture(scope="session")
def quick_dataset(tmp_path_factory):
    """A small dataset of the quick profile: 6 normal flights and the quick grid in both modes.

    Generated once per test session, not once per xdist worker: the first worker to ask writes it
    under a file lock, the others wait and read it (tests only read it)."""
    from scart_bench.generator.generate import generate_dataset

    root = _shared_root(tmp_path_factory)
    out, done = root / "quick-dataset" / "quick", root / "quick-dataset.done"
    with FileLock(str(root / "quick-dataset.lock")):
        if not done.exists():
            shutil.rmtree(out.parent, ignore_errors=True)  # a worker that died while writing it
            generate_dataset("quick", out, seed=3, n_normal=6)
            done.touch()
    return out


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


def bad_profile_key_is_refused(tmp_path: Path, capsys, section: str, key: str, value: str, expected: str) -> None:
    """A profile TOML whose ``[section]`` ``key`` is ``value`` (TOML text): ``generate`` exits 2 with one
    line naming the file and ``expected``, and writes nothing."""
    from scart_bench.cli.main import main

    bad = tmp_path / "bad.toml"
    bad.write_text(f'[profile]\nbase = "quick"\n\n[{section}]\n{key} = {value}\n')
    out = tmp_path / "out"
    code = main(["generate", "--profile", str(bad), "--flights", "1", "--normal-only", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert str(bad) in err and expected in err, err
    assert not out.exists()


def kernel_matches_numpy(cfg, seeds=(3, 4), atol: float = 1e-9):
    """Fly ``seeds`` under ``cfg`` in the numpy reference engine and the compiled kernel and check that
    every simulator message agrees (the same steps, values within ``atol``); the kernel's batch."""
    from scart_bench.generator.engine.simulate import simulate

    ref = simulate(list(seeds), cfg, engine="numpy")
    ker = simulate(list(seeds), cfg, engine="kernel")
    for topic, (steps, vals, _ok) in ref.simulator.items():
        np.testing.assert_array_equal(ker.simulator[topic][0], steps, err_msg=topic)
        np.testing.assert_allclose(ker.simulator[topic][1], vals, rtol=0, atol=atol, err_msg=topic)
    return ker


def kernel_matches_numpy_and_shows(sensors, off: dict, topic: str, seconds: float = 4.0) -> None:
    """A 4 s airborne flight with ``sensors``: the compiled kernel agrees with the numpy reference
    (:func:`kernel_matches_numpy`), and the same kernel flights with the fields of ``off`` changed give another
    ``topic``: what ``sensors`` adds reaches the telemetry."""
    import dataclasses

    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.params import MissionParams

    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=seconds), sensors=sensors)
    ker = kernel_matches_numpy(cfg)
    other = simulate([3, 4], dataclasses.replace(cfg, sensors=dataclasses.replace(sensors, **off)), engine="kernel")
    assert not np.allclose(ker.simulator[topic][1], other.simulator[topic][1]), topic
