"""The names of the former ``benchmark/scoring.py``, kept importable for plugins and users' scripts.

The code lives in three modules (issue 46), imported in one direction (tables -> metrics ->
evaluation):

- :mod:`scart_bench.benchmark.evaluation`: the counting rules; one detector's saved scores checked
  and thresholded (:func:`build_evaluation`), each attacked flight's outcome, the calibration table.
- :mod:`scart_bench.benchmark.metrics`: array-level metrics and the metric classes of metrics.csv
  (:data:`DEFAULT_METRICS`, :func:`compute_metrics`).
- :mod:`scart_bench.benchmark.tables`: the breakdown per attack dimension, the Markdown tables, the
  number formats and the operating-point lines.

New code imports from those modules; this one only re-exports them (with the names the old module
imported from :mod:`~scart_bench.benchmark.intervals`, :mod:`~scart_bench.benchmark.protocol` and
:mod:`~scart_bench.benchmark.vus`, which were importable from it too).
"""

from __future__ import annotations

from scart_bench.benchmark.evaluation import (
    ZONES,
    Evaluation,
    FlightRows,
    ScoreError,
    build_evaluation,
    calibration_table,
    flight_clusters,
    flight_outcomes,
)
from scart_bench.benchmark.intervals import (
    BOOTSTRAP_SEED,
    N_BOOTSTRAP,
    bootstrap_auc,
    cluster_weights,
    design_effect,
    design_interval,
    wilson,
)
from scart_bench.benchmark.metrics import (
    DEFAULT_METRICS,
    NEAR_ARMING_S,
    RATE_BOOTSTRAP,
    RATES,
    TIMING_COLUMNS,
    CalibrationPoint,
    DetectionDelay,
    FalseAlarmRate,
    FlightROCAUC,
    Metric,
    PaperTable,
    PointwisePRF,
    RangePRF,
    ScoringLatency,
    TatbulZeroPRF,
    ThresholdFree,
    alarm_events,
    compute_metrics,
    detection_delay,
    f1,
    point_prf,
    range_prf,
    range_scores,
    roc_auc,
    runs,
)
from scart_bench.benchmark.protocol import ATTACK_MODES, Protocol, counted_max, counted_rows
from scart_bench.benchmark.tables import (
    BREAKDOWN_COLUMNS,
    BREAKDOWN_DIMENSIONS,
    DETECTABILITY_EDGES,
    DETECTION_RULE,
    EXTRA_COLUMNS,
    INTERVAL_METHOD,
    PAPER_COLUMNS,
    breakdown,
    detectability_bins,
    format_value,
    impact_summary,
    markdown_table,
    operating_point_line,
    rate_summary,
)
from scart_bench.benchmark.vus import VUS_WINDOW, average_precision, r_prf, roc_auc_from_sorted, row_metrics
from scart_bench.errors import ScartBenchError

__all__ = [
    # evaluation
    "ZONES", "Evaluation", "FlightRows", "ScoreError", "build_evaluation", "calibration_table", "flight_clusters",
    "flight_outcomes",
    # metrics
    "DEFAULT_METRICS", "NEAR_ARMING_S", "RATES", "RATE_BOOTSTRAP", "TIMING_COLUMNS", "CalibrationPoint",
    "DetectionDelay", "FalseAlarmRate", "FlightROCAUC", "Metric", "PaperTable", "PointwisePRF", "RangePRF",
    "ScoringLatency", "TatbulZeroPRF", "ThresholdFree", "alarm_events", "compute_metrics", "detection_delay", "f1",
    "point_prf", "range_prf", "range_scores", "roc_auc", "runs",
    # tables
    "BREAKDOWN_COLUMNS", "BREAKDOWN_DIMENSIONS", "DETECTABILITY_EDGES", "DETECTION_RULE", "EXTRA_COLUMNS",
    "INTERVAL_METHOD", "PAPER_COLUMNS", "breakdown", "detectability_bins", "format_value", "impact_summary",
    "markdown_table", "operating_point_line", "rate_summary",
    # imported by the old module from elsewhere
    "ATTACK_MODES", "BOOTSTRAP_SEED", "N_BOOTSTRAP", "VUS_WINDOW", "Protocol", "ScartBenchError", "average_precision",
    "bootstrap_auc", "cluster_weights", "counted_max", "counted_rows", "design_effect", "design_interval", "r_prf",
    "roc_auc_from_sorted", "row_metrics", "wilson",
]
