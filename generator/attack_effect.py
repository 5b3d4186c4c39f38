"""What an attack really changed: rows and fields of the attacked view that differ from the clean one.

An attacked flight is only an attacked flight if the attack changed something the detectors see.
:func:`attack_effect` compares, inside the attack windows, the navigator view (what the mission
computer received) with the clean reference of the same messages: the simulator view in
simulation mode (the stream before the attack layer) or the recorded source flight in csv mode.

- ``effect_rows``: messages (timestamp, topic) inside a window whose value differs from the
  reference, or that the attack dropped;
- ``effect_fields``: ``topic.field`` columns with at least one such difference;
- ``no_effect``: True when nothing differs (the flight is not scored as attacked);
- ``detectability``: the largest ``|attacked - reference|`` inside the windows divided by the
  standard deviation of that field over the validation normal flights, maximised over fields: the
  size of what was injected in units of the field's normal variability (NaN when nothing was
  altered in value, e.g. only dropped messages, or no reference std).

Scenarios acting before the flight controller (``sensor``) or on the physics (``environment``,
``vehicle``) change the simulator view itself, so in simulation mode the two views agree by
construction; for those flights the comparison cannot tell and :func:`attack_effect` returns
NaN counts and ``no_effect`` False (they stay scored), rather than a false "no effect".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.dataset import LABEL_COLUMNS, label_rows
from scart_bench.dataset.tables import plain_columns

#: Injection points whose effect shows as a difference between the navigator and simulator views.
MESSAGE_POINTS = ("link", "command")


def _fields(df: pd.DataFrame) -> list[str]:
    return [c for c in df.columns if c != "Timestamp" and c not in LABEL_COLUMNS]


def field_stds(flights: list[dict[str, pd.DataFrame]]) -> dict[str, float]:
    """``topic.field`` -> standard deviation over all rows of the given (normal) flights."""
    values: dict[str, list[np.ndarray]] = {}
    for topics in flights:
        for topic, df in topics.items():
            for f in _fields(df):
                values.setdefault(f"{topic}.{f}", []).append(df[f].to_numpy(np.float64))
    out = {}
    for key, parts in values.items():
        v = np.concatenate(parts)
        v = v[np.isfinite(v)]
        out[key] = float(v.std()) if v.size > 1 else float("nan")
    return out


def _last_in_windows(df: pd.DataFrame, windows) -> tuple[np.ndarray, np.ndarray]:
    """Distinct timestamps of ``df``'s rows inside the windows (sorted) and, for each, the row
    of its last message (a repeated timestamp keeps its last message)."""
    ts = df["Timestamp"].to_numpy(np.int64)
    rows = np.flatnonzero(label_rows(ts, windows))
    order = np.argsort(ts[rows], kind="stable")
    ts_sorted = ts[rows][order]
    last = np.ones(len(ts_sorted), dtype=bool)
    last[:-1] = ts_sorted[1:] != ts_sorted[:-1]
    return ts_sorted[last], rows[order[last]]


def _values(df: pd.DataFrame, fields: list[str], rows: np.ndarray) -> np.ndarray:
    """``df``'s ``fields`` at ``rows`` as a float64 (rows x fields) array."""
    out = np.empty((len(rows), len(fields)))
    plain = plain_columns(df)  # plain number columns as their arrays: no Series per field
    for j, f in enumerate(fields):
        col = plain.get(f)
        out[:, j] = (df[f].to_numpy(np.float64) if col is None else col.astype(np.float64, copy=False))[rows]
    return out


def attack_effect(navigator: dict[str, pd.DataFrame], reference: dict[str, pd.DataFrame], windows,
                  stds: dict[str, float] | None = None, injection_points: str = "link") -> dict:
    """Manifest fields ``effect_rows``, ``effect_fields``, ``no_effect``, ``detectability`` of one
    attacked flight (see the module docstring); ``injection_points``: the manifest's "+"-joined
    injection points of its scenarios."""
    points = [p for p in str(injection_points).split("+") if p]
    if points and any(p not in MESSAGE_POINTS for p in points):
        return {"effect_rows": float("nan"), "effect_fields": float("nan"), "no_effect": False,
                "detectability": float("nan")}
    stds = stds or {}
    changed_rows = 0
    changed_fields: set[str] = set()
    size = float("nan")
    for topic, ref in reference.items():
        if topic == "truth" or topic not in navigator:
            continue
        nav = navigator[topic]
        r_ts, r_rows = _last_in_windows(ref, windows)
        n_ts, n_rows = _last_in_windows(nav, windows)
        if not r_ts.size and not n_ts.size:
            continue
        fields = [f for f in _fields(ref) if f in nav.columns]
        n_dropped = np.setdiff1d(r_ts, n_ts, assume_unique=True).size
        _, r_at, n_at = np.intersect1d(r_ts, n_ts, assume_unique=True, return_indices=True)
        a = _values(nav, fields, n_rows[n_at])
        b = _values(ref, fields, r_rows[r_at])
        differs = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        changed_rows += int(differs.any(axis=1).sum()) + n_dropped
        for j, f in enumerate(fields):
            if differs[:, j].any() or n_dropped:
                changed_fields.add(f"{topic}.{f}")
            if differs[:, j].any():
                d = np.abs(a[:, j] - b[:, j])
                d = d[np.isfinite(d)]
                sd = stds.get(f"{topic}.{f}", float("nan"))
                if d.size and np.isfinite(sd) and sd > 0:
                    size = float(np.nanmax([size, d.max() / sd]))
    return {"effect_rows": changed_rows, "effect_fields": len(changed_fields), "no_effect": changed_rows == 0,
            "detectability": size}
