"""Work spread over cores or machines with ``dask.distributed``: one code path for both.

fd_monitor runs no pool or scheduler of its own. :func:`open_client` starts an embedded
:class:`distributed.LocalCluster` (one single-threaded worker process per core unless told
otherwise) or connects to a running Dask scheduler (``tcp://HOST:PORT``: a real cluster,
whose workers need only the fd_monitor package installed); :func:`run_tasks` submits one task
per item and hands every result to the caller as it finishes (``as_completed``), so the caller
streams results to disk and a stop loses nothing that finished. Ctrl-C cancels what is still
pending and returns what finished (:class:`TaskRun` ``stopped``).

:class:`RateBar` is the terminal progress bar: done/total, rate, time left.

Nothing here imports rclpy.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TextIO

from fd_monitor.model.errors import FdMonitorError

__all__ = ["LEAN_CONFIG", "RateBar", "TaskRun", "default_workers", "guided_batches",
           "open_client", "run_tasks"]

#: Dask settings of the embedded cluster (and of this process's client): its background
#: work costs CPU per second of wall time in every process, which on a few cores is taken
#: from the tasks. Defaults: a 20 ms event-loop tick in each process, each worker sampling
#: its task's stack every 10 ms (the dashboard's profile, which nothing here shows), each
#: nanny measuring its worker's memory every 100 ms -- about 0.13 core of a 2-worker
#: cluster when idle, measured, and more when busy. Here: 0.04 core idle.
LEAN_CONFIG: dict[str, Any] = {
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.profile.enabled": False,
    "distributed.worker.memory.monitor-interval": "1s",
}


def default_workers() -> int:
    """One worker per core this process may use (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:           # not on Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on an embedded LocalCluster, or on a running scheduler.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the embedded cluster (one thread each); default one per core
        (:func:`default_workers`). Ignored with ``scheduler`` (the cluster has its own).
    scheduler : str, optional
        Address of a running Dask scheduler, ``tcp://HOST:PORT``.

    Raises
    ------
    FdMonitorError
        ``workers`` < 1, or the scheduler cannot be reached (one line naming it).
    """
    import dask
    from distributed import Client

    with dask.config.set(LEAN_CONFIG):
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                why = str(exc).splitlines()[0] if str(exc) else "no detail"
                raise FdMonitorError(f"--scheduler {scheduler}: cannot connect "
                                     f"({type(exc).__name__}: {why})") from None
        else:
            cluster, client = _local_cluster(workers)
    try:
        yield client
    finally:
        client.close()
        if scheduler is None:
            cluster.close()


def _local_cluster(workers: int | None) -> tuple[Any, Any]:
    """An embedded LocalCluster of ``workers`` single-threaded processes and its client."""
    from distributed import Client, LocalCluster

    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise FdMonitorError(f"--workers {workers}: expected an integer >= 1")
    # one single-threaded process per worker: the runtimes are pure Python (the GIL), and
    # numpy's own threads would fight the other workers for the cores
    # Ctrl-C in a terminal reaches the whole process group: the worker processes start with
    # SIGINT ignored (inherited), so only this process stops, cancels and closes them
    main = threading.current_thread() is threading.main_thread()
    before = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        # CRITICAL: a worker's heartbeat that meets the closing scheduler logs a traceback
        # at ERROR; a task's own failure comes back to the client, which reports it
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.CRITICAL,
                               env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                                    "MKL_NUM_THREADS": "1"})
    finally:
        if main and before is not None:
            signal.signal(signal.SIGINT, before)
    return cluster, Client(cluster)


def guided_batches(n: int, workers: int, max_batch: int = 16,
                   per_worker: int = 4) -> list[range]:
    """Cut ``n`` items (in order) into batches, one task each: guided self-scheduling.

    Each batch takes ``ceil(remaining / (per_worker * workers))`` items, at least 1 and at
    most ``max_batch``: while much remains, batches are large (fewer tasks, so less
    scheduling, transfer and result handling per item); towards the end they shrink to
    single items, so the workers finish together. With as many workers as items, one item
    a batch.

    Parameters
    ----------
    n : int
        Items.
    workers : int
        Workers of the cluster (>= 1).
    max_batch : int
        Largest batch (results stream back once per batch).
    per_worker : int
        Batches of the remaining items per worker.

    Returns
    -------
    list of range
        Consecutive ranges covering ``range(n)``.

    Examples
    --------
    >>> [len(b) for b in guided_batches(40, 2)]
    [5, 5, 4, 4, 3, 3, 2, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1]
    """
    out: list[range] = []
    at, share = 0, max(1, per_worker * max(1, workers))
    while at < n:
        size = min(max(1, -(-(n - at) // share)), max(1, max_batch))
        out.append(range(at, at + size))
        at += size
    return out


class RateBar:
    """A one-line progress bar: done/total, items per second, time left (stderr).

    Parameters
    ----------
    total : int
        Items to do.
    label : str
    unit : str
        What an item is (``bags``, ``runs``).
    stream : TextIO, optional
        Default stderr.
    enabled : bool
        False: draw nothing.
    """

    def __init__(self, total: int, label: str, unit: str, stream: TextIO | None = None,
                 enabled: bool = True, width: int = 24) -> None:
        self.total, self.label, self.unit, self.width = max(int(total), 1), label, unit, width
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.done = 0
        self.t0 = time.monotonic()
        self._drawn = 0.0

    def line(self) -> str:
        """The bar's text now."""
        el = time.monotonic() - self.t0
        rate = self.done / el if el > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else math.inf
        fill = round(self.width * self.done / self.total)
        eta = "?" if not math.isfinite(left) else _hms(left)
        return (f"{self.label} [{'#' * fill}{'.' * (self.width - fill)}] {self.done}/"
                f"{self.total} {self.unit}, {rate:.3g}/s, {_hms(el)} elapsed, {eta} left")

    def update(self, n: int = 1) -> None:
        """``n`` more items done; redraw at most 10 times a second (and at the end)."""
        self.done = min(self.done + n, self.total)
        now = time.monotonic()
        if not self.enabled or (now - self._drawn < 0.1 and self.done < self.total):
            return
        self._drawn = now
        self.stream.write("\r" + self.line().ljust(100))
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()

    def close(self) -> None:
        """End the line (after a stop)."""
        if self.enabled and self.done < self.total:
            self.stream.write("\r" + self.line().ljust(100) + "\n")
            self.stream.flush()


def _hms(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else \
        f"{s // 60}:{s % 60:02d}"


@dataclass
class TaskRun:
    """What :func:`run_tasks` did.

    Attributes
    ----------
    done : int
        Tasks whose result was handed over.
    total : int
    stopped : bool
        Ctrl-C stopped the run; the pending tasks were cancelled.
    seconds : float
        Wall time from the first submission.
    workers : int
        Workers of the cluster when the run started.
    """

    done: int = 0
    total: int = 0
    stopped: bool = False
    seconds: float = 0.0
    workers: int = 0
    failed: list[str] = field(default_factory=list)


def run_tasks(client: Any, fn: Callable[[Any], Any], items: Sequence[Any],
              on_result: Callable[[int, Any], None], bar: RateBar | None = None,
              weights: Sequence[int] | None = None) -> TaskRun:
    """Run ``fn(item)`` for every item on the cluster; ``on_result(index, result)`` in this
    process as each finishes (completion order, not item order).

    ``fn`` must be importable by the workers (a module-level function of fd_monitor) and
    should turn its own failures into results: an exception that escapes it stops the run
    (it propagates here, after the pending tasks are cancelled).

    Parameters
    ----------
    client : distributed.Client
    fn : callable
    items : sequence
        One task each (keys are unique per call, so equal items are still run twice).
    on_result : callable
        Called with ``(index into items, result)``.
    bar : RateBar, optional
        Advanced by ``weights[index]`` (default 1) per result.

    Returns
    -------
    TaskRun
        ``stopped`` when Ctrl-C (KeyboardInterrupt) arrived: what had finished was handed
        over, the rest cancelled.
    """
    from distributed import as_completed

    t0 = time.monotonic()
    run = TaskRun(total=len(items),
                  workers=len(client.scheduler_info().get("workers", {})))
    tag = f"fd-{os.getpid()}-{time.monotonic_ns()}"
    futures = [client.submit(fn, it, key=f"{tag}-{i}", pure=False)
               for i, it in enumerate(items)]
    index = {f.key: i for i, f in enumerate(futures)}
    pending = set(futures)
    try:
        for fut in as_completed(futures):
            i = index[fut.key]
            res = fut.result()
            pending.discard(fut)
            fut.release()                # the worker may forget it now
            on_result(i, res)
            run.done += 1
            if bar is not None:
                bar.update(1 if weights is None else int(weights[i]))
    except KeyboardInterrupt:
        run.stopped = True
    finally:
        if pending:
            client.cancel(list(pending))
        if bar is not None:
            bar.close()
    run.seconds = time.monotonic() - t0
    return run
