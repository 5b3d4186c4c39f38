"""Paired flights: every simulation-mode attacked flight has a normal twin, and the impact columns."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from scart_bench.dataset import DatasetWriter, open_dataset
from scart_bench.generator.attacks import SCENARIO_DIR, simulation_flights
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.impact import IMPACT_COLUMNS, TWIN_TOPIC, impact
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.scenario import scenario_from_dict
from scart_bench.generator.telemetry.tables import flight_views
from scart_bench.reports.figures import NORMAL_COLOUR, flight_path

NOISE_ON_ATTITUDE = {
    "id": "attitude-noise-1pc", "injection_point": "link",
    "start": [{"condition": "time_window", "start_s": 10.0}],
    "end": [{"condition": "duration", "seconds": 20.0}],
    "actions": [{"action": "add_white_noise", "target": ["attitude.roll", "attitude.pitch", "attitude.yaw"],
                 "std": 0.01}],
}


class _Collect:
    def __init__(self):
        self.records = []

    def write(self, record):
        self.records.append(record)


@pytest.fixture(scope="module")
def paired():
    configs = load_configurations(SCENARIO_DIR / "gps_spoof.toml") + [[scenario_from_dict(NOISE_ON_ATTITUDE)]]
    out = _Collect()
    simulation_flights(out, configs, 7, FlightConfig(), {}, 8, lambda m: None)
    return out.records


def test_gps_spoof_moves_the_true_path_away_from_the_twin(paired):
    spoof = paired[0]
    assert spoof.manifest["action"] == "gps_spoof"
    assert spoof.manifest["impact_max_dev_m"] >= 5.0
    assert not spoof.manifest["impact_crashed"]
    # the twin flown again from the same seed is the same flight: its own deviation is 0
    twin = spoof.simulator[TWIN_TOPIC]
    own = impact(twin, twin, "landed")
    assert own["impact_max_dev_m"] == 0.0 and own["impact_mission_completed"]
    # and it is the seed's normal flight
    again = flight_views(simulate([int(spoof.manifest["seed"])], FlightConfig()), 0)[1]["truth"]
    pd.testing.assert_frame_equal(again.reset_index(drop=True), twin.reset_index(drop=True))


def test_small_attitude_noise_has_no_physical_impact(paired):
    noise = paired[1]
    assert noise.manifest["impact_max_dev_m"] < 0.5
    assert noise.manifest["impact_final_dev_m"] < 0.5
    assert noise.manifest["impact_mission_completed"]
    assert noise.manifest["impact_landing_dist_m"] < 10.0


def test_impact_of_made_up_paths():
    ts = np.arange(5) * 20_000
    home = pd.DataFrame({"Timestamp": ts, "x": 0.0, "y": 0.0, "z": 0.0})
    away = home.assign(x=[0.0, 1.0, 2.0, 3.0, 12.0])
    out = impact(away.iloc[:4], home, "crashed")  # ended early: held at its last position
    assert out == {"impact_max_dev_m": 3.0, "impact_final_dev_m": 3.0, "impact_mission_completed": False,
                   "impact_landing_dist_m": 3.0, "impact_crashed": True}
    assert not impact(away, home, "landed")["impact_mission_completed"]  # landed 12 m off the twin
    assert set(impact(home.iloc[:0], home, "landed")) == set(IMPACT_COLUMNS)


def _grey_pixels(png) -> int:
    """Pixels of the twin's path: NORMAL_COLOUR at alpha 0.5 on white."""
    import matplotlib.colors
    import matplotlib.image

    img = matplotlib.image.imread(png)[..., :3]
    want = 0.5 * np.array(matplotlib.colors.to_rgb(NORMAL_COLOUR)) + 0.5
    return int((np.abs(img - want).max(axis=2) < 0.03).sum())


def test_manifest_and_path_figure_show_before_and_after(paired, tmp_path):
    writer = DatasetWriter(tmp_path / "ds", fmt="csv")
    for r in paired:
        writer.write(r)
    writer.close()
    ds = open_dataset(tmp_path / "ds")
    m = ds.manifest.set_index("flight_id")
    assert m.loc["sim-gps-spoof-link", "impact_max_dev_m"] >= 5.0
    assert bool(m.loc["sim-attitude-noise-1pc", "impact_mission_completed"])
    assert TWIN_TOPIC in ds.topics("sim-gps-spoof-link", "simulator")
    # the combined tables hold link messages only, not the twin
    combined = pd.read_csv(tmp_path / "ds/flights/sim-gps-spoof-link/combined/simulator_all_sensors.csv", nrows=1)
    assert not any(c.startswith(TWIN_TOPIC) for c in combined.columns)
    spoof = flight_path(ds, "sim-gps-spoof-link", tmp_path / "fig")
    assert _grey_pixels(spoof) > 2000  # the twin's path, apart from the attacked one
    for f in (tmp_path / "ds/flights/sim-attitude-noise-1pc/sensors/simulator").glob(f"{TWIN_TOPIC}*"):
        f.unlink()  # a flight without a twin (and no normal flight of its seed): no "before" path
    ds.trust("sim-attitude-noise-1pc")  # its files were edited on purpose: not a damaged flight
    assert _grey_pixels(flight_path(ds, "sim-attitude-noise-1pc", tmp_path / "fig")) < 1000  # text edges only
