"""The recorded messages of a batch of flights, as both engines return them and the tables read them.

It lives below the engines (generator.engine) so that the tables (generator.telemetry.tables) read a
batch without importing the engines that fly it; ``generator.engine.flight_batch.BatchResult`` and
``generator.engine.simulate.BatchResult`` still name it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class BatchResult:
    """Recorded messages of a batch of flights.

    ``simulator[topic]`` / ``navigator[topic]`` are ``(steps, values, delivered)`` with ``values``
    shaped (N, n_messages, n_fields): the stream before and after the attack layer (identical
    objects when no layer ran). ``truth`` is the true vehicle state at 50 Hz.
    """

    seeds: list[int]
    simulator: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    navigator: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    exit_step: np.ndarray  # (N,) last recorded step of each flight
    status: list[str]
    waypoints: np.ndarray  # (N, K, 3) planned mission items
    wind: np.ndarray  # (N, 3) mean wind
    gps_rejections: np.ndarray  # (N, 3) rejected GPS position, GPS velocity, baro fusions
    n_steps: int
    timing: str = "ideal"  # FlightConfig.timing: applied when the rows become tables (generator.telemetry.tables)
    timing_table: tuple = ()  # FlightConfig.timing_table: its per-topic entries, applied with ``timing``
    uorb: bool = False  # FlightConfig.uorb: the records carry the uORB view (generator.telemetry.uorb)
    #: with FlightConfig.uorb: the flight controller's streams for the uORB view (generator.telemetry.schedule.
    #: UORB_STREAMS), ``(steps, values, delivered)`` like ``simulator``'s; empty otherwise
    uorb_streams: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.seeds)
