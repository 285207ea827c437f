"""Hand batches to DSP workers through a bounded queue; take the results back in order.

The acquisition loop (:mod:`.scan_loop`) reads the digitizer, the frame DSP turns the records into
points. Done in series on one thread, a scan uses one core while the other idles (the simulated
bench's synthesis, the transport and the DSP take turns). Two ways to run the DSP beside the reads:

* :class:`ProcessDspPipeline`: on the process's DSP worker processes (:mod:`lidard.dsp_pool`), what a
  scan of several batches uses on two cores or more. The DSP's Python parts hold the GIL for about a
  quarter of its CPU; in worker threads they contend with the read loop, the transport and the
  bench's synthesis (a scan on two cores cost ~35 % more CPU than on one), in a process they do not.
* :class:`DspPipeline`: on ``workers`` threads (numpy's FFTs and ufuncs release the GIL), what a
  process limited to one core uses (a worker process there would only add its start-up), or a second
  user while the pool is leased.

Both have the same contract:

* Bounded: :meth:`DspPipeline.submit` blocks while ``depth`` batches wait for a worker, so the raw
  samples held are at most ``depth + workers`` batches however far the DSP falls behind
  (back-pressure on the reads, never an unbounded queue).
* In order: results come back in submission order (:meth:`ready`), whichever worker finished first,
  so points are merged in pixel order.
* Errors: a batch whose processing raised gives its exception at its place in the order (the
  results before it first), on the acquisition thread, as a synchronous DSP would have.
* Each worker drops its DSP scratch buffers (lidard.dsp.spectrum.scratch) when the scan's pipeline closes.
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Any
from collections.abc import Callable

import numpy as np

from ..dsp.spectrum.scratch import release as release_scratch
from ..dsp_pool import DspPool, DspWorkerLost, Slot, dsp_pool, message_id

log = logging.getLogger(__name__)

_STOP = object()


class _InOrder:
    """The hand-out both pipelines share: results in submission order, an error at its place (the
    results before it are handed out first, the error is raised at the next call).

    Once raised, an error is the caller's alone: nothing here refers to it any more. Its traceback
    holds every frame it passed through (the failed DSP's, the acquisition's) with their arrays; a
    local left bound to it in a frame of that traceback would be a cycle that keeps them all until
    the cyclic collector's next full collection, so the raising frames unbind it as it leaves."""

    _results: dict[int, tuple[bool, Any]]
    _out: int
    _error: BaseException | None

    def _raise_kept(self) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            try:
                raise exc
            finally:
                del exc

    def _hand_out(self, out: list[Any], finish: Callable[[Any], Any]) -> bool:
        """Move the next result, through ``finish``, into ``out``; False when an error stops the
        hand-out (kept for the next call when ``out`` holds results, raised now when it does not)."""
        ok, value = self._results.pop(self._out)
        self._out += 1
        if ok:
            out.append(finish(value))
            return True
        if out:
            self._error = value
            return False
        try:
            raise value
        finally:
            del value


def _same(value: Any) -> Any:
    return value


class DspPipeline(_InOrder):
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
                    del res                       # the result (or error) is the taker's from here
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
        self._raise_kept()
        out: list[Any] = []
        with self._cond:
            while self._out < self._submitted:
                if self._out not in self._results:
                    if not wait:
                        break
                    self._cond.wait()
                    continue
                if not self._hand_out(out, _same):
                    break
        return out

    def close(self) -> None:
        """Stop the workers once the queued jobs are done (their results stay to be taken)."""
        threads, self._threads = self._threads, []
        for _ in threads:
            self._q.put(_STOP)
        for t in threads:
            t.join()


