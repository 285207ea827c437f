"""The frame DSP on worker processes: one pool per process, started once and reused by every scan.

Why processes and not threads (measured on the 2-core benchmark machine, docs/measured/27_cores.md):
the DSP's Python parts (refinement, model-order tests) hold the GIL for about a quarter of its CPU, and
the acquiring process runs the read loop, the transport, the safety polls and (on the simulated bench)
the synthesis in Python too. DSP threads in that process fight them for the GIL, and a scan on two
cores cost ~35 % more CPU than on one. A worker process has a GIL of its own.

* One pool per process (:func:`dsp_pool`), started on the first scan that wants it (or at daemon
  start, :func:`warm`), its workers reused scan after scan: a scan starts no thread and no process.
  The workers come from a ``forkserver`` that has imported the frame DSP once (no fork of a process
  with running threads), ignore Ctrl-C (the acquiring process decides what a Ctrl-C stops), and end
  with the process (:func:`shutdown`, at exit).
* The raw samples of a batch go through shared memory (:class:`Slot`: written once, where the
  batch's reads are joined; the worker maps it); a scan's :class:`lidard.dsp.frame.FrameDsp` goes to
  each worker once (its :meth:`~lidard.dsp.frame.FrameDsp.to_record`), a batch's message is its slot's
  name and layout. A result (per pixel and return slot) comes back pickled: small.
* At the end of a scan each worker drops its DSP scratch buffers (lidard.dsp.spectrum.scratch): an idle daemon
  holds none.
* The workers run ``WORKER_NICE`` below the process that started them: a scan's pace is set by the
  serial chain of its acquiring thread (read -> transport -> safety check -> next read; on an
  embedded bench, the bench's synthesis threads in it too), while the DSP has slack (batches queued,
  back-pressure when it falls behind). On two busy cores the scheduler then gives the chain its core
  first and the DSP the rest; a region scan's wall time fell 7 % (5 of 5 alternated pairs at load 22,
  docs/measured/27_acquisition.md). With the kernel's autogroups it ranks them only within the
  daemon's own session.
* A worker that dies (killed, out of memory) fails the batches it held with :class:`DspWorkerLost`;
  the pool is started afresh for the next user.
* As with any multiprocessing start other than fork, a worker imports the parent's main script (not a
  ``-m`` module): a script that scans must keep its work under ``if __name__ == "__main__"`` (lidarctl,
  ``python -m lidard`` and the benchmarks do).

:class:`lidard.instrument.pipeline.ProcessDspPipeline` is the per-scan side (order, back-pressure,
slots); :func:`lidard.raw.replay.local_map` maps a replay's tasks on the same workers. A module of
its own (not of lidard.instrument): the scan's pipeline and the replay both use it.
"""

from __future__ import annotations

import atexit
import itertools
import logging
import os
import signal
import threading
import time
from multiprocessing import connection, get_context, shared_memory
from typing import Any
from collections.abc import Callable

import numpy as np

from .cores import pool_workers

log = logging.getLogger(__name__)

#: modules the forkserver imports once, so that a worker starts with the frame DSP loaded and warm
#: (:mod:`lidard.dsp_pool_preload`: the compiled kernels loaded, numba's ~0.9 s paid once by the server, not by
#: every worker of every pool)
PRELOAD = ["numpy", "lidard.dsp.frame", "lidard.dsp_pool", "lidard.dsp_pool_preload"]


class DspWorkerLost(RuntimeError):
    """A DSP worker process ended while it held batches (their points are lost)."""


# ---------------------------------------------------------------------------------------- worker side

#: how much lower than the acquiring process the workers run (nice increment; see the docstring)
WORKER_NICE = 10


def _batch_arrays(shm: shared_memory.SharedMemory, layout: list[tuple[str, str, tuple[int, ...], int]]
                  ) -> dict[str, np.ndarray]:
    return {name: np.ndarray(shape, np.dtype(dt), buffer=shm.buf, offset=off) for name, dt, shape, off in layout}


def _run_batch(dsp, msg: tuple) -> Any:
    _, _seq, slot, layout, lsb_v, mzi_delay_s = msg
    shm = shared_memory.SharedMemory(name=slot)
    try:
        a = _batch_arrays(shm, layout)
        res = dsp.process(a["beat"], lsb_v, mzi=a.get("mzi"), mzi_delay_s=mzi_delay_s, mzi_lsb_v=lsb_v,
                          mzi_q=a.get("mzi_q"), beat_q=a.get("beat_q"))
        del a           # the views go before the mapping
        return res
    finally:
        shm.close()


