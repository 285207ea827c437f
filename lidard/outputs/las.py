"""LAS 1.4 output, point format 6, as GIS tools, PDAL and web viewers read it.

x/y/z are scaled integers with a 0.1 mm scale (mm precision with margin) and the offsets at the
cloud's minimum; ``gps_time`` is the scan time ``t``, ``return_number``/``number_of_returns`` the
per-pixel return ordering. An invalid point (``valid`` 0) is withheld and classified as noise
(class 7), a valid one is class 1, so GIS and web viewers hide what the DSP rejected. LAS
``intensity`` (uint16) is a display copy of the amplitude on a linear scale whose peak sits at half
scale (no point saturates); the volts per count are in the ``lidard`` VLR (record 1, JSON). Every
schema field but x, y, z, t also travels as an extra byte of its schema dtype (``intensity`` as
``amplitude``), so a reader gets each value back exactly (:data:`lidard.outputs.schema.LAS_STANDARD`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .files import PointCloudError, as_points, atomic_write
from .schema import FIELD_BY_NAME, LAS_EXTRA_FIELDS, POINT_DTYPE, las_description, las_extra_name

__all__ = ["LAS_CLASS_NOISE", "LAS_CLASS_UNCLASSIFIED", "LAS_INTENSITY_PEAK", "LAS_SCALE_M", "las_intensity",
           "read_las", "write_las"]

LAS_SCALE_M = 1e-4
# LAS classification codes (ASPRS LAS 1.4 table 17)
LAS_CLASS_UNCLASSIFIED, LAS_CLASS_NOISE = 1, 7
# LAS intensity of the strongest point: half of uint16's range, so that no point reads as saturated
LAS_INTENSITY_PEAK = 32767
LAS_VLR_USER, LAS_VLR_RECORD = "lidard", 1


def _returns_per_pixel(pts: np.ndarray) -> np.ndarray:
    if pts.size == 0:
        return np.zeros(0, dtype=np.int64)
    key = pts["row"].astype(np.int64) * 65536 + pts["col"].astype(np.int64)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return counts[inverse]


def las_intensity(amplitude: np.ndarray) -> tuple[np.ndarray, float]:
    """LAS ``intensity`` (uint16) of the amplitudes and the volts per count: a linear scale with the
    strongest point at :data:`LAS_INTENSITY_PEAK`, so ratios survive and nothing saturates."""
    amp = np.abs(np.asarray(amplitude, np.float64))
    peak = float(amp.max()) if amp.size else 0.0
    if not np.isfinite(peak) or peak <= 0:
        return np.zeros(amp.size, np.uint16), 0.0
    volts_per_count = peak / LAS_INTENSITY_PEAK
    return np.round(amp / volts_per_count).astype(np.uint16), volts_per_count


def write_las(path: str | os.PathLike, points: np.ndarray) -> Path:
    import laspy

    pts = as_points(points)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([laspy.ExtraBytesParams(name=las_extra_name(name), type=np.dtype(FIELD_BY_NAME[name].dtype),
                                                  description=las_description(FIELD_BY_NAME[name]))
                           for name in LAS_EXTRA_FIELDS])
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    header.offsets = np.floor(xyz.min(axis=0)) if len(pts) else np.zeros(3)
    header.scales = np.full(3, LAS_SCALE_M)
    span = (xyz.max(axis=0) - header.offsets) / LAS_SCALE_M if len(pts) else np.zeros(3)
    if np.any(span > np.iinfo(np.int32).max):
        raise PointCloudError(f"{path}: point cloud spans more than the LAS int32 range at "
                              f"{LAS_SCALE_M} m scale")
    intensity, volts_per_count = las_intensity(pts["intensity"])
    header.vlrs.append(laspy.VLR(LAS_VLR_USER, LAS_VLR_RECORD, "lidard intensity scale",
                                 json.dumps({"intensity_volts_per_count": volts_per_count}).encode()))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.intensity = intensity
    n_ret = np.clip(_returns_per_pixel(pts), 1, 15)
    las.return_number = np.clip(pts["return_index"].astype(np.int64) + 1, 1, 15).astype(np.uint8)
    las.number_of_returns = n_ret.astype(np.uint8)
    las.gps_time = pts["t"].astype(np.float64)
    invalid = pts["valid"] == 0
    las.classification = np.where(invalid, LAS_CLASS_NOISE, LAS_CLASS_UNCLASSIFIED).astype(np.uint8)
    las.withheld = invalid
    for name in LAS_EXTRA_FIELDS:
        las[las_extra_name(name)] = pts[name]
    with atomic_write(path) as f:
        las.write(f)
    return Path(path)


def read_las(path: str | os.PathLike) -> np.ndarray:
    """Read a lidard LAS file back into POINT_DTYPE records (x, y, z quantised to the LAS scale)."""
    import laspy

    las = laspy.read(str(path))
    n = len(las.points)
    out = np.zeros(n, dtype=POINT_DTYPE)
    out["x"], out["y"], out["z"] = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    for name in LAS_EXTRA_FIELDS:
        out[name] = np.asarray(las[las_extra_name(name)])
    out["t"] = np.asarray(las.gps_time)
    return out
