"""Missions as data (issue 47 item 1): QGroundControl ``.plan`` and ``QGC WPL 110`` files flown by both
engines and by the sitl; malformed files refused with one line; the same seed gives the same dataset.

The test missions (tests/data/missions/): ``inspection.plan`` at PX4 SITL's home (take-off to 10 m,
speed 7 m/s, a waypoint held 4 s, a climb to 13 m, a 5 s loiter, return to launch) and
``delivery.waypoints`` at ArduPilot SITL's home, 35 deg S (take-off to 8 m, a waypoint in the AMSL
frame held 3 s, speed 6.5 m/s, a waypoint, land at a drop point).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from scart_bench.cli.main import main
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.mission_files import (
    MissionFileError,
    read_mission,
    read_missions,
    with_missions,
)
from scart_bench.generator.params import DT, MissionParams

DATA = Path(__file__).resolve().parent / "data" / "missions"
PLAN, WPL = DATA / "inspection.plan", DATA / "delivery.waypoints"
TURN_M = 5.0  # a turn: within this distance (m) of an item
CRUISE = MissionParams().cruise_speed
SEEDS = [10, 7]  # seed mod 2: 10 flies the .plan (file 0), 7 the .waypoints (file 1)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-9), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _longest_run(mask: np.ndarray, t: np.ndarray) -> float:
    best, start = 0.0, None
    for i, m in enumerate(np.append(mask, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            best = max(best, t[i - 1] - t[start])
            start = None
    return best


def check_flight(t: np.ndarray, truth: np.ndarray, items: np.ndarray, what: str, speed_of=np.max,
                 speed_tol: float = 1.0) -> None:
    """The true track (rows: north, east, down, vn, ve, vd, ... about the mission's home) flies ``items``
    (the navigator's table: north, east, down, speed, hold): within 2 m of its legs outside the turns, at
    each leg's speed (``speed_of`` the ground speeds of the leg's middle half, within ``speed_tol`` m/s),
    holds at least their stated time (and not much longer), lands at the last item."""
    pos, vel = truth[:, :3], truth[:, 3:6]
    air = pos[:, 2] < -1.0
    ne, speed = pos[air, :2], np.hypot(vel[air, 0], vel[air, 1])
    near_item = np.min([np.hypot(*(ne - it[:2]).T) for it in items], axis=0)
    legs = [(items[k - 1, :2], items[k, :2]) for k in range(1, len(items))
            if np.hypot(*(items[k, :2] - items[k - 1, :2])) > 2 * TURN_M]
    to_leg = np.min([_segment_distance(ne, a, b) for a, b in legs], axis=0)
    off = near_item > TURN_M
    assert off.sum() > 200, f"{what}: the track has legs"
    assert to_leg[off].max() < 2.0, f"{what}: {to_leg[off].max():.2f} m off the legs outside the turns"
    for k in range(1, len(items)):
        a, b = items[k - 1, :2], items[k, :2]
        length = np.hypot(*(b - a))
        if length <= 2 * TURN_M:
            continue
        mid = (_segment_distance(ne, a + 0.25 * (b - a), a + 0.75 * (b - a)) < 2.0)
        assert mid.sum() > 10, f"{what}: leg to item {k} flown"
        flew = float(speed_of(speed[mid]))
        assert abs(flew - items[k, 3]) < speed_tol, f"{what}: leg to item {k} at {items[k, 3]} m/s, flew {flew:.2f}"
    for k in np.flatnonzero(items[:, 4] > 0):
        at = (np.hypot(*(pos[:, :2] - items[k, :2]).T) < 1.5) & (np.abs(pos[:, 2] - items[k, 2]) < 1.0)
        stay = _longest_run(at, t)
        assert items[k, 4] - 0.05 <= stay <= items[k, 4] + 6.0, f"{what}: hold {items[k, 4]} s at item {k}, " \
            f"stayed {stay:.2f} s"
    assert pos[-1, 2] > -0.2, f"{what}: on the ground at the end"
    assert np.hypot(*(pos[-1, :2] - items[-1, :2])) < 2.0, f"{what}: landed at the last item"


# --- both engines ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flown():
    missions = read_missions([PLAN, WPL])
    cfg = with_missions(FlightConfig(mission=MissionParams(ground_phase=False)), missions)
    return missions, cfg, {engine: simulate(SEEDS, cfg, engine=engine) for engine in ("numpy", "kernel")}


def test_both_engines_fly_the_same_flights_of_a_plan_and_a_waypoints_file(flown):
    """The numpy reference step and the compiled kernel fly both files in one batch, step for step alike."""
    _, _, by = flown
    ref, ker = by["numpy"], by["kernel"]
    np.testing.assert_array_equal(ker.exit_step, ref.exit_step)
    for topic in ("truth", "setpoint", "local_position_ned"):
        steps = ref.simulator[topic][0]
        for i in range(len(SEEDS)):  # to each flight's end (the kernel stops flying a flight that has landed)
            n = int(np.searchsorted(steps, ref.exit_step[i], side="right"))
            np.testing.assert_allclose(ker.simulator[topic][1][i, :n], ref.simulator[topic][1][i, :n], rtol=0,
                                       atol=1e-9, err_msg=topic)
    assert ref.status == ker.status == ["landed", "landed"]


@pytest.mark.parametrize("engine", ["numpy", "kernel"])
@pytest.mark.parametrize("which", [0, 1], ids=["plan", "waypoints"])
def test_the_true_track_follows_the_legs_holds_and_lands(flown, engine, which):
    missions, _, by = flown
    r = by[engine]
    steps, vals, _ = r.simulator["truth"]
    last = int(np.searchsorted(steps, r.exit_step[which], side="right"))
    items = missions[SEEDS[which] % 2].navigator_items(CRUISE)
    check_flight(steps[:last] * DT, vals[which, :last], items, f"{engine} {missions[which].name}")


def test_a_flight_flies_the_same_alone_and_beside_a_longer_mission(flown):
    """The shorter mission in a batch lands after its own last item, as when it is flown alone."""
    _, cfg, by = flown
    alone = simulate([SEEDS[1]], cfg, engine="kernel")
    both = by["kernel"]
    k = int(alone.exit_step[0])
    assert k == both.exit_step[1]
    truth = alone.simulator["truth"][1][0]
    np.testing.assert_array_equal(truth, both.simulator["truth"][1][1, :len(truth)])


def test_the_square_is_flown_without_mission_files():
    """No files: the items are the jittered square's and the leg speed each flight's cruise speed."""
    from scart_bench.generator.flight_software.navigator import mission_table, mission_waypoints

    rngs = [np.random.default_rng(s) for s in (1, 2)]
    wps, cruise, table, last = mission_table(MissionParams(), [1, 2], rngs)
    w0, c0 = mission_waypoints(MissionParams(), [np.random.default_rng(s) for s in (1, 2)])
    np.testing.assert_array_equal(wps, w0)
    np.testing.assert_array_equal(table[:, :, 3], np.repeat(c0[:, None], wps.shape[1], axis=1))
    assert not table[:, :, 4].any() and (last == wps.shape[1] - 1).all()


# --- the sitl --------------------------------------------------------------------------------------
def _fly_in_sitl(path: Path, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """A pymavlink ground station uploads the file's items (moved to the vehicle's home), arms and starts
    the mission; the sitl flies it to the landing. Times (s), true states, home (NED), items reached."""
    pytest.importorskip("pymavlink")
    from pymavlink import mavutil

    from scart_bench.generator.sitl.missions import file_items
    from scart_bench.generator.sitl.server import SitlServer

    mav = mavutil.mavlink
    mission = read_mission(path)
    with SitlServer(("127.0.0.1", 0), seed=seed, record=True, log=lambda line: None) as sitl:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{sitl.address[1]}", source_system=255,
                                          source_component=190)
        conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        reached: list[int] = []

        def wait(kinds: str, cond=lambda m: True, timeout_s: float = 10.0):
            """The next message of one of ``kinds`` (space-separated) meeting ``cond``, in lockstep."""
            end = sitl.time_s + timeout_s
            while True:
                while (m := conn.recv_match(blocking=False)) is not None:
                    if m.get_type() == "MISSION_ITEM_REACHED":
                        reached.append(m.seq)
                    if m.get_type() in kinds.split() and cond(m):
                        return m
                assert sitl.time_s < end, f"{path.name}: no {kinds} within {timeout_s} s"
                sitl.advance(0.02)

        home = wait("HOME_POSITION")
        wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
        # as the generator's navigator flies: return at the height flown, the next leg once within 0.8 m of an item
        for name, value in (("RTL_RETURN_ALT", 0.0), ("NAV_ACC_RAD", MissionParams().acceptance_radius)):
            conn.mav.param_set_send(1, 1, name.encode(), value, mav.MAV_PARAM_TYPE_REAL32)
            assert wait("PARAM_VALUE", lambda m, n=name: m.param_id == n).param_value == pytest.approx(value)
        items = file_items(mission, (home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1e3))
        conn.mav.mission_count_send(1, 1, len(items), 0)
        while (m := wait("MISSION_REQUEST_INT MISSION_ACK")).get_type() != "MISSION_ACK":
            it = items[m.seq]
            scale = 1e4 if it.frame == 1 else 1e7
            conn.mav.mission_item_int_send(1, 1, it.seq, it.frame, it.command, 0, 1, it.param1, it.param2,
                                           it.param3, it.param4, int(round(it.x * scale)), int(round(it.y * scale)),
                                           it.z, 0)
        assert m.type == mav.MAV_MISSION_ACCEPTED
        for command, p1 in ((mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0), (mav.MAV_CMD_MISSION_START, 0.0)):
            conn.mav.command_long_send(1, 1, command, 0, p1, 0, 0, 0, 0, 0, 0)
            assert wait("COMMAND_ACK", lambda m, c=command: m.command == c).result == mav.MAV_RESULT_ACCEPTED
        wait("HEARTBEAT", lambda m: not m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, timeout_s=240.0)
        conn.close()
        ts, vals = sitl.views["simulator"]["truth"]
        return np.asarray(ts) / 1e6, np.vstack(vals), np.array([home.x, home.y, home.z]), reached


@pytest.mark.parametrize("path", [PLAN, WPL], ids=["plan", "waypoints"])
def test_the_sitl_flies_the_file_uploaded_by_a_ground_station(path):
    t, truth, home, reached = _fly_in_sitl(path, seed=3)
    mission = read_mission(path)
    n_items = len(mission.commands)
    assert reached[:n_items - 1] == list(range(n_items - 1)), f"every item reached in order: {reached}"
    rel = truth.copy()
    rel[:, :3] -= home
    check_flight(t, rel, mission.navigator_items(CRUISE), f"sitl {path.name}")


# --- the command line ------------------------------------------------------------------------------
def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_generate_with_missions_is_deterministic_and_records_the_file_each_flight_flew(tmp_path, capsys):
    args = ["generate", "--profile", "quick", "--normal-only", "--flights", "3", "--seed", "4", "--missions",
            str(PLAN), str(WPL)]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b"), "same seed, same bytes"
    flown = set()
    for cfg_file in sorted((tmp_path / "a" / "flights").glob("*/raw/config.json")):
        cfg = json.loads(cfg_file.read_text())
        path = {PLAN.name: PLAN, WPL.name: WPL}[cfg["mission_file"]]
        assert cfg["mission_file"] == [PLAN, WPL][cfg["seed"] % 2].name, "file seed mod 2"
        items = read_mission(path).navigator_items(CRUISE)
        np.testing.assert_allclose(np.array(cfg["waypoints_ned"])[:len(items)], items[:, :3])
        assert cfg["status"] == "landed"
        flown.add(cfg["mission_file"])
    assert flown == {PLAN.name, WPL.name}


def _plan(items: list) -> str:
    return json.dumps({"fileType": "Plan", "version": 1, "mission": {
        "version": 2, "plannedHomePosition": [47.397742, 8.545594, 488.0], "hoverSpeed": 5, "items": items}})


def _item(cmd: int, params: list, frame: int = 3) -> dict:
    return {"type": "SimpleItem", "command": cmd, "frame": frame, "params": params, "autoContinue": True}


TAKEOFF = _item(22, [0, 0, 0, None, 47.397742, 8.545594, 10])
SURVEY = {"type": "ComplexItem", "complexItemType": "survey", "polygon": [[47.39, 8.54], [47.40, 8.54], [47.40, 8.55]]}
WPL_HEAD = "QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488\t1\n1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10\t1\n"


@pytest.mark.parametrize("name, text, words", [
    ("survey.plan", _plan([TAKEOFF, SURVEY]), ["item 2", "survey", "expected a SimpleItem"]),
    ("latitude.plan", _plan([TAKEOFF, _item(16, [0, 0, 0, None, 123.0, 8.5, 10])]),
     ["item 2", "NAV_WAYPOINT", "expected a latitude within +-90 deg, got 123"]),
    ("hold.plan", _plan([TAKEOFF, _item(19, [-3, 0, 0, None, 47.3978, 8.5456, 10])]),
     ["item 2", "NAV_LOITER_TIME", "expected param1 (hold time) 0 to 3600 s, got -3"]),
    ("broken.plan", '{"fileType": "Plan", "mission": {', ["expected a QGroundControl .plan (JSON)"]),
    ("short.waypoints", WPL_HEAD + "2\t0\t3\t16\t0\t0\t0\t47.3978\t8.5456\t10\t1\n",
     ["line 4", "expected 12 tab-separated fields", "got 11"]),
    ("loiter.waypoints", WPL_HEAD + "2\t0\t3\t17\t0\t0\t0\t0\t47.3978\t8.5456\t10\t1\n",
     ["item 2", "line 4", "command 17", "expected one of NAV_TAKEOFF (22)"]),
    ("terrain.waypoints", WPL_HEAD + "2\t0\t10\t16\t0\t0\t0\t0\t47.3978\t8.5456\t10\t1\n",
     ["item 2", "expected frame 0 or 5", "got frame 10"]),
])
def test_a_malformed_mission_file_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, name, text, words):
    bad = tmp_path / name
    bad.write_text(text)
    out = tmp_path / "out"
    code = main(["generate", "--profile", "quick", "--normal-only", "--flights", "1", "--out", str(out),
                 "--missions", str(PLAN), str(bad)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert str(bad) in err and all(w in err for w in words), err
    assert not out.exists(), "nothing written"
    with pytest.raises(MissionFileError):
        read_mission(bad)
