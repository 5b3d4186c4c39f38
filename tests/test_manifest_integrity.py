"""A manifest is data: it is checked against each flight's own labels and event log, its fields are
typed and bounded, and every refusal is one line naming the manifest, the flight and the field.
Also the dataset writers' own failure modes: counts too large to generate, a full disk, a killed
generate's staging folder, and the project's compact files given to ``attack --input``."""

from __future__ import annotations

import errno
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from run_fixtures import ATTACK_US, plugin, write_dataset

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, open_dataset
from scart_bench.errors import ScartBenchError

ZS = plugin("ZScore")
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def compact_ds(tmp_path_factory) -> Path:
    """The run fixtures' dataset (10 normal, 6 attacked flights), compact layout, made once."""
    return write_dataset(tmp_path_factory.mktemp("compact") / "ds")


@pytest.fixture(scope="module")
def paper_ds(tmp_path_factory) -> Path:
    """The same flights in the paper's layout (CSV files, manifest.csv), made once."""
    return write_dataset(tmp_path_factory.mktemp("paper") / "ds", fmt="csv")


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> Path:
    """A real generated dataset (two normal flights and a GPS-spoofed one, with its event log)."""
    out = tmp_path_factory.mktemp("gen") / "ds"
    assert main(["generate", "--profile", "quick", "--flights", "2", "--scenarios",
                 str(REPO / "data" / "scenarios" / "gps_spoof.toml"), "--out", str(out)]) == 0
    return out


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _manifest_file(root: Path) -> Path:
    return root / "manifest.parquet" if (root / "manifest.parquet").exists() else root / "manifest.csv"


def _edit(root: Path, flight: str, **values) -> None:
    """Set manifest fields of one flight (in the manifest's own format)."""
    path = _manifest_file(root)
    m = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path, dtype={"flight_id": str})
    i = m.index[m["flight_id"] == flight][0]
    for k, v in values.items():
        if v is not None and not isinstance(v, str) and m[k].dtype.kind in "iu" and not float(v).is_integer():
            m[k] = m[k].astype("float64")
        if isinstance(v, str) and m[k].dtype.kind not in "OUS" and not isinstance(m[k].dtype, pd.StringDtype):
            m[k] = m[k].astype(object) if path.suffix == ".csv" else m[k].astype(str)  # Parquet: one type
        m.loc[i, k] = v
    if path.suffix == ".parquet":
        m.to_parquet(path, index=False)
    else:
        m.to_csv(path, index=False)


def _read_for_a_run(root: Path) -> None:
    """What a run reads before it starts: the manifest, then every flight verified."""
    ds = open_dataset(root)
    ds.check_flights(list(ds.manifest["flight_id"].astype(str)))


def _refused(root: Path, *words: str) -> str:
    with pytest.raises(ScartBenchError) as info:
        _read_for_a_run(root)
    msg = str(info.value)
    assert "\n" not in msg, msg
    for w in (str(_manifest_file(root)), *words):
        assert w in msg, msg
    return msg


# -- the manifest against the flight's labels and event log --------------------------------------

@pytest.mark.parametrize("layout", ["compact", "paper"])
def test_mode_normal_on_an_attacked_flight_is_refused(layout, compact_ds, paper_ds, tmp_path):
    """The attacked flight would be scored as a held-out normal flight: its labels say otherwise."""
    root = _copy(compact_ds if layout == "compact" else paper_ds, tmp_path / "ds")
    _edit(root, "sim-001", mode="normal", attack_start_us=None, attack_end_us=None)
    _refused(root, "'sim-001'", "'mode'", "labels")


def test_mode_normal_on_an_attacked_flight_stops_a_run(compact_ds, tmp_path, capsys):
    root = _copy(compact_ds, tmp_path / "ds")
    _edit(root, "sim-001", mode="normal", attack_start_us=None, attack_end_us=None)
    out = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(root), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manifest.parquet" in err[0] and "'sim-001'" in err[0] and "'mode'" in err[0], err
    assert not (out / "metrics.csv").exists()


