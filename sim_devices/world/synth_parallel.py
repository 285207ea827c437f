"""One digitizer read's beat synthesis on several threads (the bench's side of a scan using every core).

A read of ``n`` segments is cut into parts of consecutive segments, each synthesized by
:func:`sim_devices.world.synth.synthesize` on a thread of a small pool, and the parts' records joined
in order. numpy's trig, arithmetic and random fills release the GIL, so the parts run side by side
(and beside the host's DSP threads on an embedded bench).

The white noise does not depend on the cut: record s of the read is record ``noise.first + s`` of
the stream (:mod:`sim_devices.world.gauss`, a function of the record's index), so a read gives the
same records in one part or in four. The phase noise (when the bench synthesizes it) is drawn from
``rng_for(first)``, the generator the bench seeds for a read starting at that segment, so a part is
exactly the records a read of those segments alone would give. So the cut must be a function of
the read alone, not of the machine: a read of ``n`` segments of ``m`` samples is cut into the largest
power of two of parts, at most ``MAX_PARTS``, that leaves each at least ``MIN_PART_SAMPLES``
(:func:`read_parts`), whatever the cores; the parts then run on as many threads as the process has
cores for (one core: one after another on the calling thread, the same records). The same seed gives
the same bytes on a laptop, a 2-core CI runner and a 16-core workstation. A read smaller than two parts
stays whole, on the calling thread.
"""

from __future__ import annotations

import threading
from typing import Any
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Callable

import numpy as np

from lidard.cores import pool_workers
from sim_devices.world.gauss import NoiseStream
from sim_devices.world.synth import synthesize
from sim_devices.world.synth_types import HitBatch, Synthesized

#: samples per part at least: below ~64 k samples (128 kB of int16) a part's fixed cost (tables,
#: chunk set-up, the pool's hand-off) is a noticeable share of its work
MIN_PART_SAMPLES = 1 << 16

#: parts of one read at most: the most threads a pool gets (lidard.cores.MAX_POOL_WORKERS), a power of two
#: so that 1, 2 and 4 threads share the parts evenly
MAX_PARTS = 4

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def synth_threads() -> int:
    """Threads for one read: the cores this process may use, at most 4 (:func:`lidard.cores.pool_workers`)."""
    return pool_workers()


def _pool(workers: int) -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL._max_workers < workers:      # grown once; threads idle between reads
            _POOL = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="sim-synth")
        return _POOL


def read_parts(n_seg: int, n_samples: int) -> int:
    """The parts a read of ``n_seg`` segments of ``n_samples`` is cut into: the largest power of two, at
    most MAX_PARTS and ``n_seg``, with at least MIN_PART_SAMPLES samples in each (1: the read stays whole).
    A function of the read only: the phase noise a part draws depends on where the read is cut."""
    fit = min(MAX_PARTS, int(n_seg), int(n_seg) * int(n_samples) // MIN_PART_SAMPLES)
    return 1 << (fit.bit_length() - 1) if fit >= 1 else 1


def _part_hits(hits: HitBatch | None, a: int, b: int) -> HitBatch | None:
    if hits is None:
        return None
    seg = np.asarray(hits.seg)
    sel = (seg >= a) & (seg < b)
    if not sel.any():
        return None
    def pick(v: Any) -> Any:
        return None if v is None else np.asarray(v)[sel] if np.ndim(v) else v

    return HitBatch(seg=seg[sel] - a, tau_s=np.asarray(hits.tau_s)[sel], amplitude_v=pick(hits.amplitude_v),
                    doppler_hz=pick(hits.doppler_hz), phase_rad=pick(hits.phase_rad))


def _joined(parts: list[Synthesized]) -> Synthesized:
    first = parts[0]
    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])

    def cat_opt(name: str) -> np.ndarray | None:
        return None if getattr(first, name) is None else cat(name)

    # every part was synthesized with the same settings: all hold volts, or none
    volts = None if first.volts is None else {c: np.concatenate([(p.volts or {})[c] for p in parts])
                                              for c in first.volts}
    return Synthesized(beat=cat("beat"), beat_q=cat_opt("beat_q"), mzi=cat_opt("mzi"), overrange=cat("overrange"),
                       channels=first.channels, lsb_v=first.lsb_v, volts=volts,
                       phase_noise_rad=cat_opt("phase_noise_rad"), phase_noise_pre=first.phase_noise_pre,
                       mzi_q=cat_opt("mzi_q"))


def synthesize_read(traj, adc, t_start_s, hits: HitBatch | None, rng_for: Callable[[int], np.random.Generator],
                    *, workers: int | None = None, noise: NoiseStream | None = None, **kw) -> Synthesized:
    """:func:`synthesize` of a read, cut into :func:`read_parts` parts run on up to ``workers`` threads
    (default :func:`synth_threads`); ``rng_for(s)``: the generator of a read starting at segment ``s`` of
    this one; ``noise``: the white noise's stream from the read's first segment (None: each part keys its
    own from its generator). The records do not depend on ``workers``."""
    t0 = np.asarray(t_start_s, dtype=np.float64)
    n_seg = t0.size
    workers = synth_threads() if workers is None else int(workers)
    parts = read_parts(n_seg, int(adc.n_samples))
    if parts == 1:
        return synthesize(traj, adc, t0, hits, rng=rng_for(0), noise=noise, **kw)
    bounds = np.linspace(0, n_seg, parts + 1).astype(int)
    jobs = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    def part(a: int, b: int) -> Synthesized:
        return synthesize(traj, adc, t0[a:b], _part_hits(hits, a, b), rng=rng_for(a),
                          noise=None if noise is None else noise.shifted(a), **kw)

    if workers <= 1:
        return _joined([part(a, b) for a, b in jobs])
    pool = _pool(min(workers, parts))
    futs = [pool.submit(part, a, b) for a, b in jobs]
    return _joined([f.result() for f in futs])
