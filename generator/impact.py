"""The physical impact of an attack: the attacked flight's true path against its normal twin's.

Every simulation-mode attacked flight has a *twin*: the same seed flown without the attack layer
(same wind, sensor noise, mission and initial state; the flight kernel gives the same flight for a
seed whatever else is in the batch). The twin is not written as a dataset flight; its ``truth``
table is kept in the attacked flight's simulator view as ``twin_truth`` (for the path figure) and
the manifest gets, from the two true paths (:func:`impact`):

- ``impact_max_dev_m`` / ``impact_final_dev_m``: largest and final 3-D distance (m) between the
  attacked and the twin's true position at the same time; a flight that ended (landed, crashed)
  keeps its last position until the other ends;
- ``impact_mission_completed``: the attacked flight landed within :data:`MISSION_TOLERANCE_M` of
  where its twin landed (horizontal) -- i.e. it flew the mission the twin flew;
- ``impact_landing_dist_m``: horizontal distance (m) of the attacked flight's final true position
  from home (its first true position);
- ``impact_crashed``: the flight ended in a crash.

Normal and csv-mode flights have no twin: their impact columns are empty (NaN / <NA>).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: How far from the twin's landing point (horizontal, m) a landing still completes the mission.
MISSION_TOLERANCE_M = 5.0

#: The simulator-view topic that holds the twin's true state in an attacked flight.
TWIN_TOPIC = "twin_truth"

#: Manifest columns written by :func:`impact` (empty for flights without a twin).
IMPACT_COLUMNS = ("impact_max_dev_m", "impact_final_dev_m", "impact_mission_completed",
                  "impact_landing_dist_m", "impact_crashed")


def _aligned(a: pd.DataFrame, b: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Positions (T, 3) of both tables on the union of their timestamps, each held at its last
    row after it ends (and at its first row before it starts)."""
    ta, tb = a["Timestamp"].to_numpy(np.int64), b["Timestamp"].to_numpy(np.int64)
    ts = np.union1d(ta, tb)
    pa = a[["x", "y", "z"]].to_numpy(np.float64)
    pb = b[["x", "y", "z"]].to_numpy(np.float64)
    ia = np.clip(np.searchsorted(ta, ts, side="right") - 1, 0, len(ta) - 1)
    ib = np.clip(np.searchsorted(tb, ts, side="right") - 1, 0, len(tb) - 1)
    return pa[ia], pb[ib]


def impact(truth: pd.DataFrame, twin_truth: pd.DataFrame, status: str) -> dict:
    """Manifest impact fields of one attacked flight (see the module docstring).

    ``truth`` / ``twin_truth``: the ``truth`` tables (Timestamp, x, y, z in m, NED) of the
    attacked flight and of its twin; ``status``: the attacked flight's end ("landed", "crashed",
    "timeout").
    """
    if not len(truth) or not len(twin_truth):
        return {c: float("nan") for c in IMPACT_COLUMNS}
    pa, pb = _aligned(truth, twin_truth)
    dev = np.linalg.norm(pa - pb, axis=1)
    xy = truth[["x", "y"]].to_numpy(np.float64)
    twin_xy = twin_truth[["x", "y"]].to_numpy(np.float64)
    landed = status == "landed"
    return {
        "impact_max_dev_m": float(dev.max()),
        "impact_final_dev_m": float(dev[-1]),
        "impact_mission_completed": bool(landed and np.hypot(*(xy[-1] - twin_xy[-1])) <= MISSION_TOLERANCE_M),
        "impact_landing_dist_m": float(np.hypot(*(xy[-1] - xy[0]))),
        "impact_crashed": status == "crashed",
    }
