"""Run the scan's DSP again on a raw capture, optionally with other settings.

The scan loop turns each batch of digitizer segments into points with :class:`FrameDsp` (range FFT,
OS-CFAR, sub-bin estimator, up/down pairing: dissertation §2.1, §4.4.3; with the monitor MZI, the
phase-noise compensation of §2.3) and :func:`lidard.raw.points.frame_points`. Replaying a capture
builds the same :class:`FrameDsp` from the capture's attributes (:meth:`FrameDsp.from_record`: the
fields the scan's one constructor, :func:`lidard.instrument.dsp_plan.plan_signal`, produced, not a
rebuild from today's configuration) and feeds it the same int16 records, so the original settings
reproduce the original points exactly (the DSP treats every pixel on its own: the result does not
depend on how pixels are batched).

The points are a function of the capture's bytes and the settings only, whatever the process, the
worker count or what ran before: every task runs its DSP on the path the scan took (the capture's
``dsp_path``, :data:`DSP_PATH_ATTR`: ``numpy`` or ``compiled``, lidard.dsp.spectrum.jit.follow), so a
replay with the scan's settings gives the scan's own points bit for bit. The tone fits' two paths agree
only to rounding: a replay on the other path, or one that changed paths part-way, differed from the
scan in float32 last bits (2 of 1,744 velocities of a 10 m/s region replay, docs/measured/27_replay.md).
A capture recorded before the path was (no ``dsp_path``) replays on the path every replay of it takes
(:func:`lidard.dsp.spectrum.jit.decide`: compiled where numba is installed) and its metadata says so;
a compiled capture replayed where this process has no compiled kernels (numba missing,
``LIDARD_DSP_JIT=0``) runs on numpy and its metadata warns that the points may differ in last bits.

The capture is stored in chunks of ~1 MiB (lidard.raw.record); the DSP is run on batches of
consecutive chunks (``TASK_BYTES``): a call's fixed costs are paid per task, not per chunk (1 MiB
tasks were 1.8x slower, 8 MiB ones ~12 % slower in DSP CPU than 24 MiB ones on a recorded 10 m/s
capture, docs/measured/27_replay.md), but never fewer than ``MIN_TASKS`` tasks when the capture has
the chunks for them, so that every worker of a pool gets work. One task is one independent unit:
:func:`reprocess_task` takes a path, a task index and the settings (all picklable) and returns that
task's points, so a thread pool (the default: one thread per core), a process pool or a Dask cluster
maps it over ``range(task_count(path))``; concatenating the results in task order gives the whole
cloud (:func:`reprocess`). :func:`reprocess_chunk` does one storage chunk.
"""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args
from collections.abc import Callable, Iterable

import numpy as np

from ..dsp.ranging.estimators import EstimatorName
from ..dsp.frame import FrameDsp
from ..dsp.spectrum.jit import DspPath, check_path, follow, installed
from ..dsp.spectrum.scratch import release as release_scratch
from ..dsp.spectrum.window import WINDOW_NAMES
from ..outputs.schema import POINT_DTYPE
from .capture import RawCapture, RawCaptureError, RawChunk
from .points import frame_points

ESTIMATORS: tuple[str, ...] = get_args(EstimatorName)
#: raw bytes per reprocessing task. The DSP's CPU per sample falls with the batch up to ~120 pixels of
#: 10 m/s records (~23 MB) and is flat beyond; its working memory grows with it (~2.4x the task's samples
#: at the peak), and a task is read whole by the worker that runs it.
TASK_BYTES = 24 << 20
#: the capture attribute naming the DSP path the scan's points were computed on (lidard.dsp.spectrum.jit.DspPath)
DSP_PATH_ATTR = "dsp_path"
#: tasks a capture is cut into at least (when it has the chunks): two for each of a pool's up to four
#: workers (lidard.dsp_pool.pool_workers), so that a small capture still runs on every core
MIN_TASKS = 8


@dataclass(frozen=True)
class ReprocessSettings:
    """Overrides of the recorded DSP settings; ``None`` keeps what the scan used."""

    estimator: str | None = None
    pfa: float | None = None
    window: str | None = None
    phase_noise: bool | None = None   # True needs a capture that recorded the monitor MZI

    def __post_init__(self) -> None:
        if self.estimator is not None and self.estimator not in ESTIMATORS:
            raise RawCaptureError(f"estimator={self.estimator!r} is not one of {', '.join(ESTIMATORS)}")
        if self.window is not None and self.window not in WINDOW_NAMES:
            raise RawCaptureError(f"window={self.window!r} is not one of {', '.join(WINDOW_NAMES)}")
        if self.pfa is not None and not (isinstance(self.pfa, (int, float)) and 0 < self.pfa < 0.1):
            raise RawCaptureError(f"pfa={self.pfa!r} must lie strictly between 0 and 0.1")
        if self.phase_noise is not None and not isinstance(self.phase_noise, bool):
            raise RawCaptureError(f"phase_noise={self.phase_noise!r} must be true or false")

    def overrides(self) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


