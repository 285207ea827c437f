"""Validation of the pixels the host sends to the FPSA controller (§4.3.3: one row in four is not
wire-bonded; §4.2.1: row-column addressing, one row and one column per pixel).

PURE: a pattern or a SET_PIXEL target is checked before anything is sent: shape (n, 2), not empty,
integers, no more pixels than the array has (and a u16 count), every row and column in range and
every row wire-bonded. The error names the first bad pixel, its row and column and the reason.
Used by :class:`drivers.fpsa.driver.FpsaController`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import PatternError


def validate_pixels(pixels: Any, what: str, rows: int, cols: int, bonded: np.ndarray,
                    device: str = "fpsa") -> np.ndarray:
    """``pixels`` as an (n, 2) uint8 array of (row, col) the board can show, or a
    :class:`~drivers.fpsa.errors.PatternError` naming the first bad pixel and why.

    ``what``: "SET_PIXEL" or the name of the pattern (it names the command in the error);
    ``bonded``: bool per row, True where the row is wire-bonded."""
    ctx: dict[str, Any] = {"device": device, "command": "SET_PIXEL" if what == "SET_PIXEL" else "UPLOAD_PATTERN"}
    arr = np.asarray(pixels)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise PatternError(f"{device}: {what} must have shape (n, 2), got {arr.shape}", **ctx)
    if arr.shape[0] == 0:
        raise PatternError(f"{device}: {what} is empty", **ctx)
    if not np.issubdtype(arr.dtype, np.integer):
        raise PatternError(f"{device}: {what} must be integers, got dtype {arr.dtype}", **ctx)
    limit = min(rows * cols, 0xFFFF)
    if arr.shape[0] > limit:
        raise PatternError(f"{device}: {what} has {arr.shape[0]} pixels, more than "
                           f"{limit} ({rows}x{cols})", **ctx)
    r = arr[:, 0].astype(np.int64)
    c = arr[:, 1].astype(np.int64)
    bad_r = (r < 0) | (r >= rows)
    bad_c = (c < 0) | (c >= cols)
    bad_b = ~bad_r & ~bonded[np.clip(r, 0, rows - 1)]
    bad = bad_r | bad_c | bad_b
    if bad.any():
        i = int(np.argmax(bad))
        ri, ci = int(r[i]), int(c[i])
        if bad_r[i]:
            why = f"row {ri} outside 0..{rows - 1}"
        elif bad_c[i]:
            why = f"column {ci} outside 0..{cols - 1}"
        else:
            why = f"row {ri} is not wire-bonded"
        raise PatternError(f"{device}: {what} pixel {i} (row {ri}, col {ci}): {why}",
                           index=i, row=ri, col=ci, **ctx)
    return np.stack([r, c], axis=1).astype(np.uint8)
