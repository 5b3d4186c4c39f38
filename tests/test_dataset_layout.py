"""The compact dataset layout: the same flights as the paper's layout, in a tenth of the disk and files."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, append_flights, open_dataset
from scart_bench.dataset.compact import COMPACT_VERSION, META_KEY, float32_safe
from scart_bench.generator.generate import generate_dataset


@pytest.fixture(scope="module")
def both_layouts(tmp_path_factory):
    root = tmp_path_factory.mktemp("layouts")
    out = {}
    for layout in ("paper", "compact"):
        out[layout] = generate_dataset("quick", root / layout, seed=11, n_normal=3, with_attacks=False,
                                       layout=layout)
    return out


def _files(path):
    return [p for p in path.rglob("*") if p.is_file()]


def test_compact_flights_read_back_as_the_papers_within_float32(both_layouts):
    paper, compact = open_dataset(both_layouts["paper"]), open_dataset(both_layouts["compact"])
    assert paper.info["layout"] == "paper" and compact.info["layout"] == "compact"
    # the same rows; each flight's checksum is of its own files, which differ by layout
    pd.testing.assert_frame_equal(paper.manifest.drop(columns="checksum"), compact.manifest.drop(columns="checksum"))
    for fid in paper.manifest["flight_id"]:
        assert not paper.is_compact(fid) and compact.is_compact(fid)
        for view in ("navigator", "simulator"):
            assert paper.topics(fid, view) == compact.topics(fid, view)
            for topic in paper.topics(fid, view):
                a, b = paper.topic(fid, topic, view), compact.topic(fid, topic, view)
                assert list(a.columns) == list(b.columns)
                for col in a.columns:
                    if float32_safe(topic, col):  # float32 on disk: exactly its float32 value
                        assert np.array_equal(a[col].to_numpy(np.float32), b[col].to_numpy(np.float32), equal_nan=True)
                    else:  # time, labels, latitude and longitude: bit-exact
                        pd.testing.assert_series_equal(a[col], b[col], check_exact=True)
            for table in ("most_frequent", "all_sensors"):
                a, b = paper.flight(fid, view, table), compact.flight(fid, view, table)
                assert list(a.columns) == list(b.columns) and len(a) == len(b)
                pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=1e-6, atol=1e-5)
                for col in ("Timestamp", "Is_Anomaly", "global_position_int.lat", "gps_raw_int.lon"):
                    pd.testing.assert_series_equal(a[col], b[col], check_exact=True)


def test_compact_layout_is_a_fraction_of_the_files_and_bytes(both_layouts):
    paper, compact = _files(both_layouts["paper"]), _files(both_layouts["compact"])
    per_flight = {k: len(_files(both_layouts[k] / "flights" / "normal-0000")) for k in both_layouts}
    assert per_flight == {"paper": 25, "compact": 4}, per_flight  # raw/config.json, raw/events.csv, 2 views
    size = {k: sum(p.stat().st_size for p in v) for k, v in (("paper", paper), ("compact", compact))}
    assert size["compact"] * 6 < size["paper"], size
    # a normal flight's simulator view is the navigator's plus the true state: only the truth is stored
    meta = json.loads(pq.read_schema(both_layouts["compact"] / "flights" / "normal-0000" / "simulator.parquet")
                      .metadata[META_KEY])
    assert [s["name"] for s in meta["stored"]] == ["truth"] and "attitude" in meta["reuse"]


def test_attacked_views_are_stored_where_they_differ(quick_dataset):
    ds = open_dataset(quick_dataset)
    m = ds.manifest
    fid = m.loc[(m["mode"] == "simulation") & (m["injection_point"] == "link"), "flight_id"].iloc[0]
    meta = json.loads(pq.read_schema(ds.flight_dir(fid) / "simulator.parquet").metadata[META_KEY])
    stored = {s["name"] for s in meta["stored"]}
    assert {"truth", "twin_truth"} <= stored
    # the link attack altered what the navigator received, not what the flight controller sent
    target = str(m.loc[m["flight_id"] == fid, "target"].iloc[0])
    nav, sim = ds.flight(fid, "navigator"), ds.flight(fid, "simulator")
    changed = [c for c in nav.columns if "." in c and not np.array_equal(nav[c], sim[c], equal_nan=True)]
    assert changed and {c.split(".")[0] for c in changed} <= stored, (target, changed, stored)


def test_same_seed_same_bytes(both_layouts, tmp_path):
    again = generate_dataset("quick", tmp_path / "again", seed=11, n_normal=3, with_attacks=False)
    for p in _files(again / "flights"):
        assert p.read_bytes() == (both_layouts["compact"] / p.relative_to(again)).read_bytes(), p


def test_layout_choices_and_old_datasets(both_layouts, tmp_path, capsys):
    assert main(["generate", "--profile", "quick", "--flights", "2", "--normal-only", "--format", "csv",
                 "--layout", "compact", "--out", str(tmp_path / "x")]) == 2
    assert "layout 'compact' is Parquet only" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    # flights appended to a paper-layout dataset keep its layout
    ds = open_dataset(both_layouts["paper"])
    from scart_bench.dataset import flight_record

    topics = {t: ds.topic("normal-0000", t) for t in ds.topics("normal-0000")}
    target = tmp_path / "paper_copy"
    import shutil

    shutil.copytree(both_layouts["paper"], target)
    append_flights(target, [flight_record("extra-1", topics, topics, {"mode": "normal", "split": "test"}, {})])
    assert (target / "flights" / "extra-1" / "sensors" / "navigator").is_dir()
    assert not open_dataset(target).is_compact("extra-1")


def _without_checksums(target) -> None:
    """The dataset as a release before checksums wrote it: these tests edit its files on purpose."""
    m = pd.read_parquet(target / "manifest.parquet")
    m.drop(columns="checksum").to_parquet(target / "manifest.parquet", index=False)


def test_a_newer_or_foreign_view_file_is_refused_by_name(both_layouts, tmp_path):
    import shutil

    target = tmp_path / "ds"
    shutil.copytree(both_layouts["compact"], target)
    _without_checksums(target)
    view = target / "flights" / "normal-0001" / "navigator.parquet"
    table = pq.read_table(view)
    meta = json.loads(table.schema.metadata[META_KEY])
    meta["version"] = COMPACT_VERSION + 1
    pq.write_table(table.replace_schema_metadata({META_KEY: json.dumps(meta).encode()}), view)
    with pytest.raises(DatasetError, match=r"normal-0001/navigator\.parquet: written by a newer scart-bench"):
        open_dataset(target).flight("normal-0001")
    pd.DataFrame({"x": [1.0]}).to_parquet(view)
    with pytest.raises(DatasetError, match=r"normal-0001/navigator\.parquet: not a scart-bench flight view"):
        open_dataset(target).flight("normal-0001")


def test_a_simulator_topic_stores_only_the_fields_the_attack_changed(both_layouts, tmp_path):
    """Fields equal bit for bit to the navigator's (same rows) are kept once; the rest, a field
    whose zeros turned into -0.0 included, are stored, and every value reads back exactly."""
    import shutil

    from scart_bench.dataset import flight_record

    ds = open_dataset(both_layouts["compact"])
    nav = {t: ds.topic("normal-0000", t) for t in ds.topics("normal-0000")}
    sim = {t: ds.topic("normal-0000", t, "simulator") for t in ds.topics("normal-0000", "simulator")}
    sim["attitude"] = sim["attitude"].copy()
    sim["attitude"]["roll"] += 0.1  # an attack on one field
    zero = nav["attitude"]["yawspeed"].to_numpy().copy()
    zero[::7] = 0.0
    nav["attitude"] = nav["attitude"].assign(yawspeed=zero)
    sim["attitude"]["yawspeed"] = np.where(zero == 0.0, -0.0, zero)  # equal under ==, not in bits
    sim["highres_imu"] = sim["highres_imu"].iloc[::2].reset_index(drop=True)  # other rows: stored whole
    target = tmp_path / "ds"
    shutil.copytree(both_layouts["compact"], target)
    append_flights(target, [flight_record("extra-1", nav, sim, {"mode": "simulation", "split": "test"}, {})])
    again = open_dataset(target)
    path = again.flight_dir("extra-1") / "simulator.parquet"
    meta = json.loads(pq.read_schema(path).metadata[META_KEY])
    spans = {s["name"]: s for s in meta["stored"]}
    assert set(spans["attitude"]["shared"]["columns"]) == {"pitch", "yaw", "rollspeed", "pitchspeed"}
    assert "shared" not in spans["highres_imu"] and "global_position_int" in meta["reuse"]
    for view, written in (("navigator", nav), ("simulator", sim)):
        for topic, df in written.items():
            got = again.topic("extra-1", topic, view)
            assert list(got.columns) == list(df.columns) and len(got) == len(df)
            for col in df.columns:
                a, b = df[col], got[col]
                if float32_safe(topic, col):
                    a, b = a.to_numpy(np.float32), b.to_numpy(np.float32)
                    assert a.tobytes() == b.tobytes(), (view, topic, col)
                else:
                    pd.testing.assert_series_equal(a, b, check_exact=True, check_names=False)
    # what a detector reads: the views' combined tables differ exactly where the attack changed them
    a, b = again.flight("extra-1", "navigator"), again.flight("extra-1", "simulator")
    assert not np.array_equal(a["attitude.roll"], b["attitude.roll"], equal_nan=True)
    np.testing.assert_array_equal(a["attitude.pitch"], b["attitude.pitch"])


def test_version_1_view_files_still_read(both_layouts, tmp_path):
    """Datasets written before field sharing (layout version 1) read as before."""
    import shutil

    target = tmp_path / "ds"
    shutil.copytree(both_layouts["compact"], target)
    _without_checksums(target)
    before = open_dataset(target).flight("normal-0001", "simulator")
    for view in ("navigator", "simulator"):
        path = target / "flights" / "normal-0001" / f"{view}.parquet"
        table = pq.read_table(path)
        meta = json.loads(table.schema.metadata[META_KEY])
        assert not any("shared" in s for s in meta["stored"])
        meta["version"] = 1
        pq.write_table(table.replace_schema_metadata({META_KEY: json.dumps(meta).encode()}), path)
    pd.testing.assert_frame_equal(open_dataset(target).flight("normal-0001", "simulator"), before)


def test_fields_shared_with_the_navigator_are_bit_for_bit_the_same_and_plain_columns_are_the_frames():
    """The writer stores a copy's field only where it differs from the navigator's by a bit (0.0 against
    -0.0 and two NaN payloads differ); the number columns it reads as arrays are the frame's own values,
    text and nullable columns are read as columns."""
    from scart_bench.dataset.compact import shared_fields
    from scart_bench.dataset.tables import plain_columns

    n = 5
    nav = pd.DataFrame({"Timestamp": np.arange(n, dtype=np.int64) * 20_000, "Is_Anomaly": np.zeros(n, np.int8),
                        "Anomaly_Ids": [""] * n, "lat": np.linspace(47.0, 47.1, n), "alt": np.zeros(n),
                        "nan": np.full(n, np.nan), "count": pd.array([1, None, 3, 4, 5], dtype="Int64")})
    copy = nav.copy()
    copy["alt"] = -0.0  # equal as numbers, not as bits
    copy["nan"] = np.frombuffer(np.full(n, 0x7FF8000000000001, np.uint64).tobytes(), np.float64)  # another NaN
    assert shared_fields(copy, nav) == ["Timestamp", "Is_Anomaly", "Anomaly_Ids", "lat", "count"]
    copy.loc[2, "lat"] += 1e-12
    copy.loc[1, "Anomaly_Ids"] = "gps"
    assert shared_fields(copy, nav) == ["Timestamp", "Is_Anomaly", "count"]
    shifted = nav.assign(Timestamp=nav["Timestamp"] + 1)
    assert shared_fields(shifted, nav) is None  # other rows: nothing is shared

    plain = plain_columns(nav)
    assert set(plain) == {"Timestamp", "Is_Anomaly", "lat", "alt", "nan"}  # not the text or the nullable column
    for c, arr in plain.items():
        assert arr.dtype == nav[c].dtype and arr.tobytes() == nav[c].to_numpy().tobytes()
    assert plain_columns(pd.DataFrame(np.zeros((2, 2)), columns=["a", "a"])) == {}  # repeated labels: by column


def test_label_text_columns_are_the_columns_pandas_makes_of_the_text():
    """The label columns are built by Arrow in one call, not by pandas' per-value inference: the same
    dtype, the same text, the same Arrow data as the frame pandas builds from the strings."""
    from scart_bench.dataset.labels import LABEL_COLUMNS, label_columns, labelled_table

    ts = np.arange(400, dtype=np.int64) * 20_000
    windows = [(1_000_000, 3_000_000, "gps-bias-L1", "attack"), (2_000_000, 5_000_000, "imu-noise", "fault")]
    table = labelled_table(ts, np.zeros((400, 1)), ["x"], windows)
    by_pandas = pd.DataFrame(label_columns(ts, windows))
    for c in LABEL_COLUMNS:
        assert table[c].dtype == by_pandas[c].dtype, c
        assert table[c].tolist() == by_pandas[c].tolist(), c
    assert set(table["Anomaly_Ids"]) == {"", "gps-bias-L1", "gps-bias-L1+imu-noise", "imu-noise"}
    assert table.loc[table["Timestamp"] == 2_500_000, "Anomaly_Kind"].item() == "attack+fault"
