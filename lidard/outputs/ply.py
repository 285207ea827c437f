"""PLY output: binary little-endian, one ``vertex`` element carrying every field of
:data:`lidard.outputs.schema.POINT_FIELDS` in its schema dtype (``row``/``col`` as ``int``, which
Open3D, PCL and CloudCompare keep).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .files import as_points, atomic_write
from .schema import POINT_DTYPE, POINT_NAMES

__all__ = ["PLY_DTYPE", "read_ply", "write_ply"]

PLY_DTYPE = POINT_DTYPE  # every field in its schema dtype (all little-endian)


def write_ply(path: str | os.PathLike, points: np.ndarray) -> Path:
    from plyfile import PlyData, PlyElement

    pts = as_points(points)
    el = PlyElement.describe(pts.astype(PLY_DTYPE), "vertex")
    with atomic_write(path) as f:
        PlyData([el], text=False, byte_order="<").write(f)
    return Path(path)


def read_ply(path: str | os.PathLike) -> np.ndarray:
    from plyfile import PlyData

    ply = PlyData.read(str(path))
    data = ply["vertex"].data
    out = np.zeros(len(data), dtype=POINT_DTYPE)
    for name in POINT_NAMES:
        out[name] = data[name]
    return out
