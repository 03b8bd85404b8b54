"""Run a function over many tasks on Dask distributed: a LocalCluster or a scheduler.

Dask is imported only when a run starts, so importing this module is cheap.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

from .errors import ConfigError

__all__ = ["Progress", "run_on_dask"]

#: Called as ``progress(done, total)`` as results arrive.
Progress = Callable[[int, int], None]
T = TypeVar("T")
R = TypeVar("R")


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
        If ``workers`` is below 1 or the scheduler cannot be reached.
    """
    from dask.distributed import Client, LocalCluster, as_completed

    if workers is not None and workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
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