def _serve(conn: connection.Connection) -> None:
    """A worker's loop: ("dsp", record, path) sets the scan's DSP and the DSP path its batches take
    (lidard.dsp.spectrum.jit.follow: the scan's, whatever this worker has loaded), ("batch", seq, slot,
    layout, lsb_v, mzi_delay_s) answers (seq, ok, FrameResult or exception), ("call", seq, fn, args) answers fn(*args),
    ("release",) drops the DSP's scratch buffers, ("stop",) or a closed pipe ends it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # Ctrl-C is the acquiring process's to handle
    os.nice(WORKER_NICE)                              # the acquiring chain first (module docstring)
    from .dsp.frame import FrameDsp
    from .dsp.spectrum.jit import follow
    from .dsp.spectrum.scratch import release as release_scratch
    dsp = None
    path = None                    # the scan's DSP path (None: the process's own rule)
    built: dict[str, Any] = {}     # FrameDsp by its record: the next scan with the same DSP finds its tables
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        kind = msg[0]
        if kind == "stop":
            return
        if kind == "dsp":
            key = repr(sorted(msg[1].items()))
            dsp = built.get(key)
            if dsp is None:
                if len(built) >= 4:
                    built.pop(next(iter(built)))
                dsp = built[key] = FrameDsp.from_record(msg[1])
            path = msg[2]
            continue
        if kind == "release":
            dsp = None
            release_scratch()
            continue
        seq = msg[1]
        try:
            if kind == "batch":
                with follow(path):
                    out = (seq, True, _run_batch(dsp, msg))
            else:
                out = (seq, True, msg[2](*msg[3]))
        except Exception as exc:     # handed back in order; an unpicklable one as its text
            out = (seq, False, exc)
        try:
            conn.send(out)
        except Exception as exc:     # the exception itself did not pickle
            conn.send((seq, False, RuntimeError(f"{type(out[2]).__name__}: {out[2]} ({exc})")))


# ---------------------------------------------------------------------------------------- parent side

class Slot:
    """A shared-memory block a batch's samples are joined into (the parent writes, a worker maps)."""

    def __init__(self, nbytes: int):
        self.shm = shared_memory.SharedMemory(create=True, size=max(1, nbytes))
        self.nbytes = self.shm.size

    @property
    def name(self) -> str:
        return self.shm.name

    def write(self, fields: dict[str, list[np.ndarray]]) -> list[tuple[str, str, tuple[int, ...], int]]:
        """Join each field's parts into the block; answers the layout a worker maps them with."""
        layout, off = [], 0
        for name, parts in fields.items():
            shape = (sum(len(p) for p in parts), *parts[0].shape[1:])
            dt = parts[0].dtype
            view = np.ndarray(shape, dt, buffer=self.shm.buf, offset=off)
            np.concatenate(parts, out=view)
            del view
            layout.append((name, dt.str, shape, off))
            off += -(-int(np.prod(shape)) * dt.itemsize // 64) * 64
        return layout

    @staticmethod
    def size_of(fields: dict[str, list[np.ndarray]]) -> int:
        return sum(-(-sum(p.nbytes for p in parts) // 64) * 64 for parts in fields.values())

    def free(self) -> None:
        try:
            self.shm.close()
            self.shm.unlink()
        except (FileNotFoundError, BufferError):   # already gone / a view still alive (gc frees it)
            pass


class Worker:
    """One DSP process and the parent's end of its pipe."""

    def __init__(self, ctx: Any):
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_serve, args=(child,), name="lidard-dsp-worker", daemon=True)
        self.proc.start()
        child.close()
        self.scan_token: object = None     # whose FrameDsp it holds
        self.outstanding: set[int] = set()


class DspPool:
    """``workers`` DSP processes; leased by one user at a time (:meth:`lease` / :meth:`unlease`)."""

    def __init__(self, workers: int):
        ctx = get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        self.workers: list[Worker] = []
        try:
            for _ in range(workers):
                self.workers.append(Worker(ctx))
        except BaseException:
            self.close()          # the ones that did start
            raise
        self._lease = threading.Lock()
        self.broken = False

    def lease(self) -> bool:
        return self._lease.acquire(blocking=False)

    def unlease(self) -> None:
        self._lease.release()

    @property
    def pids(self) -> list[int]:
        return [w.proc.pid or 0 for w in self.workers]

    def alive(self) -> bool:
        return not self.broken and all(w.proc.is_alive() for w in self.workers)

    def send(self, w: Worker, msg: tuple) -> None:
        try:
            w.conn.send(msg)
        except (OSError, EOFError, BrokenPipeError) as exc:
            self.broken = True
            raise DspWorkerLost(f"DSP worker {w.proc.pid} is gone ({exc})") from exc

    def receive(self, timeout: float | None) -> list[tuple]:
        """Answers that arrived (waiting up to ``timeout`` s for one from a worker with work)."""
        busy = [w.conn for w in self.workers if w.outstanding]
        if not busy:
            return []
        out = []
        for c in connection.wait(busy, timeout):
            w = next(w for w in self.workers if w.conn is c)
            try:
                while True:
                    mid, ok, value = w.conn.recv()
                    w.outstanding.discard(mid)
                    out.append((mid, ok, value))
                    if not w.conn.poll():
                        break
            except (EOFError, OSError):
                self.broken = True
                lost = DspWorkerLost(f"DSP worker {w.proc.pid} ended (exit code {w.proc.exitcode}) "
                                     "holding batches")
                out.extend((mid, False, lost) for mid in sorted(w.outstanding))
                w.outstanding.clear()
            except BaseException:      # a Ctrl-C inside a read: the pipe may be out of step
                self.broken = True
                raise
        return out

    def map(self, fn: Callable[..., Any], args: list[tuple]) -> list[Any]:
        """``fn(*a)`` for every ``a`` on the workers, results in order (the first error raised after
        every call has ended); ``fn`` must be importable by name (picklable)."""
        results: dict[int, tuple[bool, Any]] = {}
        todo = list(enumerate(args))
        order: dict[int, int] = {}        # message id -> index of the call
        while todo or any(w.outstanding for w in self.workers):
            for w in self.workers:
                if todo and len(w.outstanding) < 2:
                    i, a = todo.pop(0)
                    mid = message_id()
                    try:
                        self.send(w, ("call", mid, fn, tuple(a)))
                    except BaseException:
                        self.broken = True
                        raise
                    w.outstanding.add(mid)
                    order[mid] = i
            for mid, ok, value in self.receive(None):
                if mid in order:
                    results[order.pop(mid)] = (ok, value)
        for w in self.workers:          # their scratch buffers go: an idle daemon holds none
            self.send(w, ("release",))
            w.scan_token = None
        for ok, value in (results[i] for i in range(len(args))):
            if not ok:
                raise value
        return [results[i][1] for i in range(len(args))]

    def close(self) -> None:
        for w in self.workers:
            try:
                w.conn.send(("stop",))
            except (OSError, EOFError):
                pass
        for w in self.workers:
            w.proc.join(5.0)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(1.0)
            w.conn.close()


_IDS = itertools.count()


def message_id() -> int:
    """A number no other message of this process's pools carries (an answer names its message)."""
    return next(_IDS)


_POOL: DspPool | None = None
_POOL_PID = 0
_LOCK = threading.Lock()


def dsp_pool() -> DspPool | None:
    """The process's DSP pool (started on first call; again after a worker died), or None when this
    process may run on one core only (a worker process would only add its start-up) or processes
    cannot be started here (then the caller falls back to threads; logged)."""
    global _POOL, _POOL_PID
    n = pool_workers()
    if n < 2:
        return None
    with _LOCK:
        if _POOL is not None and _POOL_PID == os.getpid() and _POOL.alive():
            return _POOL
        if _POOL is not None and _POOL_PID == os.getpid():
            _POOL.close()             # a worker died: a fresh pool for the next user
        _POOL = None
        try:
            _POOL, _POOL_PID = DspPool(n), os.getpid()
        except Exception as exc:      # no processes here (no /dev/shm, a sandbox, ...): threads do the work
            log.warning("DSP worker processes unavailable (%s: %s): the DSP runs on threads",
                        type(exc).__name__, exc)
            return None
        return _POOL


def warm() -> None:
    """Start the pool now (a daemon at start-up), so that its first scan does not wait for it."""
    dsp_pool()


def warm_in_background() -> None:
    """:func:`warm` on a thread of its own: the workers start (in their own processes: the forkserver
    imports and warms the DSP there, ~1 s) while the caller goes on; a scan that needs the pool before it
    is up waits for it (:func:`dsp_pool` holds the pool's lock while it starts)."""
    threading.Thread(target=warm, name="lidard-dsp-pool-warm", daemon=True).start()


def shutdown() -> None:
    """Stop the pool's workers (at exit; safe to call again)."""
    global _POOL
    with _LOCK:
        if _POOL is not None and _POOL_PID == os.getpid():
            _POOL.close()
        _POOL = None


def cpu_time() -> float:
    """This process's CPU time plus its DSP worker processes' (seconds, user + system): what a scan
    costs when its DSP runs on the pool (``time.process_time`` alone misses the workers). Take
    differences within one pool's life: a pool started afresh (after a worker died) counts from zero.
    The workers' share has the kernel's clock-tick resolution (10 ms a worker)."""
    total = time.process_time()
    pool = _POOL
    if pool is None or _POOL_PID != os.getpid():
        return total
    tick = os.sysconf("SC_CLK_TCK")
    for pid in pool.pids:
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:            # a worker gone (or no /proc): its CPU is not counted
            continue
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


atexit.register(shutdown)
