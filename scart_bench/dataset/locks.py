"""Writers that cannot tear a dataset: one writer at a time, atomic replacement, recovery after a kill
(of the dataset written, and of the partial folders killed writers left beside other datasets).

One writer at a time: an exclusive lock on a file beside what is written (``fcntl.flock``).

The kernel releases the lock when the holding process ends, however it ends, so a killed writer
leaves no stale lock behind; the file itself stays (it says which pid last held it).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from scart_bench.dataset.record import is_dataset
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


def exit_with_parent(parent: int, period_s: float = 0.5) -> None:
    """In a worker process: end it as soon as its parent is gone (SIGKILL or SIGTERM of the command
    leaves no writer behind, and no orphaned job runs on). The one watchdog of the project: the dataset
    writer's pool initializer, csv mode's attack workers and the benchmark's job workers
    (``benchmark/executors.py``) start it."""
    import threading
    import time

    def watch() -> None:
        while True:
            time.sleep(period_s)
            if os.getppid() != parent:
                os._exit(3)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def dataset_lock(out: str | Path) -> FolderLock:
    """The lock every writer of the dataset at ``out`` holds (a hidden file beside it, so that it also
    covers a dataset being built in a sibling folder): a second writer is refused (LockHeld, exit 2)."""
    out = Path(out)
    return FolderLock(out.parent / f".{out.name}.lock", str(out))


def recover(out: str | Path) -> None:
    """Finish what a killed writer left beside ``out``: its partial folder is removed and, when it
    was killed between its two renames (the old dataset moved aside, the new one not yet in place),
    the old dataset is moved back. Does nothing while another process holds the dataset's lock."""
    out = Path(out)
    partial, old = out.parent / f".{out.name}.partial", out.parent / f".{out.name}.old"
    if not (partial.exists() or old.exists()) or not out.parent.is_dir():
        return
    try:
        lock = dataset_lock(out).acquire()
    except (LockHeld, OSError):
        return
    try:
        shutil.rmtree(partial, ignore_errors=True)
        if old.exists():
            if not out.exists() and is_dataset(old):
                os.replace(old, out)
            else:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        lock.release()


def recover_beside(parent: str | Path) -> list[Path]:
    """:func:`recover` every dataset in ``parent`` that a killed writer left a partial folder beside
    (``.<name>.partial`` with the lock file ``.<name>.lock`` that every writer makes): a generate
    killed with SIGKILL runs no cleanup, and its partial folder (megabytes per flight) would stay
    until a command used that very dataset again. Returns the datasets recovered; folders of live
    writers (their lock held) are left alone."""
    parent = Path(parent)
    done = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return done
    for entry in entries:
        name = entry.name
        if not (name.startswith(".") and name.endswith(".partial")) or len(name) <= len("..partial"):
            continue
        out = parent / name[1:-len(".partial")]
        try:
            if entry.is_symlink() or not entry.is_dir() or not (parent / f".{out.name}.lock").is_file():
                continue
        except OSError:
            continue
        recover(out)
        if not entry.exists():
            done.append(out)
    return done


@contextmanager
def replacing(out: str | Path) -> Iterator[Path]:
    """Build a dataset in a hidden sibling folder and move it to ``out`` only once complete.

    Yields the folder to write into. Until the new dataset is complete, the old one at ``out`` (if
    any) is untouched: an error (a full disk) or an interrupt leaves it as it was and removes the
    partial folder. Holds :func:`dataset_lock` throughout.
    """
    out = Path(out)
    recover(out)
    recover_beside(out.parent)  # and what killed writers left beside other datasets in this folder
    with dataset_lock(out):
        partial = out.parent / f".{out.name}.partial"
        old = out.parent / f".{out.name}.old"
        shutil.rmtree(partial, ignore_errors=True)
        try:
            yield partial
            if out.exists():
                shutil.rmtree(old, ignore_errors=True)
                os.replace(out, old)  # two renames: the new dataset appears whole, the old goes after
            os.replace(partial, out)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(partial, ignore_errors=True)