def frame_dsp_attrs(dsp: FrameDsp) -> dict[str, Any]:
    """Every field of a :class:`FrameDsp`, JSON-ready: what a capture stores under ``dsp``."""
    return dsp.to_record()


@dataclass(frozen=True)
class ReplayDsp:
    """What processes a capture: the frame DSP, the ADC scale and the phase-noise choice."""

    dsp: FrameDsp
    lsb_v: float
    phase_noise: bool
    mzi_delay_s: float | None
    dsp_path: DspPath = "numpy"          # the path every task takes (:func:`replay_path`)
    dsp_path_recorded: str | None = None   # the capture's (None: recorded before the path was)
    dsp_path_warning: str | None = None    # why the path is not the recorded one, when it is not

    def meta(self) -> dict[str, Any]:
        """The ``dsp`` block of a scan's sidecar, as the scan loop writes it."""
        return self.dsp.sidecar(self.phase_noise, self.dsp_path)

    def path_meta(self) -> dict[str, Any]:
        """What a replay's metadata says of its DSP path: the recorded one and, where the replay's
        differs or none was recorded, why (``dsp_path_warning``)."""
        out: dict[str, Any] = {"dsp_path_recorded": self.dsp_path_recorded}
        if self.dsp_path_warning is not None:
            out["dsp_path_warning"] = self.dsp_path_warning
        return out

    def monitor(self, chunk: RawChunk, channels: list[str], averages: int):
        """(mzi, mzi_q) as the DSP takes them: None without compensation; ``mzi_q`` (the monitor's
        quadrature output, config ``monitor.quadrature``) only when it was recorded."""
        if not self.phase_noise:
            return None, None
        q = chunk.channel("mzi_q", channels, averages) if "mzi_q" in channels else None
        return chunk.channel("mzi", channels, averages), q

    def points(self, chunk: RawChunk, channels: list[str], averages: int) -> np.ndarray:
        # an I/Q capture (adc.iq) holds beat_i and beat_q; its imbalance correction is in the dsp settings
        beat = chunk.channel("beat_i" if self.dsp.iq else "beat", channels, averages)
        mzi, mzi_q = self.monitor(chunk, channels, averages)
        kw = {} if mzi_q is None else {"mzi_q": mzi_q}
        if self.dsp.iq:
            kw["beat_q"] = chunk.channel("beat_q", channels, averages)
        with follow(self.dsp_path):      # the scan's path on every task (module docstring)
            res = self.dsp.process(beat, self.lsb_v, mzi=mzi, mzi_delay_s=self.mzi_delay_s, mzi_lsb_v=self.lsb_v,
                                   **kw)
        return frame_points(res, chunk.pixels, chunk.t_s, chunk.directions, chunk.clipped,
                            self.dsp.measurement_delay_s(averages))


def replay_dsp(attrs: dict[str, Any], settings: ReprocessSettings | None = None) -> ReplayDsp:
    """The DSP a capture was processed with, with ``settings`` applied over it."""
    s = settings or ReprocessSettings()
    try:
        fields_ = dict(attrs["dsp"])
        lsb_v = float(attrs["adc"]["lsb_v"])
        pn = dict(attrs.get("phase_noise") or {})
    except (KeyError, TypeError) as exc:
        raise RawCaptureError(f"raw capture attributes lack {exc} (needed to reprocess)") from None
    over = s.overrides()
    pn_on = bool(over.pop("phase_noise", pn.get("on", False)))
    if pn_on and "mzi" not in attrs.get("channels", []):
        raise RawCaptureError("phase_noise=on: this capture has no monitor 'mzi' channel "
                              f"(recorded: {attrs.get('channels')}); reprocess with phase_noise off")
    try:
        dsp = FrameDsp.from_record(fields_, **over)
    except (TypeError, ValueError) as exc:
        raise RawCaptureError(f"raw capture dsp settings rejected: {exc}") from None
    delay = pn.get("mzi_delay_s")
    if pn_on and delay is None:
        raise RawCaptureError("phase_noise=on: the capture does not record the monitor delay (phase_noise.mzi_delay_s)")
    recorded = attrs.get(DSP_PATH_ATTR)
    path, warning = replay_path(recorded)
    return ReplayDsp(dsp=dsp, lsb_v=lsb_v, phase_noise=pn_on, mzi_delay_s=None if delay is None else float(delay),
                     dsp_path=path, dsp_path_recorded=recorded, dsp_path_warning=warning)


def replay_path(recorded: object) -> tuple[DspPath, str | None]:
    """The DSP path a replay of a capture that recorded ``recorded`` takes here, and a warning when
    it is not the recorded one (or none was recorded): module docstring."""
    if recorded is None:
        path: DspPath = "compiled" if installed() else "numpy"
        return path, ("the capture does not record its DSP path (recorded before lidard did): replayed on "
                      f"{path}, the path every replay of it takes here; its points may differ from the scan's "
                      "own in float32 last bits")
    try:
        want = check_path(recorded)
    except ValueError as exc:
        raise RawCaptureError(f"raw capture attribute {DSP_PATH_ATTR}: {exc}") from None
    if want == "compiled" and not installed():
        return "numpy", ("the scan's points were computed on the compiled DSP path, which this process does "
                         "not have (numba not installed, or LIDARD_DSP_JIT=0): replayed on numpy, the points "
                         "may differ from the scan's in float32 last bits")
    return want, None