@pytest.mark.parametrize("layout", ["compact", "paper"])
def test_an_attack_window_moved_inside_the_flight_is_refused(layout, compact_ds, paper_ds, tmp_path):
    root = _copy(compact_ds if layout == "compact" else paper_ds, tmp_path / "ds")
    _edit(root, "csv-001", attack_start_us=ATTACK_US[0] + 3_000_000, attack_end_us=ATTACK_US[1] + 3_000_000)
    _refused(root, "'csv-001'", "'attack_start_us'", str(ATTACK_US[0]))
    root2 = _copy(compact_ds if layout == "compact" else paper_ds, tmp_path / "ds2")
    _edit(root2, "sim-000", attack_end_us=ATTACK_US[1] - 2_000_000)
    _refused(root2, "'sim-000'", "'attack_end_us'")


@pytest.mark.parametrize("layout", ["compact", "paper"])
def test_an_attack_window_on_a_normal_flight_is_refused(layout, compact_ds, paper_ds, tmp_path):
    root = _copy(compact_ds if layout == "compact" else paper_ds, tmp_path / "ds")
    _edit(root, "normal-008", attack_start_us=ATTACK_US[0], attack_end_us=ATTACK_US[1])
    msg = _refused(root, "'normal-008'", "'attack_start_us'")
    assert "normal flight" in msg


def test_an_attacked_flight_without_its_window_is_refused(compact_ds, tmp_path):
    root = _copy(compact_ds, tmp_path / "ds")
    _edit(root, "sim-002", attack_start_us=None, attack_end_us=None)
    _refused(root, "'sim-002'", "'attack_start_us'", "labels")


def test_the_event_log_is_checked_too(compact_ds, tmp_path):
    """Where the labels agree (no checksum column: the files were edited on purpose), the flight's
    event log still has its say: an attack start logged on a normal flight, or at another time."""
    root = _copy(compact_ds, tmp_path / "ds")
    m = pd.read_parquet(root / "manifest.parquet").drop(columns="checksum")
    m.to_parquet(root / "manifest.parquet", index=False)
    events = root / "flights" / "normal-009" / "raw" / "events.csv"
    events.write_text("timestamp_us,event,scenario_id,detail\n4000000,start,sneaky,attack\n")
    msg = _refused(root, "'normal-009'", "'mode'", str(events))
    assert "4000000" in msg
    events.write_text("timestamp_us,event,scenario_id,detail\n4000000,gps_lost,defense,alarm\n")  # not an attack
    (root / "flights" / "sim-000" / "raw" / "events.csv").write_text(
        f"timestamp_us,event,scenario_id,detail\n{ATTACK_US[0] + 1},start,s0,attack\n")
    _refused(root, "'sim-000'", "'attack_start_us'", "events.csv")


def test_a_real_generated_dataset_agrees_with_itself_and_a_flipped_mode_is_caught(generated, tmp_path):
    """The generator's own labels, windows and event logs (start and end) pass the checks; the
    attacked flight's mode set to normal does not."""
    _read_for_a_run(generated)
    ds = open_dataset(generated)
    attacked = ds.manifest.loc[ds.manifest["mode"] != "normal", "flight_id"].iloc[0]
    root = _copy(generated, tmp_path / "ds")
    _edit(root, attacked, mode="normal", attack_start_us=None, attack_end_us=None)
    _refused(root, repr(attacked), "'mode'")


# -- fields: checksum, types, bounded JSON ---------------------------------------------------------

@pytest.mark.parametrize("value", [None, "", "   "])
def test_an_empty_checksum_is_refused_where_the_column_exists(value, compact_ds, tmp_path):
    root = _copy(compact_ds, tmp_path / "ds")
    _edit(root, "sim-000", checksum=value)
    _refused(root, "'sim-000'", "'checksum'")
    m = pd.read_parquet(root / "manifest.parquet").drop(columns="checksum")  # a dataset from before checksums
    m.to_parquet(root / "manifest.parquet", index=False)
    _read_for_a_run(root)


