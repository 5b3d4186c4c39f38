"""``attack --dataset`` stores what an attack changed: a copy of an all-topic log shares its untouched
fields with its source flight's file, and reads back exactly as the full copy the old path wrote; a
run scores it the same; a damaged or missing source is caught and named."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, compact, open_dataset, read_view
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.offline import attack_dataset, import_logs

ROOT = Path(__file__).parents[1]
RFLYMAD = ROOT.parent / "shared/data/ulog/rflymad_TestCase_1_1000000000.ulg"
needs = pytest.mark.skipif(not RFLYMAD.exists(), reason=f"shared log {RFLYMAD} not found")

GRID = """
[grid]
id = "g"
injection_point = "link"
[grid.axes]
action = ["bias"]
target = ["position", "attitude"]
level = [2]
duration_s = [4.0]
trigger = ["time"]
[targets.position]
fields = ["global_position_int.lat", "global_position_int.lon", "local_position_ned.x", "local_position_ned.y",
          "gps_raw_int.lat", "gps_raw_int.lon"]
magnitudes = [2.0, 5.0, 10.0, 25.0]
[targets.attitude]
fields = ["attitude.roll", "attitude.pitch"]
magnitudes = [0.03, 0.08, 0.2, 0.5]
[actions.bias]
param = "offset"
[triggers.time]
start = [{ condition = "time_window", start_s = 3.0 }]
"""


@pytest.fixture(scope="module")
def attacked(tmp_path_factory) -> tuple[Path, Path, list[str]]:
    """The RflyMAD log's first 8 s with every topic (test), two parts of it as train and validation,
    attacked by a small grid twice: full copies (the old path) and copies shared with their source."""
    tmp = tmp_path_factory.mktemp("copies")
    base = tmp / "base"
    (test,) = import_logs([RFLYMAD], base, split="test", end_s=8.0)
    for split, (start, end) in {"train": (0.0, 5.0), "validation": (5.0, 8.0)}.items():
        import_logs([base / "flights" / test], base, split=split, start_s=start, end_s=end)
    (tmp / "grid.toml").write_text(GRID)
    ids = {}
    for name, full in (("full", True), ("shared", False)):
        shutil.copytree(base, tmp / name)
        ids[name] = attack_dataset(tmp / name, tmp / "grid.toml", sources=("test",), full_copies=full)
    assert ids["full"] == ids["shared"] and len(ids["full"]) == 2
    return tmp / "full", tmp / "shared", ids["full"]


def _size(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())


@needs
def test_a_shared_copy_reads_back_as_the_full_copy_table_by_table(attacked):
    full, shared, ids = attacked
    a, b = open_dataset(full), open_dataset(shared)
    pd.testing.assert_frame_equal(a.manifest.drop(columns="checksum"), b.manifest.drop(columns="checksum"))
    for fid in ids:
        for view in ("navigator", "simulator"):
            ta, tb = read_view(a.flight_dir(fid), view), read_view(b.flight_dir(fid), view)
            assert list(ta) == list(tb) and len(ta) > 50  # every topic of the log
            for topic in ta:
                pd.testing.assert_frame_equal(ta[topic], tb[topic], check_exact=True)
            fa, fb = a.flight(fid, view), b.flight(fid, view)  # the combined table a run reads
            pd.testing.assert_frame_equal(fa, fb, check_exact=True)
            if view == "navigator" and fid == ids[0]:  # exported: the same bytes (20 s per flight of this width)
                assert fa.to_csv(index=False) == fb.to_csv(index=False)
        assert a.events(fid).equals(b.events(fid))
    # a flight folder as a log (attack --input, import of a folder) reads the same too
    la, lb = load_flight_file(a.flight_dir(ids[0])), load_flight_file(b.flight_dir(ids[0]))
    assert list(la) == list(lb) and all(la[t].equals(lb[t]) for t in la)
    for fid in ids:
        # what is stored: the changed fields, not the log's hundreds of topics again
        meta = compact.read_meta(b.flight_dir(fid) / "navigator.parquet")
        src = a.manifest.set_index("flight_id").loc[fid, "source_flight"]
        assert compact.referenced_flights(meta) == [src] and meta["version"] == 3
        assert b.sources(fid) == [src] and a.sources(fid) == []
        assert _size(b.flight_dir(fid)) * 3 < _size(a.flight_dir(fid))


@needs
def test_normal_flights_and_old_path_copies_keep_the_version_2_files(attacked):
    full, shared, ids = attacked
    for root in (full, shared):
        ds = open_dataset(root)
        for fid in ds.manifest["flight_id"]:
            if root == shared and fid in ids:
                continue
            for view in ("navigator", "simulator"):
                assert compact.read_meta(ds.flight_dir(fid) / f"{view}.parquet")["version"] == 2


@needs
def test_a_run_on_the_shared_copies_gives_the_same_scores(attacked, tmp_path):
    full, shared, _ = attacked
    scores = []
    for ds in (full, shared):
        out = tmp_path / ds.name
        assert main(["run", "--dataset", str(ds), "--detectors", "statistical", "--out", str(out),
                     "--columns", "logged", "--burn-in", "0",
                     "--features", "vehicle_local_position.*,vehicle_gps_position.*"]) == 0
        scores.append(out)
    assert (scores[0] / "flight_scores.csv").read_bytes() == (scores[1] / "flight_scores.csv").read_bytes()
    timing = ["latency_us_per_row", "fit_s", "score_s"]  # the wall clock, not the scores
    a, b = (pd.read_csv(out / "metrics.csv").drop(columns=timing) for out in scores)
    pd.testing.assert_frame_equal(a, b, check_exact=True)


def _flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


@needs
def test_the_checks_catch_a_damaged_or_missing_source_file(attacked, tmp_path):
    _, shared, ids = attacked
    ds_path = tmp_path / "ds"
    shutil.copytree(shared, ds_path)
    ds = open_dataset(ds_path)
    fid = ids[0]
    src = str(ds.manifest.set_index("flight_id").loc[fid, "source_flight"])
    _flip(ds.flight_dir(src) / "navigator.parquet")
    with pytest.raises(DatasetError) as info:
        open_dataset(ds_path).flight(fid)
    msg = str(info.value)
    assert src in msg and f"attacked copy {fid!r}" in msg and "changed since it was written" in msg
    with pytest.raises(DatasetError):
        open_dataset(ds_path).check_flights([fid])
    shutil.rmtree(ds.flight_dir(src))
    with pytest.raises(DatasetError) as info:
        open_dataset(ds_path).flight(fid)
    assert f"keeps its untouched fields in flight {src!r}" in str(info.value) and "restore" in str(info.value)
    # read without the dataset's checks, the copy's file names the missing file
    with pytest.raises(DatasetError) as info:
        read_view(ds.flight_dir(fid), "navigator")
    assert src in str(info.value) and "missing" in str(info.value)


@needs
def test_a_view_reference_outside_the_dataset_is_refused(tmp_path):
    with pytest.raises(compact.CompactError, match="expected a view name"):
        compact.view_file(tmp_path / "flights" / "x" / "navigator.parquet", "../../../etc/navigator")
    assert compact.view_file(tmp_path / "f" / "a" / "simulator.parquet", "../b/navigator") == \
        tmp_path / "f" / "b" / "navigator.parquet"


FLEET_GAPPED = ROOT.parent / "shared/data/dataflash/fleet/arducopter_7-9-2014_6.bin"  # gaps at 43.6-47.1, 104.2-119.6 s
GAP_GRID = GRID.replace('target = ["position", "attitude"]', 'target = ["attitude"]').replace(
    'duration_s = [4.0]', 'duration_s = [15.0]').replace(
    'trigger = ["time"]', 'trigger = ["early", "late"]').replace(
    '[triggers.time]\nstart = [{ condition = "time_window", start_s = 3.0 }]',
    '[triggers.early]\nstart = [{ condition = "time_window", start_s = 40.0 }]\n'
    '[triggers.late]\nstart = [{ condition = "time_window", start_s = 100.0 }]')


@pytest.mark.skipif(not FLEET_GAPPED.exists(), reason=f"shared log {FLEET_GAPPED} not found")
def test_a_shared_copy_of_a_gapped_log_reads_back_as_the_full_copy(tmp_path):
    """On a log with logging gaps csv mode replays on the logged clock: the topics it passes unchanged
    are still held as the source's tables, and read back as the full copy's, labels included."""
    assert "late" in GAP_GRID and "duration_s = [15.0]" in GAP_GRID
    import_logs([FLEET_GAPPED], tmp_path / "base", split="test")
    (tmp_path / "grid.toml").write_text(GAP_GRID)
    ids = {}
    for name, full in (("full", True), ("shared", False)):
        shutil.copytree(tmp_path / "base", tmp_path / name)
        ids[name] = attack_dataset(tmp_path / name, tmp_path / "grid.toml", sources=("test",), full_copies=full)
    assert ids["full"] == ids["shared"] and len(ids["full"]) == 2
    a, b = open_dataset(tmp_path / "full"), open_dataset(tmp_path / "shared")
    for fid in ids["full"]:
        start, end = (int(v) for v in a.manifest.set_index("flight_id").loc[fid, ["attack_start_us", "attack_end_us"]])
        assert end - start > 16e6  # 15 s of logged flight across a gap: longer on the log's clock
        ta, tb = read_view(a.flight_dir(fid), "navigator"), read_view(b.flight_dir(fid), "navigator")
        assert list(ta) == list(tb) and len(ta) > 10
        for topic in ta:
            pd.testing.assert_frame_equal(ta[topic], tb[topic], check_exact=True)
        meta = compact.read_meta(b.flight_dir(fid) / "navigator.parquet")
        shared = [s for s in meta["stored"] if s.get("shared")]
        assert len(shared) > 10  # the untouched topics' fields are read from the source flight
