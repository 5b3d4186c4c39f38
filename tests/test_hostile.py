"""Hostile or careless input: ids that would escape their folder, code named by data files, two writers,
stale results and changed flight tables. Each is refused with one line naming the culprit (exit 2),
and nothing is written where it should not be."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.benchmark.store import RunStore
from scart_bench.cli.main import main
from scart_bench.generator.scart.scenario import scenario_from_dict
from scart_bench.generator.scart.spec import ScenarioError
from scart_bench.names import IdError, check_id, inside

ZS = plugin("ZScore")
BAD_IDS = ["../../x", "a/b", "normal-0000/.", ".hidden", "a..b", "nul\x00byte", "x" * 201, "", "sp ace", "é"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


@pytest.mark.parametrize("bad", BAD_IDS)
def test_the_id_rule_refuses_what_could_leave_a_folder(bad):
    with pytest.raises(IdError, match="--flight-id"):
        check_id(bad, "--flight-id")


def test_the_id_rule_accepts_the_projects_own_ids():
    for ok in ["normal-0000", "sim-quick-bias-gps-L2-d10-t20+env-jam", "csv-normal-0003-gps_spoof", "live-20261123.1"]:
        assert check_id(ok, "id") == ok


def test_inside_refuses_a_path_that_resolves_outside(tmp_path):
    assert inside(tmp_path, "a", "b") == (tmp_path / "a" / "b").resolve()
    (tmp_path / "link").symlink_to("/")
    with pytest.raises(IdError, match="outside"):
        inside(tmp_path, "link", "etc")


@pytest.mark.parametrize("bad", ["../../../../x", "a/b", "x" * 300])
def test_scenario_ids_that_are_not_file_names_are_refused(bad):
    table = {"id": bad, "start": [{"condition": "time_window", "start_s": 1.0}],
             "actions": [{"action": "add_white_noise", "target": ["attitude.roll"], "std": 0.1}]}
    with pytest.raises(ScenarioError, match="scenario.id"):
        scenario_from_dict(table, source="evil.toml")


def test_a_scenario_cannot_name_code_to_import(tmp_path):
    table = {"id": "cb", "callback": "os:system", "start": [{"condition": "time_window", "start_s": 1.0}],
             "actions": [{"action": "add_white_noise", "target": ["attitude.roll"], "std": 0.1}]}
    with pytest.raises(ScenarioError, match="names code to import"):
        scenario_from_dict(table, source="evil.toml")


def test_an_uninstalled_callback_name_is_refused_when_the_layer_is_built():
    from scart_bench.generator.scart.layer import load_callback

    with pytest.raises(ScenarioError, match="not an installed callback"):
        load_callback("no-such-callback", "evil.toml")


@pytest.mark.parametrize("bad", ["normal-0000/.", "../../x", "a/b", "x" * 300])
def test_proxy_flight_id_is_checked_before_anything_starts(tmp_path, capsys, bad):
    pytest.importorskip("pymavlink")
    rec = tmp_path / "rec"
    code = main(["proxy", "--listen", "udp:127.0.0.1:0", "--forward", "udp:127.0.0.1:9",
                 "--scenario", "data/scenarios/gps_spoof.toml", "--record", str(rec), "--flight-id", bad,
                 "--duration", "0.1"])
    assert code == 2 and "--flight-id" in capsys.readouterr().err
    assert not rec.exists()


def test_proxy_duration_must_be_finite(capsys):
    pytest.importorskip("pymavlink")
    assert main(["proxy", "--scenario", "data/scenarios/gps_spoof.toml", "--duration", "nan"]) == 2
    assert "--duration nan" in capsys.readouterr().err


def test_a_plugin_whose_name_is_a_path_is_refused_even_with_all(tmp_path, dataset, capsys):
    evil = tmp_path / "evil.py"
    evil.write_text("from scart_bench.detectors.base import Detector\n"
                    "class Evil(Detector):\n    name = '../../x'\n"
                    "    def __init__(self, columns=None, random_state=0):\n"
                    "        self.columns = columns\n        self.random_state = random_state\n")
    out = tmp_path / "runs" / "r"
    assert main(["run", "--detectors", "all", "--plugin", f"{evil}:Evil", "--dataset", str(dataset),
                 "--out", str(out)]) == 2
    assert "detector name" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not out.exists()


def test_a_second_writer_to_a_run_folder_is_refused(tmp_path, dataset, capsys):
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(out)]
    assert main(args) == 0
    before = (out / "config.json").read_text()
    lock = RunStore(out).lock()  # another run holding the folder
    try:
        assert main(args) == 2
        assert "another scart-bench process is writing to this folder" in capsys.readouterr().err
        assert (out / "config.json").read_text() == before and (out / "metrics.csv").exists()
    finally:
        lock.release()
    assert main(args) == 0  # the lock goes with its holder


def test_changed_flight_tables_change_the_run_identity(tmp_path, dataset, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(ds), "--out", str(out), "--resume"]
    assert main(args) == 0
    assert main(args) == 0  # same tables (a copy keeps the fingerprint): resumes
    view = ds / "flights" / "normal-004" / "navigator.parquet"  # the compact layout: one file per view
    table = pq.read_table(view)
    last = table.column(table.num_columns - 1).to_numpy(zero_copy_only=False).copy()
    last[-1] += 1.0
    table = table.set_column(table.num_columns - 1, table.schema.field(table.num_columns - 1), pa.array(last))
    pq.write_table(table, view)  # the schema keeps the flight's metadata: still a readable flight
    assert main(args) == 2
    # the flight's checksum catches it before the run's identity is compared, naming the flight
    assert "flight 'normal-004' changed since it was written" in capsys.readouterr().err


def test_run_config_stores_names_not_code_and_score_imports_nothing(tmp_path, dataset):
    marker = tmp_path / "imported"
    evil = tmp_path / "evil.py"
    evil.write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    out = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset),
                 "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())
    config["plugins"] = [f"{evil}:Evil"]
    config["jobs"]["zscore_test"]["source"] = f"{evil}:Evil"
    (out / "config.json").write_text(json.dumps(config))
    assert main(["score", str(out)]) == 0
    assert main(["report", str(out), "--out", str(tmp_path / "report")]) == 0
    assert not marker.exists()


@pytest.mark.parametrize("body, said", [
    ("import time\ntime.sleep(600)\n", "did not finish within 18 s"),
    ("import os, signal\nos.kill(os.getpid(), signal.SIGSEGV)\n", "died (SIGSEGV)"),
    ("def broken(:\n", "SyntaxError"),
])
def test_a_plugin_that_hangs_or_crashes_at_import_is_refused_quickly(tmp_path, dataset, capsys, body, said):
    import time

    evil = tmp_path / "evil.py"
    evil.write_text(body + "from scart_bench.detectors.base import Detector\nclass Evil(Detector):\n    name = 'evil'\n")
    out = tmp_path / "run"
    t0 = time.monotonic()
    assert main(["run", "--detectors", "evil", "--plugin", f"{evil}:Evil", "--dataset", str(dataset),
                 "--out", str(out), "--timeout", "3"]) == 2
    assert time.monotonic() - t0 < 60
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


# -- scenario files that used to be accepted silently, or crashed ---------------------------------

_NOISE = '[[scenario.actions]]\naction = "add_white_noise"\ntarget = ["attitude.roll"]\nstd = 0.1\n'
_START = '[[scenario.start]]\ncondition = "time_window"\nstart_s = 5.0\n'


@pytest.mark.parametrize("text, named", [
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.roll"]\noffset = inf\n',
     "offset: expected a finite number, got inf"),
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "add_white_noise"\ntarget = ["attitude.roll"]\nstd = inf\n',
     "std: expected a finite number"),
    ('[scenario]\nid = "a"\ninjection_point = "environment"\n' + _START
     + '[[scenario.actions]]\naction = "wind_gust"\nspeed = 1e300\n', "speed: must be <= 100"),
    ('[scenario]\nid = "a"\n[[scenario.start]]\ncondition = "random_start"\nlow_s = 30.0\nhigh_s = 10.0\n' + _NOISE,
     "low_s (30) must be <= high_s (10)"),
    ('[scenario]\nid = "a"\n[[scenario.start]]\ncondition = "time_window"\nstart_s = 30.0\nend_s = 10.0\n' + _NOISE,
     "start_s (30) must be before end_s (10)"),
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "add_white_noise"\ntarget = []\nstd = 0.1\n',
     "target: expected at least 1 item(s), got 0"),
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "add_white_noise"\ntarget = [1, 2]\nstd = 0.1\n',
     "target: expected names (strings), got 1"),
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "delayed"\ntarget = ["attitude"]\ndelay_s = inf\n',
     "delay_s: expected a finite number"),
    ('[scenario]\nid = "a"\n' + _START + '[[scenario.actions]]\naction = "duplicate"\ntarget = ["attitude"]\nk = 200000000\n',
     "k: must be <= 90000"),
    ('[scenario]\nid = "' + "x" * 300 + '"\n' + _START + _NOISE, "at most 200"),
    ('[scenario]\nid = "a"\ncallback = 3\n' + _START + _NOISE, "callback"),
    ("x = " + "[" * 50_000 + "]" * 50_000 + "\n", "nested too deeply"),
])
def test_bad_scenario_values_exit_2_naming_file_and_field(tmp_path, capsys, text, named):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    out = tmp_path / "ds"
    assert main(["generate", "--out", str(out), "--flights", "1", "--scenarios", str(f)]) == 2
    err = capsys.readouterr().err.strip()
    assert named in err and str(f) in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_a_huge_grid_is_refused_up_front_with_how_to_allow_it(tmp_path, capsys):
    import time

    sweep = tmp_path / "sweep.toml"
    values = ", ".join(str(v / 10) for v in range(1, 101))
    sweep.write_text('[[scenario]]\nid = "a"\n' + _START + _NOISE
                     + f'[sweep]\n"a.actions.0.std" = [{values}]\n"a.start.0.start_s" = [{values}]\n'
                     + f'"a.max_windows" = [{", ".join(str(k) for k in range(1, 101))}]\n')
    t0 = time.monotonic()
    assert main(["generate", "--out", str(tmp_path / "ds"), "--flights", "1", "--scenarios", str(sweep)]) == 2
    err = capsys.readouterr().err
    assert "1,000,000 configurations" in err and "max_configurations = 1000000" in err, err
    assert time.monotonic() - t0 < 10


def test_run_timeout_and_seed_are_checked(tmp_path, dataset, capsys):
    base = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(tmp_path / "r")]
    assert main([*base, "--timeout", "nan"]) == 2
    assert "--timeout nan" in capsys.readouterr().err
    assert main([*base, "--seed", str(2**70)]) == 2
    assert "--seed" in capsys.readouterr().err
    assert main(["generate", "--out", str(tmp_path / "g"), "--seed", "-1"]) == 2
    assert "--seed -1" in capsys.readouterr().err


def test_the_same_run_twice_in_a_report_is_refused(tmp_path, dataset, capsys):
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(run)]) == 0
    assert main(["report", str(run), str(tmp_path / "." / "run"), "--out", str(tmp_path / "rep")]) == 2
    assert "given twice" in capsys.readouterr().err


def test_a_garbage_scores_file_is_named_without_pickle_advice(tmp_path, dataset, capsys):
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(run)]) == 0
    (run / "jobs" / "zscore_test" / "scores.npz").write_bytes(b"PK\x03\x04 not really a zip")
    assert main(["score", str(run)]) == 2  # the run's checksum names it first
    err = capsys.readouterr().err
    assert "scores.npz: changed since the run wrote it" in err and "pickle" not in err
    RunStore(run).seal("jobs/zscore_test/scores.npz")  # past the checksum: the reader names it
    assert main(["score", str(run)]) == 3  # the job becomes an ERROR row (exit 3, as run), the rest is scored
    metrics = pd.read_csv(run / "metrics.csv").set_index("detector")
    assert metrics.loc["zscore_test", "status"] == "ERROR"
    assert "not a valid scores file" in metrics.loc["zscore_test", "message"]
    assert "pickle" not in metrics.loc["zscore_test", "message"]
    (run / "config.json").write_text("{not json")
    assert main(["score", str(run)]) == 2
    err = capsys.readouterr().err
    assert "config.json: not valid JSON" in err


# -- datasets: one writer at a time, and --overwrite never loses the old dataset ---------------------

def _attack_args(src, out):
    scenario = src.parent.parent.parent / "roll_noise.toml"
    if not scenario.exists():
        scenario.write_text('[scenario]\nid = "roll-noise"\n' + _START.replace("5.0", "2.0") + _NOISE.replace("0.1", "0.5"))
    return ["attack", "--input", str(src), "--scenario", str(scenario), "--out", str(out)]


@pytest.fixture(scope="module")
def flight_csv(tmp_path_factory) -> Path:
    """One recorded flight as a dataset flight folder (the single-log form of attack reads it)."""
    return write_dataset(tmp_path_factory.mktemp("attack-src") / "ds") / "flights" / "normal-007"


def test_a_second_dataset_writer_is_refused(tmp_path, flight_csv, capsys):
    from scart_bench.dataset import dataset_lock

    out = tmp_path / "attacked"
    with dataset_lock(out):
        assert main(_attack_args(flight_csv, out)) == 2
        assert "another scart-bench process is writing to this folder" in capsys.readouterr().err
        assert main(["generate", "--out", str(out), "--flights", "1", "--normal-only"]) == 2
        assert not out.exists()
    assert main(_attack_args(flight_csv, out)) == 0


def test_attack_overwrite_that_fails_half_way_keeps_the_old_dataset(tmp_path, flight_csv, monkeypatch, capsys):
    import errno

    import scart_bench.dataset.write as dataset_mod

    out = tmp_path / "attacked"
    assert main(_attack_args(flight_csv, out)) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "flights"))

    monkeypatch.setattr(dataset_mod, "write_flight", full_disk)
    assert main([*_attack_args(flight_csv, out), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and len(err.strip().splitlines()) == 1
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert not any(p.name.startswith(f".{out.name}.partial") for p in tmp_path.iterdir())


def test_generate_overwrite_that_fails_at_the_end_keeps_the_old_dataset(tmp_path, monkeypatch):
    import errno

    from scart_bench.dataset import DatasetWriter

    out = tmp_path / "ds"
    assert main(["generate", "--out", str(out), "--flights", "1", "--normal-only"]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def full_disk(self):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.out / "manifest.parquet"))

    monkeypatch.setattr(DatasetWriter, "close", full_disk)
    assert main(["generate", "--out", str(out), "--flights", "1", "--normal-only", "--overwrite", "--seed", "5"]) == 2
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


def test_killing_generate_leaves_no_writer_process_behind(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "scart_bench", "generate", "--out", str(tmp_path / "ds"),
                             "--flights", "12", "--normal-only"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    workers: list[int] = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not workers:
        out = subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "spawn_main"], capture_output=True, text=True)
        workers = [int(x) for x in out.stdout.split()]
        time.sleep(0.2)
    if not workers:
        proc.kill()
        pytest.skip("generate finished before its writer process could be seen")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(Path(f"/proc/{w}").exists() for w in workers):
        time.sleep(0.2)
    alive = [w for w in workers if Path(f"/proc/{w}").exists()
             and "zombie" not in Path(f"/proc/{w}/status").read_text().lower()]
    assert not alive, f"writer process(es) {alive} outlived the killed generate"
    assert not (tmp_path / "ds").exists()


def test_a_csv_with_two_readings_at_one_time_is_refused(tmp_path, capsys):
    from scart_bench.errors import ScartBenchError
    from scart_bench.generator.logs.importers import load_flight_file
    from scart_bench.generator.scart.spec import ScenarioError  # noqa: F401 (same error family)

    f = tmp_path / "imu.csv"
    f.write_text("timestamp,ax,ay\n1000,0.1,0.2\n2000,0.1,0.2\n2000,0.5,0.2\n3000,0.1,0.2\n")
    with pytest.raises(ScartBenchError, match=r"imu.csv: topic 'imu': rows with the same timestamp .*'ax'"):
        load_flight_file(f)
    same = tmp_path / "gps.csv"
    same.write_text("timestamp,lat\n1000,47.1\n2000,47.2\n2000,47.2\n3000,47.3\n")
    assert len(load_flight_file(same)["gps"]) == 3  # a repeated identical row is only a repeat


def test_csv_dataset_ids_read_back_as_text(tmp_path):
    from run_fixtures import _topics

    from scart_bench.dataset import DatasetWriter, FlightRecord, open_dataset

    rng = np.random.default_rng(0)
    w = DatasetWriter(tmp_path / "ds", fmt="csv")
    topics = _topics(rng)
    w.write(FlightRecord("007", topics, topics, {"mode": "normal", "split": "train", "seed": 1}, {"seed": 1}))
    w.close()
    ds = open_dataset(tmp_path / "ds")
    assert list(ds.manifest["flight_id"]) == ["007"]
    assert len(ds.flight("007")) > 0


def test_a_damaged_flight_table_stops_the_run_before_anything_is_written(tmp_path, dataset, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    table = ds / "flights" / "sim-001" / "navigator.parquet"
    table.write_bytes(table.read_bytes()[:100])
    out = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(ds), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "flights/sim-001: flight 'sim-001' changed since it was written" in err and "regenerate it" in err, err
    assert not out.exists()


def test_a_path_that_is_not_utf8_is_refused_before_anything_runs(tmp_path, dataset, capsys):
    import os

    out = os.fsdecode(os.fsencode(str(tmp_path)) + b"/run\xff")
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", out]) == 2
    assert "--out" in capsys.readouterr().err and "not valid UTF-8" in capsys.readouterr().err + "not valid UTF-8"
    assert list(tmp_path.iterdir()) == []


def test_proxy_run_monitor_imports_nothing_a_run_folder_names(tmp_path, dataset):
    from scart_bench.benchmark.live import monitor_from_run
    from scart_bench.errors import RunError

    marker = tmp_path / "imported"
    evil = tmp_path / "evil.py"
    evil.write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    out = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(out)]) == 0
    shutil.copytree(out / "jobs" / "zscore_test", out / "jobs" / "evil_test")  # a job whose class is the file
    for name in ("status.json", "scores.npz"):  # recorded as the run's own, to reach the plugin check
        RunStore(out).seal(f"jobs/evil_test/{name}")
    config = json.loads((out / "config.json").read_text())
    config["plugins"] = [f"{evil}:Evil"]
    config["jobs"]["evil_test"] = {**config["jobs"]["zscore_test"], "source": f"{evil}:Evil"}
    config["detectors"].append("evil_test")
    (out / "config.json").write_text(json.dumps(config))
    with pytest.raises(RunError, match="load it with --plugin"):
        monitor_from_run(out, "evil_test", log=lambda m: None)
    assert not marker.exists()


def test_a_csv_with_100k_columns_is_refused_quickly(tmp_path):
    import time

    from scart_bench.errors import ScartBenchError
    from scart_bench.generator.logs.importers import load_flight_file

    f = tmp_path / "wide.csv"
    n = 100_000
    f.write_text("timestamp," + ",".join(f"c{i}" for i in range(n)) + "\n" + "0," + ",".join("1" for _ in range(n)) + "\n")
    t0 = time.monotonic()
    with pytest.raises(ScartBenchError, match="100001 columns, more than the 5000"):
        load_flight_file(f)
    assert time.monotonic() - t0 < 10


def test_a_run_without_its_labels_is_named(tmp_path, dataset, capsys):
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(run)]) == 0
    (run / "truth.parquet").unlink()
    capsys.readouterr()
    assert main(["score", str(run)]) == 2
    err = capsys.readouterr().err
    assert "truth.parquet: missing" in err and len(err.strip().splitlines()) == 1


def test_an_attack_that_never_starts_writes_nothing(tmp_path, flight_csv, capsys):
    scenario = tmp_path / "never.toml"
    # a start condition the flight never meets (a time past a log's end now moves earlier, issue 48)
    scenario.write_text('[scenario]\nid = "never"\n[[scenario.start]]\ncondition = "altitude_above"\n'
                        'height = 100000.0\ntopic = "local_position_ned"\n' + _NOISE)
    out = tmp_path / "att"
    assert main(["attack", "--input", str(flight_csv), "--scenario", str(scenario), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "never started" in err and "nothing was written" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_full_disk_during_a_run_is_one_line_and_leaves_no_metrics(tmp_path, dataset, capsys, monkeypatch):
    import errno

    import scart_bench.benchmark.store as store_mod

    real = store_mod.atomic_write_bytes

    def full_after_config(path, data):
        if Path(path).name in ("results.csv", "metrics.csv", "scores.npz"):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(store_mod, "atomic_write_bytes", full_after_config)
    out = tmp_path / "run"
    code = main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "No space left on device" in err[-1] and err[-1].startswith("scart-bench run: error:")
    assert not (out / "metrics.csv").exists()
