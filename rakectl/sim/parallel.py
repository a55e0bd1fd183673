"""Running independent simulated jobs: on forked worker processes or in this one
(:class:`LocalExecutor`), or on a Dask cluster (:class:`DaskExecutor`, the ``[cluster]``
extra). Jobs must be deterministic in their inputs (the campaign's cases are, from
(seed, index)): whoever runs them, the results are the same.
"""

from __future__ import annotations

import multiprocessing
import threading
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol, TypeVar

from rakectl.errors import ConfigError, RakeError

J = TypeVar("J")
R = TypeVar("R")


def fork_map(run: Callable[[J], R], jobs: Sequence[J], workers: int) -> Iterator[R]:
    """``run`` over ``jobs`` on up to ``workers`` forked processes (in this process when
    ``workers`` <= 1 or there is a single job), yielded as they finish. The pool is torn
    down however the caller stops iterating."""
    if workers <= 1 or len(jobs) <= 1:
        yield from map(run, jobs)
        return
    pool = multiprocessing.get_context("fork").Pool(min(workers, len(jobs)))
    try:
        yield from pool.imap_unordered(run, jobs)
        pool.close()
    finally:
        pool.terminate()
        pool.join()


class Executor(Protocol):
    """Runs ``run`` over ``jobs`` and yields the results as they finish (any order)."""

    def map_unordered(self, run: Callable[[J], R], jobs: Sequence[J]) -> Iterator[R]: ...

    def slots(self) -> int:
        """How many jobs it runs at once."""
        ...

    def close(self) -> None: ...

    def describe(self) -> str: ...

    def physics(self) -> str:
        """Which physics its workers run (drivers.compiled.status), in one line."""
        ...


def physics_status() -> str:
    """This process's physics (a function of this module, so that Dask can send it)."""
    from drivers import compiled

    return compiled.status()


def workers_physics(statuses: dict[str, str]) -> str:
    """One line from each worker's :func:`physics_status`: the common one, or each kind
    with how many workers run it (a cluster whose nodes are built differently)."""
    if not statuses:
        return "physics: no worker answered"
    kinds = Counter(statuses.values())
    if len(kinds) == 1:
        return f"{next(iter(kinds))} (on all {len(statuses)} worker(s))"
    return "workers DIFFER: " + "; ".join(f"{n} with {line}" for line, n in sorted(kinds.items()))


class LocalExecutor:
    """Forked processes on this machine (:func:`fork_map`)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers

    def map_unordered(self, run: Callable[[J], R], jobs: Sequence[J]) -> Iterator[R]:
        return fork_map(run, jobs, self.workers)

    def slots(self) -> int:
        return max(1, self.workers)

    def close(self) -> None:
        pass

    def describe(self) -> str:
        return f"{self.workers} local process(es)"

    def physics(self) -> str:
        return physics_status()  # forked from this process: the modules it has


class DaskExecutor:
    """A Dask cluster: an existing scheduler (``tcp://HOST:PORT``) or a LocalCluster of
    ``N`` single-threaded worker processes started here (``local:N``). A job whose worker
    dies is run again elsewhere by the scheduler (up to ``distributed``'s
    allowed-failures, 3 by default); a job that raises is not retried (it is
    deterministic: it would raise again), its error ends the run."""

    def __init__(self, scheduler: str, retries: int = 0) -> None:
        require_cluster_extra()
        from distributed import Client, LocalCluster

        self.scheduler, self.retries = scheduler, retries
        self._cluster: Any = None
        self._before: set[Any] = set()
        self._threads_before: set[threading.Thread] = set()
        workers = local_workers(scheduler)
        if workers:
            before = set(multiprocessing.active_children())
            self._threads_before = set(threading.enumerate())
            self._cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                         processes=True, dashboard_address=None)
            self._before = before
            try:
                self._client = Client(self._cluster)
            except BaseException:
                self._cluster.close()
                raise
        else:
            try:
                self._client = Client(scheduler, timeout=30)
            except OSError as exc:
                raise RakeError(f"--scheduler {scheduler}: no scheduler there ({exc})") from exc
            try:  # workers with other versions could compute other results: refuse them
                self._client.get_versions(check=True)
            except Exception as exc:  # distributed raises its own error for a mismatch
                self._client.close()
                raise RakeError(f"--scheduler {scheduler}: the workers' packages differ "
                                f"from this machine's ({exc})") from exc

    def map_unordered(self, run: Callable[[J], R], jobs: Sequence[J]) -> Iterator[R]:
        """Each result is released on the cluster once it is here: a finished job held
        there would be computed again if its worker went away (a node lost, a worker
        restarted after missing its heartbeats), and a long campaign would hold every
        result it has already written."""
        from distributed import as_completed

        pending = as_completed(self._client.map(run, list(jobs), pure=False,
                                                retries=self.retries))
        try:
            for future in pending:
                result = future.result()
                future.release()
                yield result
        finally:
            left = list(pending.futures)
            pending.clear()
            self._client.cancel(left)

    def held_results(self) -> int:
        """How many jobs' results the workers hold (those finished and not yet yielded)."""
        return sum(len(keys) for keys in self._client.has_what().values())

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
            # the workers' processes (a restarted one too) are gone when this returns,
            # and so are the threads that watched them end (distributed's AsyncProcess
            # joins each process in a thread of its own, which outlives the join briefly)
            for child in set(multiprocessing.active_children()) - self._before:
                child.join(timeout=10.0)
            for thread in set(threading.enumerate()) - self._threads_before:
                if thread.name.startswith("AsyncProcess"):
                    thread.join(timeout=10.0)

    def slots(self) -> int:
        workers = self._client.scheduler_info().get("workers", {})
        return max(1, sum(int(w.get("nthreads", 1)) for w in workers.values()))

    def describe(self) -> str:
        workers = len(self._client.scheduler_info().get("workers", {}))
        return f"Dask {self.scheduler} ({workers} worker(s))"

    def physics(self) -> str:
        """Asked of every worker: each node runs the physics built on it, or Python."""
        return workers_physics(self._client.run(physics_status))


def require_cluster_extra() -> None:
    """RakeError saying how to install Dask's ``distributed`` where it is missing."""
    try:
        import distributed  # noqa: F401
    except ImportError as exc:
        raise RakeError("--scheduler needs the [cluster] extra: pip install "
                        f"'rakectl[cluster]' ({exc})") from exc


def local_workers(scheduler: str) -> int:
    """N of ``local:N``, 0 for ``tcp://HOST:PORT``; ConfigError naming anything else, and
    RakeError without the [cluster] extra (so a command can check its --scheduler before
    long work that precedes the cluster's)."""
    require_cluster_extra()
    if scheduler.startswith("tcp://"):
        return 0
    if scheduler.startswith("local:"):
        try:
            workers = int(scheduler.removeprefix("local:"))
        except ValueError:
            workers = 0
        if workers < 1:
            raise ConfigError(f"--scheduler {scheduler}: local:N needs N >= 1 workers")
        return workers
    raise ConfigError(f"--scheduler {scheduler!r}: give tcp://HOST:PORT or local:N")


def executor_for(scheduler: str | None, workers: int) -> LocalExecutor | DaskExecutor:
    """The executor a command line asks for: Dask with a scheduler, else local processes."""
    return DaskExecutor(scheduler) if scheduler else LocalExecutor(workers)
