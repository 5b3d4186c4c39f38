"""Defense in the loop (issue 32): a detector scoring the navigator's stream while the flight is flown, and
the flight controller's response on its alarm (generator.defense, benchmark.defense)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.defense import (
    BatchMonitor,
    DefendedDetector,
    ScheduledAlarms,
    defend,
    defense_table,
    replay_notices,
    table_markdown,
)
from scart_bench.dataset.labels import combine
from scart_bench.detectors.base import Detector
from scart_bench.detectors.statistical import Statistical
from scart_bench.generator.defense import DefenseHook, Response
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.geo import latlon_to_ned
from scart_bench.generator.modes import _builtin_rates
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import scenario_from_dict
from scart_bench.generator.telemetry.tables import flight_views, truth_table

CFG = FlightConfig(timing="ideal")
NORMAL_SEEDS = [11, 12]
ATTACK_SEEDS = [1, 2]
#: A 40 m GPS position jump at the sensor level that lasts to the end of the flight: the estimator's gate
#: rejects it, then (14 s without position fusion) EKF2's reset takes it in and the mission is flown 40 m off.
JUMP = scenario_from_dict(
    {
        "id": "gps-jump-40",
        "injection_point": "sensor",
        "start": [{"condition": "altitude_above", "height": 5.0}],
        "end": [{"condition": "duration", "seconds": 600.0}],
        "actions": [
            {"action": "bias", "target": ["gps.lat", "gps.lon"], "offset": 40.0, "direction_deg": 90.0}
        ],
    }
)


class GpsDisagreement(Detector):
    """A small real detector: the horizontal distance (m) between the GPS receiver's fix and the estimate."""

    name = "gps_disagreement"

    def __init__(self, columns: list[str] | None = None, random_state: int = 0):
        self.columns = columns
        self.random_state = random_state

    def _fit(self, X_list) -> None:
        self.history_rows_ = 1

    def _score(self, X: np.ndarray) -> np.ndarray:
        raw = X * self.scale_ + self.mean_
        n1, e1 = latlon_to_ned(raw[:, 0], raw[:, 1])
        n2, e2 = latlon_to_ned(raw[:, 2], raw[:, 3])
        return np.hypot(n1 - n2, e1 - e2)


COLUMNS = ["global_position_int.lat", "global_position_int.lon", "gps_raw_int.lat", "gps_raw_int.lon"]


@pytest.fixture(scope="module")
def normal():
    return simulate(NORMAL_SEEDS, CFG)


@pytest.fixture(scope="module")
def tables(normal):
    return [combine(flight_views(normal, i)[0], [])["most_frequent"] for i in range(len(NORMAL_SEEDS))]


@pytest.fixture(scope="module")
def disagreement(tables):
    """Fitted on the normal flights; threshold twice their largest score."""
    det = GpsDisagreement(columns=COLUMNS).fit(tables)
    return det, 2.0 * max(float(det.score(t).max()) for t in tables)


@pytest.fixture(scope="module")
def undefended():
    return simulate(ATTACK_SEEDS, CFG, layer=_layer(ATTACK_SEEDS))


def _layer(seeds):
    return AttackLayer([[JUMP] for _ in seeds], seeds, rates=_builtin_rates())


def _same(a, b) -> None:
    assert a.status == b.status and np.array_equal(a.exit_step, b.exit_step)
    for view in ("simulator", "navigator"):
        va, vb = getattr(a, view), getattr(b, view)
        for topic in va:
            if topic in vb:
                for x, y in zip(va[topic], vb[topic]):
                    assert np.array_equal(x, y), (view, topic)


