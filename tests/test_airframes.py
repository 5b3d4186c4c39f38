"""Airframes (generator.physics.airframes): each hovers and flies a leg within 2 m, their published
values hold, a batch of mixed airframes gives every flight the bytes it has alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scart_bench.generator.engine.flight_batch import flight_vehicles, vehicle_groups
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import GRAVITY, MissionParams
from scart_bench.generator.physics.airframes import AIRFRAMES, airframe, airframe_for_seed

#: deliveries (a long straight leg out and back, a hover at the drop) in light wind
CALM = MissionParams(ground_phase=False, wind_max=2.0, families=(("delivery", 1.0),), duration_range=(20.0, 30.0))


def _truth(r, j: int) -> np.ndarray:
    steps, vals, _ = r.simulator["truth"]
    return vals[j, :np.searchsorted(steps, r.exit_step[j], side="right")]


@pytest.fixture(scope="module")
def flown():
    seeds = [21, 22]
    out = {}
    for name in AIRFRAMES:
        v, c = airframe(name)
        out[name] = simulate(seeds, FlightConfig(vehicle=v, controller=c, mission=CALM, timing="ideal"))
    return out


@pytest.mark.parametrize("name", list(AIRFRAMES))
def test_each_airframe_hovers_and_flies_a_leg_within_2_m(flown, name):
    r = flown[name]
    for j in range(len(r)):
        assert r.status[j] == "landed"
        truth = _truth(r, j)
        wps = r.waypoints[j]
        # the take-off hold: 5 s over the take-off point, within 1 m
        over = (-truth[:, 2] > -wps[0, 2] - 0.3) & (np.hypot(truth[:, 0], truth[:, 1]) < 3.0)
        hold = truth[np.flatnonzero(over)[:200]]
        assert len(hold) >= 200 and np.hypot(hold[:, 0], hold[:, 1]).max() < 1.0
        # the leg out to the drop and the leg home, 10-90 % along them: within 2 m of their line
        for a, b in ((wps[0, :2], wps[1, :2]), (wps[3, :2], wps[4, :2])):
            u = (b - a) / np.linalg.norm(b - a)
            p = truth[:, :2] - a
            along, across = p @ u, p @ np.array([-u[1], u[0]])
            mid = (along > 0.1 * np.linalg.norm(b - a)) & (along < 0.9 * np.linalg.norm(b - a))
            assert mid.sum() > 50 and np.abs(across[mid]).max() < 2.0, (name, j, np.abs(across[mid]).max())
        # the hover at the drop, within 1 m of it
        low = np.hypot(*(truth[:, :2] - wps[2, :2]).T) < 3.0
        low &= np.abs(truth[:, 2] - wps[2, 2]) < 0.3
        assert low.sum() > 100 and np.hypot(*(truth[low, :2] - wps[2, :2]).T).max() < 1.0


def test_published_values_and_hover_throttle():
    """The x500 is gz's model; the hover thrust fractions follow the airframe files' MPC_THR_HOVER."""
    x500, _ = airframe("x500")
    assert x500.motor_constant == 8.54858e-06 and x500.max_rot_velocity == 1000.0 and x500.moment_constant == 0.016
    assert x500.inertia[2] == pytest.approx(0.04)
    hover = {n: airframe(n)[0].mass * GRAVITY / (4 * airframe(n)[0].max_thrust) for n in AIRFRAMES}
    assert hover["x500"] == pytest.approx(0.60, abs=0.02)  # 4001_gz_x500: MPC_THR_HOVER 0.60
    assert hover["qav250"] == pytest.approx(0.3 * 0.25**2 + 0.7 * 0.25, abs=0.01)  # 0.25 throttle, THR_MDL_FAC 0.3
    assert airframe("qav250")[1].att_p == (8.0, 8.0, 4.0)  # 4052_holybro_qav250: MC_ROLL_P/PITCH_P 8, YAW_P 4
    assert airframe("iris") == (FlightConfig().vehicle, FlightConfig().controller)
    with pytest.raises(ValueError, match="airframe 'f450'"):
        airframe("f450")


def test_a_mixed_batch_gives_each_flight_its_bytes_alone():
    mix = (("iris", 0.34), ("qav250", 0.33), ("x500", 0.33))
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=40.0), timing="ideal", airframes=mix)
    seeds = [int(s) for s in range(30, 36)]
    names = {airframe_for_seed(mix, s) for s in seeds}
    assert len(names) >= 2 and len(vehicle_groups(seeds, cfg)) == len(names)
    together = simulate(seeds, cfg)
    for j in (0, 3):
        alone = simulate([seeds[j]], cfg)
        assert alone.exit_step[0] == together.exit_step[j]
        for topic, (steps, vals, _) in alone.simulator.items():
            np.testing.assert_array_equal(together.simulator[topic][1][j, :len(steps)], vals[0], err_msg=topic)
    # and the airframe shows: hover thrust differs (the setpoint's thrust is not logged; the rotor speed is)
    assert [n for n, _ in flight_vehicles(seeds, cfg)] == [airframe_for_seed(mix, s) for s in seeds]


def test_an_attack_layer_over_mixed_airframes_is_a_clear_error():
    from scart_bench.generator.scart.layer import AttackLayer

    mix = (("iris", 0.5), ("x500", 0.5))
    seeds = [s for s in range(40, 60) if airframe_for_seed(mix, s) == "iris"][:1] + \
            [s for s in range(40, 60) if airframe_for_seed(mix, s) == "x500"][:1]
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=2.0), airframes=mix)
    with pytest.raises(ValueError, match="one airframe"):
        simulate(seeds, cfg, layer=AttackLayer([[], []], seeds))
    sub = vehicle_groups(seeds, cfg)
    assert [dataclasses.asdict(c.vehicle)["mass"] for c, _ in sub] == [1.5, airframe("x500")[0].mass]