def chunk_count(raw_path: str | Path) -> int:
    """Committed (storage) chunks of a capture."""
    return RawCapture(raw_path).n_chunks


def _chunks_per_task(cap: RawCapture) -> int:
    chunk_bytes = cap.chunk_pixels * cap.averages * len(cap.channels) * int(cap.attrs["record_length"]) * 2
    return max(1, min(TASK_BYTES // max(chunk_bytes, 1), cap.n_chunks // MIN_TASKS))


def task_count(raw_path: str | Path) -> int:
    """Tasks of a reprocessing: runs of consecutive committed chunks of about TASK_BYTES (fewer bytes
    when that would leave fewer than MIN_TASKS tasks)."""
    cap = RawCapture(raw_path)
    return -(-cap.n_chunks // _chunks_per_task(cap))


def reprocess_task(raw_path: str | Path, task_index: int, settings: ReprocessSettings | None = None,
                   chunks_per_task: int | None = None) -> np.ndarray:
    """Points (POINT_DTYPE) of one task (its chunks in one DSP call). Picklable arguments;
    ``chunks_per_task``: the tasks' cut as the caller counted them (default: from TASK_BYTES here)."""
    cap = RawCapture(raw_path)
    k = int(chunks_per_task) if chunks_per_task else _chunks_per_task(cap)
    first = int(task_index) * k
    if not 0 <= first < cap.n_chunks:
        raise RawCaptureError(f"raw capture {cap.path}: task {task_index} out of range")
    replay = replay_dsp(cap.attrs, settings)
    stop = min(first + k, cap.n_chunks)
    chunk = cap.chunks(first, stop)
    cap.prefetch(stop, stop + k)        # the next task's samples come off the disk while this one's DSP runs
    return replay.points(chunk, cap.channels, cap.averages)


def local_map(fn, *iterables):
    """``map`` on the process's DSP worker processes (:mod:`lidard.dsp_pool`: one per core
    this process may use, started once and reused; ``fn`` must be importable by name), results in
    order; on one thread per core when there is no pool to be had (one core, or it is busy with a scan)."""
    from ..dsp_pool import dsp_pool
    from ..cores import usable_cores
    args = list(zip(*iterables))
    pool = dsp_pool() if len(args) > 1 else None
    if pool is not None and pool.lease():
        try:
            return pool.map(fn, args)
        finally:
            pool.unlease()
    workers = usable_cores()
    if workers == 1 or len(args) < 2:
        return [fn(*a) for a in args]
    # the pool's threads end with the map, and their scratch buffers (thread-local) with them
    with ThreadPoolExecutor(max_workers=min(workers, len(args)), thread_name_prefix="lidard-replay") as pool:
        return list(pool.map(lambda a: fn(*a), args))


def reprocess_chunk(raw_path: str | Path, chunk_index: int,
                    settings: ReprocessSettings | None = None) -> np.ndarray:
    """Points (POINT_DTYPE) of one chunk. Pure apart from reading the capture; picklable arguments."""
    cap = RawCapture(raw_path)
    return replay_dsp(cap.attrs, settings).points(cap.chunk(int(chunk_index)), cap.channels, cap.averages)


@dataclass
class Reprocessed:
    points: np.ndarray
    meta: dict[str, Any]                 # dsp (as used), settings overrides, chunks, pixels, wall time
    timings: dict[str, float] = field(default_factory=dict)


def reprocess(raw_path: str | Path, settings: ReprocessSettings | None = None, *,
              map_fn: Callable[..., Iterable[np.ndarray]] | None = None) -> Reprocessed:
    """All committed chunks of a capture through the DSP, in scan-sized tasks (``map_fn``: a pool's or
    a cluster's map; default :func:`local_map`, every core; ``map`` runs them on this thread).

    A crashed capture (``complete: false``) reprocesses its committed prefix; ``meta`` says so.
    """
    t0 = time.perf_counter()
    cap = RawCapture(raw_path)
    replay = replay_dsp(cap.attrs, settings)       # validate before any task runs
    k = _chunks_per_task(cap)         # cut here and passed on: a worker process has its own TASK_BYTES
    n = -(-cap.n_chunks // k)
    try:
        parts = list((map_fn or local_map)(reprocess_task, [str(cap.path)] * n, range(n), [settings] * n, [k] * n))
    finally:
        release_scratch()   # the DSP's per-thread buffers (lidard.dsp.spectrum.scratch) of a local map: none held idle
    points = np.concatenate(parts) if parts else np.zeros(0, POINT_DTYPE)
    meta = {"dsp": replay.meta(), "overrides": (settings or ReprocessSettings()).overrides(),
            "chunks": cap.n_chunks, "tasks": n, "pixels": cap.n_pixels, "raw_complete": cap.complete,
            "calibration_id": cap.attrs.get("calibration_id"), **replay.path_meta()}
    return Reprocessed(points=points, meta=meta, timings={"wall_s": time.perf_counter() - t0})
