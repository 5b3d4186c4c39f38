"""Attacks on the control link: forged commands, mission tampering, link loss, replay and flooding.

The flight controller reacts as PX4 would (generator.flight_software.commander); the navigator sees what reaches it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.commander import OFFBOARD_LOSS_ACTIONS, ControlParams
from scart_bench.generator.params import MissionParams
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import scenario_from_dict
from scart_bench.generator.scart.spec import ScenarioError

#: The attacks start at 34 s: the vehicle (seed 11: armed after its GPS fix and the estimator's
#: origin, off the ground at 15.3 s after 3 s at idle, 9 s of hover at 10 m) is on the square's first
#: side, between its first corner (reached at 32.0 s) and its second (38.5 s).
START_S = 34.0


def _sc(sid: str, point: str, action: dict, end_s: float | None = None, start_s: float = START_S):
    table = {"id": sid, "injection_point": point, "start": [{"condition": "time_window", "start_s": start_s}],
             "actions": [action]}
    if end_s is not None:
        table["end"] = [{"condition": "duration", "seconds": end_s}]
    return scenario_from_dict(table)


CASES = {
    "normal": None,
    "disarm": _sc("disarm", "command", {"action": "inject_command", "command": "disarm"}),
    "disarm_wrong_system": _sc("disarm-other", "command",
                               {"action": "inject_command", "command": "disarm", "target_system": 2}),
    "disarm_no_force": _sc("disarm-noforce", "command", {"action": "inject_command", "command": "disarm",
                                                         "force": False}),
    "land": _sc("land", "command", {"action": "inject_command", "command": "land"}),
    "return": _sc("rtl", "command", {"action": "inject_command", "command": "set_mode", "mode": "return"}),
    "tamper": _sc("tamper", "command", {"action": "mission_tamper", "item": 2, "shift_m": 20.0,
                                        "direction_deg": 0.0}, start_s=0.0),
    "loss": _sc("loss", "link", {"action": "link_loss"}, end_s=5.0),
}


@pytest.fixture(scope="module")
def flown():
    names = list(CASES)
    seeds = [11] * len(names)
    layer = AttackLayer([[CASES[k]] if CASES[k] else [] for k in names], seeds)
    batch = simulate(seeds, FlightConfig(), layer=layer)
    return {k: i for i, k in enumerate(names)}, batch, layer


def _truth(batch, i):
    steps, vals, _ = batch.simulator["truth"]
    last = np.searchsorted(steps, batch.exit_step[i], side="right")
    return steps[:last] / 250.0, vals[i, :last]


def test_a_forged_disarm_in_flight_makes_the_vehicle_fall_and_crash(flown):
    idx, batch, _ = flown
    i = idx["disarm"]
    assert batch.status[i] == "crashed"
    t, tr = _truth(batch, i)
    after = t >= START_S
    assert tr[after, 9][5:].max() == 0.0, "motors off (disarmed) after the forged command"
    assert tr[after, 5].max() > 8.0, "free fall from 10 m: over 8 m/s down before impact"
    assert batch.exit_step[i] / 250.0 < START_S + 3.0


def test_a_forged_command_is_refused_unless_it_would_be_accepted(flown):
    """Wrong target system, or a disarm in the air without PX4's force code: the mission goes on."""
    idx, batch, _ = flown
    for case in ("disarm_wrong_system", "disarm_no_force"):
        i = idx[case]
        assert batch.status[i] == "landed", case
        assert batch.exit_step[i] == batch.exit_step[idx["normal"]], case


def test_a_forged_land_lands_short_of_the_mission(flown):
    idx, batch, _ = flown
    i, n = idx["land"], idx["normal"]
    assert batch.status[i] == "landed"
    t, tr = _truth(batch, i)
    assert t[-1] < START_S + 15.0 < _truth(batch, n)[0][-1]
    home_dist = np.hypot(*tr[-1, :2])
    assert home_dist > 8.0, "it landed where it was, not at home"
    assert tr[:, 0].max() < 35.0, "it never reached the second corner (40 m north)"