def test_reject_gps_then_return_brings_a_spoofed_flight_home(disagreement, undefended):
    det, threshold = disagreement
    n = len(ATTACK_SEEDS)
    twin = simulate(ATTACK_SEEDS, CFG)
    hook = DefenseHook(
        BatchMonitor(det, threshold, n, burn_in_s=1.0),
        Response("reject_gps_then_return"),
        n,
        layer=_layer(ATTACK_SEEDS),
    )
    defended = simulate(ATTACK_SEEDS, CFG, layer=hook)
    for i in range(n):
        plan = truth_table(twin, i)[["x", "y"]].to_numpy()[-1]
        und = truth_table(undefended, i)[["x", "y"]].to_numpy()
        assert np.hypot(*(und[-1] - plan)) >= 20.0  # undefended: lands at least 20 m off its planned landing
        d = truth_table(defended, i)[["x", "y"]].to_numpy()
        assert defended.status[i] == "landed"
        assert np.hypot(*(d[-1] - d[0])) <= 5.0  # defended: within 5 m of home
        onset = hook.labelled_windows(i, 10**12)[0][0]
        assert (
            onset <= hook.notice_us[i] <= hook.response_us[i] < onset + 5_000_000
        )  # alarmed during the attack
        log = hook.event_log(i, 10**12)
        events = [(e["event"], e["scenario_id"]) for e in log]
        assert ("alarm", "defense") in events and ("response", "defense") in events
        assert [e["timestamp_us"] for e in log] == sorted(e["timestamp_us"] for e in log)
    # the replay (what defend flies): the notices the monitor raises, found on the undefended flights, then only
    # the alarmed flights flown with the response: the same flights, byte for byte, without the detector inside
    notices = replay_notices(undefended, DefendedDetector("d", det, threshold, burn_in_s=1.0), alarms=1)
    np.testing.assert_array_equal(notices.notice_us, hook.notice_us)
    again = DefenseHook(ScheduledAlarms(notices.notice_us, 1), Response("reject_gps_then_return"), n,
                        layer=_layer(ATTACK_SEEDS))
    _same(defended, simulate(ATTACK_SEEDS, CFG, layer=again))
    np.testing.assert_array_equal(again.response_us, hook.response_us)


@pytest.mark.parametrize("response", ["reject_gps_then_return", "hold"])
def test_a_never_alarming_defense_is_byte_identical(normal, undefended, disagreement, response):
    det, _ = disagreement
    n = len(NORMAL_SEEDS)
    hook = DefenseHook(BatchMonitor(det, math.inf, n), Response(response), n)
    _same(normal, simulate(NORMAL_SEEDS, CFG, layer=hook))
    assert (hook.response_us < 0).all() and not hook.events
    if response.startswith("reject"):  # an attacked batch too: the layer's own flight, unchanged
        hook = DefenseHook(BatchMonitor(det, math.inf, 2), Response(response), 2, layer=_layer(ATTACK_SEEDS))
        _same(undefended, simulate(ATTACK_SEEDS, CFG, layer=hook))


def test_an_always_alarming_defense_aborts_every_normal_flight(disagreement):
    det, _ = disagreement
    always = DefendedDetector("always", det, threshold=-1.0, burn_in_s=1.0)  # distances are >= 0
    run = defend([always], [Response("land")], [], [], NORMAL_SEEDS, flight_config=CFG)
    table = defense_table(run.flights)
    row = table.iloc[0]
    assert row["normal"] == len(NORMAL_SEEDS) and row["false_aborts"] == len(NORMAL_SEEDS)
    assert row["false_abort_low"] > 0.0
    assert "always | land (x1)" in table_markdown(table)


def test_the_monitor_scores_the_rows_the_recorded_flight_has(normal, tables):
    """Block scoring in the loop gives the detector's batch scores on the recorded navigator view."""
    det = Statistical(window=20).fit(tables)
    mon = BatchMonitor(det, math.inf, len(NORMAL_SEEDS), block_rows=7)
    _same(normal, simulate(NORMAL_SEEDS, CFG, layer=DefenseHook(mon, Response("hold"), len(NORMAL_SEEDS))))
    times = np.concatenate([t for t, _ in mon.blocks])
    scores = np.concatenate([s for _, s in mon.blocks], axis=1)
    for i, table in enumerate(tables):
        want = pd.Series(det.score(table), index=table["Timestamp"].to_numpy())
        got = pd.Series(scores[i], index=times)
        common = want.index.intersection(got.index[np.isfinite(got.to_numpy())])
        assert len(common) > 0.9 * len(want)
        np.testing.assert_allclose(
            got[common].to_numpy(), want[common].to_numpy(), rtol=1e-6, atol=1e-9
        )  # rolling sums: window vs flight


