"""Raw digitizer captures (Zarr) and reprocessing them with the scan DSP.

:mod:`.capture` writes and reads the captures, :mod:`.points` turns DSP results into point records
(shared with the scan loop), :mod:`.record` is the scan loop's side of a capture, :mod:`.replay`
replays the DSP per chunk, :mod:`.spectrum` shows one pixel's spectra with the CFAR threshold,
a stored scan is reprocessed into a new linked one by :mod:`lidard.jobs.reprocess`.

Names are imported on first use (PEP 562), so that the job queue can reach :mod:`.capture` without
loading the DSP (the API and the queue import no numerical core; tests/lidard/test_instrument_rooms.py).
"""

from __future__ import annotations

from .._lazy import lazy_getattr


_LAZY = {
    "PixelNotRecorded": "capture", "RawCapture": "capture", "RawCaptureError": "capture", "RawChunk": "capture",
    "RawWriter": "capture", "capture_size_bytes": "capture", "chunk_pixels_for": "capture",
    "remove_capture": "capture", "frame_points": "points", "ReplayDsp": "replay", "Reprocessed": "replay",
    "ReprocessSettings": "replay", "chunk_count": "replay", "frame_dsp_attrs": "replay",
    "replay_dsp": "replay", "reprocess": "replay", "reprocess_chunk": "replay",
    "reprocess_task": "replay", "task_count": "replay", "local_map": "replay",
}

__all__ = sorted(_LAZY)  # noqa: PLE0605 - the lazily loaded names, listed once in _LAZY


__getattr__ = lazy_getattr(__name__, _LAZY, globals())