def test_a_forged_return_flies_home_without_the_rest_of_the_mission(flown):
    idx, batch, _ = flown
    t, tr = _truth(batch, idx["return"])
    assert batch.status[idx["return"]] == "landed"
    assert np.hypot(*tr[-1, :2]) < 2.0
    assert _closest(tr, batch.waypoints[idx["return"], 3]) > 10.0, "it never flew the rest of the square"


def _closest(tr, item) -> float:
    return float(np.hypot(tr[:, 0] - item[0], tr[:, 1] - item[1]).min())


def test_a_mission_tamper_moves_a_corner_and_the_true_path_goes_there(flown):
    idx, batch, _ = flown
    corner = batch.waypoints[idx["tamper"], 2, :2] + (20.0, 0.0)  # item 2 moved 20 m north
    for case, near in (("tamper", True), ("normal", False)):
        _, tr = _truth(batch, idx[case])
        d = np.hypot(tr[:, 0] - corner[0], tr[:, 1] - corner[1]).min()
        assert (d < 2.0) == near, (case, d)
    np.testing.assert_array_equal(batch.waypoints[idx["tamper"]], batch.waypoints[idx["normal"]])


def test_a_5s_link_loss_lands_where_it_was(flown):
    """PX4's defaults: no setpoint for COM_OF_LOSS_T = 1 s -> COM_OBL_ACT = Land. The vehicle brakes
    and lands near where the loss began; it does not go back to the mission when the link returns."""
    idx, batch, layer = flown
    i = idx["loss"]
    t, tr = _truth(batch, i)
    (s, e), = layer.windows(i, 10**12)
    assert (e - s) / 1e6 == pytest.approx(5.0, abs=0.05)
    at_failsafe = tr[np.searchsorted(t, s / 1e6 + 1.0), :2]  # COM_OF_LOSS_T after the loss began
    assert batch.status[i] == "landed"
    assert np.hypot(*(tr[-1, :2] - at_failsafe)) < 8.0, "it braked and landed there"
    assert _closest(tr, batch.waypoints[i, 3]) > 10.0, "the mission did not resume"
    assert t[-1] < _truth(batch, idx["normal"])[0][-1]
    nav_ok = batch.navigator["local_position_ned"][2][i]
    steps = batch.navigator["local_position_ned"][0] * 4000
    lost = (steps >= s) & (steps < e)
    assert not nav_ok[lost].any() and nav_ok[~lost][: np.searchsorted(steps, e)].sum() > 0


@pytest.fixture(scope="module")
def held():
    """The same loss with COM_OBL_ACT = Hold, and with Hold then a 3 s datalink timeout (NAV_DLL_ACT)."""
    configs = [ControlParams(offboard_loss_action="hold"),
               ControlParams(offboard_loss_action="hold", datalink_loss_s=3.0)]
    out = []
    for control in configs:
        layer = AttackLayer([[CASES["loss"]]], [11])
        out.append((simulate([11], dataclasses.replace(FlightConfig(), control=control), layer=layer), layer))
    return out


def test_a_5s_link_loss_with_hold_holds_then_resumes_the_mission(held):
    """COM_OBL_ACT = Hold: the vehicle holds; the link is back before COM_DL_LOSS_T = 10 s, so the
    mission computer re-engages offboard and finishes the mission."""
    batch, layer = held[0]
    t, tr = _truth(batch, 0)
    (s, e), = layer.windows(0, 10**12)
    holding = (t >= s / 1e6 + 3.0) & (t < e / 1e6)  # 1 s to the failsafe, then braking
    spread = np.ptp(tr[holding, :2], axis=0)
    assert spread.max() < 1.5, f"the vehicle holds its position during the loss (moved {spread})"
    assert batch.status[0] == "landed"
    assert _closest(tr, batch.waypoints[0, 3]) < 2.0, "the mission resumed"


def test_a_5s_link_loss_returns_when_the_datalink_timeout_is_shorter(held):
    """Hold, then COM_DL_LOSS_T = 3 s, NAV_DLL_ACT = return: the vehicle flies home and lands."""
    batch, _ = held[1]
    t, tr = _truth(batch, 0)
    assert batch.status[0] == "landed"
    assert np.hypot(*tr[-1, :2]) < 2.0
    assert _closest(tr, batch.waypoints[0, 3]) > 10.0, "it never flew the rest of the square"


