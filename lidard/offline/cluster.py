"""Run many independent tasks on Dask: a LocalCluster by default, or an existing scheduler.

The reusable layer under ``lidarctl sweep`` (and, later, ``lidarctl reprocess`` of raw captures):

* :func:`open_client` starts a ``distributed.LocalCluster`` of worker PROCESSES (numpy releases the
  GIL only in parts of the DSP, so threads would serialize the Python glue) or connects to a running
  scheduler given as ``tcp://host:8786``; either way the caller gets a ``distributed.Client``.
* :func:`run_tasks` submits ``fn(task)`` for every task with a bounded number in flight (a sweep of
  a million tasks must not hold a million futures), hands each result to ``on_result`` as it arrives
  (so a writer can persist it at once and an interrupted run loses little), calls ``on_progress``,
  and returns the results IN TASK ORDER. A task that raises does not stop the others: it becomes a
  :class:`TaskFailure` carrying the task's own parameters, the exception and its traceback.
* :func:`run_serial` is the same contract without Dask, in this process: the baseline of the
  scheduling-overhead benchmark and the reference the Dask path must equal.
* :func:`mapper` wraps either as a drop-in for the builtin ``map`` (results in order, or
  :class:`TasksFailed` naming every failed call's arguments): for code that takes a ``map_fn``, such
  as the raw-capture reprocessing (``lidard.raw.replay.reprocess(path, settings, map_fn=...)``).

Task functions must be importable on the workers (module-level functions of an installed package,
not lambdas defined in ``__main__``) and their arguments picklable.
"""

from __future__ import annotations

import logging
import os
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from lidard.errors import LidardError

from . import require_offline_extra

ResultCallback = Callable[[int, Any, Any], None]      # (index, task, result)
ProgressCallback = Callable[[int, int, int], None]    # (done, total, failed)


class ClusterError(LidardError):
    """The scheduler cannot be reached or the cluster cannot start; the message names the address."""


@dataclass(frozen=True)
class TaskFailure:
    """One task that raised: its position, its parameters (``describe(task)``) and the error."""

    index: int
    params: Any
    error_type: str
    message: str
    traceback: str = ""

    def summary(self) -> str:
        return f"task {self.index} {self.params}: {self.error_type}: {self.message}"


@dataclass
class RunReport:
    """What :func:`run_tasks` / :func:`run_serial` return: results in task order, failures, timing."""

    results: list[Any]
    failures: list[TaskFailure] = field(default_factory=list)
    elapsed_s: float = 0.0
    workers: int = 0

    @property
    def ok(self) -> bool:
        return not self.failures


@contextmanager
def open_client(scheduler: str | None = None, *, n_workers: int | None = None, threads_per_worker: int = 1,
                processes: bool = True, connect_timeout_s: float = 10.0) -> Iterator[Any]:
    """A ``distributed.Client``: on ``scheduler`` if given, else on a new LocalCluster (closed after).

    ``n_workers`` defaults to the CPU count. ``processes=False`` runs the workers as threads of this
    process (the tests' in-process cluster: no spawn cost, same scheduler and futures).
    """
    require_offline_extra(("dask", "distributed"))
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{connect_timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                               f"{connect_timeout_s:g} s ({exc}); is `dask scheduler` running there?") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = int(n_workers or os.cpu_count() or 1)
    if n < 1 or threads_per_worker < 1:
        raise ClusterError(f"need n_workers >= 1 and threads_per_worker >= 1, got {n}, {threads_per_worker}")
    cluster = LocalCluster(n_workers=n, threads_per_worker=threads_per_worker, processes=processes,
                           dashboard_address=":0", silence_logs=logging.WARNING)
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def _n_workers(client) -> int:
    try:
        return len(client.scheduler_info().get("workers", {}))
    except Exception:   # an information call only; never fail a run over it
        return 0


