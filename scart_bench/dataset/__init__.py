"""The dataset format: the contract between the generator, the benchmark, the reports and detector plugins.

It imports nothing of the rest of the project. Two layouts, the compact one (default) and the paper's:

```
<dataset>/manifest.(parquet|csv)     one row per flight; written last: a dataset is complete
                                     exactly when its manifest exists
<dataset>/dataset.json               format, layout, profile, seed, versions
<dataset>/flights/<id>/raw/          config.json (scenario, mission, seed, versions), events.csv
compact layout (Parquet; scart_bench.dataset.compact):
<dataset>/flights/<id>/<view>.parquet  navigator.parquet, simulator.parquet: every topic of the view
                                     in one file; the combined tables are made from it on reading
paper layout (the paper's files; CSV or Parquet):
<dataset>/flights/<id>/sensors/      navigator/<topic>.<ext> and simulator/<topic>.<ext>
<dataset>/flights/<id>/combined/     navigator_all_sensors, navigator_most_frequent,
                                     simulator_all_sensors, simulator_most_frequent
```
Readers read both layouts (each flight's own); the tables read back are the same, except that the
compact layout's float32 fields come back as float64 holding their float32 values.
Topic tables have columns ``Timestamp`` (integer microseconds from the start of the run), the
labels and the topic's fields. Combined tables start with ``Index``, ``Timestamp``, the labels and
then one ``topic.field`` column per field of every topic. The labels: ``Is_Anomaly`` (1 inside
any window), ``Anomaly_Ids`` (the active scenario ids, joined by "+", empty outside windows) and
``Anomaly_Kind`` ("attack", "fault" or "attack+fault"; empty outside windows).

Modules: :mod:`.schema` (topics, fields, units), :mod:`.record` (formats, views, a flight's record),
:mod:`.labels`, :mod:`.compact` (the compact layout), :mod:`.tables` (one table on disk), :mod:`.locks`
(one writer at a time, atomic replacement, stale staging folders), :mod:`.checks` (the manifest's fields,
and each row against its flight's labels and event log), :mod:`.write` and :mod:`.read`. The names below are the
public API; import them from ``scart_bench.dataset``.
"""

from __future__ import annotations

from scart_bench.dataset.checks import (  # noqa: F401
    MODES,
    SPLITS,
    check_manifest,
)
from scart_bench.dataset.labels import (  # noqa: F401
    LABEL_COLUMNS,
    SourceTopic,
    combine,
    insert_labels,
    label_columns,
    label_rows,
    labelled_table,
)
from scart_bench.dataset.locks import (  # noqa: F401
    FolderLock,
    LockHeld,
    dataset_lock,
    exit_with_parent,
    recover,
    recover_beside,
    replacing,
)
from scart_bench.dataset.read import (  # noqa: F401
    Dataset,
    open_dataset,
    read_view,
)
from scart_bench.dataset.record import (  # noqa: F401
    FORMATS,
    LAYOUTS,
    MANIFEST_COLUMNS,
    MANIFEST_DEFAULTS,
    TABLES,
    TOPIC_VIEWS,
    TRUTH_TOPICS,
    VIEWS,
    DatasetError,
    FlightRecord,
    check_layout,
    flight_record,
    is_dataset,
    json_default,
)
from scart_bench.dataset.tables import (  # noqa: F401
    flight_checksum,
    read_csv_exact,
    read_table,
    write_table,
)
from scart_bench.dataset.write import (  # noqa: F401
    DatasetWriter,
    append_flights,
    check_output_dir,
    write_flight,
)
