"""Scan plans: which FPSA pixels a scan visits, and in which order.

The FPSA (dissertation §4.1, §4.3) addresses one antenna at a time by closing one row switch and one
column switch, so a "scan pattern" is nothing but an ordered list of (row, col) pairs. Only the
wire-bonded rows of a device can be switched (§4.3.3: one row line in four is left unbonded on the
128 x 128 chip), so every plan is restricted to ``optics.bonded_rows``.

Patterns (``ScanRequest.pattern``):

* ``raster``: row-major, every row left to right (the frame of Fig. 4-35).
* ``serpentine``: like raster but every other scanned row runs right to left, which halves the
  column-switch travel between rows (the next pixel is always a neighbour).
* ``roi``: raster restricted to ``rows`` / ``cols`` ([first, stop) ranges, Python style). ``rows`` and
  ``cols`` restrict raster and serpentine too; ``roi`` insists that at least one is given.
* ``pixels``: an explicit random-access list; an unbonded or out-of-array pixel is an error that names
  the pixel.
* ``adaptive``: a coarse pass (every ``step``-th bonded row and column) and then a dense re-scan of
  the cells in which the coarse pass saw returns. Because the second plan depends on measured data it
  is a generator: :func:`adaptive_plans` yields the coarse plan, receives the coarse points via
  ``send()``, and yields the dense plan. :func:`plan` returns the coarse plan for ``adaptive``.

Pure numpy; no I/O.
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np

from .types import ScanRequest
from ..physics.optics import FpsaOptics

ADAPTIVE_STEP = 4


class ScanPlanError(ValueError):
    """A scan request cannot be planned; the message names the field and the bad value."""


def _check_range(name: str, rng, limit: int) -> tuple[int, int]:
    if rng is None:
        return 0, limit
    try:
        first, stop = (int(v) for v in rng)
    except (TypeError, ValueError):
        raise ScanPlanError(f"{name}: expected a [first, stop) pair of integers, got {rng!r}") from None
    if not (0 <= first < stop <= limit):
        raise ScanPlanError(f"{name}: [{first}, {stop}) is not a non-empty range inside [0, {limit})")
    return first, stop


def selected_rows(request: ScanRequest, optics: FpsaOptics) -> np.ndarray:
    """Bonded rows inside ``request.rows`` (ascending)."""
    first, stop = _check_range("rows", request.rows, optics.rows)
    bonded = np.asarray(optics.bonded_rows, dtype=np.int64)
    rows = bonded[(bonded >= first) & (bonded < stop)]
    if rows.size == 0:
        raise ScanPlanError(f"rows: [{first}, {stop}) contains no wire-bonded row")
    return rows


def selected_cols(request: ScanRequest, optics: FpsaOptics) -> np.ndarray:
    first, stop = _check_range("cols", request.cols, optics.cols)
    return np.arange(first, stop, dtype=np.int64)


def grid(rows: np.ndarray, cols: np.ndarray, *, serpentine: bool = False) -> np.ndarray:
    """All (row, col) pairs of ``rows x cols``, row-major; reverse every other row if serpentine."""
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    cc = np.tile(cols, (rows.size, 1))
    if serpentine:
        cc[1::2] = cc[1::2, ::-1]
    rr = np.repeat(rows, cols.size)
    return np.stack([rr, cc.ravel()], axis=1)


def pixel_list(pixels, optics: FpsaOptics) -> np.ndarray:
    """Validate an explicit pixel list: inside the array and on a bonded row; order is kept."""
    if pixels is None or len(pixels) == 0:
        raise ScanPlanError("pixels: pattern 'pixels' needs a non-empty list of [row, col]")
    bonded = set(int(r) for r in optics.bonded_rows)
    out = np.empty((len(pixels), 2), dtype=np.int64)
    for i, p in enumerate(pixels):
        try:
            row, col = (int(v) for v in p)
        except (TypeError, ValueError):
            raise ScanPlanError(f"pixels[{i}]: expected [row, col], got {p!r}") from None
        if not (0 <= row < optics.rows and 0 <= col < optics.cols):
            raise ScanPlanError(f"pixels[{i}]: pixel ({row}, {col}) is outside the "
                                f"{optics.rows} x {optics.cols} array")
        if row not in bonded:
            raise ScanPlanError(f"pixels[{i}]: pixel ({row}, {col}) is on row {row}, which is not "
                                f"wire-bonded on this device")
        out[i] = row, col
    return out


def coarse_plan(request: ScanRequest, optics: FpsaOptics, step: int = ADAPTIVE_STEP) -> np.ndarray:
    """First pass of the adaptive pattern: every ``step``-th bonded row and column (serpentine)."""
    if step < 1:
        raise ScanPlanError(f"adaptive step must be >= 1, got {step}")
    rows = selected_rows(request, optics)
    cols = selected_cols(request, optics)
    return grid(rows[::step], cols[::step], serpentine=True)


def dense_plan(request: ScanRequest, optics: FpsaOptics, coarse_points: np.ndarray,
               step: int = ADAPTIVE_STEP, margin_cells: int = 1) -> np.ndarray:
    """Second pass of the adaptive pattern.

    Each coarse sample stands for a cell of ``step`` bonded rows x ``step`` columns whose first pixel
    it is. Cells whose sample produced at least one valid return are refined, together with their
    neighbours up to ``margin_cells`` away (an edge can cut a cell whose own corner pixel missed).
    Pixels already measured in the coarse pass are not repeated. Serpentine order.
    """
    rows = selected_rows(request, optics)
    cols = selected_cols(request, optics)
    n_cell_r = -(-rows.size // step)
    n_cell_c = -(-cols.size // step)
    hit = np.zeros((n_cell_r, n_cell_c), dtype=bool)
    pts = np.asarray(coarse_points)
    if pts.size:
        if "valid" in (pts.dtype.names or ()):
            pts = pts[pts["valid"] != 0]
        ri = np.searchsorted(rows, pts["row"].astype(np.int64))
        ci = np.searchsorted(cols, pts["col"].astype(np.int64))
        ok = (ri < rows.size) & (ci < cols.size)
        ok[ok] &= (rows[ri[ok]] == pts["row"][ok]) & (cols[ci[ok]] == pts["col"][ok])
        hit[ri[ok] // step, ci[ok] // step] = True
    if margin_cells > 0 and hit.any():
        grown = hit.copy()
        for dr in range(-margin_cells, margin_cells + 1):
            for dc in range(-margin_cells, margin_cells + 1):
                src = hit[max(0, -dr):n_cell_r - max(0, dr), max(0, -dc):n_cell_c - max(0, dc)]
                grown[max(0, dr):n_cell_r - max(0, -dr), max(0, dc):n_cell_c - max(0, -dc)] |= src
        hit = grown
    # Expand the cell mask to a pixel mask over (selected rows x selected cols).
    mask = np.repeat(np.repeat(hit, step, axis=0), step, axis=1)[:rows.size, :cols.size]
    mask[::step, ::step] = False  # already scanned in the coarse pass
    out = []
    for k, r in enumerate(rows):
        cs = cols[mask[k]]
        if k % 2:
            cs = cs[::-1]
        out.append(np.stack([np.full(cs.size, r, dtype=np.int64), cs], axis=1))
    return np.concatenate(out, axis=0) if out else np.empty((0, 2), dtype=np.int64)


def adaptive_plans(request: ScanRequest, optics: FpsaOptics, step: int = ADAPTIVE_STEP,
                   margin_cells: int = 1) -> Generator[np.ndarray, np.ndarray, None]:
    """Yield the coarse plan, receive its points via ``send()``, yield the dense plan.

    >>> gen = adaptive_plans(req, optics); coarse = next(gen); dense = gen.send(coarse_points)
    """
    coarse_points = yield coarse_plan(request, optics, step)
    if coarse_points is None:
        raise ScanPlanError("adaptive: send() the coarse pass's points to get the dense plan")
    yield dense_plan(request, optics, coarse_points, step, margin_cells)


def plan(request: ScanRequest, optics: FpsaOptics) -> np.ndarray:
    """The ordered (n, 2) int64 array of (row, col) a request visits (coarse pass for adaptive)."""
    kind = request.pattern
    if kind == "pixels":
        return pixel_list(request.pixels, optics)
    if request.pixels is not None:
        raise ScanPlanError(f"pixels: only allowed with pattern 'pixels', not {kind!r}")
    if kind == "roi" and request.rows is None and request.cols is None:
        raise ScanPlanError("roi: give rows and/or cols as [first, stop) ranges")
    if kind in ("raster", "roi"):
        return grid(selected_rows(request, optics), selected_cols(request, optics))
    if kind == "serpentine":
        return grid(selected_rows(request, optics), selected_cols(request, optics), serpentine=True)
    if kind == "adaptive":
        return coarse_plan(request, optics)
    if kind == "track":
        raise ScanPlanError("pattern: 'track' plans each frame of a stream from the last ones (lidarctl stream, "
                            "POST /streams); a single scan cannot use it")
    raise ScanPlanError(f"pattern: {kind!r} unknown; allowed: raster, serpentine, roi, pixels, adaptive")


def planned_pixel_count(request: ScanRequest, optics: FpsaOptics) -> int:
    """Pixels a request will visit (for adaptive: the full ROI, the upper bound of both passes)."""
    if request.pattern == "adaptive":
        return int(selected_rows(request, optics).size * selected_cols(request, optics).size)
    return int(plan(request, optics).shape[0])
