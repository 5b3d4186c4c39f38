"""The compiled flight kernel: held against the numpy reference step, deterministic, batch-independent."""

from __future__ import annotations

import numpy as np
import pytest

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.engine import compiled as kernel_batch
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import MissionParams
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import scenario_from_dict

TOPIC_FIELDS = {name: i for i, name in enumerate(TOPICS["gps_raw_int"].field_names)}

STEPS_1000 = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=4.0))  # 1,000 steps: arm, take off, climb


def _assert_close(kernel: dict, reference: dict, atol: float = 1e-9) -> None:
    assert list(kernel) == list(reference)
    for topic, (steps, vals, ok) in reference.items():
        k_steps, k_vals, k_ok = kernel[topic]
        np.testing.assert_array_equal(k_steps, steps, err_msg=topic)
        np.testing.assert_array_equal(k_ok, ok, err_msg=topic)
        np.testing.assert_allclose(k_vals, vals, rtol=0, atol=atol, err_msg=topic)


def test_kernel_matches_the_numpy_reference_step_over_1000_steps():
    """Same seeds, same noise: every recorded state (truth, estimator telemetry, setpoints) within 1e-9."""
    ref = simulate([3, 4], STEPS_1000, engine="numpy")
    ker = simulate([3, 4], STEPS_1000, engine="kernel")
    assert ker.n_steps == ref.n_steps == 1000
    truth = ref.simulator["truth"][1]
    assert truth[:, -1, 2].max() < -1.0, "the flights are airborne by the end (the test covers flight dynamics)"
    _assert_close(ker.simulator, ref.simulator)
    np.testing.assert_array_equal(ker.gps_rejections, ref.gps_rejections)
    np.testing.assert_array_equal(ker.exit_step, ref.exit_step)


def test_kernel_matches_the_reference_through_the_ground_phase():
    """GPS fix, the estimator's origin, arming and take-off at each flight's own times, and the
    receiver's settling satellites and accuracy: the two engines agree step for step."""
    cfg = FlightConfig(mission=MissionParams(max_duration_s=16.0))  # seed 4 arms at 11.3 s, lifts off 3 s later
    ref = simulate([3, 4], cfg, engine="numpy")
    ker = simulate([3, 4], cfg, engine="kernel")
    truth = ref.simulator["truth"][1]
    assert truth[:, 0, 2].max() == 0.0 and truth[:, -1, 2].max() < -1.0, "on the ground first, then airborne"
    _assert_close(ker.simulator, ref.simulator)
    np.testing.assert_array_equal(ker.gps_rejections, ref.gps_rejections)


def _layer_scenarios() -> list:
    link = scenario_from_dict({
        "id": "k-link", "injection_point": "link", "start": [{"condition": "time_window", "start_s": 2.0}],
        "actions": [{"action": "add_white_noise", "target": ["local_position_ned.x", "attitude.yaw"], "std": 0.3},
                    {"action": "disconnect_sensor", "target": ["local_position_ned"], "probability": 0.3}]})
    sensor = scenario_from_dict({
        "id": "k-sensor", "injection_point": "sensor", "start": [{"condition": "time_window", "start_s": 1.5}],
        "actions": [{"action": "bias", "target": ["sensor_gps.lat", "sensor_gps.lon"], "offset": 3.0},
                    {"action": "disconnect_sensor", "target": ["sensor_mag", "sensor_baro"], "probability": 0.2}]})
    command = scenario_from_dict({
        "id": "k-cmd", "injection_point": "command", "start": [{"condition": "time_window", "start_s": 2.5}],
        "actions": [{"action": "bias", "target": ["setpoint.vz"], "offset": -0.3}]})
    return [[link, sensor, command], [], [link]]


