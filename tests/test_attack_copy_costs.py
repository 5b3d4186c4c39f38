"""What a copy of an all-topic log costs per topic (issue 48 acceptance 5): the per-topic checks made
cheaper must still decide as before. A topic whose label text differs from what the copy's windows
give is not taken as untouched; the manifest's ``rows`` counts distinct timestamps whatever their order."""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.dataset import label_columns, labelled_table
from scart_bench.dataset.write import _most_frequent_rows
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