def test_the_sitl_takes_the_same_offboard_loss_failsafe():
    """One set of failsafe defaults: the live sitl's COM_OBL_ACT is the simulation mode's action."""
    from scart_bench.generator.sitl.commander import Params

    params = Params()
    assert OFFBOARD_LOSS_ACTIONS[int(params["COM_OBL_ACT"])] == ControlParams().offboard_loss_action == "land"
    assert params["COM_OF_LOSS_T"] == ControlParams().offboard_loss_s
    with pytest.raises(ValueError, match=r"control.offboard_loss_action: expected one of"):
        ControlParams(offboard_loss_action="loiter")


def test_inject_command_and_mission_tamper_only_at_the_command_point():
    with pytest.raises(ScenarioError, match="command_long"):
        _sc("x", "link", {"action": "inject_command", "command": "land"})
    with pytest.raises(ScenarioError, match="mission"):
        _sc("x", "command", {"action": "mission_tamper", "target": ["setpoint"]})


@pytest.fixture(scope="module")
def replay_flood():
    # seed 5 reaches the square's first corner at 30.6 s (armed after its GPS fix and the estimator's
    # origin, 3 s at idle, 9 s of hover): on its first side at 31 s, at cruise speed
    cfg = FlightConfig(mission=MissionParams(max_duration_s=41.0))
    replay = _sc("replay", "link", {"action": "replay", "span_s": 2.0}, end_s=4.0, start_s=31.0)
    flood = _sc("flood", "link", {"action": "flood", "rate_hz": 150.0}, end_s=4.0, start_s=31.0)
    layer = AttackLayer([[replay], [flood], []], [5, 5, 5])
    return simulate([5, 5, 5], cfg, layer=layer), layer


def _window(layer, i):
    (s, e), = layer.windows(i, 10**12)
    return s, e


@pytest.mark.parametrize("topic", ["local_position_ned", "attitude", "setpoint"])
def test_replay_feeds_the_captured_span_again_exactly_in_the_labelled_rows(replay_flood, topic):
    """The navigator (telemetry) and the flight controller (setpoints) receive, inside the window,
    the messages of the 2 s before it, in a loop; outside it, what was sent."""
    batch, layer = replay_flood
    s, e = _window(layer, 0)
    steps, sent, _ = batch.simulator[topic]
    _, got, ok = batch.navigator[topic]
    t_us = steps * 4000
    inside = (t_us >= s) & (t_us < e)
    assert ok[0].all()
    np.testing.assert_array_equal(got[0, ~inside], sent[0, ~inside])
    src = s - 2_000_000 + np.mod(t_us[inside] - s, 2_000_000)
    j = np.searchsorted(t_us, src, side="right") - 1
    np.testing.assert_array_equal(got[0, inside], sent[0, j])
    changed = np.any(got[0] != sent[0], axis=1)
    assert changed[inside].mean() > 0.9 and not changed[~inside].any()


def test_flood_delays_then_drops_real_messages_exactly_in_the_labelled_rows(replay_flood):
    """150 frames/s of 53 bytes on a 5760 B/s link half used: the queue grows 0.88 s per second up
    to 1 s; each real message carries the value sent that long before, and once the queue is full
    about half of them (1 / 1.88) get through."""
    batch, layer = replay_flood
    s, e = _window(layer, 1)
    steps, sent, _ = batch.simulator["local_position_ned"]
    _, got, ok = batch.navigator["local_position_ned"]
    t_us = steps * 4000
    inside = (t_us >= s) & (t_us < e)
    np.testing.assert_array_equal(got[1, ~inside], sent[1, ~inside])
    assert ok[1, ~inside].all()
    overload = 150.0 * 53.0 / 5760.0 + 0.5
    delay = np.round(np.minimum((t_us[inside] - s) / 1e6 * (overload - 1.0), 1.0) * 1e6).astype(np.int64)
    j = np.searchsorted(t_us, t_us[inside] - delay, side="right") - 1
    np.testing.assert_array_equal(got[1, inside], sent[1, j])
    full = (t_us[inside] - s) / 1e6 * (overload - 1.0) >= 1.0
    assert ok[1, inside][~full].all()
    assert ok[1, inside][full].mean() == pytest.approx(1.0 / overload, abs=0.05)


