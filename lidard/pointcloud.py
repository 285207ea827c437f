"""Point-cloud files: PLY, LAS 1.4, NPZ and the JSON sidecar, all written atomically.

A scan's points are :data:`lidard.point_schema.POINT_DTYPE` records, the per-pixel output of the FMCW
processing of §2.1/§4.4 (Fig. 4-35 shows such a frame). Every layout below is derived from that one
schema (:data:`lidard.point_schema.POINT_FIELDS`: name, dtype, unit, meaning), so each field has the
same type in every file; the field tables of README.md and docs/api.md are generated from it too.

* PLY: binary little-endian, one ``vertex`` element carrying every field in its schema dtype
  (``row``/``col`` as ``int``, which Open3D, PCL and CloudCompare keep).
* LAS 1.4, point format 6: x/y/z as scaled integers with a 0.1 mm scale (mm precision with margin)
  and the offsets at the cloud's minimum; ``gps_time`` is the scan time ``t``,
  ``return_number``/``number_of_returns`` the per-pixel return ordering. An invalid point (``valid``
  0) is withheld and classified as noise (class 7), a valid one is class 1, so GIS and web viewers
  hide what the DSP rejected. LAS ``intensity`` (uint16) is a display copy of the amplitude on a
  linear scale whose peak sits at half scale (no point saturates); the volts per count are in the
  ``lidard`` VLR (record 1, JSON). Every schema field but x, y, z, t also travels as an extra byte of
  its schema dtype (``intensity`` as ``amplitude``), so a reader gets each value back exactly.
* NPZ: ``numpy.savez`` of the record array ``points`` and a 0-d string array ``meta`` (JSON).
* Sidecar ``<file>.json``: what was measured with which settings (profile, chirp, ADC, calibration
  id, hardware and wall time, coverage, software version, simulated, partial).

Every file is written to a temporary file in the target directory, flushed, fsync'd and moved into
place with ``os.replace``, so a reader never sees a half-written file and a failing writer leaves
none behind. The target directory must exist: a typo in a path is reported, not created.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .outputs.files import PointCloudError, as_points as _as_points, atomic_write, dumps_meta
from .point_schema import (FIELD_BY_NAME, LAS_EXTRA_FIELDS, POINT_DTYPE, POINT_FORMATS, POINT_NAMES, las_description,
                           las_extra_name)

# Format names (lidard.point_schema.POINT_FORMATS; pcd, mcap, ros2 are written by lidard.outputs) and
# their file suffixes: Foxglove (mcap) and rosbag2 (ros2) are both MCAP files, told apart by the suffix.
FORMATS = POINT_FORMATS
SUFFIX: dict[str, str] = {"ros2": ".ros2.mcap"}
# Download media types (x-: no IANA registration exists for these formats; LAS has vnd.las)
MEDIA_TYPE = {"ply": "model/x-ply", "las": "application/vnd.las", "npz": "application/x-npz",
              "pcd": "application/x-pcd", "mcap": "application/x-mcap", "ros2": "application/x-mcap"}
PLY_DTYPE = POINT_DTYPE  # every field in its schema dtype (all little-endian)
LAS_SCALE_M = 1e-4
# LAS classification codes (ASPRS LAS 1.4 table 17)
LAS_CLASS_UNCLASSIFIED, LAS_CLASS_NOISE = 1, 7
# LAS intensity of the strongest point: half of uint16's range, so that no point reads as saturated
LAS_INTENSITY_PEAK = 32767
LAS_VLR_USER, LAS_VLR_RECORD = "lidard", 1


def suffix_of(fmt: str) -> str:
    """The file suffix of format ``fmt`` (``.ros2.mcap`` for the ROS 2 flavour of MCAP)."""
    return SUFFIX.get(fmt, "." + fmt)


# ---------------------------------------------------------------------------------------------- PLY
def write_ply(path: str | os.PathLike, points: np.ndarray) -> Path:
    from plyfile import PlyData, PlyElement

    pts = _as_points(points)
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


# ---------------------------------------------------------------------------------------------- LAS
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

    pts = _as_points(points)
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


# ---------------------------------------------------------------------------------------------- NPZ
def write_npz(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any] | None = None) -> Path:
    pts = _as_points(points)
    with atomic_write(path) as f:
        np.savez(f, points=pts, meta=np.array(dumps_meta(meta or {})))
    return Path(path)


def read_npz(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, Any]]:
    with np.load(str(path), allow_pickle=False) as z:
        return z["points"], json.loads(str(z["meta"]))


# ------------------------------------------------------------------------------------------ sidecar
def sidecar_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.with_name(p.name + ".json")


def write_sidecar(path: str | os.PathLike, meta: dict[str, Any]) -> Path:
    """Write ``<path>.json`` describing the point file ``path``."""
    side = sidecar_path(path)
    text = dumps_meta(meta)
    with atomic_write(side) as f:
        f.write(text.encode("utf-8"))
    return side


def scene_identity(path: str | os.PathLike) -> dict[str, str]:
    """The sidecar's ``scene`` entry on a simulated bench: the scene file's absolute path and the
    sha256 of its bytes, so a point cloud names exactly the world it was measured in."""
    import hashlib

    from .errors import ConfigError

    p = Path(path).resolve()
    try:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
    except FileNotFoundError:
        # the bench could not load it either: name the scene, not the sidecar that asked first
        raise ConfigError(f"scene file {p} not found (--scene, or sim.scene of the configuration)") from None
    except OSError as exc:
        raise ConfigError(f"scene file {p} cannot be read ({exc.strerror or exc})") from None
    return {"path": str(p), "sha256": digest}


def read_sidecar(path: str | os.PathLike) -> dict[str, Any]:
    return json.loads(sidecar_path(path).read_text(encoding="utf-8"))


def format_of(path: str | os.PathLike) -> str:
    name = Path(path).name.lower()
    for fmt, suffix in SUFFIX.items():
        if name.endswith(suffix):
            return fmt
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise PointCloudError(f"{path}: unknown point-cloud format {ext!r}; allowed: "
                              f"{', '.join(suffix_of(f) for f in FORMATS)}")
    return ext


def write_points(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any],
                 fmt: str | None = None) -> list[Path]:
    """Write ``points`` in ``fmt`` (default: from the extension) plus its JSON sidecar."""
    fmt = fmt or format_of(path)
    if fmt == "ply":
        write_ply(path, points)
    elif fmt == "las":
        write_las(path, points)
    elif fmt == "npz":
        write_npz(path, points, meta)
    elif fmt == "pcd":
        from .outputs.pcd import write_pcd  # lidard.outputs imports this module (atomic_write)
        write_pcd(path, points)
    elif fmt == "mcap":
        from .outputs.mcap import write_mcap
        write_mcap(path, points, meta)
    elif fmt == "ros2":
        from .outputs.ros2 import write_ros2_mcap
        write_ros2_mcap(path, points, meta)
    else:
        raise PointCloudError(f"{path}: unknown point-cloud format {fmt!r}; allowed: {', '.join(FORMATS)}")
    return [Path(path), write_sidecar(path, {**meta, "format": fmt, "points": int(len(points))})]


def read_points(path: str | os.PathLike) -> np.ndarray:
    fmt = format_of(path)
    if fmt == "ply":
        return read_ply(path)
    if fmt == "las":
        return read_las(path)
    if fmt == "pcd":
        from .outputs.pcd import read_pcd
        return _as_points(read_pcd(path)).copy()   # a writable array, not a view of the file's bytes
    if fmt == "mcap":
        from .outputs.mcap import read_mcap
        return _as_points(read_mcap(path)[0]).copy()
    if fmt == "ros2":
        from .outputs.ros2 import read_ros2_mcap
        return _as_points(read_ros2_mcap(path)).copy()
    return read_npz(path)[0]
