"""The window classifier gives both sides their phases from the same signals (issue 47 acc. 3).

A window's phase reads the flight's land state and altitude and, to tell hover from cruise, its GPS
horizontal speed. A real log without a GPS fix has no speed, so its still airborne windows are ``air``
(never ``hover``); the generated flights of that log's mission (``generate --like``) have GPS and got
``hover`` windows. Now a generated flight whose mission was recovered from a speedless log of the
comparison takes its phases without its speed too: the same flight with and without GPS gets the same
phases.
"""

from __future__ import annotations

import numpy as np

from perf import realism_windows as rw

HZ = 50.0


def _flight(name: str, side: str, gps: bool, mission: str | None = None, seed: int = 0) -> rw.FlightSignals:
    """100 s: 10 s on the ground, then 90 s airborne at 5 m without moving (a still hover); with
    ``gps``, its velocity (0.2 m/s, under the hover's 1 m/s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 100, 1 / HZ)
    n = len(t)
    f = rw.FlightSignals(name, side)
    f.mission = mission
    for sig in ("roll", "pitch", "acc_x", "gyro_x"):
        f.signals[sig] = (t, rng.normal(0, 0.01, n))
    if gps:
        f.signals["vel_n"] = (t, np.full(n, 0.2))
        f.signals["vel_e"] = (t, np.zeros(n))
    f.ground = (t, t < 10)
    f.altitude = (t, np.where(t < 10, 0.0, 5.0))
    return f


def _windows(c: rw.Comparison) -> dict[str, dict[str, int]]:
    return {ph: r.windows for ph, r in c.phases.items()}


def test_a_gps_less_log_and_its_missions_flight_with_gps_get_the_same_phases():
    gen = _flight("normal-0000", "generated", gps=True, mission="log_a")
    real = _flight("log_a.bin", "real", gps=False, seed=1)
    c = rw.compare([gen], [real], groups=False)
    w = _windows(c)
    # the still airborne windows are "air" on both sides: no hover on either
    assert w["hover"] == {"generated": 0, "real": 0}
    assert w["ground"]["generated"] == w["ground"]["real"]
    assert w["all"]["generated"] == w["all"]["real"] > 10
    assert any("as their logs'" in n and "log_a" in n for n in c.notes)
    # window by window, the generated flight's phases are its GPS-less twin's
    rates = {s: c.rates[s] for s in c.signals}
    twin = _flight("normal-0000", "generated", gps=False, mission="log_a")
    assert gen.phase_speed is True  # compare works on copies
    paired = rw.FlightSignals(gen.name, "generated", gen.signals, gen.sources, gen.ground, gen.altitude)
    paired.mission, paired.phase_speed = "log_a", False
    a = rw.flight_windows(paired, rates)["phase"].tolist()
    b = rw.flight_windows(twin, rates)["phase"].tolist()
    assert a == b and "air" in a and "hover" not in a


def test_a_flight_keeps_its_speed_when_its_log_has_one_or_it_has_no_mission():
    for mission in ("log_b", None, "a_log_not_compared"):
        gen = _flight("normal-0001", "generated", gps=True, mission=mission)
        real = _flight("log_b.bin", "real", gps=True, seed=1)
        w = _windows(rw.compare([gen], [real], groups=False))
        assert w["hover"]["generated"] == w["hover"]["real"] > 10, mission
    # a speedless log pairs only with its own missions' flights
    gen = _flight("normal-0002", "generated", gps=True, mission="log_c")
    real = _flight("log_d.bin", "real", gps=False, seed=1)
    w = _windows(rw.compare([gen], [real], groups=False))
    assert w["hover"] == {"generated": w["hover"]["generated"], "real": 0} and w["hover"]["generated"] > 10


def test_a_generated_flight_knows_the_log_of_its_mission():
    class Dataset:
        def __init__(self, cfg):
            self.cfg = cfg

        def config(self, fid):
            if self.cfg is None:
                raise OSError("no raw/config.json")
            return self.cfg

    assert rw._mission_log(Dataset({"mission_file": "arducopter_6-3-2014_7.waypoints"}), "x") == "arducopter_6-3-2014_7"
    assert rw._mission_log(Dataset({"mission_file": None}), "x") is None
    assert rw._mission_log(Dataset(None), "x") is None
    assert rw.log_stem("fleet (ArduCopter)/arducopter_6-3-2014_7.bin") == "arducopter_6-3-2014_7"
