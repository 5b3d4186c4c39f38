"""Time in real logs: logging gaps, and the logged clock that attack windows count on.

ArduCopter logs only while armed (and a log may pause for other reasons), so a recording can have
stretches of seconds to minutes with no row at all. An attack of 15 s on such a log should label
15 s of *logged* flight, not 15 s of wall time of which most is a gap. :class:`LoggedClock` maps a
log's time to logged time, where each gap shrinks to one typical row interval; csv mode replays a
log on that clock (generator.logs.offline) and maps the copy's rows, windows and events back, so
the copy keeps the log's own timestamps.

A *gap* is an interval with no row of any topic longer than :data:`GAP_MIN_S` and
:data:`GAP_FACTOR` times the log's median row interval (so a log whose topics are all slow has
no gap between its rows). A generated flight has none: its clock is the identity.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: Shortest stretch without any row (s) that counts as a logging gap.
GAP_MIN_S = 2.0
#: ... and it must be this many times the log's median interval between rows.
GAP_FACTOR = 20.0


def log_times(tables: dict[str, pd.DataFrame]) -> np.ndarray:
    """Every distinct row time (µs) of a log's topic tables, sorted."""
    parts = [df["Timestamp"].to_numpy(np.int64) for df in tables.values() if len(df) and "Timestamp" in df]
    return np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)


def logging_gaps(tables: dict[str, pd.DataFrame], min_s: float = GAP_MIN_S) -> list[tuple[int, int]]:
    """The log's gaps as ``(last row before, first row after)`` in µs, in time order."""
    t = log_times(tables)
    if len(t) < 3:
        return []
    d = np.diff(t)
    limit = max(min_s * 1e6, GAP_FACTOR * float(np.median(d)))
    return [(int(t[i]), int(t[i + 1])) for i in np.flatnonzero(d > limit)]


def gap_record(gaps: list[tuple[int, int]]) -> dict:
    """What import records of a log's gaps (config.json ``logging_gaps``): count, longest and total
    (s), and each gap's ``[start_s, end_s]``."""
    lengths = [(b - a) / 1e6 for a, b in gaps]
    return {"count": len(gaps), "longest_s": round(max(lengths, default=0.0), 3),
            "total_s": round(sum(lengths), 3), "gaps_s": [[round(a / 1e6, 3), round(b / 1e6, 3)] for a, b in gaps]}


def gap_line(gaps: list[tuple[int, int]]) -> str:
    """One line on a log's gaps: ``2 logging gaps (longest 221.6 s at 60.4-282.0 s, 266.6 s in all)``."""
    if not gaps:
        return "no logging gap"
    a, b = max(gaps, key=lambda g: g[1] - g[0])
    total = sum(e - s for s, e in gaps) / 1e6
    return (f"{len(gaps)} logging gap{'' if len(gaps) == 1 else 's'} (longest {(b - a) / 1e6:.1f} s at "
            f"{a / 1e6:.1f}-{b / 1e6:.1f} s, {total:.1f} s in all)")


