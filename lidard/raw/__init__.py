"""Raw digitizer captures (Zarr) and reprocessing them with the scan DSP (issue 16, items 3-4).

:mod:`.capture` writes and reads the captures, :mod:`.points` turns DSP results into point records
(shared with the scan loop), :mod:`.reprocess` replays the DSP per chunk, :mod:`.spectrum` shows one
pixel's spectra with the CFAR threshold.
"""

from .capture import PixelNotRecorded, RawCapture, RawCaptureError, RawChunk, RawWriter, capture_size_bytes, chunk_pixels_for, remove_capture
from .points import frame_points
from .reprocess import (ReplayDsp, Reprocessed, ReprocessSettings, chunk_count, frame_dsp_attrs, replay_dsp,
                        reprocess, reprocess_chunk)

__all__ = ["PixelNotRecorded", "RawCapture", "RawCaptureError", "RawChunk", "RawWriter", "ReplayDsp", "Reprocessed",
           "ReprocessSettings", "capture_size_bytes", "chunk_count", "chunk_pixels_for", "frame_dsp_attrs",
           "frame_points", "remove_capture", "replay_dsp", "reprocess", "reprocess_chunk"]