def test_response_parameters_are_checked():
    with pytest.raises(ValueError, match="expected one of"):
        Response("explode")
    with pytest.raises(ValueError, match="alarms"):
        Response("hold", alarms=0)


# -- live: the sitl with a detector and a response (acceptance 4) -----------------------------------------
#: a 40 m GPS jump at the sensor point, 16 s after boot (on the mission's first leg), to the end of the flight
LIVE_JUMP = scenario_from_dict(
    {
        "id": "gps-jump-live",
        "injection_point": "sensor",
        "start": [{"condition": "time_window", "start_s": 16.0}],
        "end": [{"condition": "duration", "seconds": 600.0}],
        "actions": [
            {"action": "bias", "target": ["gps.lat", "gps.lon"], "offset": 40.0, "direction_deg": 90.0}
        ],
    }
)


def test_sitl_mission_under_gps_spoofing_switches_to_the_response_and_returns_home(disagreement):
    """A pymavlink mission (arm, take off, square mission) under a GPS jump: the detector alarms, the vehicle
    switches to Return (heartbeat custom mode, STATUSTEXT) and, GPS rejected, lands within 5 m of home."""
    pytest.importorskip("pymavlink")
    from pymavlink import mavutil

    from scart_bench.benchmark.live import StreamMonitor
    from scart_bench.generator.defense import LiveDefense
    from scart_bench.generator.sitl.server import SitlServer

    mav = mavutil.mavlink
    det, _ = disagreement
    monitor = StreamMonitor(det, 10.0, name="gps_disagreement", log=lambda line: None, burn_in_s=1.0)
    defense = LiveDefense(monitor, Response("reject_gps_then_return"))
    with SitlServer(("127.0.0.1", 0), [LIVE_JUMP], seed=3, record=True, log=lambda line: None,
                    defense=defense) as sitl:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{sitl.address[1]}", source_system=255)
        conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        seen: list[tuple[float, object]] = []

        def wait(kind, cond=lambda m: True, timeout_s=30.0):
            end = sitl.time_s + timeout_s
            while True:
                while (m := conn.recv_match(blocking=False)) is not None:
                    seen.append((sitl.time_s, m))
                    if m.get_type() == kind and cond(m):
                        return m
                assert sitl.time_s < end, f"no {kind} within {timeout_s} s (t={sitl.time_s:.2f} s)"
                sitl.advance(0.02)

        def command(cmd, *p):
            conn.mav.command_long_send(1, 1, cmd, 0, *(list(p) + [0.0] * (7 - len(p))))
            return wait("COMMAND_ACK", lambda m: m.command == cmd).result

        home = wait("HOME_POSITION")
        wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
        assert command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        nan = float("nan")
        command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, home.altitude / 1000 + 10.0)
        wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 9500)
        lat0, lon0 = home.latitude, home.longitude
        corners = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0)]
        conn.mav.mission_count_send(1, 1, len(corners), 0)
        while (m := wait("MISSION_REQUEST_INT", timeout_s=2.0)) is not None:
            n, e = corners[m.seq]
            conn.mav.mission_item_int_send(
                1, 1, m.seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 1, 0, nan,
                lat0 + int(n / 111194.93 * 1e7), lon0 + int(e / (111194.93 * math.cos(math.radians(lat0 / 1e7))) * 1e7),
                10.0, 0)
            if m.seq == len(corners) - 1:
                break
        assert command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
        rtl = wait("HEARTBEAT", lambda m: m.custom_mode == (4 << 16 | 5 << 24))  # AUTO.RTL
        t_rtl = sitl.time_s
        wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, timeout_s=90)
        conn.close()
        notices = [m.text for _, m in seen if m.get_type() == "STATUSTEXT" and "Anomaly" in m.text]
        assert rtl is not None and notices == ["Anomaly notice: reject_gps_then_return"]
        assert 16.0 <= defense.notice_us / 1e6 <= defense.response_us / 1e6 < 17.0  # alarmed within a second
        assert defense.response_us / 1e6 <= t_rtl < defense.response_us / 1e6 + 1.0
        ts, truth = np.asarray(sitl.views["simulator"]["truth"][0]), np.vstack(sitl.views["simulator"]["truth"][1])
        at_response = truth[np.searchsorted(ts, defense.response_us), :2]
        assert np.hypot(*at_response) > 10.0  # the vehicle was out on the mission
        assert np.hypot(*truth[-1, :2]) <= 5.0  # and came back home
        assert 2 not in [m.seq for _, m in seen if m.get_type() == "MISSION_ITEM_REACHED"]  # mission cut short
        events = [e["event"] for e in sitl.record("sitl-defended").events if e["scenario_id"] == "defense"]
        assert events == ["alarm", "response"]