class LoggedClock:
    """A log's time (µs) <-> logged time (µs): each gap shrinks to one typical row interval.

    ``fit(tables)`` finds the gaps; ``to_logged`` maps log times (a time inside a gap maps to the
    next logged row, where a trigger that falls in the gap starts); ``to_log`` maps logged times
    back (a row's logged time to the row's own time). Without gaps both are the identity.
    """

    def __init__(self, min_gap_s: float = GAP_MIN_S):
        self.min_gap_s = min_gap_s

    def fit(self, tables: dict[str, pd.DataFrame]) -> LoggedClock:
        t = log_times(tables)
        self.gaps_ = logging_gaps(tables, self.min_gap_s)
        self.start_us_ = int(t[0]) if len(t) else 0
        self.end_us_ = int(t[-1]) if len(t) else 0
        step = int(np.median(np.diff(t))) if len(t) > 1 else 1
        self.step_us_ = max(step, 1)
        a = np.array([g[0] for g in self.gaps_], dtype=np.int64)
        b = np.array([g[1] for g in self.gaps_], dtype=np.int64)
        self._before, self._after = a, b  # last row before and first row after each gap
        self._shift = np.cumsum(b - a - self.step_us_)  # time removed up to and including each gap
        self._times_of: dict[int, tuple] = {}  # replayed tables' times on both clocks (back)
        return self

    @property
    def identity(self) -> bool:
        return not self.gaps_

    def to_logged(self, t_us) -> np.ndarray:
        """Logged time of log times ``t_us`` (a time inside a gap: the next row's)."""
        t = np.asarray(t_us, dtype=np.int64)
        if self.identity:
            return t.copy()
        k = np.searchsorted(self._after, t, side="right") - 1  # last gap whose next row is at or before t
        j = np.searchsorted(self._before, t, side="left") - 1  # last gap whose last row is before t
        in_gap = j > k  # after the gap's last row, before its next one
        t = np.where(in_gap, self._after[np.clip(j, 0, None)], t)
        k = np.where(in_gap, j, k)
        return t - np.where(k >= 0, self._shift[np.clip(k, 0, None)], 0)

    def to_log(self, logged_us) -> np.ndarray:
        """Log time of logged times (inverse of :meth:`to_logged` on rows; a logged time inside a
        shrunk gap maps to the next row)."""
        tau = np.asarray(logged_us, dtype=np.int64)
        if self.identity:
            return tau.copy()
        after = self._after - self._shift  # logged time of the first row after each gap
        before = self._before - np.r_[0, self._shift[:-1]]  # ... and of the last row before it
        k = np.searchsorted(after, tau, side="right") - 1
        j = np.searchsorted(before, tau, side="left") - 1
        real = tau + np.where(k >= 0, self._shift[np.clip(k, 0, None)], 0)
        return np.where(j > k, self._after[np.clip(j, 0, None)], real)

    def logged_s(self, t0_us: int, t1_us: int) -> float:
        """Logged seconds between two log times."""
        lo, hi = self.to_logged([t0_us, t1_us])
        return float(hi - lo) / 1e6

    def gap_at(self, t_us: float) -> tuple[int, int] | None:
        """The gap that log time ``t_us`` falls in (strictly between its rows), or None."""
        for a, b in self.gaps_:
            if a < t_us < b:
                return a, b
        return None

    def tables(self, tables: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
        """The tables on the logged clock (rows and values unchanged, ``Timestamp`` in logged time)."""
        if self.identity:
            return tables
        out = {}
        for topic, df in tables.items():
            new = df.copy(deep=False)
            new["Timestamp"] = self.to_logged(df["Timestamp"].to_numpy(np.int64))
            out[topic] = new
        return out

    def back(self, result: tuple, replayed: dict[str, pd.DataFrame] | None = None) -> tuple:
        """A csv-mode result (tables, windows, events) replayed on this clock, on the log's own time.

        A topic csv mode left out (None: passed unchanged, ``leave_passed``; ``replayed``: the tables
        it replayed, on this clock) stays None where its labels come out the same counted on the log's
        time, that is the source table with the copy's windows (generator.logs.copies); otherwise it
        is built here as csv mode builds it (labels on this clock), with the log's timestamps."""
        if self.identity:
            return result
        nav, windows, events = result
        wins = []
        for w in windows:
            s, e = (int(v) for v in self.to_log([w[0], w[1]]))
            wins.append((s, e, *w[2:]))
        tables = {}
        for topic, df in nav.items():
            if df is None:
                if replayed is None:
                    raise ValueError("LoggedClock.back: a result with topics left out (None) needs the replayed tables")
                times = self._times(replayed[topic])
                if self._same_rows(times, windows, wins):
                    tables[topic] = None
                    continue
                from scart_bench.generator.modes import passed_table  # modes imports what imports this module

                df = passed_table(replayed[topic], windows)
            new = df.copy(deep=False)
            new["Timestamp"] = self.to_log(df["Timestamp"].to_numpy(np.int64))
            tables[topic] = new
        evs = [{**ev, "timestamp_us": int(self.to_log([ev["timestamp_us"]])[0])} for ev in events]
        return tables, wins, evs

    def _times(self, table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        """A replayed table's timestamps on this clock and on the log's, kept for the next copy."""
        cache = self._times_of
        if cache.get(id(table), (None,))[0] is not table:
            logged = table["Timestamp"].to_numpy(np.int64)
            cache[id(table)] = (table, logged, self.to_log(logged))
        return cache[id(table)][1:]

    @staticmethod
    def _same_rows(times: tuple[np.ndarray, np.ndarray], logged_windows, log_windows) -> bool:
        """Whether each window holds the same rows counted on this clock and on the log's time (so
        every row's labels agree): both clocks' times in order, each window the same run of rows."""
        logged, log = times
        if len(logged) > 1 and not ((logged[1:] >= logged[:-1]).all() and (log[1:] >= log[:-1]).all()):
            return False
        for a, b in zip(logged_windows, log_windows):
            if (np.searchsorted(logged, [a[0], a[1]]) != np.searchsorted(log, [b[0], b[1]])).any():
                return False
        return True


def _s(us: float) -> str:
    return f"{us / 1e6:.1f} s"


def notes_of(scenario_id: str, notes: list[str]) -> bool:
    """True when a note is about the scenario ``scenario_id``."""
    return any(n.startswith(f"{scenario_id}: ") for n in notes)


def log_triggers(job: list, clock: LoggedClock, takeoff_us: int | None = None) -> tuple[list, list[str]]:
    """A configuration's scenarios with their time triggers on the logged clock, and a note for each
    trigger that moved.

    - ``time_window`` (``start_s``, ``end_s``) and ``random_start`` (``low_s``) are times of the log:
      one that falls in a gap moves to the next logged row (noted); ``random_start``'s span
      (``high_s - low_s``), like a ``duration``, counts logged seconds.
    - A start whose attack would not fit before the end of the log (its ``duration`` end
      condition counted) moves earlier, to the latest start that fits but not before take-off
      (``takeoff_us``, else the log's first row); a random span moves with it, and when the log
      leaves no room for a whole window, onsets spread over the first half of what is left after
      take-off (each attack then covers the rest of the log). Noted.

    A log without gaps whose triggers fit (a generated flight) keeps its scenarios unchanged.
    """
    from dataclasses import replace

    end = float(clock.to_logged([clock.end_us_])[0])
    first = float(clock.to_logged([takeoff_us if takeoff_us is not None else clock.start_us_])[0])
    if first >= end:
        first = float(clock.to_logged([clock.start_us_])[0])
    anchor = "take-off" if takeoff_us is not None else "the log's start"
    out, notes = [], []
    for sc in job:
        dur = min((p["seconds"] * 1e6 for n, p in sc.end if n == "duration"), default=0.0)
        latest = end - dur  # the latest start of a whole window
        start = []
        for name, p in sc.start:
            if name == "time_window":
                p = dict(p)
                t = p["start_s"] * 1e6
                tau = float(clock.to_logged([int(t)])[0])
                gap = clock.gap_at(t)
                if gap:
                    notes.append(f"{sc.id}: time_window start_s={p['start_s']:g} falls in the logging gap "
                                 f"{_s(gap[0])}-{_s(gap[1])}: starts at the next logged row ({_s(gap[1])})")
                if tau > latest and tau > first:
                    new = max(latest, first)
                    notes.append(f"{sc.id}: time_window start_s={p['start_s']:g} leaves no {dur / 1e6:g} s of the "
                                 f"log ({_s(clock.end_us_)}): starts at {_s(clock.to_log([int(new)])[0])} "
                                 f"({'the latest start that fits' if new == latest else anchor})")
                    tau = new
                if clock.identity and not notes_of(sc.id, notes):
                    start.append((name, p))
                    continue
                p["start_s"] = tau / 1e6
                if np.isfinite(p["end_s"]):
                    p["end_s"] = max(float(clock.to_logged([int(p["end_s"] * 1e6)])[0]) / 1e6, p["start_s"] + 1e-6)
                start.append((name, p))
            elif name == "random_start":
                p = dict(p)
                t = p["low_s"] * 1e6
                lo = float(clock.to_logged([int(t)])[0])
                hi = lo + (p["high_s"] - p["low_s"]) * 1e6
                gap = clock.gap_at(t)
                if gap:
                    notes.append(f"{sc.id}: random_start low_s={p['low_s']:g} falls in the logging gap "
                                 f"{_s(gap[0])}-{_s(gap[1])}: onsets from the next logged row ({_s(gap[1])}), "
                                 f"over {p['high_s'] - p['low_s']:g} s of logged flight")
                if hi > latest and hi > first:
                    shift = hi - max(latest, first)
                    new_lo, new_hi = max(lo - shift, first), hi - shift
                    if new_hi <= new_lo:  # no room for a whole window: spread over what is left
                        new_lo, new_hi = first, (first + end) / 2
                    notes.append(f"{sc.id}: random_start {p['low_s']:g}-{p['high_s']:g} s leaves no {dur / 1e6:g} s "
                                 f"of the log ({_s(clock.end_us_)}): onsets in "
                                 f"{_s(clock.to_log([int(new_lo)])[0])}-{_s(clock.to_log([int(new_hi)])[0])}")
                    lo, hi = new_lo, new_hi
                if clock.identity and not notes_of(sc.id, notes):
                    start.append((name, p))
                    continue
                p["low_s"], p["high_s"] = lo / 1e6, hi / 1e6
                start.append((name, p))
            else:
                start.append((name, p))
        changed = any(a[1] != b[1] for a, b in zip(start, sc.start))
        out.append(replace(sc, start=start) if changed else sc)
    return out, notes
