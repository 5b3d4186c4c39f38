"""The live MAVLink proxy: the generator's flight controller <-> proxy <-> mission computer on loopback.

Acceptance of issue 8: (1) a link GPS spoofing scenario through the proxy moves the true path as
in simulation mode and the recording scores in a benchmark run; (2) unknown messages and the
command direction pass byte-identical; (3) malformed datagrams are counted and dropped; (5)
Ctrl-C leaves a complete recording. (4), the speed, is ``perf/proxy_speed.py``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import truth

pytest.importorskip("pymavlink")

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import DatasetWriter, open_dataset  # noqa: E402
from scart_bench.dataset.schema import TOPICS, TRUTH_FIELDS  # noqa: E402
from scart_bench.generator.mavlink.codec import CODECS, KNOWN, Packer, split_frames  # noqa: E402
from scart_bench.generator.mavlink.link import MavlinkLink  # noqa: E402
from scart_bench.generator.mavlink.proxy import MavlinkProxy  # noqa: E402
from scart_bench.generator.mavlink.recording import save_recording  # noqa: E402
from scart_bench.generator.scart.scenario import load_scenarios  # noqa: E402
from scart_bench.generator.telemetry.tables import flight_views, normal_record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SPOOF = ROOT / "data" / "scenarios" / "gps_spoof.toml"
SEED = 5
X, Y = TRUTH_FIELDS.index("x"), TRUTH_FIELDS.index("y")
SPOOFED = ("global_position_int", "local_position_ned", "gps_raw_int")
LOCAL = ("127.0.0.1", 0)


@pytest.fixture(scope="module")
def reference():
    """Simulation mode, one batch: seed 5 normal and spoofed, and two more normal flights."""
    from scart_bench.generator.modes import simulation_mode

    batch, layer = simulation_mode([SEED, SEED, 100, 101], [[], load_scenarios(SPOOF), [], []])
    return batch, layer


@pytest.fixture(scope="module")
def loopback():
    """Seed 5 flown by the generator over MAVLink/UDP through the proxy running gps_spoof.toml."""
    from scart_bench.generator.engine.simulate import simulate

    with MavlinkLink(keep_raw=True) as link:
        proxy = MavlinkProxy(LOCAL, link.mission_computer_address, load_scenarios(SPOOF), seed=SEED,
                             record=True).start()
        try:
            link.connect(proxy.listen_address)
            batch = simulate([SEED], layer=link)
        finally:
            proxy.stop()
    return batch, proxy, link


@pytest.fixture(scope="module")
def live_dataset(reference, loopback, tmp_path_factory):
    """A dataset of the reference's normal flights with the proxied flight recorded into it."""
    batch, _ = reference
    out = tmp_path_factory.mktemp("live") / "ds"
    writer = DatasetWriter(out, info={"profile": "test"})
    for i, fid, split in ((2, "normal-100", "train"), (3, "normal-101", "validation"), (0, "normal-005", "test")):
        writer.write(normal_record(batch, i, fid, split, {}))
    writer.close()
    save_recording(loopback[1].record("live-001"), out)
    return out