def test_replay_and_flood_on_a_recorded_flight_in_csv_mode(tmp_path):
    """csv mode applies replay, flood and link loss to a recorded flight (nothing reacts); forged
    commands and mission tampering need the closed loop and are refused with a clear error."""
    from scart_bench.dataset import DatasetError
    from scart_bench.generator.logs.offline import attack_file

    log = tmp_path / "flight.csv"
    t = np.arange(0, 20.0, 0.02)
    import pandas as pd

    pd.DataFrame({"timestamp": (t * 1e6).astype(np.int64), "x": np.sin(t), "y": np.cos(t), "z": -5.0 + 0 * t}
                 ).to_csv(log, index=False)
    for name, action in (("replay", {"action": "replay", "span_s": 2.0}), ("flood", {"action": "flood"}),
                         ("loss", {"action": "link_loss"})):
        sc = tmp_path / f"{name}.toml"
        body = "\n".join(f"{k} = {v!r}".replace("'", '"') for k, v in action.items())
        sc.write_text(f'[scenario]\nid = "{name}"\n[[scenario.start]]\ncondition = "time_window"\nstart_s = 8.0\n'
                      f'[[scenario.end]]\ncondition = "duration"\nseconds = 4.0\n[[scenario.actions]]\n{body}\n')
        out = tmp_path / name
        attack_file(log, sc, out)
        assert any(out.rglob("*")), name
    sc = tmp_path / "disarm.toml"
    sc.write_text('[scenario]\nid = "d"\ninjection_point = "command"\n[[scenario.actions]]\naction = "inject_command"\n')
    with pytest.raises(DatasetError, match="inject_command.*simulation mode"):
        attack_file(log, sc, tmp_path / "d")
    # in a grid, the closed-loop configurations get no copy and the link ones are written
    from scart_bench.dataset import open_dataset

    grid = tmp_path / "grid.toml"
    text = open("data/scenarios/control_link.toml").read()
    grid.write_text(text.replace("start_s = 20.0", "start_s = 8.0"))
    attack_file(log, grid, tmp_path / "g")
    actions = set(open_dataset(tmp_path / "g").manifest["action"])
    assert actions == {"link_loss", "replay", "flood"}


def test_csv_mode_replays_delays_and_drops_exactly_in_the_labelled_rows():
    import pandas as pd

    from scart_bench.generator.modes import csv_mode

    t_us = np.arange(0, 20_000_000, 20_000)
    table = pd.DataFrame({"Timestamp": t_us, "x": t_us / 1e6, "y": -t_us / 1e6})
    jobs = [[_sc("r", "link", {"action": "replay", "span_s": 2.0}, end_s=4.0, start_s=8.0)],
            [_sc("f", "link", {"action": "flood", "rate_hz": 150.0}, end_s=4.0, start_s=8.0)],
            [_sc("l", "link", {"action": "link_loss"}, end_s=4.0, start_s=8.0)]]
    for sc in jobs:  # the generator's topics resolve against this recording's
        sc[0] = dataclasses.replace(sc[0], actions=[(sc[0].actions[0][0], {**sc[0].actions[0][1], "target": ["*"]})])
    (replay, rw, _), (flood, fw, _), (loss, lw, _) = csv_mode([{"pos": table}] * 3, jobs, [0, 0, 0])
    s, e = rw[0][:2]
    assert (s, e) == (8_000_000, 12_000_000) and fw[0][:2] == lw[0][:2] == (s, e)
    r = replay["pos"]
    inside = (r["Timestamp"] >= s) & (r["Timestamp"] < e)
    assert (r["Is_Anomaly"] == inside).all()
    expect = (s - 2_000_000 + np.mod(r["Timestamp"][inside] - s, 2_000_000)) / 1e6
    np.testing.assert_allclose(r["x"][inside], expect)
    np.testing.assert_allclose(r["x"][~inside], r["Timestamp"][~inside] / 1e6)
    f = flood["pos"]
    inside_f = (f["Timestamp"] >= s) & (f["Timestamp"] < e)
    assert (f["x"][inside_f] < f["Timestamp"][inside_f] / 1e6 - 0.5).mean() > 0.5, "late values"
    assert len(f) < len(table), "the full queue dropped some"
    lo = loss["pos"]
    assert len(lo) == len(table) - 200 and not ((lo["Timestamp"] >= s) & (lo["Timestamp"] < e)).any()


