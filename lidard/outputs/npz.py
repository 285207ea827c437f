"""NPZ output: ``numpy.savez`` of the record array ``points`` and a 0-d string array ``meta`` (JSON)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .files import as_points, atomic_write, dumps_meta

__all__ = ["read_npz", "write_npz"]


def write_npz(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any] | None = None) -> Path:
    pts = as_points(points)
    with atomic_write(path) as f:
        np.savez(f, points=pts, meta=np.array(dumps_meta(meta or {})))
    return Path(path)


def read_npz(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, Any]]:
    with np.load(str(path), allow_pickle=False) as z:
        return z["points"], json.loads(str(z["meta"]))
