"""One way to reach a dask cluster for every command that scales out (``generate`` and ``run``).

``connect(None, jobs)`` starts a ``LocalCluster`` of ``jobs`` single-threaded worker processes, each in a
folder of its own; ``connect("tcp://host:8786")`` joins a running scheduler. Either way the caller gets
a :class:`Cluster` to ``close`` (a context manager too).
"""

from __future__ import annotations

from dataclasses import dataclass

from scart_bench.errors import ClusterError

#: Seconds allowed to connect to a dask scheduler.
CONNECT_TIMEOUT_S = 5.0


@dataclass
class Cluster:
    """A connected ``distributed.Client`` and, for a local cluster, the cluster it started."""

    client: object
    local: object | None = None

    def close(self) -> None:
        self.client.close()
        if self.local is not None:
            self.local.close()

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def connect(scheduler: str | None = None, jobs: int = 1, timeout: float = CONNECT_TIMEOUT_S,
            error: type[Exception] = ClusterError) -> Cluster:
    """Connect to ``scheduler`` (``error`` naming the address when it cannot be reached) or start a
    local cluster of ``jobs`` single-threaded worker processes."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Cluster(Client(scheduler, timeout=timeout, set_as_default=False))
        except Exception as exc:
            raise error(f"--scheduler {scheduler}: cannot reach a dask scheduler there within {timeout:g} s "
                        f"({type(exc).__name__}: {exc}); expected the address of a running scheduler such "
                        "as tcp://host:8786, or no --scheduler for a local cluster") from None
    local = LocalCluster(n_workers=max(1, int(jobs)), threads_per_worker=1, processes=True,
                         dashboard_address=None, memory_limit=0, silence_logs=logging.ERROR)
    return Cluster(Client(local, set_as_default=False), local)


def worker_temp_root() -> str | None:
    """The running dask worker's own folder (its ``local_directory``), None outside a worker."""
    try:
        from distributed import get_worker

        return get_worker().local_directory
    except (ImportError, ValueError):
        return None