def test_a_benchmark_run_on_a_dataset_with_control_link_attacks_reports_them(tmp_path, capsys):
    """generate (simulation and csv mode) -> run -> breakdown by action names every new action."""
    import sys
    from pathlib import Path

    import pandas as pd

    from scart_bench.cli.main import main
    from scart_bench.dataset import open_dataset

    sys.path.insert(0, str(Path(__file__).parent))
    from run_fixtures import plugin

    out = tmp_path / "ds"
    # the grid's attacks start at 20 s, where a flight without a ground phase was on its second leg;
    # a flight that waits for its GPS fix and arms at 6.5-14.5 s is there about 13 s later
    grid = tmp_path / "control_link.toml"
    grid.write_text(open("data/scenarios/control_link.toml").read().replace("start_s = 20.0", "start_s = 33.0"))
    assert main(["generate", "--profile", "quick", "--flights", "4", "--scenarios", str(grid),
                 "--out", str(out)]) == 0
    m = open_dataset(out).manifest.set_index("flight_id")
    attacked = m[m["mode"] != "normal"]
    assert (attacked["kind"] == "attack").all()
    sim = attacked[attacked["mode"] == "simulation"]
    assert set(sim["action"]) == {"inject_command", "mission_tamper", "link_loss", "replay", "flood"}
    assert not sim["no_effect"].any(), "every attack changed the flight (or what its navigator received)"
    assert set(attacked.loc[attacked["mode"] == "csv", "action"]) == {"link_loss", "replay", "flood"}
    from scart_bench.reports.figures import flight_path

    ds = open_dataset(out)
    for fid in sim.index:  # the paper-style path figure: the attacked path beside its normal twin
        assert flight_path(ds, fid, tmp_path / "figures").stat().st_size > 0
    by_action = sim.reset_index().set_index("action")
    assert by_action.loc["mission_tamper", "impact_max_dev_m"] > 10.0, "the path went to the moved corner"
    assert not by_action.loc["inject_command", "impact_mission_completed"], "the forged land ended it early"
    run = tmp_path / "run"
    assert main(["run", "--dataset", str(out), "--detectors", "zscore_test", "--plugin", plugin("ZScore"),
                 "--out", str(run)]) == 0
    capsys.readouterr()
    bd = pd.read_csv(run / "breakdown.csv")
    actions = set(bd.loc[bd["dimension"] == "action", "value"])
    assert {"inject_command", "mission_tamper", "link_loss", "replay", "flood"} <= actions


def test_a_mission_longer_than_the_message_flies_its_tail_untouched():
    """A mission of more items than the link's MISSION message holds (a hand-flown flight's stick
    samples, a long survey) goes through the command point: its first items as the message carries
    them (a tamper moves them), the rest as they were."""
    from scart_bench.generator.flight_software.commander import MAX_MISSION_ITEMS, exchange

    class _Tamper:
        def on_messages(self, point, step, t_us, msgs):
            out = {k: (v.copy(), np.ones(len(v), dtype=bool)) for k, v in msgs.items()}
            out["mission"][0][:, 0] += 20.0  # item 0 moved 20 m north
            return out

    k = MAX_MISSION_ITEMS + 8
    mission = np.arange(2 * k * 3, dtype=float).reshape(2, k, 3)
    _, _, _, items = exchange(_Tamper(), 0, 0, np.zeros((2, 6)), mission)
    assert items.shape == mission.shape
    np.testing.assert_array_equal(items[:, 0, 0], mission[:, 0, 0] + 20.0)
    np.testing.assert_array_equal(items[:, 1:], mission[:, 1:])