def call_batch(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[tuple]:
    """Run ``fn`` on each item of a batch (on a worker): ("ok", result) or ("err", type, message, tb)
    per item, so one raising item does not hide the results of the others in its batch."""
    out: list[tuple] = []
    for item in items:
        try:
            out.append(("ok", fn(item)))
        except Exception as exc:     # reported per item by run_tasks, with the item's parameters
            out.append(("err", type(exc).__name__, str(exc), "".join(traceback.format_tb(exc.__traceback__))))
    return out


@dataclass
class _Collector:
    """Where outcomes land: results in task order, failures with parameters, callbacks per item."""

    tasks: Sequence[Any]
    describe: Callable[[Any], Any]
    on_result: ResultCallback | None
    on_progress: ProgressCallback | None
    results: list[Any] = field(default_factory=list)
    failures: list[TaskFailure] = field(default_factory=list)
    done: int = 0

    def __post_init__(self) -> None:
        self.results = [None] * len(self.tasks)

    def take(self, i: int, outcome: tuple) -> None:
        if outcome[0] == "ok":
            self.results[i] = outcome[1]
            if self.on_result is not None:
                self.on_result(i, self.tasks[i], outcome[1])
        else:
            _, etype, msg, tb = outcome
            self.failures.append(TaskFailure(index=i, params=self.describe(self.tasks[i]), error_type=etype,
                                             message=msg, traceback=tb))
        self.done += 1
        if self.on_progress is not None:
            self.on_progress(self.done, len(self.tasks), len(self.failures))

    def report(self, t0: float, workers: int) -> RunReport:
        return RunReport(results=self.results, failures=sorted(self.failures, key=lambda f: f.index),
                         elapsed_s=time.perf_counter() - t0, workers=workers)


def _future_outcomes(fut, n: int) -> list[tuple]:
    if fut.status == "error":       # the whole Dask task failed (e.g. its worker died): every item did
        exc, tb = fut.exception(), fut.traceback()
        return [("err", type(exc).__name__, str(exc), "".join(traceback.format_tb(tb)) if tb is not None else "")] * n
    return fut.result()


def run_tasks(client, fn: Callable[[Any], Any], tasks: Sequence[Any], *,
              describe: Callable[[Any], Any] = repr, on_result: ResultCallback | None = None,
              on_progress: ProgressCallback | None = None, max_in_flight: int | None = None,
              batch_size: int = 1, key_prefix: str = "lidard-task") -> RunReport:
    """Run ``fn(task)`` for every task on ``client``; results in task order, failures reported.

    ``batch_size`` > 1 runs that many consecutive tasks in one Dask task (:func:`call_batch`): Dask
    spends milliseconds per task (docs/sweeps.md), so tasks of tens of ms are worth grouping; each
    item still gets its own result, failure and progress step. At most ``max_in_flight`` Dask tasks
    (default: 8 per worker thread, at least 64) are submitted at once; each completion submits the
    next one, so memory stays bounded however long the list.
    """
    require_offline_extra(("dask", "distributed"))
    from distributed import as_completed

    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    t0 = time.perf_counter()
    col = _Collector(tasks, describe, on_result, on_progress)
    if max_in_flight is None:
        threads = sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values())
        max_in_flight = max(64, 8 * max(threads, 1))
    token = f"{os.getpid()}-{time.monotonic_ns()}"      # unique keys: the same task twice is two runs
    batches = [range(i, min(i + batch_size, len(tasks))) for i in range(0, len(tasks), batch_size)]
    batch_of: dict[str, range] = {}

    def submit(b: int):
        fut = client.submit(call_batch, fn, [tasks[i] for i in batches[b]], key=f"{key_prefix}-{token}-{b}",
                            pure=False)
        batch_of[fut.key] = batches[b]
        return fut

    nxt = min(max_in_flight, len(batches))
    pending = as_completed([submit(b) for b in range(nxt)])
    try:
        for fut in pending:
            idx = batch_of.pop(fut.key)
            outcomes = _future_outcomes(fut, len(idx))
            fut.release()
            for i, oc in zip(idx, outcomes):
                col.take(i, oc)
            if nxt < len(batches):
                pending.add(submit(nxt))
                nxt += 1
    except BaseException:
        # Ctrl-C or a failing callback: stop the cluster's work too, not just this loop
        client.cancel(list(pending.futures))
        raise
    return col.report(t0, _n_workers(client))


def run_serial(fn: Callable[[Any], Any], tasks: Sequence[Any], *, describe: Callable[[Any], Any] = repr,
               on_result: ResultCallback | None = None,
               on_progress: ProgressCallback | None = None) -> RunReport:
    """:func:`run_tasks` without Dask: every task in this process, one after the other."""
    t0 = time.perf_counter()
    col = _Collector(tasks, describe, on_result, on_progress)
    for i, task in enumerate(tasks):
        (outcome,) = call_batch(fn, [task])
        col.take(i, outcome)
    return col.report(t0, 0)


class TasksFailed(LidardError):
    """Some tasks of a :func:`mapper` call raised; ``failures`` holds each with its parameters."""

    def __init__(self, failures: list[TaskFailure], total: int) -> None:
        self.failures = failures
        shown = "; ".join(f.summary() for f in failures[:3]) + ("; ..." if len(failures) > 3 else "")
        super().__init__(f"{len(failures)} of {total} tasks failed: {shown}")


def _star(job: tuple) -> Any:
    fn, args = job
    return fn(*args)


def mapper(client=None, *, on_progress: ProgressCallback | None = None,
           batch_size: int = 1) -> Callable[..., list]:
    """A drop-in for the builtin ``map(fn, *iterables)`` that runs on ``client`` (or in this process
    when None) and returns the results as a list in order: the seam for code written against ``map``
    (the raw-capture reprocessing's ``map_fn``). Every task runs; if any raised, :class:`TasksFailed`
    names each with its arguments afterwards.
    """
    def run(fn: Callable[..., Any], *iterables) -> list:
        jobs = [(fn, args) for args in zip(*iterables)]
        describe = lambda job: job[1]          # noqa: E731 - the task's own arguments
        if client is None:
            rep = run_serial(_star, jobs, describe=describe, on_progress=on_progress)
        else:
            rep = run_tasks(client, _star, jobs, describe=describe, on_progress=on_progress, batch_size=batch_size)
        if rep.failures:
            raise TasksFailed(rep.failures, len(jobs))
        return rep.results
    return run