def test_a_text_rows_value_names_the_manifest_flight_and_field(compact_ds, tmp_path, capsys):
    """In a CSV manifest one text cell makes the column text: the other rows still read as numbers."""
    root = _copy(compact_ds, tmp_path / "ds")
    pd.read_parquet(root / "manifest.parquet").to_csv(root / "manifest.csv", index=False)
    (root / "manifest.parquet").unlink()
    _edit(root, "normal-002", rows="many")
    _refused(root, "'normal-002'", "'rows'", "expected an integer")
    out = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(root), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'rows'" in err[0] and "manifest.csv" in err[0] and "invalid literal" not in err[0]


def test_a_deeply_nested_dataset_json_or_config_json_is_one_line(compact_ds, tmp_path):
    root = _copy(compact_ds, tmp_path / "ds")
    (root / "dataset.json").write_text("[" * 100_000)
    with pytest.raises(DatasetError, match=r"dataset\.json: nested more than") as info:
        open_dataset(root)
    assert "\n" not in str(info.value)
    (root / "dataset.json").write_text('{"flight_defaults": "two"}')
    with pytest.raises(DatasetError, match=r"dataset\.json: field 'flight_defaults'"):
        open_dataset(root)
    (root / "dataset.json").write_text("{}")
    config = root / "flights" / "normal-000" / "raw" / "config.json"
    config.write_text("[" * 100_000)
    with pytest.raises(DatasetError, match=r"normal-000/raw/config\.json: nested more than"):
        open_dataset(root).config("normal-000")


def test_a_view_files_metadata_nested_deeply_is_one_line(compact_ds, tmp_path):
    """A compact file's metadata is JSON too (a dataset from before checksums is not verified)."""
    import pyarrow.parquet as pq

    from scart_bench.dataset.compact import META_KEY

    root = _copy(compact_ds, tmp_path / "ds")
    pd.read_parquet(root / "manifest.parquet").drop(columns="checksum").to_parquet(root / "manifest.parquet")
    view = root / "flights" / "normal-000" / "navigator.parquet"
    table = pq.read_table(view)
    for meta, said in ((b"[" * 100_000, "nested more than"), (b'{"version": "2"}', "not a scart-bench flight view")):
        pq.write_table(table.replace_schema_metadata({META_KEY: meta}), view)
        with pytest.raises(DatasetError, match=said) as info:
            open_dataset(root).flight("normal-000")
        assert "normal-000/navigator.parquet" in str(info.value) and "\n" not in str(info.value)


# -- counts, a full disk, killed generates, compact files as input ---------------------------------

