"""Progress of long work that a person can follow: flights flown, files imported, copies written.

On a terminal every part of the work (for example the normal, simulation-mode and csv-mode flights
of a generation) gets a tqdm bar; anywhere else (a log file, CI, a batch job's output) a plain line
sums up all parts every ``$SCART_BENCH_PROGRESS_S`` seconds (default 30) and once at the end::

    generate: normal 256/772, simulation 0/2048, csv 64/2048 flights; 5.2 flights/s, about 15 min left

The counts are sent by the code doing the work (``add``); the totals are declared up front
(``expect``) and may be declared again when they become known. Progress goes to stderr, so stdout
keeps a command's result.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import TextIO


def progress_every_s() -> float:
    """Seconds between plain progress lines (``$SCART_BENCH_PROGRESS_S``, default 30)."""
    try:
        return max(0.05, float(os.environ.get("SCART_BENCH_PROGRESS_S", "30")))
    except ValueError:
        return 30.0


def duration(seconds: float) -> str:
    """A time left, as a person would say it."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


class Progress:
    """Counts of work done per part, shown as bars on a terminal and as periodic lines elsewhere.

    Parameters
    ----------
    what : str
        The work's name at the start of each line ("generate", "import").
    unit : str
        What is counted ("flights", "files", "copies").
    every_s : float or None
        Seconds between plain lines; None reads ``$SCART_BENCH_PROGRESS_S``.
    stream : text stream or None
        Where to write (default stderr).
    bars : bool or None
        tqdm bars; None: when ``stream`` is a terminal.
    enabled : bool
        False: count silently (``quiet()``).

    Safe to call from several threads (csv mode's relay thread adds while the main one flies).
    """

    def __init__(self, what: str, unit: str = "flights", every_s: float | None = None,
                 stream: TextIO | None = None, bars: bool | None = None, enabled: bool = True):
        self.what = what
        self.unit = unit
        self.every_s = every_s
        self.stream = stream
        self.bars = bars
        self.enabled = enabled
        self.totals: dict[str, int] = {}
        self.done: dict[str, int] = {}
        self._bars: dict = {}
        self._lock = threading.Lock()
        self._t0: float | None = None
        self._last = 0.0

    # -- what the work reports ----------------------------------------------------------------
    def expect(self, part: str, total: int) -> None:
        """Declare (or correct) how many units ``part`` has in all."""
        with self._lock:
            self._start()
            self.totals[part] = int(total)
            self.done.setdefault(part, 0)
            bar = self._bar(part)
            if bar is not None:
                bar.total = int(total)
                bar.refresh()

    def add(self, part: str, n: int = 1) -> None:
        """``n`` more units of ``part`` are done."""
        with self._lock:
            self._start()
            self.done[part] = self.done.get(part, 0) + int(n)
            bar = self._bar(part)
            if bar is not None:
                bar.update(int(n))
            elif self.enabled and time.monotonic() - self._last >= self._period():
                self._say(self.line())

    def note(self, line: str) -> None:
        """A log line that does not break the bars."""
        if not self.enabled:
            return
        with self._lock:
            if self._bars:
                from tqdm import tqdm

                tqdm.write(line, file=self._stream())
            else:
                print(line, file=self._stream(), flush=True)

    def close(self, summary: bool = True) -> None:
        """Close the bars and, with ``summary``, say all parts' counts and the elapsed time once more."""
        with self._lock:
            for bar in self._bars.values():
                bar.close()
            self._bars.clear()
            if summary and self.enabled and self._t0 is not None and self.totals:
                elapsed = time.monotonic() - self._t0
                self._say(f"{self._counts()} in {duration(elapsed)}")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        # work that failed ends with its error alone: no summary that could read as done
        self.close(summary=exc_type is None)

    # -- the line ----------------------------------------------------------------------------
    def line(self) -> str:
        """All parts' counts, the rate since the start and a guess of the time left."""
        done, total = sum(self.done.values()), sum(self.totals.values())
        elapsed = time.monotonic() - (self._t0 or time.monotonic())
        text = self._counts()
        if done and elapsed > 0:
            text += f"; {done / elapsed:,.1f} {self.unit}/s"
            if total > done:
                text += f", about {duration(elapsed / done * (total - done))} left"
        return text

    def _counts(self) -> str:
        parts = ", ".join(f"{p} {self.done.get(p, 0)}/{t}" for p, t in self.totals.items())
        return f"{self.what}: {parts} {self.unit}"

    # -- plumbing ----------------------------------------------------------------------------
    def _start(self) -> None:
        if self._t0 is None:
            self._t0 = self._last = time.monotonic()

    def _stream(self) -> TextIO:
        return self.stream if self.stream is not None else sys.stderr

    def _period(self) -> float:
        return self.every_s if self.every_s is not None else progress_every_s()

    def _use_bars(self) -> bool:
        if not self.enabled:
            return False
        if self.bars is not None:
            return self.bars
        isatty = getattr(self._stream(), "isatty", None)
        return bool(isatty and isatty())

    def _bar(self, part: str):
        if part in self._bars or not self._use_bars():
            return self._bars.get(part)
        from tqdm import tqdm

        self._bars[part] = tqdm(total=self.totals.get(part), desc=f"{self.what}: {part}", unit=f" {self.unit}",
                                position=len(self._bars), file=self._stream(), leave=True, dynamic_ncols=True)
        return self._bars[part]

    def _say(self, line: str) -> None:
        self._last = time.monotonic()
        print(line, file=self._stream(), flush=True)


def quiet() -> Progress:
    """A Progress that counts and shows nothing (the default of library calls)."""
    return Progress("", enabled=False)


def log_to_stderr(msg: str) -> None:
    """The live loops' default log (proxy, sitl and ROS sessions): one line to stderr, flushed."""
    print(msg, file=sys.stderr, flush=True)
