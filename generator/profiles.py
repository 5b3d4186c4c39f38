"""Dataset profiles: the one table of flight counts, attack grid, GPS accuracy and job time limit per profile.

Kept free of heavy imports so that the command line can list the profiles without loading the
generator.
"""

from __future__ import annotations

from dataclasses import dataclass, field


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
    #: the mission mix, family -> weight (generator.flight_software.families.FAMILIES); empty: every
    #: flight flies the square
    missions: dict[str, float] = field(default_factory=dict)
    #: s, with a mission mix: the range of each flight's planned mission duration (drawn log-uniform;
    #: take-off, landing and the ground phase come on top)
    mission_duration_s: tuple[float, float] = (60.0, 180.0)
    #: the airframe mix, name -> weight (generator.physics.airframes.AIRFRAMES); empty: the 3DR Iris
    airframes: dict[str, float] = field(default_factory=dict)

    def flight_config(self):
        """The FlightConfig for this profile's flights (the defaults at its GPS accuracy, sensor
        profile and timing, flying its mission and airframe mixes)."""
        import dataclasses

        from scart_bench.generator.engine.simulate import FlightConfig
        from scart_bench.generator.flight_software.families import FAMILIES
        from scart_bench.generator.params import with_gps_accuracy, with_sensor_profile
        from scart_bench.generator.physics.airframes import AIRFRAMES, check_mix

        config = with_sensor_profile(with_gps_accuracy(FlightConfig(timing=self.timing), self.gps_accuracy),
                                     self.sensor_profile)
        if self.missions:
            lo, hi = (float(x) for x in self.mission_duration_s)
            if not 0 < lo <= hi:
                raise ValueError(f"profile {self.name}: mission_duration_s {self.mission_duration_s!r}, "
                                 "expected (shortest, longest) in seconds, 0 < shortest <= longest")
            mission = dataclasses.replace(config.mission, families=check_mix(self.missions, "mission family", FAMILIES),
                                          duration_range=(lo, hi))
            config = dataclasses.replace(config, mission=mission)
        if self.airframes:
            config = dataclasses.replace(config, airframes=check_mix(self.airframes, "airframe", AIRFRAMES))
        return config

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
#:
#: Missions and airframes (docs/missions.md): the quick and standard profiles fly a mix of mission
#: families (MISSION_MIX) on three airframes (AIRFRAMES_MIX), as a fleet does; quick flights are short
#: (planned missions of 30-120 s: flights of about 1-3.5 min) so that `make run` stays a few minutes,
#: standard ones 60-300 s. The paper profile flies the square on the Iris, as the paper's flights flew
#: one fixed square-like mission, so its datasets are byte-identical to those before the mixes.
MISSION_MIX = {"square": 0.15, "survey": 0.15, "orbit": 0.1, "corridor": 0.1, "delivery": 0.1,
               "random_waypoints": 0.15, "hover": 0.1, "hand_flown": 0.15}
AIRFRAMES_MIX = {"iris": 0.4, "x500": 0.4, "qav250": 0.2}
PROFILES: dict[str, Profile] = {
    "quick": Profile("quick", 8, 60, 30, "quick.toml", job_timeout_s=1800.0, n_csv_source=17,
                     missions=MISSION_MIX, mission_duration_s=(30.0, 120.0), airframes=AIRFRAMES_MIX),
    "standard": Profile("standard", 24, 100, 100, "standard.toml", job_timeout_s=7200.0, n_csv_source=32,
                        missions=MISSION_MIX, mission_duration_s=(60.0, 300.0), airframes=AIRFRAMES_MIX),
    "paper": Profile("paper", 60, 100, 100, "paper.toml", job_timeout_s=6 * 3600.0, n_csv_source=512),
}


def get_profile(name: str) -> Profile:
    """The profile called ``name`` (ValueError listing the known ones otherwise)."""
    if name not in PROFILES:
        from scart_bench.errors import ScartBenchError

        raise ScartBenchError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}")
    return PROFILES[name]