# -- detectors that cannot keep up with the link are refused -------------------------------------------
class SlowDisagreement(GpsDisagreement):
    """GpsDisagreement that takes ``call_s`` per scoring call and ``row_s`` per row scored."""

    def __init__(self, columns=None, random_state: int = 0, call_s: float = 0.0, row_s: float = 0.0):
        super().__init__(columns, random_state)
        self.call_s = call_s
        self.row_s = row_s

    def _score(self, X: np.ndarray) -> np.ndarray:
        import time

        time.sleep(self.call_s + self.row_s * len(X))
        return super()._score(X)


def test_a_detector_slower_than_the_link_is_refused_naming_its_rate(tables):
    from scart_bench.benchmark.defense import BLOCK_ROWS, require_link_rate
    from scart_bench.errors import RunError

    slow = SlowDisagreement(columns=COLUMNS, call_s=0.025).fit(tables)  # 40 calls/s
    with pytest.raises(RunError) as err:
        require_link_rate("slow", slow, where="the live loop")  # row by row: 40 rows/s
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("--detector slow: scores ")
    assert "rows/s row by row, below the link's 50 rows/s (global_position_int at 50 Hz); refused for the live" in msg
    rate = float(msg.split("scores ")[1].split(" rows/s")[0])
    assert 20.0 < rate < 50.0
    assert require_link_rate("slow", slow, block_rows=BLOCK_ROWS) > 50.0  # in blocks of 25: one call per 25 rows