def test_an_unreasonable_flight_count_is_refused_up_front(tmp_path, capsys):
    start = time.monotonic()
    assert main(["generate", "--flights", str(10**12), "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--flights" in err[0] and "10,000,000" in err[0], err
    assert main(["generate", "--flights", "2", "--batch-size", str(10**9), "--out", str(tmp_path / "ds")]) == 2
    assert "--batch-size" in capsys.readouterr().err
    assert time.monotonic() - start < 30 and not (tmp_path / "ds").exists()
    from scart_bench.generator.generate import generate_dataset

    with pytest.raises(DatasetError, match="flight count"):
        generate_dataset("quick", tmp_path / "ds", n_normal=10**12)


def test_import_and_attack_check_their_numbers_up_front(tmp_path, capsys):
    log = tmp_path / "flight.csv"
    log.write_text("timestamp_us,attitude.roll\n0,0.1\n20000,0.2\n40000,0.1\n")
    assert main(["import", str(log), "--out", str(tmp_path / "ds"), "--start", "nan"]) == 2
    assert "--start nan: expected a finite number" in capsys.readouterr().err
    assert main(["attack", "--input", str(log), "--scenario", str(log), "--out", str(tmp_path / "a"),
                 "--seed", "-5"]) == 2
    assert "--seed -5" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists() and not (tmp_path / "a").exists()


def _no_space_for(name: str):
    def fail(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")  # as write() says it: no file name
    return fail


def test_a_full_disk_while_the_manifest_is_written_names_the_file(tmp_path, monkeypatch, capsys):
    real = pd.DataFrame.to_parquet

    def full(self, path, *args, **kwargs):
        if Path(path).name.startswith(".manifest.tmp"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, path, *args, **kwargs)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    out = tmp_path / "ds"
    assert main(["generate", "--out", str(out), "--flights", "1", "--normal-only"]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("flying")]
    assert len(err) == 1 and "manifest.parquet" in err[0] and "no space left" in err[0].lower(), err
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith(".lock")) == []


def test_a_full_disk_while_a_flight_is_written_keeps_the_old_dataset(compact_ds, tmp_path, monkeypatch, capsys):
    import scart_bench.dataset.compact as compact_mod

    src = compact_ds / "flights" / "normal-007"
    scenario = tmp_path / "noise.toml"
    scenario.write_text('[scenario]\nid = "roll-noise"\n[[scenario.start]]\ncondition = "time_window"\n'
                        'start_s = 2.0\n[[scenario.actions]]\naction = "add_white_noise"\n'
                        'target = ["attitude.roll"]\nstd = 0.5\n')
    out = tmp_path / "attacked"
    args = ["attack", "--input", str(src), "--scenario", str(scenario), "--out", str(out)]
    assert main(args) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    monkeypatch.setattr(compact_mod, "write_view", _no_space_for("view"))
    assert main([*args, "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "navigator.parquet" in err[0] and "no space left" in err[0].lower(), err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not (tmp_path / ".attacked.partial").exists()


def test_a_killed_generate_leaves_no_staging_folder_after_the_next_start(tmp_path):
    """kill -9 runs no cleanup: the partial folder stays until the next generate in that folder."""
    proc = subprocess.Popen([sys.executable, "-m", "scart_bench", "generate", "--out", str(tmp_path / "a"),
                             "--flights", "12", "--normal-only"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    partial = tmp_path / ".a.partial"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if partial.is_dir() and any((partial / "flights").glob("normal-*")):
            break
        time.sleep(0.1)
    if proc.poll() is not None:
        pytest.skip("generate finished before it could be killed")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(1.5)  # its writer process follows its parent within half a second
    assert partial.is_dir() and not (tmp_path / "a").exists()
    assert main(["generate", "--out", str(tmp_path / "b"), "--flights", "1", "--normal-only"]) == 0
    assert not partial.exists() and not (tmp_path / "a").exists()


def test_a_dead_generates_temp_staging_folder_is_removed_at_the_next_start(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / "tmp" / f"scart-generate-{dead.pid}-abc123"
    (stale / "dataset" / "flights").mkdir(parents=True)
    (stale / ".owner").write_text(f"scart-bench pid {dead.pid}\n")
    assert main(["generate", "--out", str(tmp_path / "ds"), "--flights", "1", "--normal-only"]) == 0
    assert not stale.exists()
    # a generate to a URL writes in a staging folder named by its pid and owned (flock) while it lives
    import scart_bench.storage as storage

    real, seen = storage.publish_dataset, []

    def spy(local, url, **kwargs):
        seen.append((Path(local).parent.name, (Path(local).parent / ".owner").is_file()))
        return real(local, url, **kwargs)

    monkeypatch.setattr(storage, "publish_dataset", spy)
    assert main(["generate", "--out", "memory://bucket/staged", "--flights", "1", "--normal-only"]) == 0
    assert seen and seen[0][0].startswith(f"scart-generate-{os.getpid()}-") and seen[0][1], seen
    assert not any((tmp_path / "tmp").iterdir())


def test_attack_input_reads_the_projects_own_compact_file(generated, tmp_path, capsys):
    """A flight's navigator.parquet is one table of every topic stacked: read per topic, like the
    flight folder, not as one topic of a timestamp seen many times."""
    from scart_bench.generator.logs.importers import load_flight_file

    flight = generated / "flights" / "normal-0000"
    from_folder = load_flight_file(flight)
    from_file = load_flight_file(flight / "navigator.parquet")
    assert sorted(from_file) == sorted(from_folder)
    for topic, df in from_folder.items():
        pd.testing.assert_frame_equal(from_file[topic], df)
    scenario = tmp_path / "noise.toml"
    scenario.write_text('[scenario]\nid = "roll-noise"\n[[scenario.start]]\ncondition = "time_window"\n'
                        'start_s = 5.0\n[[scenario.actions]]\naction = "add_white_noise"\n'
                        'target = ["attitude.roll"]\nstd = 0.5\n')
    out = tmp_path / "attacked"
    assert main(["attack", "--input", str(flight / "navigator.parquet"), "--scenario", str(scenario),
                 "--out", str(out)]) == 0, capsys.readouterr().err
    ds = open_dataset(out)
    copy = ds.flight(ds.manifest["flight_id"].iloc[0])
    assert len(copy) == len(open_dataset(generated).flight("normal-0000")) and copy["Is_Anomaly"].any()
    lone = tmp_path / "alone" / "simulator.parquet"  # the simulator view keeps most topics in the navigator's
    lone.parent.mkdir()
    shutil.copy(generated / "flights" / "normal-0000" / "simulator.parquet", lone)
    with pytest.raises(DatasetError, match=r"simulator\.parquet: keeps topic\(s\) .* navigator view's file"):
        load_flight_file(lone)


# -- the property: random manifests either read or are refused in one line naming file and field ---

#: hostile values for any cell
HOSTILE = [None, "", "../../etc/passwd", "/tmp/x", "a/b", ".hidden", "normal", "many", -1, 1.5, 10**30, math.nan,
           math.inf, -math.inf, True, 2**63 - 1, "0" * 300]
#: columns whose any present value of the right type and range is fine
FREE_TEXT = ("scenario_id", "action", "target", "injection_point", "params", "source_flight", "kind")


#: the largest accepted value of the integer columns
INT_MAX = {"rows": 10**10, "effect_rows": 10**10, "effect_fields": 10**7, "seed": 2**64 - 1}


def _same(value, current) -> bool:
    if isinstance(value, bool) or value is None or pd.isna(current) or (isinstance(value, float) and math.isnan(value)):
        return False
    if isinstance(value, str) or isinstance(current, str):
        return isinstance(value, str) and isinstance(current, str) and value == current
    return bool(value == current)


def _expectation(base: pd.DataFrame, column: str, fid: str, value, fmt: str, as_text: bool) -> bool:
    """Whether setting ``column`` of flight ``fid`` to ``value`` must be refused (True), or may read.
    ``as_text``: the column was written as text (Parquet holds one type per column)."""
    row = base.loc[base["flight_id"] == fid].iloc[0]
    if fmt == "csv" and isinstance(value, str) and value.strip() and column != "flight_id":
        try:  # a CSV has no types: digits read back as a number
            value = float(value)
            value = int(value) if value.is_integer() else value
        except ValueError:
            pass
    attacked = row["mode"] != "normal"
    missing = value is None or (isinstance(value, float) and math.isnan(value)) or (fmt == "csv" and value == "")
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if _same(value, row[column]):
        return False  # nothing changed
    if column == "flight_id":
        return True  # a hostile, empty, repeated or unknown id: refused somewhere
    if column == "mode":
        return not (value in ("simulation", "csv") or (value == "normal" and not attacked))
    if column == "split":
        return value not in ("train", "validation", "test", "csv_source")
    if column == "checksum":
        return True
    if column in ("attack_start_us", "attack_end_us"):
        if missing:
            return attacked
        edge = ATTACK_US[0] if column == "attack_start_us" else ATTACK_US[1]
        if fmt == "csv" and attacked and number and edge - 20_000 < value <= edge:
            return False  # the paper layout's labels bound a window to its 20 ms rows
        return True
    if column in INT_MAX:
        if missing:
            return False
        return not (number and math.isfinite(value) and float(value).is_integer() and 0 <= value <= INT_MAX[column])
    if column == "duration_s":
        if missing:
            return False
        if not number or not math.isfinite(value) or value < 0 or value > 10 * 365 * 86_400:
            return True
        return attacked and value * 1e6 + 1e6 < ATTACK_US[1]
    if column in FREE_TEXT:
        return not (missing or isinstance(value, str) or fmt == "csv" or as_text)  # a CSV has no types
    if column == "no_effect":
        return not (missing or isinstance(value, bool) or str(value).lower() in ("true", "false", "0", "1", ""))
    return False


def _write_manifest(m: pd.DataFrame, root: Path, fmt: str) -> bool:
    """Write ``m`` in ``fmt``; True when a column of mixed types had to be written as text."""
    if fmt == "csv":
        m.to_csv(root / "manifest.csv", index=False)
        return False
    try:
        m.to_parquet(root / "manifest.parquet", index=False)
        return False
    except Exception:  # a column of mixed types: Parquet holds one type per column, here text
        for c in m.columns:
            if m[c].dtype == object:
                m[c] = m[c].map(lambda v: v if v is None or isinstance(v, str) else str(v))
        m.to_parquet(root / "manifest.parquet", index=False)
        return True


def _mutate(base_root: Path, root: Path, fmt: str, row: int, column: str, value, drop: bool) -> bool:
    """A copy of the dataset ``base_root`` at ``root`` whose manifest has ``column`` of flight ``row`` set
    to ``value`` (or, with ``drop``, the column removed); True when reading it must fail."""
    base = open_dataset(base_root).manifest
    fid = str(base["flight_id"].iloc[row])
    shutil.copytree(base_root, root, copy_function=os.link)  # the flights' files shared, not copied
    _manifest_file(root).unlink()
    m = base.copy()
    if drop:  # the column missing altogether
        m = m.drop(columns=column)
        _write_manifest(m, root, fmt)
        return column in ("flight_id", "mode", "split", "attack_start_us", "attack_end_us")
    m[column] = m[column].astype(object)
    m.loc[m["flight_id"] == fid, column] = [value]
    as_text = _write_manifest(m, root, fmt)
    return _expectation(base, column, fid, value, fmt, as_text)


MANIFEST_CASES = dict(
    fmt=st.sampled_from(["parquet", "csv"]), row=st.integers(0, 15),
    column=st.sampled_from(["flight_id", "mode", "split", "rows", "duration_s", "attack_start_us",
                            "attack_end_us", "checksum", "seed", "no_effect", "scenario_id", "effect_rows"]),
    value=st.one_of(st.sampled_from(HOSTILE), st.integers(-10**6, 10**8), st.sampled_from(
        ["train", "test", "simulation", "csv", "sim-000", "normal-000", "b2:" + "0" * 32])),
    drop=st.booleans())


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(**MANIFEST_CASES)
def test_random_manifests_read_or_are_refused_in_one_line(compact_ds, paper_ds, fmt, row, column, value, drop):
    base_root = compact_ds if fmt == "parquet" else paper_ds
    fid = str(open_dataset(base_root).manifest["flight_id"].iloc[row])
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ds"
        must_fail = _mutate(base_root, root, fmt, row, column, value, drop)
        try:
            _read_for_a_run(root)
        except ScartBenchError as exc:
            msg = str(exc)
            assert "\n" not in msg, msg
            assert str(root) in msg, msg
            named = {column} | ({"attack_start_us", "attack_end_us"} if column in ("mode", "attack_start_us",
                                                                                   "attack_end_us") else set())
            assert any(c in msg for c in named) or column == "flight_id" or (
                column == "checksum" and "changed since it was written" in msg), msg
            return
        assert not must_fail, f"{column}={value!r} on {fid} ({fmt}, drop={drop}) was accepted"


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(**MANIFEST_CASES)
def test_run_on_a_random_manifest_works_or_exits_2_in_one_line(compact_ds, paper_ds, capsys, fmt, row, column,
                                                               value, drop):
    """The same hostile manifests through the ``run`` command itself: exit 0, or exit 2 with one line
    (never a traceback, never exit 0 on a manifest that must be refused)."""
    base_root = compact_ds if fmt == "parquet" else paper_ds
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ds"
        must_fail = _mutate(base_root, root, fmt, row, column, value, drop)
        capsys.readouterr()
        rc = main(["run", "--dataset", str(root), "--detectors", "zscore_test", "--plugin", ZS,
                   "--out", str(Path(tmp) / "run"), "--jobs", "1"])
        err = capsys.readouterr().err.strip()
        assert rc in (0, 2), err
        if rc == 2:
            assert len(err.splitlines()) == 1 and err.startswith("scart-bench run: error: "), err
        else:
            assert not must_fail, f"run accepted {column}={value!r} ({fmt}, drop={drop})"
