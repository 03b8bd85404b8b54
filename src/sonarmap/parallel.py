"""Run a function over many tasks on Dask distributed: a LocalCluster or a scheduler.

Dask is imported only when a run starts, so importing this module is cheap.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import TypeVar

from .errors import ConfigError

__all__ = [
    "MIN_PROCESS_LIMIT",
    "PROCESSES_PER_CORE",
    "Progress",
    "check_workers",
    "process_limit",
    "run_on_dask",
]

#: Processes one run may start per core, and at least (a team's ZeroMQ nodes, a
#: LocalCluster's workers): more only queue for the cores, each with the memory of a
#: Python process holding numpy and numba, and a typo such as 100000 would start that
#: many before failing.
PROCESSES_PER_CORE = 4
MIN_PROCESS_LIMIT = 8

#: Called as ``progress(done, total)`` as results arrive.
Progress = Callable[[int, int], None]
T = TypeVar("T")
R = TypeVar("R")


def process_limit() -> int:
    """Processes one run may start on this machine: :data:`PROCESSES_PER_CORE` per core
    this process may run on, at least :data:`MIN_PROCESS_LIMIT`, at most 64."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform (macOS, Windows)
        cores = os.cpu_count() or 1
    return min(64, max(MIN_PROCESS_LIMIT, PROCESSES_PER_CORE * cores))


def check_workers(workers: int | None) -> None:
    """Refuse a LocalCluster of ``workers`` processes unless 1 <= workers <=
    :func:`process_limit` (None: the cores, always fine).

    Raises
    ------
    ConfigError
        With ``field="workers"``.
    """
    if workers is None:
        return
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}", field="workers")
    limit = process_limit()
    if workers > limit:
        raise ConfigError(
            f"workers {workers}: at most {limit} worker processes on this machine "
            f"({PROCESSES_PER_CORE} per core, at least {MIN_PROCESS_LIMIT})",
            field="workers",
        )


def run_on_dask(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
) -> list[R]:
    """``fn`` over every task on a Dask cluster, results in completion order.

    Parameters
    ----------
    fn : callable
        Run once per task on a worker; it and the tasks must pickle.
    tasks : sequence
        The tasks, each submitted as one (impure) Dask future.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:port``); default a LocalCluster.
    workers : int, optional
        Worker processes of the LocalCluster (default: the machine's cores), one thread
        each.
    progress : callable, optional
        Called as ``progress(done, total)`` after each result arrives.

    Returns
    -------
    list
        ``fn(task)`` for every task, in the order they completed.

    Raises
    ------
    ConfigError
        If ``workers`` is out of :func:`check_workers`'s range or the scheduler cannot
        be reached.
    """
    check_workers(workers)
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    try:
        if scheduler is None:
            # Port 0: the scheduler's HTTP endpoint takes a free port, so two runs on one
            # machine do not fight over the default 8787.
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=":0")
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler, timeout=10)
            except OSError as err:
                raise ConfigError(
                    f"cannot reach the Dask scheduler at {scheduler} ({err})"
                ) from err
        with client:
            futures = client.map(fn, list(tasks), pure=False)
            out: list[R] = []
            for k, fut in enumerate(as_completed(futures)):
                out.append(fut.result())
                if progress is not None:
                    progress(k + 1, len(tasks))
    finally:
        if cluster is not None:
            cluster.close()
    return out
