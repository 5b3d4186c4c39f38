"""csv mode's replay of recorded messages through the layer, at the cost of what the layer reads.

The layer's contract in csv mode is one ``on_messages`` call per distinct timestamp of the
recording, with every topic's message of that time (a topic's repeated timestamp: its last
message). Most of those calls do nothing: a topic the layer neither listens to nor targets (nor
needs for a flight's origin) passes unchanged, and a call whose time is no change point of any
group (``AttackLayer.next_change``: the pure conditions evaluated on many times at once) changes
no state. :func:`replay` makes only the calls that can matter, so a flight costs what its attacked
and listened topics cost, whatever its message schedule; the output is the same, bit for bit, as
the call at every timestamp (``per_message``, kept for that comparison: tests/test_csv_batch.py).
"""

from __future__ import annotations

import numpy as np

from scart_bench.generator.scart.layer import AttackLayer


def _last_per_time(times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct timestamps, index of each one's last message) of one topic's sorted-or-not times."""
    order = np.argsort(times, kind="stable")
    ts = times[order]
    last = np.ones(len(ts), dtype=bool)
    last[:-1] = ts[1:] != ts[:-1]
    return ts[last], order[last]


def per_message(layer: AttackLayer, times: dict[str, np.ndarray], values: dict[str, np.ndarray],
                out_vals: dict[str, np.ndarray], delivered: dict[str, np.ndarray]) -> None:
    """The reference replay: one call per distinct timestamp with every topic's message of that time."""
    events = sorted((int(ts), t, k) for t in times for k, ts in enumerate(times[t]))
    j = 0
    while j < len(events):
        t_us = events[j][0]
        batch = {}
        while j < len(events) and events[j][0] == t_us:
            _, t, k = events[j]
            batch[t] = k
            j += 1
        msgs = {t: values[t][:, k, :] for t, k in batch.items()}
        altered = layer.on_messages(None, 0, t_us, msgs)
        for t, k in batch.items():
            v, ok = altered[t]
            out_vals[t][:, k, :] = v
            delivered[t][:, k] = ok


def replay(layer: AttackLayer, times: dict[str, np.ndarray], values: dict[str, np.ndarray],
           out_vals: dict[str, np.ndarray], delivered: dict[str, np.ndarray]) -> None:
    """Replay ``values[topic]`` ((flights, messages, fields), sent at ``times[topic]``, µs) through
    ``layer``, writing what it delivers into ``out_vals`` and ``delivered`` (which start as a copy
    of the values and all True): the same as :func:`per_message`, calling the layer only where a
    call can change something."""
    topics = list(times)
    if not topics:
        return
    ticks = np.unique(np.concatenate([np.asarray(times[t], dtype=np.int64) for t in topics]))
    last = {t: _last_per_time(np.asarray(times[t], dtype=np.int64)) for t in topics}
    layer.plan_ticks(ticks, {t: last[t][0] for t in topics})  # every call below is at one of the ticks
    pos = 0  # next tick not yet replayed
    while True:
        origin_open = layer.origin_open
        seen = sorted(layer.must_see(topics))  # sorted: the order of a call's messages, as per_message's
        calls = _calls(ticks, last, seen, pos)
        for call, batch in calls:
            _quiet_ticks(layer, ticks, pos, call)
            altered = layer.on_messages(None, 0, int(ticks[call]), {t: values[t][:, k, :] for t, k in batch})
            for t, k in batch:
                v, ok = altered[t]
                out_vals[t][:, k, :] = v
                delivered[t][:, k] = ok
            pos = call + 1
            if origin_open and not layer.origin_open:
                break  # every origin is known: the lat/lon topics no longer matter (unless listened)
        else:
            break
    _quiet_ticks(layer, ticks, pos, len(ticks))


def _calls(ticks: np.ndarray, last: dict, seen: list[str], pos: int):
    """The calls with messages from tick ``pos`` on: (tick index, [(topic, message index)]) in time
    order, the topics of one call in ``seen``'s order."""
    if not seen:
        return
    at, names, ks = [], [], []
    for j, t in enumerate(seen):
        ts, k = last[t]
        i = np.searchsorted(ticks, ts)
        keep = i >= pos
        at.append(i[keep])
        names.append(np.full(int(keep.sum()), j, dtype=np.int64))
        ks.append(k[keep])
    at_all, name_all, k_all = np.concatenate(at), np.concatenate(names), np.concatenate(ks)
    order = np.lexsort((name_all, at_all))
    at_l, name_l, k_l = at_all[order].tolist(), name_all[order].tolist(), k_all[order].tolist()
    i = 0
    while i < len(at_l):
        j = i
        batch = []
        while j < len(at_l) and at_l[j] == at_l[i]:
            batch.append((seen[name_l[j]], k_l[j]))
            j += 1
        yield at_l[i], batch
        i = j


def _quiet_ticks(layer: AttackLayer, ticks: np.ndarray, lo: int, hi: int) -> None:
    """The calls at ``ticks[lo:hi]``, which carry no message the layer must see: only those at a
    change point are made (with no message: the others' pass unchanged)."""
    while lo < hi:
        k = layer.next_change(ticks[lo:hi])
        if lo + k >= hi:
            return
        layer.on_messages(None, 0, int(ticks[lo + k]), {})
        lo += k + 1
