"""Raw digitizer captures in Zarr: write them during a scan, read them back for reprocessing.

A scan with ``record_raw`` keeps every digitizer segment exactly as read (int16 codes, every
channel the acquisition had: the LiDAR ``beat`` and, with phase-noise compensation, the monitor
``mzi``; dissertation §4.4.1 for the acquisition, §2.3 for the monitor) next to its point cloud,
so that the DSP can be run again later with other settings and without the hardware.

Layout of ``raw.zarr`` (a Zarr v3 group on a local directory):

* ``segments``        int16 (n_segments, n_channels, record_length), segment = pixel * averages + k,
  channels in the digitizer's order (attribute ``channels``): the bytes as read, nothing scaled;
* ``trigger_time_ns`` int64 (n_segments,): the digitizer's hardware trigger time stamps;
* ``overrange``       uint8 (n_segments,): the digitizer's clip flag per segment;
* ``t_s``             float64 (n_pixels,): the pixel times the scan gave its points;
* ``pixels``          int64 (n_pixels, 2) and ``directions`` float64 (n_pixels, 3): the pixel order
  of the plan and each beam's unit direction (so reprocessing needs neither the config nor the
  optics model), written whole when the capture is created;
* group attributes: everything needed to reprocess (chirp, ADC plan, DSP settings, calibration id,
  monitor delay, software versions) and the commit state.

Chunks: one chunk holds the whole records of ``chunk_pixels`` consecutive pixels along the first
axis of every per-segment/per-pixel array, so chunk ``i`` of every array belongs to the same pixels
and can be reprocessed on its own (a replay task reads several consecutive ones).

Crash safety: the store's files are written to a temporary name and renamed into place (zarr's
``LocalStore`` does this for every key since zarr 3.1), so a chunk file is either absent or whole.
The group attribute ``chunks_complete`` is raised only after all arrays' chunk ``i`` are written,
and ``complete`` stays false until :meth:`RawWriter.close`: a process killed mid-scan leaves a
readable prefix of ``chunks_complete`` chunks, marked partial.
"""

from __future__ import annotations

import importlib.metadata
import platform
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import BloscCodec

from ..errors import LidardError
from .chunkfiles import ChunkFiles

FORMAT = "lidard-raw/1"
RAW_NAME = "raw.zarr"        # a scan's capture: <data dir>/scans/<id>/raw.zarr
# Fast enough to keep up with the digitizer on one core; noise-like int16 gains little from more.
# Bit-shuffled: a recorded 10 m/s capture's samples to 44 % of their bytes (byte-shuffled: 67 %), in
# less CPU both ways (docs/measured/27_replay.md). The codec is each array's own metadata: captures
# written byte-shuffled read as before.
_COMPRESSOR = BloscCodec(cname="lz4", clevel=1, shuffle="bitshuffle")


class RawCaptureError(LidardError):
    """A raw capture is missing, malformed, or asked for something it does not hold; names it."""

    http_status = 422


class PixelNotRecorded(RawCaptureError):
    """The capture holds no committed record of the pixel asked for."""

    http_status = 404


def _software() -> dict[str, str]:
    def version(pkg: str) -> str:
        try:
            return importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            return "unknown"
    return {"lidard": version("lidard"), "numpy": np.__version__, "scipy": version("scipy"),
            "zarr": zarr.__version__, "python": platform.python_version()}


