"""PCD v0.7 output, binary, as PCL's ``pcl::io::loadPCDFile`` and Open3D's ``read_point_cloud`` read it.

Header then the points as packed little-endian records, one per detected return (unorganized:
``WIDTH`` = number of points, ``HEIGHT`` = 1, since a pixel may have several returns or none, §4.4).
Every field of :data:`lidard.outputs.schema.POINT_FIELDS` is kept in its schema dtype (``TYPE``/``SIZE``
from :data:`lidard.outputs.schema.PCD_TYPE`): the records are POINT_DTYPE's bytes as they are.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .schema import PCD_TYPE, POINT_DTYPE, POINT_FIELDS, POINT_NAMES
from .files import PointCloudError, atomic_write

# (field, PCD type, size) in file order
_LAYOUT = tuple((f.name, *PCD_TYPE[f.dtype]) for f in POINT_FIELDS)
_NP = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 4): "<u4", ("U", 1): "u1", ("U", 2): "<u2",
       ("I", 4): "<i4", ("I", 2): "<i2", ("I", 1): "i1"}
PCD_DTYPE = POINT_DTYPE


def pcd_header(n: int) -> bytes:
    return ("# .PCD v0.7 - written by lidard\n"
            "VERSION 0.7\n"
            f"FIELDS {' '.join(f for f, _, _ in _LAYOUT)}\n"
            f"SIZE {' '.join(str(s) for _, _, s in _LAYOUT)}\n"
            f"TYPE {' '.join(t for _, t, _ in _LAYOUT)}\n"
            f"COUNT {' '.join('1' for _ in _LAYOUT)}\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n").encode("ascii")


def write_pcd(path: str | os.PathLike, points: np.ndarray) -> Path:
    out = np.zeros(len(points), PCD_DTYPE)
    for name in POINT_NAMES:
        out[name] = points[name]
    with atomic_write(path) as f:
        f.write(pcd_header(len(points)))
        f.write(out.tobytes())
    return Path(path)


def read_pcd(path: str | os.PathLike) -> np.ndarray:
    """A binary PCD file (any field layout) -> structured array named by its FIELDS."""
    raw = Path(path).read_bytes()
    head: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise PointCloudError(f"{path}: PCD header ends before DATA")
        line = raw[pos:end].decode("ascii").strip()
        pos = end + 1
        if line and not line.startswith("#"):
            key, *vals = line.split()
            head[key.upper()] = vals
            if key.upper() == "DATA":
                break
    if head["DATA"] != ["binary"]:
        raise PointCloudError(f"{path}: PCD DATA {head['DATA']} not supported (binary only)")
    if any(c != "1" for c in head.get("COUNT", [])):
        raise PointCloudError(f"{path}: PCD fields with COUNT > 1 are not supported")
    dtype = np.dtype([(f, _NP[(t, int(s))]) for f, t, s in zip(head["FIELDS"], head["TYPE"], head["SIZE"])])
    n = int(head["POINTS"][0])
    return np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
