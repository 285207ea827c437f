"""The static scene's hits of every pixel cast so far, in one flat store (the world's per-pixel cache).

A pixel's hits (the central ray's, or for a mixed pixel the footprint's weighted returns) are cast
once and kept; a digitizer read then needs the hits of its beams, a few tens of pixels repeated over
the averages and the beams of a switch transition. Kept as one tuple of arrays per pixel, that cost a
Python step per distinct pixel and seven concatenations per read, and the cast of a scan's next
pixels one tuple per pixel. Here the hits sit end to end in seven columns with each pixel's slot
(start, count) in a (row, column) table, so storing a cast and gathering a read's hits are a few
array operations whatever the number of pixels; the values and their order are the same (hits of a
beam in the ray's order, beams in the given order).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: the hit columns, in the order the world's beams use them
COLUMNS = ("range_m", "incidence_rad", "reflectivity", "radial_velocity_mps", "transmission", "target", "weight")


class HitStore:
    """Hits per pixel: the central ray's (``footprint=False``) and, for a mixed pixel, the
    footprint's weighted returns standing in for them (``footprint=True``)."""

    def __init__(self) -> None:
        self._cols = [np.zeros(1024) for _ in COLUMNS]
        self._n = 0
        # per pixel (row, col): start and count of its central hits, and of the hits a beam uses
        # (the footprint's on a mixed pixel); count -1 = not cast yet
        self._start = np.zeros((0, 0), np.int64)
        self._count = np.full((0, 0), -1, np.int64)
        self._fp_start = np.zeros((0, 0), np.int64)
        self._fp_count = np.full((0, 0), -1, np.int64)
        self._is_mixed = np.zeros((0, 0), bool)

    # -- storing ------------------------------------------------------------------------------
    def _grow_tables(self, rows: np.ndarray, cols: np.ndarray) -> None:
        need_r = int(rows.max()) + 1 if rows.size else 0
        need_c = int(cols.max()) + 1 if cols.size else 0
        r0, c0 = self._count.shape
        if need_r <= r0 and need_c <= c0:
            return
        shape = (max(r0, need_r, 2 * r0), max(c0, need_c, 2 * c0))

        def grown(a: np.ndarray, fill) -> np.ndarray:
            out = np.full(shape, fill, a.dtype)
            out[:r0, :c0] = a
            return out

        self._start, self._count = grown(self._start, 0), grown(self._count, -1)
        self._fp_start, self._fp_count = grown(self._fp_start, 0), grown(self._fp_count, -1)
        self._is_mixed = grown(self._is_mixed, False)

    def _append(self, values: Sequence[np.ndarray]) -> int:
        """Append equal-length columns; returns where they start."""
        m = len(values[0])
        if self._n + m > self._cols[0].size:
            size = max(2 * self._cols[0].size, self._n + m)
            self._cols = [np.concatenate([c[:self._n], np.zeros(size - self._n)]) for c in self._cols]
        for c, v in zip(self._cols, values):
            c[self._n:self._n + m] = v
        start, self._n = self._n, self._n + m
        return start

    def add_cast(self, rows: np.ndarray, cols: np.ndarray, hits) -> None:
        """The central rays of distinct pixels (rows, cols) not stored yet: ``hits`` as the scene's cast
        returns them ((n, max_hits) arrays and ``count`` per ray), weight 1."""
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        count = np.asarray(hits.count, np.int64)
        valid = np.arange(np.shape(hits.range_m)[1])[None, :] < count[:, None]    # row-major: ray by ray
        values = [np.asarray(hits.range_m)[valid], np.asarray(hits.incidence_rad)[valid],
                  np.asarray(hits.reflectivity)[valid], np.asarray(hits.radial_velocity_mps)[valid],
                  np.asarray(hits.transmission)[valid], np.asarray(hits.target_index)[valid].astype(np.float64),
                  np.ones(int(count.sum()))]
        start = self._append(values) + np.cumsum(count) - count
        self._grow_tables(rows, cols)
        self._start[rows, cols] = start
        self._count[rows, cols] = count
        self._fp_start[rows, cols] = start
        self._fp_count[rows, cols] = count

    def add_mixed(self, row: int, col: int, entry: Sequence[np.ndarray]) -> None:
        """A mixed pixel's footprint-weighted returns (the seven columns), used by its beams."""
        start = self._append([np.asarray(v, np.float64).ravel() for v in entry])
        self._grow_tables(np.array([row]), np.array([col]))
        self._fp_start[row, col], self._fp_count[row, col] = start, len(entry[0])
        self._is_mixed[row, col] = True

    # -- looking up ---------------------------------------------------------------------------
    def missing(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(n,) True where the pixel is not stored yet."""
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        r, c = self._count.shape
        inside = (rows < r) & (cols < c)
        out = ~inside
        out[inside] = self._count[rows[inside], cols[inside]] < 0
        return out

    def mixed(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(n,) True where the stored pixel's beams use the footprint's returns."""
        return self._is_mixed[np.asarray(rows, np.int64), np.asarray(cols, np.int64)]

    def gather(self, rows: np.ndarray, cols: np.ndarray, footprint: bool) -> tuple[list[np.ndarray], np.ndarray]:
        """(the seven columns of every hit, beam index) of beams at (rows, cols), all stored: each
        beam's hits in order, beams in the given order."""
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        starts, counts = (self._fp_start, self._fp_count) if footprint else (self._start, self._count)
        start, count = starts[rows, cols], counts[rows, cols]
        beam = np.repeat(np.arange(rows.size), count)
        first = np.cumsum(count) - count
        idx = np.repeat(start - first, count) + np.arange(beam.size)
        return [c[:self._n][idx] for c in self._cols], beam
