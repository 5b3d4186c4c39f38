"""Each vehicle's rocking in forward flight (MissionParams.rocking_flow_levels, physics.vehicle.FlowRocking), issue 47
acceptance 3: the ArduCopter fleet's hand-flown vehicles rock in roll and pitch at 1-5 Hz when they move, 3-30x more
than at rest, where the generated flights' roll was too smooth in cruise (lag-1 at 10 Hz 0.95 against 0.90, 2-5 Hz
power x0.25; docs/like.md "Rocking in forward flight"). A low-passed angular acceleration growing with the true
horizontal speed, from the flight's own stream: the same in both engines, none at rest, off by default, fitted per log
by ``--like``, a profile TOML's bad values refused naming the key."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import bad_profile_key_is_refused, kernel_matches_numpy

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import MissionParams


def test_a_vehicle_rocking_in_forward_flight_moves_in_both_engines_alike():
    """A 6 s flight whose rocking is full from 0.1 m/s (the climb moves it): the kernel records every message within
    1e-9 of the numpy reference; the flight at level 0 is the flight without levels (its own stream)."""
    m = MissionParams(ground_phase=False, max_duration_s=6.0, rocking_levels=((0.0, 0.0, 0.0), (5.0, 5.0, 0.0)),
                      rocking_flow_levels=((0.0, 0.0), (20.0, 20.0)), rocking_flow_from_m_s=0.0,
                      rocking_flow_full_m_s=0.1)
    cfg = FlightConfig(mission=m)
    ker = kernel_matches_numpy(cfg, seeds=(4, 7))
    plain = simulate([4, 7], dataclasses.replace(cfg, mission=dataclasses.replace(m, rocking_flow_levels=())),
                     engine="kernel")
    for topic in ("highres_imu", "truth", "attitude"):
        np.testing.assert_array_equal(ker.simulator[topic][1][0], plain.simulator[topic][1][0])
    assert not np.allclose(ker.simulator["truth"][1][1], plain.simulator["truth"][1][1])


def _roll_power(att: np.ndarray, lo: float = 1.0, hi: float = 5.0, hz: float = 50.0) -> float:
    from scipy.signal import periodogram

    f, p = periodogram(att, fs=hz, window="hann", detrend="linear")
    return float(p[(f >= lo) & (f < hi)].sum() * (f[1] - f[0]))


def test_the_rocking_shows_in_the_roll_at_1_5_hz_when_the_vehicle_moves_and_not_at_rest():
    """The square at 3 m/s with 15 rad/s^2 of forward-flight rocking (from 0.5 m/s, the default): until the vehicle
    first moves at 0.5 m/s its true attitude is the plain flight's to the bit; on the legs its true roll's power in
    1-5 Hz is over 3x the plain flight's."""
    m = MissionParams(ground_phase=False, max_duration_s=24.0, takeoff_hold_s=2.0, cruise_speed=3.0,
                      rocking_flow_levels=((15.0, 15.0),))
    cfg = FlightConfig(mission=m)
    rock = simulate([5], cfg, engine="kernel")
    plain = simulate([5], dataclasses.replace(cfg, mission=dataclasses.replace(m, rocking_flow_levels=())),
                     engine="kernel")
    truth, truth0 = rock.simulator["truth"][1][0], plain.simulator["truth"][1][0]
    speed0 = np.hypot(truth0[:, 3], truth0[:, 4])
    first = int(np.argmax(speed0 > MissionParams().rocking_flow_from_m_s))
    assert first > 0
    np.testing.assert_array_equal(truth[:first - 1], truth0[:first - 1])
    assert len(truth) == len(truth0)  # both fly the whole 24 s
    moving = np.flatnonzero(speed0 > 2.0)
    assert len(moving) > 250, len(moving)
    sel = slice(int(moving[0]), None)  # the truth's 50 Hz roll from the first leg on
    ratio = _roll_power(truth[sel, 6]) / _roll_power(truth0[sel, 6])
    assert ratio > 3.0, ratio


def test_the_forward_flight_rocking_is_off_by_default():
    from scart_bench.generator.physics.vehicle import flow_start
    from scart_bench.generator.plan import plan_generation

    assert MissionParams().rocking_flow_levels == ()
    assert flow_start([1, 2], ()) is None
    mission = plan_generation("quick", seed=3, n_normal=2).config_dict["flight_config"]["mission"]
    assert not [k for k in mission if k.startswith("rocking_flow")]


def test_like_fits_the_level_that_adds_the_log_s_power_and_credits_its_speed(monkeypatch):
    """Calibration flights with 1e-3 rad^2 of roll/pitch power in 1-5 Hz without the rocking and 5e-3 at the reference
    level (20 rad/s^2): a log at 2e-3 at full speed gets 10, one at 2e-3 at 1.75 m/s (half the gain) 20, one at 5e-3
    (20 at its speed) the cap, one at or below the generated figure 0, one without 10 s moving the median of the
    others."""
    from scart_bench.generator.like import flow

    cal = iter([{"moving_roll": 1e-3, "moving_pitch": 1e-3}, {"moving_roll": 5e-3, "moving_pitch": 5e-3}])
    monkeypatch.setattr(flow, "calibration", lambda config, measure, level: next(cal))

    def fig(power: float, speed: float) -> dict[str, float]:
        return {"moving_roll": power, "moving_pitch": power, "moving_speed": speed, "moving_windows": 4.0}

    figs = {"full.bin": fig(2e-3, 3.0), "slow.bin": fig(2e-3, 1.75), "rough.bin": fig(5e-3, 3.0),
            "quiet.bin": fig(5e-4, 3.0), "gpsless.bin": {}}
    lines: list[str] = []
    levels, fields = flow.fit_flow(figs, FlightConfig(), None, lines)
    assert flow.REF == 20.0 and flow.FROM_M_S == 0.5 and flow.FULL_M_S == 3.0
    assert levels["full.bin"] == (10.0, 10.0)
    assert levels["slow.bin"] == (20.0, 20.0)
    assert levels["rough.bin"] == (flow.MAX_AT_SPEED, flow.MAX_AT_SPEED)
    assert levels["quiet.bin"] == (0.0, 0.0)
    assert levels["gpsless.bin"] == (11.0, 11.0)  # the median of 10, 20, 12 and 0
    assert fields["rocking_flow_hz"][0] == flow.FLOW_HZ
    assert len(lines) == 1 and "4 of 5 logs move 10 s" in lines[0]


@pytest.mark.parametrize("key, value, expected", [
    ("rocking_flow_levels", "[[1.0, 2.0, 3.0]]", "mission.rocking_flow_levels[0]: expected a list of 2 values"),
    ("rocking_flow_levels", "[[1.0, -1.0]]", "mission.rocking_flow_levels[0][1]: expected a number in [0, 1000]"),
    ("rocking_flow_hz", "0.0", "mission.rocking_flow_hz: expected a number in [0.01, 100]"),
    ("rocking_flow_levels = [[1.0, 1.0]]\nrocking_flow_full_m_s", "0.5",
     "mission.rocking_flow_full_m_s: expected a speed above rocking_flow_from_m_s"),
])
def test_bad_forward_flight_rocking_in_a_profile_exits_2_naming_the_key(tmp_path, capsys, key, value, expected):
    bad_profile_key_is_refused(tmp_path, capsys, "mission", key, value, expected)
