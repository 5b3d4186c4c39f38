"""Dataset profiles: the one table of flight counts, attack grid, GPS accuracy and job time limit per profile.

Kept free of heavy imports so that the command line can list the profiles without loading the
generator.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Profile:
    """How many flights a dataset holds, which scenario grid attacks them, and how long a benchmark
    job on it may take by default.

    ``n_csv_source`` normal flights (split ``csv_source``) are reserved as the recordings that csv
    mode attacks: never trained on, calibrated on or scored as normal test flights.
    """

    name: str
    n_train: int
    n_validation: int
    n_test: int
    scenario_grid: str | None  # file under data/scenarios/, or None for normal flights only
    job_timeout_s: float = 1800.0
    batch_size: int = 256
    n_csv_source: int = 0
    #: GPS accuracy of the flights: "simulator" (PX4 SITL-like eph/epv ~0.3/0.5 m) or
    #: "real_receiver" (~2.8/5.9 m, as real receivers report); see generator/params.py GPS_ACCURACY
    gps_accuracy: str = "simulator"
    #: message timing of the written flights: "realistic" (jitter, drops, late messages, GPS after
    #: its fix; generator.telemetry.timing) or "ideal" (periodic from t = 0)
    timing: str = "realistic"
    #: magnetometer and barometer noise: "gazebo" (PX4 Gazebo SITL and hardware) or "rflymad"
    #: (RflySim SIL, 3x quieter); see generator/params.py SENSOR_PROFILES
    sensor_profile: str = "gazebo"

    def flight_config(self):
        """The FlightConfig for this profile's flights (the defaults at its GPS accuracy, sensor
        profile and timing)."""
        from scart_bench.generator.engine.simulate import FlightConfig
        from scart_bench.generator.params import with_gps_accuracy, with_sensor_profile

        config = with_gps_accuracy(FlightConfig(timing=self.timing), self.gps_accuracy)
        return with_sensor_profile(config, self.sensor_profile)

    @property
    def n_normal(self) -> int:
        return self.n_train + self.n_validation + self.n_test + self.n_csv_source


#: Normal flights per profile (evaluation protocol v2, scart_bench.benchmark.protocol): enough
#: validation flights that the conformal threshold reaches alpha = 5 % with room and is not one
#: flight's score (30 flights: the 30th of 30, the maximum, which a single odd flight sets; 60: the
#: 58th of 60, a guaranteed rate of 4.9 %; 100: the 96th of 100, 4.95 %) and enough held-out test
#: flights to measure the false-alarm rate (100 flights: a 95 % interval of about +-4.5 points at
#: 5 %; the paper flew 100 normal flights). csv-mode copies replay ``n_csv_source`` recordings,
#: at most 4 copies each (quick: 66 link configurations, standard 128, paper 2048).
PROFILES: dict[str, Profile] = {
    "quick": Profile("quick", 8, 60, 30, "quick.toml", job_timeout_s=1800.0, n_csv_source=17),
    "standard": Profile("standard", 24, 100, 100, "standard.toml", job_timeout_s=7200.0, n_csv_source=32),
    "paper": Profile("paper", 60, 100, 100, "paper.toml", job_timeout_s=6 * 3600.0, n_csv_source=512),
}


def get_profile(name: str) -> Profile:
    """The profile called ``name`` (ValueError listing the known ones otherwise)."""
    if name not in PROFILES:
        from scart_bench.errors import ScartBenchError

        raise ScartBenchError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}")
    return PROFILES[name]