@pytest.fixture(scope="module")
def bench_run(live_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / "live-run"
    assert main(["run", "--detectors", "statistical", "--dataset", str(live_dataset), "--out", str(run)]) == 0
    return run


# --- 1. the loopback flight ----------------------------------------------------------------------
def test_loopback_gps_spoofing_moves_true_path_as_in_simulation_mode(reference, loopback):
    ref, ref_layer = reference
    batch, proxy, _ = loopback
    assert batch.status == ["landed"]
    assert proxy.windows() == ref_layer.windows(1, proxy.end_us), "the attack window is the simulation's"
    (_, live), (_, spoofed), (_, normal) = truth(batch, 0), truth(ref, 1), truth(ref, 0)
    n = min(len(live), len(spoofed), len(normal))
    off_sim = np.hypot(*(live[:n, [X, Y]] - spoofed[:n, [X, Y]]).T)
    off_normal = np.hypot(*(live[:n, [X, Y]] - normal[:n, [X, Y]]).T)
    assert off_normal.max() >= 5.0, "the spoofing pulls the vehicle off the normal path"
    assert off_sim.max() < 0.5, f"live and simulation-mode paths differ by {off_sim.max():.2f} m"
    st = proxy.stats
    assert st.altered > 0 and st.malformed == 0 and st.dropped == 0 and st.errors == 0


def test_recording_has_both_views_and_labels_from_the_layer(loopback, live_dataset):
    _, proxy, _ = loopback
    ds = open_dataset(live_dataset)
    row = ds.manifest.set_index("flight_id").loc["live-001"]
    assert row["mode"] == "simulation" and row["split"] == "test" and row["scenario_id"] == "gps-spoof-link"
    (start, end), = proxy.windows()
    assert (row["attack_start_us"], row["attack_end_us"]) == (start, end)
    nav = ds.topic("live-001", "local_position_ned")
    sim = ds.topic("live-001", "local_position_ned", view="simulator")
    ts = nav["Timestamp"].to_numpy()
    inside = (ts >= start) & (ts < end)
    np.testing.assert_array_equal(nav["Is_Anomaly"].to_numpy(), inside.astype(np.int8))
    moved = np.hypot(*(nav[["x", "y"]].to_numpy() - sim[["x", "y"]].to_numpy()).T)
    assert moved[~inside].max() == 0.0 and moved[inside].max() > 5.0
    combined = ds.flight("live-001")
    assert combined["Is_Anomaly"].sum() > 0 and "setpoint.vx" in combined.columns


def test_recorded_dataset_scores_in_a_benchmark_run(bench_run):
    import pandas as pd

    metrics = pd.read_csv(bench_run / "metrics.csv")
    assert metrics.set_index("detector").loc["statistical", "status"] == "OK"
    flights = pd.read_csv(bench_run / "flight_scores.csv")
    assert "live-001" in set(flights["flight_id"])


def test_monitor_scores_the_stream_like_the_batch_detector(loopback, live_dataset, bench_run):
    from scart_bench.benchmark.live import StreamMonitor, monitor_from_run

    _, proxy, _ = loopback
    (start, _), = proxy.windows()
    until = start + 4_000_000  # the stream up to 4 s into the attack
    order = {"setpoint": 1}  # a step's setpoint comes after its telemetry, as on the link
    events = sorted(((t, order.get(topic, 0), k, topic) for topic, (ts, _) in proxy.views.forwarded.items()
                     for k, t in enumerate(ts) if t <= until))
    monitor = monitor_from_run(bench_run, "statistical", log=lambda line: None)
    batch = monitor.detector.score(open_dataset(live_dataset).flight("live-001"))
    lines: list[str] = []
    low = StreamMonitor(monitor.detector, float(batch.min()) - 1.0, "statistical", log=lines.append)  # always alarms
    for t, _, k, topic in events:
        for m in (monitor, low):
            m.on_message(topic, t, proxy.views.forwarded[topic][1][k], proxy.layer)
    monitor.flush()
    low.flush()
    stream = np.array([s for _, s in monitor.scores])
    # the stream holds the link's float64 values, the recorded dataset their float32 (compact layout)
    np.testing.assert_allclose(stream, batch[:len(stream)], rtol=2e-5, atol=1e-5)
    assert len(stream) == (open_dataset(live_dataset).flight("live-001")["Timestamp"] <= until).sum()
    assert len(low.alarms) == len(stream)
    assert len(lines) == 1 and lines[0].startswith("ALARM statistical: t=0.00 s"), "logged once, at its onset"
    delays = [a.delay_s for a in low.alarms if a.delay_s is not None]
    assert delays and min(delays) == 0.0 and max(delays) <= 4.0
    assert "rows scored" in low.summary()


def test_monitor_raises_no_alarm_before_arming_and_its_burn_in():
    """As the benchmark counts rows: a detector alarming on every row alarms live only from 8 s after
    the navigator armed the vehicle (its setpoint's ``armed`` field), never on the ground."""
    from scart_bench.benchmark.live import StreamMonitor
    from scart_bench.dataset.schema import TOPICS

    class Always:
        columns_ = ["attitude.roll"]

        def score(self, frame):
            return np.ones(len(frame))

    monitor = StreamMonitor(Always(), 0.5, "always", log=lambda line: None, burn_in_s=8.0)
    armed_at = TOPICS["setpoint"].field_names.index("armed")
    for k in range(0, 30 * 50):  # 30 s at 50 Hz, armed at 10 s
        t = k * 20_000
        monitor.on_message("attitude", t, np.zeros(len(TOPICS["attitude"].field_names)))
        sp = np.zeros(len(TOPICS["setpoint"].field_names))
        sp[armed_at] = 1.0 if t >= 10_000_000 else 0.0
        monitor.on_message("setpoint", t, sp)
    monitor.flush()
    assert monitor.armed_us == 10_000_000
    assert len(monitor.scores) == 30 * 50
    assert min(a.t_us for a in monitor.alarms) == 18_000_000


# --- 2. byte-identical pass-through ----------------------------------------------------------------
def test_traffic_outside_the_attack_and_the_command_direction_pass_byte_identical(loopback):
    _, proxy, link = loopback
    assert link.mc.sent == link.fc.received, "every command datagram arrives as sent"
    sent, received = link.fc.sent, link.mc.received
    assert len(sent) == len(received)
    (start, end), = proxy.windows()
    changed = 0
    for a, b in zip(sent, received):
        fa, fb = split_frames(a)[0], split_frames(b)[0]
        assert [f.msgid for f in fa] == [f.msgid for f in fb]
        t_us = _step_time(a, fa)
        for x, y in zip(fa, fb):
            ra, rb = a[x.start:x.end], b[y.start:y.end]
            if KNOWN[x.msgid].msgname.lower() in SPOOFED and start <= t_us < end:
                changed += ra != rb
                assert rb[4:10] == ra[4:10], "header (seq, system, component, message id) kept"
            else:
                assert ra == rb, f"{KNOWN[x.msgid].msgname} changed outside the attack"
    assert changed > 0


def _step_time(data: bytes, frames) -> int:
    """The step time of a flight-controller datagram, from its closing SYSTEM_TIME."""
    msg = Packer().decode(data[frames[-1].start:frames[-1].end])
    assert msg.get_msgId() == 2
    return msg.time_boot_ms * 1000


def _frame(msgid: int, payload: bytes, seq: int = 0) -> bytes:
    """A MAVLink 2 frame of any message id (the CRC is meaningless for ids the dialect lacks)."""
    return bytes([0xFD, len(payload), 0, 0, seq, 1, 1, msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16]) + payload + b"\x12\x34"


@pytest.fixture
def proxy_pair():
    """A proxy (gps_spoof) with raw sockets as autopilot and mission computer."""
    mc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mc.bind(LOCAL)
    mc.settimeout(2.0)
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.bind(LOCAL)
    ap.settimeout(2.0)
    proxy = MavlinkProxy(LOCAL, mc.getsockname(), load_scenarios(SPOOF)).start()
    yield proxy, ap, mc
    proxy.stop()
    ap.close()
    mc.close()


def test_unknown_messages_pass_byte_identical_both_ways(proxy_pair):
    proxy, ap, mc = proxy_pair
    packer = Packer()
    heartbeat = packer.pack(KNOWN[0](2, 12, 0, 0, 4, 3), 1, 1, 7)
    status = packer.pack(KNOWN[253](6, b"hello from px4"), 1, 1, 8)
    gpi = packer.pack(CODECS["global_position_int"].new_message(
        np.array([47.3977, 8.5456, 498.0, 10.0, 1.0, 2.0, -0.5, 1.0]), 1_000_000), 1, 1, 9)
    v1 = packer.pack(KNOWN[0](2, 12, 0, 0, 4, 3), 1, 1, 10, version=1)
    unknown = _frame(0x7FFF01, b"vendor payload \x00\xfd\xfe", seq=11)
    for dgram in (heartbeat, status, unknown, v1, gpi, heartbeat + unknown + status + gpi):
        ap.sendto(dgram, proxy.listen_address)
        data, addr = mc.recvfrom(65535)
        assert data == dgram
    back = addr
    spt = packer.pack(CODECS["setpoint"].new_message(np.array([1.0, 2.0, 0.0, 0.3, 2.0, 1.0]), 2_000_000), 1, 191, 3)
    arm = packer.pack(KNOWN[76](1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0), 1, 191, 4)
    for dgram in (spt, arm, unknown, spt + arm + unknown + heartbeat):
        mc.sendto(dgram, back)
        data, _ = ap.recvfrom(65535)
        assert data == dgram
    assert proxy.stats.unknown == 4 and proxy.stats.malformed == 0


def test_a_second_sender_cannot_take_the_link_over(proxy_pair):
    proxy, ap, mc = proxy_pair
    packer = Packer()
    heartbeat = packer.pack(KNOWN[0](2, 12, 0, 0, 4, 3), 1, 1, 7)
    ap.sendto(heartbeat, proxy.listen_address)
    _, back = mc.recvfrom(65535)
    intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    intruder.bind(LOCAL)
    intruder.settimeout(0.5)
    try:
        forged = packer.pack(KNOWN[0](6, 8, 0, 0, 0, 3), 1, 1, 99)
        for _ in range(5):
            intruder.sendto(forged, proxy.listen_address)
        arm = packer.pack(KNOWN[76](1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0), 1, 191, 4)
        mc.sendto(arm, back)  # the mission computer's command still reaches the first peer
        data, _ = ap.recvfrom(65535)
        assert data == arm
        with pytest.raises(TimeoutError):
            intruder.recvfrom(65535)
        ap.sendto(heartbeat, proxy.listen_address)  # and the intruder's datagrams never reached the mission computer
        assert mc.recvfrom(65535)[0] == heartbeat
    finally:
        intruder.close()
    assert proxy.stats.foreign == 5 and proxy.autopilot == ap.getsockname()


def test_a_far_future_timestamp_does_not_break_the_clock(proxy_pair):
    proxy, ap, mc = proxy_pair
    packer = Packer()
    gpi = CODECS["global_position_int"]  # a topic the scenario listens to: its time drives the layer
    values = np.array([47.3977, 8.5456, 498.0, 10.0, 1.0, 2.0, -0.5, 1.0])
    times_ms = [1_000, 1_020, 1_040, 4_000_000, 1_060, 1_080]
    for k, t in enumerate(times_ms):
        ap.sendto(packer.pack(gpi.new_message(values, t * 1000), 1, 1, k), proxy.listen_address)
        mc.recvfrom(65535)
    assert proxy.stats.clock_jumps == 1
    assert proxy.clock_us == 80_000  # the stream's time goes on from where it was


# --- 3. malformed datagrams ------------------------------------------------------------------------
def test_split_frames_counts_each_malformed_piece():
    packer = Packer()
    good = packer.pack(KNOWN[0](2, 12, 0, 0, 4, 3), 1, 1, 0)
    flipped = bytearray(good)
    flipped[12] ^= 0x40
    frames, bad = split_frames(good + bytes(flipped) + b"\x01\x02\x03" + good + good[:9])
    assert [f.start for f in frames] == [0, 2 * len(good) + 3] and bad == 3
    assert split_frames(b"") == ([], 0)
    bad_flags = bytearray(good)
    bad_flags[2] = 0x80
    assert split_frames(bytes(bad_flags)) == ([], 1)


def test_fuzzed_stream_is_counted_and_dropped_and_the_proxy_keeps_running(proxy_pair):
    proxy, ap, mc = proxy_pair
    rng = np.random.default_rng(8)
    packer = Packer()
    goods = [packer.pack(CODECS["attitude"].new_message(rng.normal(size=6), 4000 * k), 1, 1, k) for k in range(200)]
    expected_bad, expect = 0, []
    for k, good in enumerate(goods):
        kind = k % 5
        if kind == 0:  # valid
            dgram, out = good, good
        elif kind == 1:  # truncated
            cut = int(rng.integers(1, len(good)))
            dgram, out, bad = good[:cut], None, 1
        elif kind == 2:  # a flipped payload or CRC bit
            b = bytearray(good)
            b[int(rng.integers(10, len(b)))] ^= 1 << int(rng.integers(8))
            dgram, out, bad = bytes(b), None, 1
        elif kind == 3:  # garbage (no frame start) in front of a valid frame
            junk = bytes(int(x) for x in rng.integers(0, 0xFD, size=int(rng.integers(1, 40))))
            dgram, out, bad = junk + good, good, 1
        else:  # random bytes
            dgram, out, bad = rng.bytes(int(rng.integers(1, 300))), None, None
        if kind not in (0, 4):
            expected_bad += bad
        ap.sendto(dgram, proxy.listen_address)
        if out is not None:
            expect.append(out)
    marker = packer.pack(KNOWN[2](0, 123456), 1, 1, 0)  # SYSTEM_TIME
    ap.sendto(marker, proxy.listen_address)
    got = []
    while True:
        data, _ = mc.recvfrom(65535)
        if data == marker:
            break
        got.append(data)
    valid = [g for g in got if split_frames(g)[1] == 0 and split_frames(g)[0]]
    assert [g for g in valid if g in expect] == expect, "every valid frame arrives, unchanged and in order"
    st = proxy.stats
    assert st.malformed >= expected_bad and st.errors == 0
    assert proxy._thread is not None and proxy._thread.is_alive()


# --- 5. Ctrl-C ------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(LOCAL)
        return s.getsockname()[1]


def _proxy_cli(port: int, forward_port: int, out, *extra) -> tuple[subprocess.Popen, str]:
    """``scart-bench proxy --record OUT`` in its own process, returned once it listens, with what it
    wrote to stderr until then."""
    cmd = [sys.executable, "-m", "scart_bench.cli", "proxy", "--listen", f"udp:127.0.0.1:{port}",
           "--forward", f"udp:127.0.0.1:{forward_port}", "--scenario", str(SPOOF), "--record", str(out), *extra]
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    seen, line = [], ""
    while "listening on" not in line:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            proc.communicate()
            raise AssertionError("proxy exited early: " + "".join(seen))
        seen.append(line)
    return proc, "".join(seen)


def test_ctrl_c_stops_cleanly_and_leaves_a_complete_recording(reference, bench_run, tmp_path):
    batch, _ = reference
    nav, _ = flight_views(batch, 0)
    mc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mc.bind(LOCAL)
    mc.settimeout(10.0)
    port = _free_port()
    out = tmp_path / "rec"
    proc, _ = _proxy_cli(port, mc.getsockname()[1], out, "--detector", "statistical", "--run", str(bench_run))
    try:
        packer = Packer()
        ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        topics = ("attitude", "highres_imu", "global_position_int", "local_position_ned")
        rows = {t: nav[t][list(TOPICS[t].field_names)].to_numpy() for t in topics}
        times = {t: nav[t]["Timestamp"].to_numpy() for t in topics}
        n = 200  # 4 s of the 50 Hz topics (local_position_ned at its 30 Hz)
        for k in range(n):
            t_us = int(times["attitude"][k])
            frames = [packer.pack(CODECS[t].new_message(rows[t][j], t_us), 1, 1, k)
                      for t in topics for j in np.flatnonzero(times[t] == t_us)]
            ap.sendto(b"".join(frames), ("127.0.0.1", port))
            mc.recvfrom(65535)
        ap.close()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        mc.close()
    assert proc.returncode == 0, stderr
    assert "recorded in" in stdout and "statistical:" in stderr
    ds = open_dataset(out)
    (fid,) = ds.manifest["flight_id"]
    assert len(ds.topic(fid, "attitude")) == n and len(ds.flight(fid)) == n
    assert (ds.flight_dir(fid) / "raw" / "events.csv").exists()


# --- the CLI ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("args, words", [
    (["--listen", "udp:nohost"], ["--listen", "udp:HOST:PORT"]),
    (["--scenario", "data/scenarios/sensor_gps_jump.toml"], ["'sensor'", "link", "command"]),
    (["--detector", "statistical"], ["--detector", "--run"]),
    (["--record", "README.md"], ["--record", "README.md"]),
    (["--scenario", "missing.toml"], ["missing.toml", "no such file"]),
])
def test_bad_input_exits_2_with_one_clear_line(args, words, capsys):
    argv = ["proxy", "--scenario", str(SPOOF), *args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_without_pymavlink_the_error_says_how_to_install():
    code = ("import sys; sys.modules['pymavlink'] = None; from scart_bench.cli.main import main; "
            f"sys.exit(main(['proxy', '--scenario', {str(SPOOF)!r}]))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "pip install scart-bench[mavlink]" in res.stderr, res.stderr


def test_codec_round_trip_within_mavlink_quantisation(reference):
    batch, _ = reference
    _, sim = flight_views(batch, 0)
    packer = Packer()
    tol = {"global_position_int": [2e-7, 2e-7, 1e-3, 1e-3, 0.01, 0.01, 0.01, 2e-4],
           "gps_raw_int": [2e-7, 2e-7, 1e-3, 0.01, 0.01, 0.01, 2e-4, 0.02, 0.02, np.inf, 0, 0],
           "scaled_pressure": [1e-4, 0.01], "battery_status": [1e-3, 0.01, 0.01]}
    from scart_bench.generator.mavlink.codec import LinkState

    for topic, codec in CODECS.items():
        table = sim[topic][list(TOPICS[topic].field_names)].to_numpy()
        v = table[len(table) // 2]
        frame = packer.pack(codec.new_message(v, 12_000), 1, 1, 0)
        got = np.asarray(codec.decode(packer.decode(frame), LinkState()))
        atol = np.asarray(tol.get(topic, [1e-5 * max(1.0, abs(x)) for x in v]), dtype=float)
        if topic == "setpoint":
            atol[4:] = np.inf  # seq and armed come with MISSION_CURRENT / COMMAND_LONG
        assert np.all(np.abs(got - v) <= atol + 1e-12), (topic, got, v)


def test_a_killed_recording_keeps_what_was_flown(reference, tmp_path):
    """proxy --record checkpoints the flight as it flies: killed (SIGKILL) after 2 s of traffic, the
    next proxy --record adds the flight to the dataset, marked incomplete, with the rows up to its
    last checkpoint."""
    batch, _ = reference
    nav, _ = flight_views(batch, 0)
    mc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mc.bind(LOCAL)
    mc.settimeout(10.0)
    out = tmp_path / "rec"

    port = _free_port()
    proc, _ = _proxy_cli(port, mc.getsockname()[1], out, "--checkpoint", "0.2", "--flight-id", "live-killed")
    try:
        packer = Packer()
        ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rows = nav["attitude"][list(TOPICS["attitude"].field_names)].to_numpy()
        times = nav["attitude"]["Timestamp"].to_numpy()
        for k in range(100):  # 2 s of the 50 Hz attitude, sent in about 2 s
            ap.sendto(packer.pack(CODECS["attitude"].new_message(rows[k], int(times[k])), 1, 1, k),
                      ("127.0.0.1", port))
            mc.recvfrom(65535)
            time.sleep(0.02)
        ap.close()
        time.sleep(0.5)  # a checkpoint after the last message
        proc.kill()
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not (out / "manifest.parquet").exists()  # killed: the recording itself was never written
    again, startup = _proxy_cli(_free_port(), mc.getsockname()[1], out, "--duration", "0.5",
                                "--flight-id", "live-next")
    stdout, stderr = again.communicate(timeout=120)
    stderr = startup + stderr
    mc.close()
    assert again.returncode == 2 and "nothing was recorded" in stderr  # nothing proxied this time
    assert "live-killed, an interrupted recording" in stderr, stderr
    ds = open_dataset(out)
    assert "live-killed" in set(ds.manifest["flight_id"])
    config = ds.config("live-killed")
    assert config["incomplete"] is True
    assert 90 <= len(ds.topic("live-killed", "attitude")) <= 100
