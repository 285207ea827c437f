"""Per-thread scratch buffers for the DSP's hot path: a batch reuses the memory of the last one.

A large numpy array is a fresh anonymous mapping every time it is created, and its pages fault in on
first touch: about 3 ms per 80 MB on the 2-core benchmark machine, paid again by every batch for every
temporary. The range spectrum of the detection chain and its power are the same shape batch after
batch (and a chunk of windowed ramps chunk after chunk), so they are kept per thread and written over.

Only a value that never leaves the function asking for it may live in a scratch buffer: the next
request for the same ``tag`` on the same thread overwrites it. One buffer per tag per thread (no lock,
no sharing between the daemon's threads); buffers above :data:`MAX_BYTES` are not kept (a one-off huge
batch does not pin its memory).
"""

from __future__ import annotations

import threading

import numpy as np

MAX_BYTES = 192 << 20   # a 12,288-pixel frame's spectra at N = 512 are ~50 MB; beyond this, plain allocation

_LOCAL = threading.local()


def scratch(tag: str, shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """An uninitialised array of ``shape`` and ``dtype``, reused by the next call with this ``tag``."""
    dt = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
    if nbytes > MAX_BYTES:
        return np.empty(shape, dt)
    bufs = getattr(_LOCAL, "bufs", None)
    if bufs is None:
        bufs = _LOCAL.bufs = {}
    buf = bufs.get(tag)
    if buf is None or buf.nbytes < nbytes:
        buf = bufs[tag] = np.empty(max(nbytes, 1), np.uint8)    # page-aligned when large (its own mapping)
    return buf[:nbytes].view(dt).reshape(shape)


def release() -> None:
    """Drop this thread's buffers (after a scan, so an idle daemon does not hold them)."""
    _LOCAL.__dict__.pop("bufs", None)