class ProcessDspPipeline(_InOrder):
    """The same contract as :class:`DspPipeline` (bounded, in order, errors in place) on the process's
    DSP pool (:mod:`lidard.dsp_pool`): a batch's samples go to a worker through a shared-memory slot, its
    frame result comes back and ``finish(result, meta)`` turns it into the caller's value here.

    At most ``2 x workers`` batches are in the workers (one running and one waiting each) and each
    holds a slot, so the raw samples held stay bounded however far the DSP falls behind; the slots
    are freed when the pipeline closes. The pool is leased for the pipeline's life (a second user at
    the same time, e.g. a replay during a scan, gets None from :meth:`open` and uses threads)."""

    def __init__(self, pool: DspPool, dsp, *, lsb_v: float, mzi_delay_s: float,
                 finish: Callable[[Any, Any], Any]):
        self._pool, self._finish = pool, finish
        self._record = dsp.to_record()
        self.dsp_path: str | None = None   # the scan's DSP path, sent with its DSP (set before the first batch)
        self._token = object()
        self._lsb_v, self._mzi_delay_s = lsb_v, mzi_delay_s
        self._free: list[Slot] = []
        self._busy: dict[int, tuple[int, Slot, Any]] = {}      # message id -> (seq, its slot, its meta)
        self._results: dict[int, tuple[bool, Any]] = {}
        self._submitted = 0
        self._out = 0
        self._error: BaseException | None = None
        self._closed = False
        self._capacity = 2 * len(pool.workers)

    @classmethod
    def open(cls, dsp, **kw) -> ProcessDspPipeline | None:
        pool = dsp_pool()
        if pool is None or not pool.lease():
            return None
        return cls(pool, dsp, **kw)

    @property
    def in_flight(self) -> int:
        return self._submitted - self._out

    def _take(self, timeout: float | None) -> None:
        for mid, ok, value in self._pool.receive(timeout):
            entry = self._busy.pop(mid, None)
            if entry is None:        # the answer to a message whose sending was interrupted: not ours
                continue
            seq, slot, meta = entry
            self._free.append(slot)
            self._results[seq] = (ok, (value, meta) if ok else value)

    def submit(self, fields: dict[str, list[np.ndarray]], meta: Any) -> None:
        """Join ``fields`` (the batch's sample arrays, in parts) into a free slot and hand it to the
        least busy worker; blocks while every slot is in a worker (back-pressure)."""
        if self._closed:
            raise RuntimeError("ProcessDspPipeline: submit after close")
        self._take(0)
        while len(self._busy) >= self._capacity:
            self._take(None)
        need = Slot.size_of(fields)
        slot = next((s for s in self._free if s.nbytes >= need), None)
        if slot is None:
            if len(self._free) + len(self._busy) >= self._capacity and self._free:
                self._free.pop(0).free()        # too small for this batch: replaced, not added
            slot = Slot(need)
        else:
            self._free.remove(slot)
        layout = slot.write(fields)
        mid = message_id()
        w = min(self._pool.workers, key=lambda w: len(w.outstanding))
        try:
            if w.scan_token is not self._token:
                self._pool.send(w, ("dsp", self._record, self.dsp_path))
                w.scan_token = self._token
            self._pool.send(w, ("batch", mid, slot.name, layout, self._lsb_v, self._mzi_delay_s))
        except BaseException:
            # not sent, or half sent (a Ctrl-C inside the write): the slot is never reused, and the
            # pool, whose pipe may now be out of step, is replaced before its next user
            slot.free()
            self._pool.broken = True
            raise
        w.outstanding.add(mid)
        self._busy[mid] = (self._submitted, slot, meta)
        self._submitted += 1

    def ready(self, wait: bool = False) -> list[Any]:
        """As :meth:`DspPipeline.ready`: the finished results in order, an error at its place."""
        self._raise_kept()
        if not self._closed:      # once closed every answer is in (and the pool may be another's)
            self._take(0)
        out: list[Any] = []
        while self._out < self._submitted:
            if self._out not in self._results:
                if not wait or self._closed:
                    break
                self._take(None)
                continue
            if not self._hand_out(out, lambda v: self._finish(*v)):
                break
        return out

    def close(self) -> None:
        """No more batches; once none is in a worker, the slots are freed, the workers drop the scan's
        scratch buffers and the pool is free for the next user (the results stay to be taken)."""
        if self._closed:
            return
        self._closed = True
        try:
            while self._busy and not self._pool.broken:
                self._take(None)
            for seq, slot, _ in self._busy.values():    # a broken pool: what it held is lost
                self._results[seq] = (False, DspWorkerLost("the DSP worker pool broke while it held this batch"))
                self._free.append(slot)
            self._busy.clear()
            for w in self._pool.workers if not self._pool.broken else ():
                if w.scan_token is self._token:
                    self._pool.send(w, ("release",))
                    w.scan_token = None
        except DspWorkerLost as exc:
            log.warning("%s", exc)
        finally:
            for s in self._free:
                s.free()
            self._free = []
            self._pool.unlease()
