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

from scart_bench.generator.dataset import LABEL_COLUMNS, label_rows

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
        r_in = ref[label_rows(ref["Timestamp"].to_numpy(np.int64), windows).astype(bool)]
        n_in = nav[label_rows(nav["Timestamp"].to_numpy(np.int64), windows).astype(bool)]
        fields = [f for f in _fields(ref) if f in nav.columns]
        if r_in.empty and n_in.empty:
            continue
        r_in = r_in.drop_duplicates("Timestamp", keep="last").set_index("Timestamp")
        n_in = n_in.drop_duplicates("Timestamp", keep="last").set_index("Timestamp")
        dropped = r_in.index.difference(n_in.index)
        both = r_in.index.intersection(n_in.index)
        a = n_in.loc[both, fields].to_numpy(np.float64)
        b = r_in.loc[both, fields].to_numpy(np.float64)
        differs = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        changed_rows += int(differs.any(axis=1).sum()) + len(dropped)
        for j, f in enumerate(fields):
            if differs[:, j].any() or len(dropped):
                changed_fields.add(f"{topic}.{f}")
            if differs[:, j].any():
                d = np.abs(a[:, j] - b[:, j])
                d = d[np.isfinite(d)]
                sd = stds.get(f"{topic}.{f}", float("nan"))
                if d.size and np.isfinite(sd) and sd > 0:
                    size = float(np.nanmax([size, d.max() / sd]))
    return {"effect_rows": changed_rows, "effect_fields": len(changed_fields), "no_effect": changed_rows == 0,
            "detectability": size}