def test_defend_refuses_a_slow_detector_before_flying(tables, tmp_path, monkeypatch, capsys):
    import scart_bench.benchmark.defense as bd
    from scart_bench.cli.main import main

    slow = SlowDisagreement(columns=COLUMNS, call_s=0.7).fit(tables)  # under 50 rows/s even in blocks of 25
    monkeypatch.setattr(bd, "from_run", lambda run, name, plugins=None, log=None: DefendedDetector(name, slow, 1.0))
    out = tmp_path / "defense"
    code = main(["defend", "--run", str(tmp_path), "--detector", "slow", "--response", "return", "--flights", "1",
                 "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert "in blocks of 25 rows, below the link's 50 rows/s" in err[-1] and "refused for the loop" in err[-1]


@pytest.mark.parametrize(
    "args",
    [["--detector", "statistical"], ["--response", "return"], ["--detector", "s", "--run", "r"],
     ["--detector", "s", "--run", "r", "--response", "land", "--alarms", "0"]],
)
def test_sitl_defense_options_go_together(args, capsys):
    pytest.importorskip("pymavlink")
    from scart_bench.cli.main import main

    assert main(["sitl", "--listen", "udp:127.0.0.1:0", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ("go together" in err or "--alarms 0" in err)


# -- the table in the report: the leaderboard's section and the example flight's figure -------------------
@pytest.fixture(scope="module")
def defense_folder(disagreement, tmp_path_factory):
    """defend() on the spoofed flights and as many normal ones, written as scart-bench defend writes it."""
    from scart_bench.benchmark.defense import write_defense

    det, threshold = disagreement
    run = defend([DefendedDetector("gps_disagreement", det, threshold, burn_in_s=1.0)],
                 [Response("reject_gps_then_return")], [[JUMP] for _ in ATTACK_SEEDS], ATTACK_SEEDS, NORMAL_SEEDS,
                 flight_config=CFG)
    out = tmp_path_factory.mktemp("defense") / "defense"
    write_defense(run, out, "Run test, grid gps-jump-40; wall 1.0 s.")
    return out


def test_report_shows_the_defense_table_and_the_example_flight(defense_folder, tmp_path):
    from run_fixtures import plugin, write_dataset

    from scart_bench.cli.main import main

    table = pd.read_csv(defense_folder / "defense.csv").iloc[0]
    assert (table["missions_saved"], table["endangered"], table["false_aborts"], table["normal"]) == (2, 2, 0, 2)
    paths = pd.read_csv(defense_folder / "defense_paths.csv")
    end = {name: p[["x", "y"]].to_numpy()[-1] for name, p in paths.groupby("path")}
    assert np.hypot(*end["defended"]) <= 5.0 and np.hypot(*(end["undefended"] - end["normal"])) >= 20.0

    ds = write_dataset(tmp_path / "ds")
    run = tmp_path / "run"
    assert main(["run", "--profile", "quick", "--detectors", "zscore_test", "--plugin", plugin("ZScore"),
                 "--dataset", str(ds), "--out", str(run), "--jobs", "1"]) == 0
    out = tmp_path / "report"
    assert main(["report", str(run), "--defense", str(defense_folder), "--out", str(out)]) == 0
    md = (out / "leaderboard.md").read_text()
    assert "## Defense in the loop" in md and "Run test, grid gps-jump-40" in md
    assert "| gps_disagreement | reject_gps_then_return (x1) | 2/2 (" in md
    html = (out / "leaderboard.html").read_text()
    assert "<h2>Defense in the loop</h2>" in html and "<td>gps_disagreement</td>" in html
    figure = next((out / "figures").glob("defense_*.png"))
    assert f"]({figure.relative_to(out).as_posix()})" in md and "the attacked flight undefended and defended" in html
    assert main(["report", str(run), "--defense", str(tmp_path), "--out", str(tmp_path / "r2")]) == 2


def test_proxy_sends_the_response_to_the_autopilot_on_the_notice(disagreement):
    """The generator flies over MAVLink through the proxy (gps_spoof on the link); the monitor alarms 20 s after
    arming (threshold below every score): the proxy sends RETURN_TO_LAUNCH and the vehicle lands at home."""
    pytest.importorskip("pymavlink")
    from scart_bench.benchmark.live import StreamMonitor
    from scart_bench.generator.attacks import grid_path
    from scart_bench.generator.defense import LiveDefense
    from scart_bench.generator.mavlink.link import MavlinkLink
    from scart_bench.generator.mavlink.proxy import MavlinkProxy
    from scart_bench.generator.scart.scenario import load_scenarios

    det, _ = disagreement
    lines: list[str] = []
    defense = LiveDefense(StreamMonitor(det, -1.0, name="always", log=lambda line: None, burn_in_s=20.0),
                          Response("return"))
    with MavlinkLink() as link:
        proxy = MavlinkProxy(("127.0.0.1", 0), link.mission_computer_address, load_scenarios(grid_path("gps_spoof.toml")),
                             seed=5, log=lines.append, defense=defense).start()
        try:
            link.connect(proxy.listen_address)
            batch = simulate([5], layer=link)
        finally:
            proxy.stop()
    xy = truth_table(batch, 0)[["x", "y"]].to_numpy()
    t_resp = defense.response_us / 1e6
    armed = defense.monitor.armed_us / 1e6
    assert batch.status == ["landed"] and armed + 20.0 <= t_resp < armed + 21.0
    assert np.hypot(*xy[int(t_resp * 50)]) > 10.0 and np.hypot(*xy[-1]) < 3.0  # out on the mission, then home
    assert any("anomaly notice from always" in ln and "COMMAND_LONG 20 sent" in ln for ln in lines)
    assert proxy.stats.errors == 0
    with pytest.raises(Exception, match="cannot stop the autopilot fusing GPS"):
        MavlinkProxy(("127.0.0.1", 0), ("127.0.0.1", 9), [], defense=LiveDefense(
            defense.monitor, Response("reject_gps")))
