"""Reading a capture's arrays straight from their chunk files, for the layout lidard writes.

Why not zarr's own read: zarr 3 pays ~0.6 ms for every chunk it reads (the synchronous call goes
through zarr's event loop, each chunk's file read and its decode through a thread of their own), and
a capture keeps six arrays chunked alike, so a 1,536-pixel capture of 1 MiB chunks is 1,848 chunk
reads: ~1.0 s of a ~3.6 s replay of that capture on one core went to the five small per-pixel and
per-segment arrays and ~0.4 s to the samples, against ~0.25 s for reading and decoding the same
sample files directly (docs/measured/27_replay.md). Here a chunk is one file read and one decode,
the samples' decoded straight into the caller's array (no intermediate copy).

Only the layout :class:`lidard.raw.capture.RawWriter` writes (and wrote before: every capture of
format ``lidard-raw/1``) is read this way: a Zarr v3 array, a regular chunk grid along the first axis
with every other axis whole, default chunk keys, the ``bytes`` codec (little-endian) followed by at
most one of ``blosc`` or ``zstd``. :meth:`ChunkFiles.open` answers None for anything else, and the
caller reads it through zarr (the reference: tests compare the two on every array). A chunk file that
is absent (zarr writes no chunk that holds only the fill value) reads as the fill value.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from collections.abc import Callable

import numpy as np
from numcodecs import blosc  # type: ignore[import-untyped]
from numcodecs.zstd import Zstd  # type: ignore[import-untyped]

Decoder = Callable[[bytes, np.ndarray], None]


def _blosc(data: bytes, out: np.ndarray) -> None:
    blosc.decompress(data, out)


def _zstd(data: bytes, out: np.ndarray) -> None:
    Zstd().decode(data, out)


def _plain(data: bytes, out: np.ndarray) -> None:
    out.reshape(-1).view(np.uint8)[:] = np.frombuffer(data, np.uint8)


_DECODERS: dict[str | None, Decoder] = {"blosc": _blosc, "zstd": _zstd, None: _plain}


def _decoder(codecs: list[dict[str, Any]], itemsize: int) -> Decoder | None:
    """The decode of a ``bytes`` (little-endian) + at most one known compressor chain, else None."""
    if not codecs or codecs[0].get("name") != "bytes" or len(codecs) > 2:
        return None
    endian = (codecs[0].get("configuration") or {}).get("endian", "little")
    if itemsize > 1 and endian != "little":
        return None
    comp = codecs[1] if len(codecs) == 2 else None
    if comp is not None and comp.get("name") == "zstd" and (comp.get("configuration") or {}).get("checksum"):
        return None
    return _DECODERS.get(None if comp is None else comp.get("name"))


@dataclass(frozen=True)
class ChunkFiles:
    """One array of a capture, chunked along its first axis, read chunk file by chunk file."""

    root: Path
    shape: tuple[int, ...]
    dtype: np.dtype
    rows_per_chunk: int
    separator: str
    fill_value: Any
    decode: Decoder

    @classmethod
    def open(cls, array_dir: Path) -> ChunkFiles | None:
        """The array at ``array_dir`` when its layout is one this reader knows, else None."""
        try:
            meta = json.loads((array_dir / "zarr.json").read_text())
        except (OSError, ValueError):
            return None
        try:
            if meta.get("zarr_format") != 3 or meta.get("node_type") != "array" or meta.get("storage_transformers"):
                return None
            shape = tuple(int(s) for s in meta["shape"])
            dtype = np.dtype(meta["data_type"]).newbyteorder("<")
            grid, keys = meta["chunk_grid"], meta["chunk_key_encoding"]
            chunk = tuple(int(c) for c in grid["configuration"]["chunk_shape"])
            if grid.get("name") != "regular" or keys.get("name") != "default" or not shape:
                return None
            if len(chunk) != len(shape) or chunk[1:] != shape[1:] or chunk[0] < 1:
                return None
            decode = _decoder(meta["codecs"], dtype.itemsize)
            fill = meta.get("fill_value", 0)
            if decode is None or not isinstance(fill, (int, float)):
                return None
            sep = (keys.get("configuration") or {}).get("separator", "/")
        except (KeyError, TypeError, ValueError):
            return None
        return cls(array_dir, shape, dtype, chunk[0], sep, fill, decode)

    def _key(self, i: int) -> Path:
        return self.root / self.separator.join(["c", str(i)] + ["0"] * (len(self.shape) - 1))

    def advise(self, start: int, stop: int) -> None:
        """Ask the kernel to read the chunk files of rows ``start`` .. ``stop - 1`` into the page cache
        now (``posix_fadvise`` WILLNEED: the disk reads run while the caller computes, no CPU here)."""
        start, stop = max(0, start), min(stop, self.shape[0])
        for i in range(start // self.rows_per_chunk, -(-stop // self.rows_per_chunk)):
            try:
                fd = os.open(self._key(i), os.O_RDONLY)
            except OSError:
                continue
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_WILLNEED)
            except (OSError, AttributeError):
                pass
            finally:
                os.close(fd)

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start`` .. ``stop - 1`` (within the array's shape) as a new array."""
        start, stop = max(0, start), min(stop, self.shape[0])
        out = np.empty((max(0, stop - start),) + self.shape[1:], self.dtype)
        rows = self.rows_per_chunk
        spare: np.ndarray | None = None
        for i in range(start // rows, -(-stop // rows)):
            c0, c1 = i * rows, (i + 1) * rows        # the chunk's rows; [a, b) the part wanted
            a, b = max(c0, start), min(c1, stop)
            try:
                data = self._key(i).read_bytes()
            except FileNotFoundError:
                out[a - start:b - start] = self.fill_value
                continue
            if a == c0 and b == c1:                  # a whole chunk: decoded in place
                self.decode(data, out[a - start:b - start])
                continue
            if spare is None:
                spare = np.empty((rows,) + self.shape[1:], self.dtype)
            self.decode(data, spare)
            out[a - start:b - start] = spare[a - c0:b - c0]
        return out
