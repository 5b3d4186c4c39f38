"""Generated flights for the detector tests, in the combined-table layout.

``normal_flights`` and ``attacked_flight`` are the only interface the tests use. They come from
the real flight generator: one batch of normal flights is flown once per process and cached;
``seed`` picks which flights of the batch are returned. The attacked flight is a held-out normal
flight replayed in csv mode with 20 m white noise on every position report of the link.
"""

from __future__ import annotations

from functools import lru_cache

import pandas as pd

from generator.dataset import LABEL_COLUMNS, combine
from generator.modes import csv_mode
from generator.records import flight_views
from generator.scart.scenario import scenario_from_dict
from generator.simulate import simulate

FLEET = 12
#: (start, end) of the attacked window as fractions of the returned rows.
ATTACK_WINDOW = (0.4, 0.6)
#: Standard deviation of the position noise of the attacked flight, metres.
ATTACK_NOISE_M = 20.0
POSITION_FIELDS = ["global_position_int.lat", "global_position_int.lon", "local_position_ned.x",
                   "local_position_ned.y", "gps_raw_int.lat", "gps_raw_int.lon"]


@lru_cache(maxsize=1)
def _fleet():
    batch = simulate([9000 + i for i in range(FLEET)])
    views = []
    for i in range(FLEET):
        nav, _ = flight_views(batch, i)
        views.append({t: df.drop(columns=list(LABEL_COLUMNS)) for t, df in nav.items()})
    return views


def _pick(n: int, seed: int) -> list[int]:
    start = (seed * 4) % FLEET
    return [(start + k) % FLEET for k in range(n)]


def normal_flights(n: int, seed: int, rows: int = 1500) -> list[pd.DataFrame]:
    """``n`` normal flights (navigator most_frequent tables), the first ``rows`` rows of each."""
    fleet = _fleet()
    return [combine(fleet[i], [])["most_frequent"].iloc[:rows].reset_index(drop=True) for i in _pick(n, seed)]


def attacked_flight(seed: int, rows: int = 1500) -> pd.DataFrame:
    """A normal flight with 20 m GPS noise injected on the link over the middle fifth of ``rows``."""
    topics = _fleet()[_pick(1, seed)[0]]
    t_end = int(topics["attitude"]["Timestamp"].iloc[min(rows, len(topics["attitude"])) - 1])
    start_s = ATTACK_WINDOW[0] * t_end / 1e6
    seconds = (ATTACK_WINDOW[1] - ATTACK_WINDOW[0]) * t_end / 1e6
    scenario = scenario_from_dict({
        "id": "gps-noise-20m", "start": [{"condition": "time_window", "start_s": start_s}],
        "end": [{"condition": "duration", "seconds": seconds}],
        "actions": [{"action": "add_white_noise", "target": POSITION_FIELDS, "std": ATTACK_NOISE_M}]})
    (nav, windows, _), = csv_mode([topics], [[scenario]], [seed])
    return combine(nav, windows)["most_frequent"].iloc[:rows].reset_index(drop=True)
