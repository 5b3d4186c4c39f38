"""One writer at a time: an exclusive lock on a file beside what is written (``fcntl.flock``).

The kernel releases the lock when the holding process ends, however it ends, so a killed writer
leaves no stale lock behind; the file itself stays (it says which pid last held it).
"""

from __future__ import annotations

import os
from pathlib import Path

from scart_bench.errors import ScartBenchError


class LockHeld(ScartBenchError):
    """Another process is writing to the same folder."""


class FolderLock:
    """An exclusive, non-blocking lock on ``path`` (created if needed); ``what`` names the folder in errors."""

    def __init__(self, path: str | Path, what: str):
        self.path = Path(path)
        self.what = what
        self._fh = None

    def acquire(self) -> FolderLock:
        import fcntl

        self.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(self.path, "a+")  # noqa: SIM115 - held until release()
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "another process"
            fh.close()
            raise LockHeld(f"{self.what}: another scart-bench process is writing to this folder ({holder}); "
                           "wait for it to finish or choose another output folder") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()}\n")
        fh.flush()
        self._fh = fh
        return self

    def release(self) -> None:
        if self._fh is not None:
            self._fh.close()  # closing the file releases the flock
            self._fh = None

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
