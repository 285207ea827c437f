"""Hand batches to DSP worker threads through a bounded queue; take the results back in order.

The acquisition loop (:mod:`.scan_loop`) reads the digitizer, the frame DSP turns the records into
points. Done in series on one thread, a scan uses one core while the other idles (the simulated
bench's synthesis, the transport and the DSP take turns). Here the DSP runs on ``workers`` threads:
numpy's FFTs, ufuncs and random fills release the GIL, so the next read (and, on the simulated bench,
its synthesis) proceeds while a batch is in the DSP.

* Bounded: :meth:`DspPipeline.submit` blocks while ``depth`` batches wait for a worker, so the raw
  samples held are at most ``depth + workers`` batches however far the DSP falls behind
  (back-pressure on the reads, never an unbounded queue).
* In order: results come back in submission order (:meth:`ready`), whichever worker finished first,
  so points are merged in pixel order.
* Errors: a batch whose processing raised gives its exception at its place in the order (the
  results before it first), on the acquisition thread, as a synchronous DSP would have.
* Each worker drops its per-thread DSP scratch buffers (lidard.dsp.spectrum.scratch) when it ends.
"""

from __future__ import annotations

import os
import queue
import threading
from typing import Any
from collections.abc import Callable

from ..dsp.spectrum.scratch import release as release_scratch

_STOP = object()


def dsp_workers() -> int:
    """DSP worker threads for this process: one per core it may run on (its affinity), at most 4
    (beyond that the read loop, not the DSP, sets the pace; each worker holds its own scratch)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


class DspPipeline:
    """``fn(job)`` on ``workers`` threads; at most ``depth`` jobs queued behind the running ones."""

    def __init__(self, fn: Callable[[Any], Any], workers: int, depth: int | None = None,
                 name: str = "lidard-dsp"):
        if workers < 1:
            raise ValueError(f"DspPipeline: workers must be >= 1, got {workers!r}")
        self._fn = fn
        self._q: queue.Queue = queue.Queue(maxsize=max(1, depth if depth is not None else workers))
        self._cond = threading.Condition()
        self._results: dict[int, tuple[bool, Any]] = {}
        self._submitted = 0
        self._out = 0
        self._error: BaseException | None = None     # raised at the next ready() after its results
        self._threads = [threading.Thread(target=self._work, name=f"{name}-{i}", daemon=True)
                         for i in range(workers)]
        for t in self._threads:
            t.start()

    @property
    def in_flight(self) -> int:
        """Jobs submitted whose results have not been taken yet."""
        return self._submitted - self._out

    def _work(self) -> None:
        try:
            while True:
                item = self._q.get()
                if item is _STOP:
                    return
                seq, job = item
                try:
                    res = (True, self._fn(job))
                except BaseException as exc:      # handed to the acquisition thread, in order
                    res = (False, exc)
                del job, item                     # the raw samples go as soon as they are processed
                with self._cond:
                    self._results[seq] = res
                    self._cond.notify_all()
        finally:
            release_scratch()

    def submit(self, job: Any) -> None:
        """Queue ``job``; blocks while ``depth`` jobs are waiting (back-pressure)."""
        if not self._threads:
            raise RuntimeError("DspPipeline: submit after close")
        self._q.put((self._submitted, job))
        self._submitted += 1

    def ready(self, wait: bool = False) -> list[Any]:
        """The results finished in order since the last call (``wait``: every submitted one).
        A job that raised: the results before it are returned, its exception is raised next call."""
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc
        out: list[Any] = []
        with self._cond:
            while self._out < self._submitted:
                if self._out not in self._results:
                    if not wait:
                        break
                    self._cond.wait()
                    continue
                ok, value = self._results.pop(self._out)
                self._out += 1
                if not ok:
                    if out:
                        self._error = value
                        return out
                    raise value
                out.append(value)
        return out

    def close(self) -> None:
        """Stop the workers once the queued jobs are done (their results stay to be taken)."""
        threads, self._threads = self._threads, []
        for _ in threads:
            self._q.put(_STOP)
        for t in threads:
            t.join()
