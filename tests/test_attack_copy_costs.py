"""What a copy of an all-topic log costs per topic (issue 48 acceptance 5): the per-topic checks made
cheaper must still decide as before. A topic whose label text differs from what the copy's windows
give is not taken as untouched; the manifest's ``rows`` counts distinct timestamps whatever their order;
a topic held as its source's table is written as the table it stands for."""

from __future__ import annotations

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from scart_bench.dataset import SourceTopic, compact, flight_record, label_columns, labelled_table
from scart_bench.dataset.labels import label_patterns
from scart_bench.dataset.write import _most_frequent_rows, built
from scart_bench.generator.logs.copies import untouched

WINDOWS = [(2_000, 5_000, "s1", "attack"), (4_000, 7_000, "s2", "noise")]


def _source() -> dict[str, pd.DataFrame]:
    ts = np.arange(10, dtype=np.int64) * 1_000
    values = np.arange(20, dtype=np.float64).reshape(10, 2)
    return {"a": labelled_table(ts, values, ["x", "y"], []), "b": labelled_table(ts, values + 1, ["x", "y"], [])}


def test_untouched_takes_a_topic_only_when_its_labels_are_the_windows_labels():
    source = _source()
    nav = {t: labelled_table(df["Timestamp"].to_numpy(), df[["x", "y"]].to_numpy(), ["x", "y"], WINDOWS)
           for t, df in source.items()}
    assert untouched(nav, source, WINDOWS) == {"a", "b"}
    ids = nav["b"]["Anomaly_Ids"].to_numpy(dtype=object).copy()
    ids[4] = "s9"  # one row's attack id differs from the windows': the topic must be written as it is
    nav["b"] = nav["b"].assign(Anomaly_Ids=pd.array(ids, dtype=nav["a"]["Anomaly_Ids"].dtype))
    assert untouched(nav, source, WINDOWS) == {"a"}
    kinds = label_columns(nav["a"]["Timestamp"].to_numpy(), WINDOWS)["Anomaly_Kind"]
    assert list(kinds[4:5]) == ["attack+noise"]


def test_rows_count_distinct_timestamps_in_any_order():
    ts = np.array([3, 1, 3, 2, 5], dtype=np.int64) * 1_000  # 4 distinct, out of order
    topics = {"a": pd.DataFrame({"Timestamp": ts}), "b": pd.DataFrame({"Timestamp": np.array([1, 2, 2, 3], dtype=np.int64) * 1_000}),
              "c": pd.DataFrame({"Timestamp": np.array([], dtype=np.int64)})}
    assert _most_frequent_rows(topics) == 4
    assert _most_frequent_rows({"b": topics["b"]}) == 3


# A copy's topic held as its source's table (SourceTopic): the labels are made per run of rows, and
# what the writer stores for it is what it stores for the built table, for any timestamps and windows.
_times = st.lists(st.integers(0, 100), max_size=40)
_windows = st.lists(st.tuples(st.integers(-10, 110), st.integers(0, 60), st.sampled_from(["s1", "s2", "", "s1+s3"]),
                              st.sampled_from(["attack", "fault"])).map(lambda w: (w[0], w[0] + w[1], w[2], w[3])),
                    max_size=4)


@settings(max_examples=150, deadline=None)
@given(_times, st.booleans(), _windows)
def test_label_patterns_give_label_columns_row_for_row(times, ordered, windows):
    ts = np.array(sorted(times) if ordered else times, dtype=np.int64)
    index, labels = label_patterns(ts, windows)
    expected = label_columns(ts, windows)
    for column, want in expected.items():
        got = np.array([labels[i][column][0] for i in index], dtype=want.dtype)
        assert np.array_equal(got, want)


@settings(max_examples=60, deadline=None)
@given(_times, _windows)
def test_a_source_topic_is_stored_as_its_built_table(times, windows):
    ts = np.sort(np.array(times, dtype=np.int64))
    table = pd.DataFrame({"Timestamp": ts, "x": np.linspace(0, 1, len(ts)), "n": np.arange(len(ts), dtype=np.int32)})
    held = SourceTopic("t", table, windows)
    built = held.frame()
    assert list(built.columns) == held.columns and built.dtypes.tolist() == held.dtypes
    for shared in ({}, {"t": ("../f/navigator", ["x", "n"])}):
        a, meta_a = compact.stack_view({"t": built}, shared=shared)
        b, meta_b = compact.stack_view({"t": held}, shared=shared)
        assert a.equals(b) and meta_a == meta_b


def test_the_paper_layout_writes_a_source_topic_as_its_table(tmp_path):
    ts = np.arange(5, dtype=np.int64) * 1_000
    table = pd.DataFrame({"Timestamp": ts, "x": np.arange(5.0)})
    held = SourceTopic("a", table, [(1_000, 3_000, "s1", "attack")])
    rec = flight_record("f1", {"a": held}, {"a": held}, {"mode": "csv"}, {}, held.windows)
    out = built(rec)
    assert isinstance(out.navigator["a"], pd.DataFrame) and out.simulator["a"] is out.navigator["a"]
    assert out.navigator["a"]["Is_Anomaly"].tolist() == [0, 1, 1, 0, 0]
    assert built(out) is out


def test_label_patterns_hold_more_windows_than_a_bit_mask():
    rng = np.random.default_rng(1)
    windows = [(int(a), int(a) + 50, f"s{k}", "attack") for k, a in enumerate(rng.integers(0, 950, 70))]
    for ts in (rng.integers(0, 1000, 300), np.sort(rng.integers(0, 1000, 300))):
        index, labels = label_patterns(ts, windows)
        for column, want in label_columns(ts, windows).items():
            assert np.array_equal(np.array([labels[i][column][0] for i in index], dtype=want.dtype), want)
