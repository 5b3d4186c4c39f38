"""The pilot in attitude mode (generator.flight_software.pilot; MissionParams.pilot_*): a hand-flown flight's
sticks, flown through the attitude controller, fitted by ``generate --like`` (generator.like.pilot)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import periodogram

from scart_bench.dataset.schema import TRUTH_FIELDS
from scart_bench.generator.engine import kernel as K
from scart_bench.generator.engine import kernel_layout as L
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.pilot import Pilot, pilot_start, stick_lag, stick_params
from scart_bench.generator.like import pilot as like_pilot
from scart_bench.generator.params import MissionParams

SEEDS = [5, 7]
#: the square at 2 m/s (a leg: full stick), no ground phase
BASE = MissionParams(cruise_speed=2.0, ground_phase=False)
PILOT = dataclasses.replace(BASE, pilot_stick_deg=4.0, pilot_stick_hz=1.0, pilot_yaw_deg=2.0, pilot_throttle=0.04)
FLEET_LOG = Path(__file__).resolve().parents[2] / "shared" / "data" / "dataflash" / "fleet" / "arducopter_10-11-2014_105.bin"


def _fly(mission: MissionParams):
    return simulate(SEEDS, FlightConfig(mission=mission, timing="ideal"))


@pytest.fixture(scope="module")
def flights():
    return {"off": _fly(BASE), "on": _fly(PILOT), "double": _fly(dataclasses.replace(PILOT, pilot_stick_deg=8.0))}


def _band(x: np.ndarray, fs: float, lo: float, hi: float) -> float:
    f, p = periodogram(x, fs=fs, window="hann", detrend="constant")
    return float(p[(f >= lo) & (f < hi)].sum() * (f[1] - f[0]))


def _roll_power(result, i: int) -> float:
    """Median roll power (rad^2) in 1-5 Hz over the 10 s windows of the true track flown above 3 m at over 1 m/s."""
    steps, v, _ = result.simulator["truth"]
    fs = 250.0 / float(np.median(np.diff(steps)))
    roll, alt, speed = v[i][:, TRUTH_FIELDS.index("roll")], -v[i][:, 2], np.hypot(v[i][:, 3], v[i][:, 4])
    w = int(10 * fs)
    p = [_band(roll[a:a + w], fs, 1.0, 5.0) for a in range(0, len(roll) - w, w // 2)
         if (alt[a:a + w] > 3.0).all() and np.median(speed[a:a + w]) > 1.0]
    assert len(p) >= 10
    return float(np.median(p))


def _route_distance(xy: np.ndarray, wps: np.ndarray) -> np.ndarray:
    best = np.full(len(xy), np.inf)
    for a, b in zip(wps[:-1], wps[1:]):
        seg = b - a
        s = np.clip((xy - a) @ seg / (seg @ seg), 0, 1) if seg @ seg > 0 else np.zeros(len(xy))
        best = np.minimum(best, np.linalg.norm(xy - (a + np.outer(s, seg)), axis=1))
    return best


def test_kernel_sticks_are_the_reference_sticks():
    """The compiled kernel's sticks are the numpy reference's, value for value (same integer draws, same lags)."""
    m = dataclasses.replace(PILOT, pilot_stick_deg=5.0, pilot_stick_hz=2.0)
    start = pilot_start([11], m)
    ref = Pilot(m)
    st = ref.init_state(start)
    row = np.zeros(L.WIDTH)
    row[L.PILOT_RNG], row[L.PILOT_GAIN] = start[0]
    p = np.zeros(L.N_PARAMS)
    p[L.PARAM_INDEX["pilot"]:L.PARAM_INDEX["pilot"] + 9] = stick_params(m)
    for _ in range(200):
        want = ref.step(st, np.array([10.0]), np.array([3.0]))[0]
        got = [K._pilot_stick(row, p, a, row[L.PILOT_GAIN]) for a in range(4)]
        assert got == list(want)
    assert np.std([ref.step(st, np.array([10.0]), np.array([3.0]))[0, 0] for _ in range(2000)]) > 0.3 * math.radians(5)


def test_attitude_pilot_flight_lands_home_and_keeps_to_the_route(flights):
    """With the sticks on, every flight still lands (within 1 m of home) and stays within 2.5 m of the square."""
    r = flights["on"]
    assert r.status == ["landed", "landed"]
    _, v, _ = r.simulator["truth"]
    for i in range(len(SEEDS)):
        end = v[i][-1, :3]
        assert math.hypot(end[0], end[1]) < 1.0
        air = -v[i][:, 2] > 3.0
        d = _route_distance(v[i][air, :2], r.waypoints[i][:, :2])
        assert d.max() < 2.5, d.max()


def test_roll_power_is_what_the_sticks_say(flights):
    """Roll power in 1-5 Hz: 0.35-1.0 of the roll stick's own (its std x the flight's factor, the two lags'
    share of 1-5 Hz; the attitude loop's ~1 Hz bandwidth and the velocity loop's corrections take the rest),
    over 100x the same flight's without the pilot, and four times as much with twice the stick (0.6-1.2 x 4)."""
    a, norm = stick_lag(PILOT.pilot_stick_hz)
    f = np.linspace(0.0, 25.0, 50001)
    h2 = np.abs(norm * ((1 - a) / (1 - a * np.exp(-2j * np.pi * f / 50.0))) ** 2) ** 2 * 2.0 / 50.0
    share = float(h2[(f >= 1.0) & (f < 5.0)].sum() * (f[1] - f[0]))
    for i, seed in enumerate(SEEDS):
        factor = pilot_start([seed], PILOT)[0, 1]
        stick = (math.radians(PILOT.pilot_stick_deg) * factor) ** 2 * share
        on, off, double = (_roll_power(flights[k], i) for k in ("on", "off", "double"))
        assert 0.35 * stick < on < 1.0 * stick, (on, stick)
        assert on > 100 * off
        assert 0.6 * 4 < double / on < 1.2 * 4


def test_no_pilot_is_the_flight_without_one(flights):
    """The sticks draw from a stream of their own: with the pilot drawn for no flight (share 0) the flights are
    the ones without a pilot, byte for byte; a dataset without a pilot names no pilot_* field."""
    none = _fly(dataclasses.replace(PILOT, pilot_share=0.0))
    off = flights["off"]
    for topic in ("truth", "attitude", "highres_imu"):
        assert np.array_equal(none.simulator[topic][1], off.simulator[topic][1])
    from scart_bench.generator.plan import plan_generation

    plan = plan_generation("quick", seed=1, n_normal=2, with_attacks=False)
    assert not any(k.startswith("pilot_") for k in plan.config_dict["flight_config"]["mission"])


def test_like_says_hand_flown_from_the_modes():
    """A fleet log flown in STABILIZE / ALT_HOLD / LOITER is hand-flown, with cruise roll/pitch power in 0.5-2 Hz
    above the threshold; a fleet where no log is hand-flown gets no pilot (one line saying so)."""
    from scart_bench.generator.like.fit import measure_log

    m = measure_log(FLEET_LOG)
    assert like_pilot.is_hand_flown(m.pilot)
    assert m.pilot["cruise_tilt_0.5_2"] > like_pilot.HAND_TILT_POWER
    fields, lines = like_pilot.fit_pilot([{"hand": 0.0}, {"hand": 0.0}], ["a", "b"], FlightConfig(), None)
    assert fields == {} and len(lines) == 1 and "0 of 2" in lines[0]