def test_kernel_matches_the_reference_with_the_layer_at_every_injection_point():
    """Link, sensor and command hooks: both views, the uORB streams (the IMU as the estimator received
    it, after the sensor attack), the delivered masks and the event log agree."""
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=5.0), uorb=True)
    seeds = [7, 8, 9]
    runs = {}
    for engine in ("numpy", "kernel"):
        layer = AttackLayer(_layer_scenarios(), seeds)
        runs[engine] = simulate(seeds, cfg, layer=layer, engine=engine), layer
    (ref, ref_layer), (ker, ker_layer) = runs["numpy"], runs["kernel"]
    _assert_close(ker.simulator, ref.simulator)
    _assert_close(ker.navigator, ref.navigator)
    _assert_close(ker.uorb_streams, ref.uorb_streams)
    assert list(ker.uorb_streams) == ["sensor_combined", "vehicle_attitude", "vehicle_local_position",
                                      "actuator_controls_0"]
    assert not ker.navigator["local_position_ned"][2][0].all(), "the link dropped messages"
    assert [e.__dict__ for e in ker_layer.events] == [e.__dict__ for e in ref_layer.events]
    assert ker_layer.events, "the scenarios started"


def _physical(sid: str, point: str, start_s: float, action: dict) -> object:
    return scenario_from_dict({"id": sid, "injection_point": point,
                               "start": [{"condition": "time_window", "start_s": start_s}], "actions": [action]})


def test_kernel_matches_the_reference_under_environment_attacks_and_faults():
    """Jamming (fix lost), RF spoofing, a gust, magnetic interference, motor and battery faults and
    lost sensor instances (frozen and failed over) change the flights as the reference step does."""
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=5.0), uorb=True)
    env, veh = "environment", "vehicle"
    flights = [
        [_physical("jam", env, 1.6, {"action": "gps_jamming", "js_db": 80.0}),
         _physical("baro", veh, 2.0, {"action": "sensor_instance_loss", "sensor": "baro", "failover": False})],
        [_physical("spoof", env, 1.6, {"action": "gps_rf_spoof", "rate": 2.0, "accel": 1.0}),
         _physical("mag", env, 1.5, {"action": "mag_interference", "center": [0.0, 2.0], "strength": 0.3})],
        [_physical("gust", env, 1.5, {"action": "wind_gust", "speed": 6.0, "rise_s": 0.5}),
         _physical("motor", veh, 2.0, {"action": "motor_efficiency", "motor": 2, "efficiency": 0.8})],
        [_physical("sag", veh, 1.5, {"action": "battery_sag", "volts": 2.0}),
         _physical("gps", veh, 2.0, {"action": "sensor_instance_loss", "sensor": "gps", "offset": 3.0}),
         _physical("imu", veh, 2.5, {"action": "sensor_instance_loss", "sensor": "accel", "offset": 0.2})],
    ]
    seeds = [31, 32, 33, 34]
    runs = {}
    for engine in ("numpy", "kernel"):
        layer = AttackLayer(flights, seeds)
        runs[engine] = simulate(seeds, cfg, layer=layer, engine=engine), layer
    (ref, ref_layer), (ker, ker_layer) = runs["numpy"], runs["kernel"]
    _assert_close(ker.simulator, ref.simulator)
    _assert_close(ker.navigator, ref.navigator)
    _assert_close(ker.uorb_streams, ref.uorb_streams)  # the mixer's command before a motor's limit, too
    assert [e.__dict__ for e in ker_layer.events] == [e.__dict__ for e in ref_layer.events]
    fix = ref.simulator["gps_raw_int"][1][0, -1, TOPIC_FIELDS["fix_type"]]
    assert fix < 3, "the jammed receiver lost its fix"


def _link_attack(sid: str, point: str, start_s: float, action: dict, seconds: float | None = None) -> object:
    table = {"id": sid, "injection_point": point, "start": [{"condition": "time_window", "start_s": start_s}],
             "actions": [action]}
    if seconds is not None:
        table["end"] = [{"condition": "duration", "seconds": seconds}]
    return scenario_from_dict(table)