def chunk_pixels_for(bytes_per_pixel: int, target_bytes: int = 8 << 20) -> int:
    """Pixels per chunk for about ``target_bytes`` of raw samples (at least one pixel)."""
    if bytes_per_pixel <= 0:
        raise RawCaptureError(f"bytes_per_pixel={bytes_per_pixel!r} must be positive")
    return max(1, int(target_bytes) // int(bytes_per_pixel))


class RawWriter:
    """Appends batches of segments as they are read; writes whole chunks, commits each one.

    Create with :meth:`create`; call :meth:`append` with every batch in scan order (any batch size:
    segments wait in memory until a chunk is full), then :meth:`close`. Without ``close`` (a crash)
    the capture stays readable up to its last committed chunk and says ``complete: false``.
    """

    def __init__(self, group: zarr.Group, path: Path, chunk_pixels: int, averages: int):
        self._g = group
        self.path = path
        self.chunk_pixels = chunk_pixels
        self.averages = averages
        self.n_pixels = int(_arr(group, "t_s").shape[0])
        self.pixels_written = 0
        self.chunks_complete = 0
        self._pending: list[tuple[np.ndarray, ...]] = []
        self._pending_pix = 0
        self._closed = False

    @classmethod
    def create(cls, path: str | Path, *, pixels: np.ndarray, directions: np.ndarray, averages: int,
               channels: tuple[str, ...] | list[str], record_length: int, chunk_pixels: int,
               attrs: dict[str, Any], drive_v: np.ndarray | None = None) -> RawWriter:
        """A new capture for the planned ``pixels`` (in scan order); refuses an existing path.

        ``attrs`` must hold ``adc`` (with ``lsb_v``) and ``dsp`` (the frame DSP's fields, see
        :mod:`lidard.raw.replay`); it is stored as is (JSON) next to the commit state.
        """
        p = Path(path)
        px = np.asarray(pixels, dtype=np.int64)
        d = np.asarray(directions, dtype=np.float64)
        if px.ndim != 2 or px.shape[1] != 2 or d.shape != (len(px), 3):
            raise RawCaptureError(f"raw capture {p}: pixels must be (n, 2) and directions (n, 3), "
                                  f"got {px.shape} and {d.shape}")
        if averages < 1 or record_length < 1 or chunk_pixels < 1 or not channels:
            raise RawCaptureError(f"raw capture {p}: averages={averages}, record_length={record_length}, "
                                  f"chunk_pixels={chunk_pixels}, channels={channels!r}: all must be positive")
        for key in ("adc", "dsp"):
            if key not in attrs:
                raise RawCaptureError(f"raw capture {p}: attrs lack {key!r} (needed to reprocess)")
        if p.exists():
            raise RawCaptureError(f"raw capture {p}: already exists; refusing to overwrite")
        n, cp = len(px), int(chunk_pixels)
        g = zarr.open_group(zarr.storage.LocalStore(p), mode="w-")
        seg_chunk = cp * averages
        g.create_array("segments", shape=(n * averages, len(channels), record_length), dtype="int16",
                       chunks=(seg_chunk, len(channels), record_length), compressors=_COMPRESSOR, fill_value=0)
        g.create_array("trigger_time_ns", shape=(n * averages,), dtype="int64", chunks=(seg_chunk,), fill_value=0)
        g.create_array("overrange", shape=(n * averages,), dtype="uint8", chunks=(seg_chunk,), fill_value=0)
        g.create_array("t_s", shape=(n,), dtype="float64", chunks=(cp,), fill_value=0.0)
        g.create_array("pixels", shape=(n, 2), dtype="int64", chunks=(cp, 2), fill_value=0)[...] = px
        g.create_array("directions", shape=(n, 3), dtype="float64", chunks=(cp, 3), fill_value=0.0)[...] = d
        if drive_v is not None and np.asarray(drive_v).size:
            dv = np.asarray(drive_v, dtype=np.float64)
            g.create_array("drive_v", shape=dv.shape, dtype="float64", chunks=dv.shape)[...] = dv
        g.attrs.update({**attrs, "format": FORMAT, "channels": list(channels), "averages": int(averages),
                        "record_length": int(record_length), "chunk_pixels": cp, "pixels_planned": n,
                        "software": _software(), "complete": False, "chunks_complete": 0, "pixels_written": 0})
        return cls(g, p, cp, int(averages))

    def append(self, segments: np.ndarray, trigger_time_ns: np.ndarray, overrange: np.ndarray,
               t_s: np.ndarray) -> None:
        """One batch of whole pixels: ``segments`` (n_pix * averages, n_channels, record_length) int16
        as read, their trigger times and clip flags, and the pixels' times ``t_s`` (n_pix,)."""
        if self._closed:
            raise RawCaptureError(f"raw capture {self.path}: append after close")
        seg = np.asarray(segments)
        t = np.asarray(t_s, dtype=np.float64)
        n_pix = len(t)
        shape = _arr(self._g, "segments").shape
        if seg.dtype != np.int16 or seg.shape != (n_pix * self.averages,) + shape[1:]:
            raise RawCaptureError(f"raw capture {self.path}: segments must be int16 "
                                  f"{(n_pix * self.averages,) + shape[1:]}, got {seg.dtype} {seg.shape}")
        if self.pixels_written + self._pending_pix + n_pix > self.n_pixels:
            raise RawCaptureError(f"raw capture {self.path}: more pixels than the {self.n_pixels} planned")
        tt = np.asarray(trigger_time_ns, dtype=np.int64).reshape(-1)
        ov = np.asarray(overrange).astype(np.uint8).reshape(-1)
        if len(tt) != len(seg) or len(ov) != len(seg):
            raise RawCaptureError(f"raw capture {self.path}: trigger_time_ns and overrange need one entry "
                                  f"per segment ({len(seg)}), got {len(tt)} and {len(ov)}")
        self._pending.append((seg, tt, ov, t))
        self._pending_pix += n_pix
        while self._pending_pix >= self.chunk_pixels:
            self._write_chunk(self.chunk_pixels)

    def _take(self, n_pix: int) -> tuple[np.ndarray, ...]:
        seg, tt, ov, t = (np.concatenate(a) for a in zip(*self._pending))
        k = n_pix * self.averages
        rest = (seg[k:], tt[k:], ov[k:], t[n_pix:])
        self._pending = [rest] if len(rest[3]) else []
        self._pending_pix -= n_pix
        return seg[:k], tt[:k], ov[:k], t[:n_pix]

    def _write_chunk(self, n_pix: int) -> None:
        seg, tt, ov, t = self._take(n_pix)
        p0 = self.pixels_written
        s0, s1 = p0 * self.averages, (p0 + n_pix) * self.averages
        g = self._g
        _arr(g, "segments")[s0:s1] = seg
        _arr(g, "trigger_time_ns")[s0:s1] = tt
        _arr(g, "overrange")[s0:s1] = ov
        _arr(g, "t_s")[p0:p0 + n_pix] = t
        # the commit: only now do readers see this chunk
        self.pixels_written += n_pix
        self.chunks_complete += 1
        g.attrs.update({"chunks_complete": self.chunks_complete, "pixels_written": self.pixels_written})

    def close(self, **final_attrs: Any) -> None:
        """Write what is pending (a last, shorter chunk), trim the arrays to the pixels written and
        mark the capture complete; ``final_attrs`` (e.g. ``stop_reason``) are stored with it."""
        if self._closed:
            return
        if self._pending_pix:
            self._write_chunk(self._pending_pix)
        n = self.pixels_written
        g = self._g
        for name in ("segments", "trigger_time_ns", "overrange"):
            arr = _arr(g, name)
            arr.resize((n * self.averages,) + arr.shape[1:])
        for name in ("t_s", "pixels", "directions"):
            arr = _arr(g, name)
            arr.resize((n,) + arr.shape[1:])
        g.attrs.update({**final_attrs, "complete": True, "scan_partial": n < int(g.attrs["pixels_planned"])})  # type: ignore[arg-type]
        self._closed = True


@dataclass(frozen=True)
class RawChunk:
    """The records of one chunk's pixels, as the scan loop had them before its DSP."""

    index: int
    segments: np.ndarray        # int16 (n_pix * averages, n_channels, record_length)
    overrange: np.ndarray       # uint8 (n_pix * averages,)
    trigger_time_ns: np.ndarray
    pixels: np.ndarray          # (n_pix, 2)
    directions: np.ndarray      # (n_pix, 3)
    t_s: np.ndarray             # (n_pix,)

    def channel(self, name: str, channels: list[str], averages: int) -> np.ndarray:
        """One channel as (n_pix, averages, record_length) int16."""
        if name not in channels:
            raise RawCaptureError(f"raw chunk {self.index}: no channel {name!r} (recorded: {channels})")
        s = self.segments[:, channels.index(name), :]
        return s.reshape(len(self.t_s), averages, s.shape[-1])

    @property
    def clipped(self) -> np.ndarray:
        """Per pixel: any of its segments overranged (the scan marks its points invalid)."""
        return np.asarray(self.overrange.reshape(len(self.t_s), -1).any(axis=1))


class RawCapture:
    """Read side. ``n_chunks``/``n_pixels`` count only committed data (a crashed capture's prefix)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not (self.path / "zarr.json").is_file():
            raise RawCaptureError(f"raw capture {self.path}: not found (no zarr.json)")
        try:
            self._g = zarr.open_group(zarr.storage.LocalStore(self.path, read_only=True), mode="r")
        except Exception as exc:
            raise RawCaptureError(f"raw capture {self.path}: unreadable: {type(exc).__name__}: {exc}") from None
        self.attrs: dict[str, Any] = dict(self._g.attrs)
        if self.attrs.get("format") != FORMAT:
            raise RawCaptureError(f"raw capture {self.path}: format {self.attrs.get('format')!r}, "
                                  f"expected {FORMAT!r}")
        self.channels: list[str] = list(self.attrs["channels"])
        self.averages = int(self.attrs["averages"])
        self.chunk_pixels = int(self.attrs["chunk_pixels"])
        self.n_pixels = int(self.attrs["pixels_written"])
        # a daemon killed between a chunk's count and its pixels' count leaves the count one ahead:
        # a chunk without a written pixel is not committed data
        self.n_chunks = min(int(self.attrs["chunks_complete"]), -(-self.n_pixels // max(self.chunk_pixels, 1)))
        self.complete = bool(self.attrs["complete"])
        self._arrays: dict[str, zarr.Array] = {}    # opened once: a lookup reads the array's metadata
        self._files: dict[str, ChunkFiles | None] = {}   # the direct reader of each array, None: zarr reads it

    def _array(self, name: str) -> zarr.Array:
        a = self._arrays.get(name)
        if a is None:
            a = self._arrays[name] = _arr(self._g, name)
        return a

    def _chunk_files(self, name: str) -> ChunkFiles | None:
        if name not in self._files:
            self._files[name] = ChunkFiles.open(self.path / name)
        return self._files[name]

    def prefetch(self, first: int, stop: int) -> None:
        """Have the kernel start reading the samples of chunks ``first`` .. ``stop - 1`` from disk now
        (a replay asks for its next task's as it starts the DSP on this one: a capture that is not in
        the page cache is read while the DSP runs). Nothing happens for a layout read through zarr."""
        files = self._chunk_files("segments")
        first, stop = max(0, first), min(stop, self.n_chunks)
        if files is not None and first < stop:
            files.advise(first * self.chunk_pixels * self.averages, stop * self.chunk_pixels * self.averages)

    def chunk(self, index: int) -> RawChunk:
        return self.chunks(index, index + 1)

    def chunks(self, first: int, stop: int) -> RawChunk:
        """Chunks ``first`` .. ``stop - 1`` as one (a replay task's: one read per array, not per chunk)."""
        if not 0 <= first < stop <= self.n_chunks:
            raise RawCaptureError(f"raw capture {self.path}: chunk {first if first < 0 or first >= self.n_chunks else stop - 1} "
                                  f"out of range (0..{self.n_chunks - 1} committed)")
        p0 = first * self.chunk_pixels
        p1 = min(stop * self.chunk_pixels, self.n_pixels)
        s0, s1 = p0 * self.averages, p1 * self.averages
        seg, pix = slice(s0, s1), slice(p0, p1)

        def read(name: str, rows: slice) -> np.ndarray:
            files = self._chunk_files(name)
            if files is None:
                return np.asarray(self._array(name)[rows])
            try:
                return files.read(rows.start, rows.stop)
            except (OSError, ValueError, RuntimeError) as exc:    # a damaged chunk file: named, as zarr's read is
                raise RawCaptureError(f"raw capture {self.path}: {name} rows {rows.start}..{rows.stop - 1} "
                                      f"unreadable: {type(exc).__name__}: {exc}") from None

        return RawChunk(index=first, segments=read("segments", seg), overrange=read("overrange", seg),
                        trigger_time_ns=read("trigger_time_ns", seg), pixels=read("pixels", pix),
                        directions=read("directions", pix), t_s=read("t_s", pix))

    def pixel_index(self, row: int, col: int) -> int:
        """Index (scan order) of the first committed record of pixel (row, col)."""
        px = np.asarray(_arr(self._g, "pixels")[: self.n_pixels])
        hit = np.flatnonzero((px[:, 0] == row) & (px[:, 1] == col))
        if not len(hit):
            raise PixelNotRecorded(f"raw capture {self.path}: pixel ({row}, {col}) was not recorded")
        return int(hit[0])

    def drive_v(self) -> np.ndarray | None:
        return np.asarray(_arr(self._g, "drive_v")[...]) if "drive_v" in self._g else None


def capture_size_bytes(path: str | Path) -> int:
    """Bytes on disk of a capture directory (0 when absent)."""
    p = Path(path)
    if not p.exists():
        return 0
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())


def remove_capture(path: str | Path) -> bool:
    """Delete a capture directory; True when there was one."""
    p = Path(path)
    if not p.exists():
        return False
    shutil.rmtree(p)
    return True


def _arr(group: zarr.Group, name: str) -> zarr.Array:
    """The array ``name`` of a capture's group (a RawCaptureError if it is missing or a group)."""
    node = group.get(name)
    if not isinstance(node, zarr.Array):
        raise RawCaptureError(f"raw capture: {name!r} is not an array of the capture")
    return node
