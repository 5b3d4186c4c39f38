"""Detector speed: fit time, batch scoring throughput and streaming latency per sample.

    python -m perf.detector_speed [--detectors all|a,b] [--flights N] [--rows R]

For every detector (built-ins, entry-point plugins and ``--plugin`` specs) this fits on ``N``
generated normal flights of ``R`` rows at 50 Hz, then measures on a held-out flight:

- fit seconds;
- batch throughput: rows per second when ``score`` gets the whole flight at once;
- streaming latency: the flight's rows fed one at a time to the detector's ``stream()`` (its
  incremental scorer, or by default its trailing ``W`` rows scored by ``score_last``), as a live
  50 Hz monitor would; p50 and p99 in milliseconds over the last ``S`` samples, p99 as a
  fraction of the 20 ms between two samples of a 50 Hz stream (> 1: it falls behind, and the
  status says "over budget"), and "stream err", the largest relative gap between the streamed
  and the batch scores.

``W``, the history a detector needs, comes from the fitted detector's ``history_rows_``
attribute when it sets one (the rows that reproduce the last row's score: e.g. Telemanom's LSTM
history plus its EWMA memory); otherwise 500 rows (10 s). A detector whose import or fit fails
is reported and skipped. Torch runs on one thread unless ``--threads`` says otherwise: small
models gain little from more, and on shared cores extra threads stall each other. The flights are the
conformance kit's generated normal flights (:mod:`scart_bench.testing`).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from importlib.metadata import entry_points

import numpy as np
import pandas as pd

from scart_bench.detectors import registry

#: Seconds between two samples of a 50 Hz telemetry stream.
BUDGET_MS = 20.0
#: Streaming history when a detector does not say how much it needs (``history_rows_``).
DEFAULT_HISTORY_ROWS = 500


@dataclass
class SpeedResult:
    """Timings of one detector (NaN where not measured)."""

    name: str
    status: str = "ok"
    fit_s: float = float("nan")
    rows_per_s: float = float("nan")
    history_rows: int = 0
    p50_ms: float = float("nan")
    p99_ms: float = float("nan")
    stream_rel_err: float = float("nan")

    @property
    def budget_ratio(self) -> float:
        return self.p99_ms / BUDGET_MS


# -- flights --------------------------------------------------------------------------------------
def synthetic_flights(n: int, seed: int, rows: int) -> list[pd.DataFrame]:
    """``n`` generated normal flights (the conformance kit's, :func:`scart_bench.testing.normal_flights`)."""
    from scart_bench.testing import normal_flights

    return normal_flights(n, seed=seed, rows=rows)


# -- detectors ------------------------------------------------------------------------------------
def detector_names(spec: str) -> list[str]:
    """Names for ``--detectors``: "all" is every built-in, entry-point and loaded plugin."""
    if spec.strip() != "all":
        return [s.strip() for s in spec.split(",") if s.strip()]
    names = list(registry.BUILTINS)
    for ep in entry_points(group=registry.ENTRY_POINT_GROUP):
        try:
            name = getattr(ep.load(), "name", ep.name)
        except Exception as exc:  # a broken plugin must not hide the others
            print(f"skip plugin entry point {ep.name!r}: {type(exc).__name__}: {exc}", file=sys.stderr)
            continue
        names.append(name)
    names += registry.plugin_names()
    return list(dict.fromkeys(names))


def measure(
    name: str,
    train: list[pd.DataFrame],
    flight: pd.DataFrame,
    samples: int,
    params: dict | None = None,
) -> SpeedResult:
    """Fit ``name`` on ``train`` and time batch and streaming scoring of ``flight``."""
    res = SpeedResult(name)
    try:
        det = registry.make(name, **(params or {}))
    except Exception as exc:
        res.status = f"skipped: cannot import/make ({type(exc).__name__}: {exc})"
        return res
    try:
        t0 = time.perf_counter()
        det.fit(train)
        res.fit_s = time.perf_counter() - t0

        det.score(flight.iloc[:64])  # warm-up (lazy imports, model build, caches)
        times = []
        while len(times) < 3 and sum(times) < 2.0:
            t0 = time.perf_counter()
            scores = det.score(flight)
            times.append(time.perf_counter() - t0)
        if not np.all(np.isfinite(scores)):
            res.status = "non-finite scores"
        res.rows_per_s = len(flight) / float(np.median(times))

        hist = getattr(det, "history_rows_", None)
        res.history_rows = int(min(hist if hist else DEFAULT_HISTORY_ROWS, len(flight)))
        n = min(len(flight), res.history_rows + samples)
        raw = flight[det.columns_].to_numpy(dtype=np.float64)
        stream = det.stream() if hasattr(det, "stream") else None
        streamed, lat = np.empty(n), []
        for i in range(n):
            t0 = time.perf_counter()
            if stream is not None:
                streamed[i] = stream.update(raw[i])
            else:  # a duck-typed plugin: its trailing window, last row kept
                streamed[i] = float(det.score(flight.iloc[max(i + 1 - res.history_rows, 0) : i + 1])[-1])
            dt = time.perf_counter() - t0
            if i >= n - samples:
                lat.append(dt * 1e3)
        res.stream_rel_err = float(np.max(np.abs(streamed - scores[:n]) / np.maximum(np.abs(scores[:n]), 1e-9)))
        if lat:
            res.p50_ms, res.p99_ms = (float(v) for v in np.percentile(lat, [50, 99]))
        if res.status == "ok" and res.p99_ms > BUDGET_MS:
            res.status = "over budget"
    except Exception as exc:
        res.status = f"failed: {type(exc).__name__}: {exc}"
    return res


def format_table(results: list[SpeedResult]) -> str:
    """The results as an aligned text table."""
    head = (
        f"{'detector':<14} {'fit s':>8} {'score rows/s':>13} {'history':>8} "
        f"{'p50 ms':>8} {'p99 ms':>8} {'p99/20ms':>9} {'stream err':>10}  status"
    )
    lines = [head, "-" * len(head)]
    for r in results:
        lines.append(
            f"{r.name:<14} {r.fit_s:>8.2f} {r.rows_per_s:>13,.0f} {r.history_rows:>8d} "
            f"{r.p50_ms:>8.2f} {r.p99_ms:>8.2f} {r.budget_ratio:>9.2f} {r.stream_rel_err:>10.1e}  {r.status}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.detector_speed", description=__doc__.split("\n")[0])
    p.add_argument("--detectors", default="all", metavar="all|NAME,...", help="detectors to time (default all)")
    p.add_argument("--flights", type=int, default=3, metavar="N", help="training flights (default 3)")
    p.add_argument("--rows", type=int, default=1500, metavar="R", help="rows per flight (default 1500 = 30 s)")
    p.add_argument("--samples", type=int, default=50, metavar="S", help="streaming samples timed (default 50)")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic flights (default 0)")
    p.add_argument("--threads", type=int, default=1, metavar="T",
                   help="torch.set_num_threads(T) before timing (default 1, as one live monitor; 0: torch's default)")
    p.add_argument("--plugin", action="append", metavar="SPEC", default=[],
                   help="also load a detector from module:Class or path/to/file.py:Class (repeatable)")
    args = p.parse_args(argv)
    if args.flights < 1 or args.rows < 2 or args.samples < 4 or args.threads < 0:
        p.error("need --flights >= 1, --rows >= 2, --samples >= 4 and --threads >= 0")

    for spec in args.plugin:
        registry.load_plugin(spec)
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    train = synthetic_flights(args.flights, args.seed, args.rows)
    flight = synthetic_flights(1, args.seed + 1000, args.rows)[0]
    n_cols = sum("." in c for c in flight.columns)
    threads = f"{args.threads} torch thread(s)" if args.threads else "torch's default threads"
    print(
        f"{args.flights} training flights x {args.rows} rows, {n_cols} channels; held-out flight of "
        f"{len(flight)} rows; {args.samples} streaming samples; {threads}; "
        f"budget {BUDGET_MS:g} ms/sample (50 Hz)"
    )
    results = []
    for name in detector_names(args.detectors):
        print(f"... {name}", file=sys.stderr, flush=True)
        results.append(measure(name, train, flight, args.samples))
    print(format_table(results))
    return 0 if all(r.status in ("ok", "over budget") or r.status.startswith("skipped") for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