def test_kernel_matches_the_reference_under_attacks_on_the_control_link():
    """Forged disarm (a fall and a crash), land, return and reposition, a refused command, a tampered
    mission, a link loss into a hold then the datalink failsafe, replay and flooding: both engines react alike."""
    from scart_bench.generator.flight_software.commander import ControlParams

    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=24.0),
                       control=ControlParams(offboard_loss_action="hold", datalink_loss_s=2.0))
    scenarios = [
        [_link_attack("disarm", "command", 7.0, {"action": "inject_command", "command": "disarm"})],
        [_link_attack("land", "command", 6.0, {"action": "inject_command", "command": "land"})],
        [_link_attack("rtl", "command", 6.0, {"action": "inject_command", "command": "return"})],
        [_link_attack("goto", "command", 6.0, {"action": "inject_command", "command": "reposition",
                                                "north_m": 5.0, "east_m": -5.0, "alt_m": 6.0})],
        [_link_attack("refused", "command", 6.0, {"action": "inject_command", "command": "land",
                                                   "target_component": 7})],
        [_link_attack("tamper", "command", 0.0, {"action": "mission_tamper", "item": 1, "shift_m": 8.0})],
        [_link_attack("loss", "link", 5.0, {"action": "link_loss"}, seconds=5.0)],
        [_link_attack("replay", "link", 6.0, {"action": "replay", "span_s": 1.5}, seconds=3.0),
         _link_attack("flood", "link", 10.0, {"action": "flood", "rate_hz": 150.0}, seconds=4.0)],
        [],
    ]
    seeds = list(range(60, 60 + len(scenarios)))
    runs = {}
    for engine in ("numpy", "kernel"):
        layer = AttackLayer(scenarios, seeds)
        runs[engine] = simulate(seeds, cfg, layer=layer, engine=engine), layer
    (ref, ref_layer), (ker, ker_layer) = runs["numpy"], runs["kernel"]
    np.testing.assert_array_equal(ker.exit_step, ref.exit_step)
    assert len(set(ker.exit_step.tolist())) > 2, "flights end at different steps"
    for view in ("simulator", "navigator"):  # each flight up to its end (the reference flies on after it)
        for topic, (steps, vals, ok) in getattr(ref, view).items():
            k_steps, k_vals, k_ok = getattr(ker, view)[topic]
            np.testing.assert_array_equal(k_steps, steps, err_msg=topic)
            for i, end in enumerate(ref.exit_step):
                last = np.searchsorted(steps, end, side="right")
                np.testing.assert_array_equal(k_ok[i, :last], ok[i, :last], err_msg=f"{view} {topic} {i}")
                np.testing.assert_allclose(k_vals[i, :last], vals[i, :last], rtol=0, atol=1e-9,
                                           err_msg=f"{view} {topic} flight {i}")
    assert ker.status == ref.status and ker.status[0] == "crashed"
    np.testing.assert_array_equal(ker.exit_step, ref.exit_step)
    assert [e.__dict__ for e in ker_layer.events] == [e.__dict__ for e in ref_layer.events]


def test_batch_equals_its_flights_flown_one_by_one_exactly():
    """Whole flights of different lengths: each flight's bytes are the same alone and in the batch."""
    seeds = [11, 12, 13]
    together = simulate(seeds)
    assert len(set(together.exit_step.tolist())) > 1, "flights end at different steps"
    for j, seed in enumerate(seeds):
        alone = simulate([seed])
        assert alone.exit_step[0] == together.exit_step[j] and alone.status[0] == together.status[j]
        for topic, (steps, vals, _) in alone.simulator.items():
            np.testing.assert_array_equal(together.simulator[topic][1][j, :len(steps)], vals[0], err_msg=topic)


def test_results_do_not_depend_on_the_block_size(monkeypatch):
    """Noise blocks and the steps where finished flights leave the batch change nothing."""
    a = simulate([21, 22])
    monkeypatch.setattr(kernel_batch, "BLOCK_STEPS", 137)
    b = simulate([21, 22])
    for topic, (steps, vals, _) in a.simulator.items():
        np.testing.assert_array_equal(b.simulator[topic][0], steps)
        np.testing.assert_array_equal(b.simulator[topic][1], vals, err_msg=topic)


def test_unknown_engine_is_a_clear_error():
    with pytest.raises(ValueError, match="engine must be one of"):
        simulate([1], STEPS_1000, engine="gpu")


def test_batches_flown_from_two_threads_at_once_are_unchanged():
    """simulate() may be called from several threads (the parallel stretches take turns)."""
    from concurrent.futures import ThreadPoolExecutor

    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=10.0))
    seeds = ([41, 42, 43, 44, 45], [51, 52, 53, 54, 55])
    with ThreadPoolExecutor(max_workers=2) as pool:
        together = list(pool.map(lambda s: simulate(s, cfg), seeds))
    for s, got in zip(seeds, together):
        alone = simulate(s, cfg)
        for topic, (_, vals, _) in alone.simulator.items():
            np.testing.assert_array_equal(got.simulator[topic][1], vals, err_msg=topic)
