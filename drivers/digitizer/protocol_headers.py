"""Segment headers of the digitizer's stream, one at a time and a read's worth at a time.

PURE, part of the codec ``drivers.digitizer.protocol`` (which re-exports every name here; the byte
layout is its docstring and docs/protocols/digitizer.md). :class:`SegmentHeader` is one decoded
header. :class:`SegmentHeaders` is the headers of one read of many segments as columns (numpy
arrays taken from the read's record array in one pass each): a scan reads ~200 segments per read
and ~10^5 per frame, and only needs the trigger times and overrange flags as arrays, so the
per-segment Python objects of a list of headers were pure overhead; an item is still a
:class:`SegmentHeader` (built on access). :func:`payload_crc32s` and :func:`header_crc32s` are the
two crc32 fields of a batch of segments laid end to end (zlib's C crc32, one call per segment and
field: a vectorised numpy CRC over ~200 segments costs more than those calls).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from drivers.digitizer.protocol_format import HEADER_LEN, bytes_per_sample

#: the header crc32 covers header bytes 0..27 (everything before itself)
HEADER_CRC_SPAN = 28


@dataclass(frozen=True)
class SegmentHeader:
    index: int
    trigger_time_ns: int
    n_samples: int
    channel_mask: int
    bits: int
    overrange: int          # bit i = i-th present channel over range
    payload_crc32: int

    @property
    def n_channels(self) -> int:
        return bin(self.channel_mask).count("1")

    @property
    def payload_len(self) -> int:
        return self.n_channels * self.n_samples * bytes_per_sample(self.bits)

    @property
    def trigger_time_s(self) -> float:
        return self.trigger_time_ns * 1e-9


#: SegmentHeader's fields and the segment record's (protocol_format.segment_dtype) field for each
_COLUMNS = (("index", "index"), ("trigger_time_ns", "trigger_time_ns"), ("n_samples", "n_samples"),
            ("channel_mask", "mask"), ("bits", "bits"), ("overrange", "overrange"),
            ("payload_crc32", "payload_crc32"))


class SegmentHeaders(Sequence[SegmentHeader]):
    """The headers of consecutive segments as columns: ``index``, ``trigger_time_ns``, ``n_samples``,
    ``channel_mask``, ``bits``, ``overrange``, ``payload_crc32`` (1-D numpy arrays of one length).

    A sequence of :class:`SegmentHeader` (indexing, iteration, ``len``) for code that looks at a few;
    a scan reads the columns."""

    __slots__ = tuple(name for name, _ in _COLUMNS)
    # the segment numbers (SegmentHeader.index), which hides Sequence.index (a search by value)
    index: np.ndarray  # type: ignore[assignment]
    trigger_time_ns: np.ndarray
    n_samples: np.ndarray
    channel_mask: np.ndarray
    bits: np.ndarray
    overrange: np.ndarray
    payload_crc32: np.ndarray

    def __init__(self, **columns: Any) -> None:
        names = [name for name, _ in _COLUMNS]
        if sorted(columns) != sorted(names):
            raise TypeError(f"SegmentHeaders needs the columns {names}, got {sorted(columns)}")
        arrays = {k: np.asarray(v) for k, v in columns.items()}
        lengths = {a.shape for a in arrays.values()}
        if len(lengths) != 1 or len(next(iter(lengths))) != 1:
            raise ValueError(f"SegmentHeaders columns must be 1-D of one length, got shapes {sorted(lengths)}")
        for k, v in arrays.items():
            setattr(self, k, v)

    @classmethod
    def from_records(cls, recs: np.ndarray) -> SegmentHeaders:
        """The header columns of a record array of segments (``segment_dtype``), copied out of it (the
        records may live in a transfer buffer that the next read reuses)."""
        return cls(**{name: recs[field].copy() for name, field in _COLUMNS})

    def __len__(self) -> int:
        return int(self.index.shape[0])

    @overload
    def __getitem__(self, i: int) -> SegmentHeader: ...
    @overload
    def __getitem__(self, i: slice) -> SegmentHeaders: ...

    def __getitem__(self, i: int | slice) -> SegmentHeader | SegmentHeaders:
        if isinstance(i, slice):
            return SegmentHeaders(**{name: getattr(self, name)[i] for name, _ in _COLUMNS})
        return SegmentHeader(*(int(getattr(self, name)[i]) for name, _ in _COLUMNS))

    def __iter__(self) -> Iterator[SegmentHeader]:
        for vals in zip(*(getattr(self, name).tolist() for name, _ in _COLUMNS)):
            yield SegmentHeader(*vals)

    def __repr__(self) -> str:
        n = len(self)
        return f"SegmentHeaders({n} segments{f', index {self.index[0]}..{self.index[-1]}' if n else ''})"


def header_column(headers: Sequence[SegmentHeader], name: str) -> np.ndarray:
    """Field ``name`` of every header as an int64 array: the column of a :class:`SegmentHeaders`, or
    gathered from any other sequence of headers."""
    if isinstance(headers, SegmentHeaders):
        return getattr(headers, name).astype(np.int64)
    return np.array([int(getattr(h, name)) for h in headers], dtype=np.int64)


def payload_crc32s(buf: memoryview, size: int, count: int) -> list[int]:
    """crc32 of the payload of each of ``count`` segments of ``size`` bytes laid end to end in ``buf``."""
    crc = zlib.crc32
    return [crc(buf[o + HEADER_LEN:o + size]) for o in range(0, count * size, size)]


def header_crc32s(buf: memoryview, size: int, count: int) -> list[int]:
    """crc32 of header bytes 0..27 of each of ``count`` segments of ``size`` bytes in ``buf`` (compute
    it after the payload crc field, bytes 24..27, is in place)."""
    crc = zlib.crc32
    return [crc(buf[o:o + HEADER_CRC_SPAN]) for o in range(0, count * size, size)]
