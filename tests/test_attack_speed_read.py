"""``attack --dataset`` on wide (all-topic) logs pays for its source flight once: the source's view file is
read once for both the replay and the writer's comparison, and a view file with thousands of stacked
columns is read topic group by topic group, giving exactly the tables a whole read gives (issue 48 item 5)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.dataset import compact, open_dataset, read_view
from scart_bench.generator.logs.offline import attack_dataset, import_logs

TOPICS, FIELDS, ROWS = 11, 48, 80  # 528 fields: more than compact.READ_COLUMNS_AT_ONCE

GRID = """
[grid]
id = "w"
injection_point = "link"
[grid.axes]
action = ["bias"]
target = ["one"]
level = [0, 1]
duration_s = [0.3]
trigger = ["time"]
[targets.one]
fields = ["t03.f01"]
magnitudes = [1.0, 5.0]
[actions.bias]
param = "offset"
[triggers.time]
start = [{ condition = "time_window", start_s = 0.5 }]
"""


@pytest.fixture(scope="module")
def wide(tmp_path_factory) -> Path:
    """A dataset of one wide normal flight (11 topics x 48 fields, rates differing per topic), split test."""
    tmp = tmp_path_factory.mktemp("wide")
    rng = np.random.default_rng(7)
    t = np.arange(ROWS) * 25_000
    cols = {"timestamp_us": t}
    for k in range(TOPICS):
        every = 1 + k % 3  # a topic logs every first, second or third row: the others' rows are empty
        for j in range(FIELDS):
            v = rng.normal(size=ROWS)
            v[np.arange(ROWS) % every != 0] = np.nan
            cols[f"t{k:02d}.f{j:02d}"] = v
    pd.DataFrame(cols).to_csv(tmp / "wide.csv", index=False)
    import_logs([tmp / "wide.csv"], tmp / "ds", split="test")
    (tmp / "grid.toml").write_text(GRID)
    return tmp


def test_a_wide_view_reads_the_same_by_topic_group_as_whole(wide, monkeypatch):
    ds = open_dataset(wide / "ds")
    (fid,) = ds.manifest["flight_id"].astype(str)
    path = ds.flight_dir(fid) / "navigator.parquet"
    meta = compact.read_meta(path)
    assert sum(len(s["columns"]) for s in meta["stored"]) > compact.READ_COLUMNS_AT_ONCE
    grouped = compact.read_topics(path, None, meta)
    grouped_arrays = compact.read_topics(path, None, meta, arrays=True)
    some = compact.read_topics(path, ["t05", "t09"], meta)
    monkeypatch.setattr(compact, "READ_COLUMNS_AT_ONCE", 10**9)
    whole = compact.read_topics(path, None, meta)
    assert list(grouped) == list(whole) and len(whole) == TOPICS
    for name, df in whole.items():
        pd.testing.assert_frame_equal(grouped[name], df, check_exact=True)
        for col in df.columns:
            assert np.array_equal(np.asarray(grouped_arrays[name][col]), df[col].to_numpy())
    assert list(some) == ["t05", "t09"]
    for name, df in some.items():
        pd.testing.assert_frame_equal(df, whole[name], check_exact=True)


def test_attack_reads_its_source_flight_once_and_copies_as_before(wide, monkeypatch, tmp_path):
    reads = []
    original = compact.read_topics

    def counted(path, *args, **kwargs):
        reads.append(Path(path).parent.name)
        return original(path, *args, **kwargs)

    monkeypatch.setattr(compact, "read_topics", counted)
    ids = {}
    for name, full in (("full", True), ("shared", False)):
        shutil.copytree(wide / "ds", tmp_path / name)
        reads.clear()
        ids[name] = attack_dataset(tmp_path / name, wide / "grid.toml", sources=("test",), full_copies=full)
        source = str(open_dataset(tmp_path / name).manifest["source_flight"].dropna().iloc[-1])
        if not full:
            assert reads.count(source) == 1, reads  # the replay's tables and the comparison: one read
    assert ids["full"] == ids["shared"] and len(ids["shared"]) == 2
    a, b = open_dataset(tmp_path / "full"), open_dataset(tmp_path / "shared")
    for fid in ids["full"]:
        assert compact.referenced_flights(compact.read_meta(b.flight_dir(fid) / "navigator.parquet"))  # shared
        for view in ("navigator", "simulator"):
            ta, tb = read_view(a.flight_dir(fid), view), read_view(b.flight_dir(fid), view)
            assert list(ta) == list(tb)
            for topic in ta:
                pd.testing.assert_frame_equal(ta[topic], tb[topic], check_exact=True)
