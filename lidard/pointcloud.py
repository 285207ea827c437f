"""Point-cloud files: PLY, LAS 1.4, NPZ and the JSON sidecar, all written atomically.

A scan's points are :data:`lidard.instrument.types.POINT_DTYPE` records (x, y, z in the sensor frame of
§4.1.1, range, radial velocity, intensity, SNR, the FPSA pixel, return index, time, valid flag), the
per-pixel output of the FMCW processing of §2.1/§4.4 (Fig. 4-35 shows such a frame). Float32 is used
only here, at the file edge.

* PLY: binary little-endian, one ``vertex`` element carrying every POINT_DTYPE field, with ``row``
  and ``col`` stored as ``int`` (int32) because Open3D skips ``ushort`` properties.
* LAS 1.4, point format 6: x/y/z as scaled integers with a 0.1 mm scale (mm precision with margin)
  and the offsets at the cloud's minimum; LAS ``intensity`` (uint16) holds the amplitude scaled to
  the largest one, ``return_number``/``number_of_returns`` the per-pixel return ordering and
  ``gps_time`` the scan time ``t``; the physical values travel as extra bytes (range, velocity,
  snr_db, amplitude, row, col, valid, flags) so that a reader gets them back exactly.
* NPZ: ``numpy.savez`` of the record array ``points`` and a 0-d string array ``meta`` (JSON).
* Sidecar ``<file>.json``: what was measured with which settings (profile, chirp, ADC, calibration
  id, hardware and wall time, coverage, software version, simulated, partial).

Every file is written to a temporary file in the target directory, flushed, fsync'd and moved into
place with ``os.replace``, so a reader never sees a half-written file and a failing writer leaves
none behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, BinaryIO, Iterator

import numpy as np

from .instrument.types import POINT_DTYPE

FORMATS = ("ply", "las", "npz", "pcd", "mcap")  # pcd, mcap: lidard.outputs
# PLY vertex properties: POINT_DTYPE with the pixel indices widened to int32. Open3D drops ``ushort``
# properties ("unsupported datatype"); ``int`` is kept by Open3D, PCL and CloudCompare alike.
PLY_DTYPE = np.dtype([(name, "<i4" if name in ("row", "col") else POINT_DTYPE[name].newbyteorder("<"))
                      for name in POINT_DTYPE.names])
LAS_SCALE_M = 1e-4
# Extra-bytes dimensions of the LAS file and their POINT_DTYPE source field.
_LAS_EXTRA = (("range", "range", np.float32), ("velocity", "velocity", np.float32),
              ("snr_db", "snr_db", np.float32), ("amplitude", "intensity", np.float32),
              ("row", "row", np.uint16), ("col", "col", np.uint16), ("valid", "valid", np.uint8),
              ("flags", "flags", np.uint8))


class PointCloudError(ValueError):
    """A point-cloud file cannot be written or read; the message names the file and the problem."""


def _read_umask() -> int:
    # Reading the umask means setting it; do it once, at import, not while worker threads create files.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Yield a binary file in ``path``'s directory; on success fsync and ``os.replace`` it into place.

    On any exception the temporary file is removed and ``path`` is left as it was (absent or old).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            # mkstemp makes the file 0600; a point cloud gets the permissions of any new file
            os.fchmod(f.fileno(), 0o666 & ~_UMASK)
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    # Make the rename itself durable (best effort: not every platform can fsync a directory).
    with contextlib.suppress(OSError):
        dfd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def _as_points(points: np.ndarray) -> np.ndarray:
    arr = np.asarray(points)
    if arr.dtype != POINT_DTYPE:
        if arr.dtype.names is None or set(arr.dtype.names) != set(POINT_DTYPE.names):
            raise PointCloudError(f"points: expected POINT_DTYPE records, got dtype {arr.dtype}")
        arr = arr.astype(POINT_DTYPE)
    return np.ascontiguousarray(arr.reshape(-1))


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, (Path, tuple, set)):
        return str(o) if isinstance(o, Path) else list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps_meta(meta: dict[str, Any]) -> str:
    return json.dumps(meta, default=_json_default, indent=2, sort_keys=True, allow_nan=False)


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
    for name in POINT_DTYPE.names:
        out[name] = data[name]
    return out


# ---------------------------------------------------------------------------------------------- LAS
def _returns_per_pixel(pts: np.ndarray) -> np.ndarray:
    if pts.size == 0:
        return np.zeros(0, dtype=np.int64)
    key = pts["row"].astype(np.int64) * 65536 + pts["col"].astype(np.int64)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return counts[inverse]


def write_las(path: str | os.PathLike, points: np.ndarray) -> Path:
    import laspy

    pts = _as_points(points)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=typ, description=f"lidard {src}")
                           for name, src, typ in _LAS_EXTRA])
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    header.offsets = np.floor(xyz.min(axis=0)) if len(pts) else np.zeros(3)
    header.scales = np.full(3, LAS_SCALE_M)
    span = (xyz.max(axis=0) - header.offsets) / LAS_SCALE_M if len(pts) else np.zeros(3)
    if np.any(span > np.iinfo(np.int32).max):
        raise PointCloudError(f"{path}: point cloud spans more than the LAS int32 range at "
                              f"{LAS_SCALE_M} m scale")
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    amp = pts["intensity"].astype(np.float64)
    peak = float(np.max(np.abs(amp))) if len(pts) else 0.0
    las.intensity = np.round(np.abs(amp) / peak * 65535).astype(np.uint16) if peak > 0 \
        else np.zeros(len(pts), np.uint16)
    n_ret = np.clip(_returns_per_pixel(pts), 1, 15)
    las.return_number = np.clip(pts["return_index"].astype(np.int64) + 1, 1, 15).astype(np.uint8)
    las.number_of_returns = n_ret.astype(np.uint8)
    las.gps_time = pts["t"].astype(np.float64)
    for name, src, typ in _LAS_EXTRA:
        las[name] = pts[src].astype(typ)
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
    for name, src, _ in _LAS_EXTRA:
        out[src] = np.asarray(las[name])
    out["return_index"] = np.asarray(las.return_number).astype(np.int64) - 1
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

    p = Path(path).resolve()
    try:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
    except OSError as exc:
        raise PointCloudError(f"scene {p}: cannot be read for the sidecar ({exc.strerror or exc})") from None
    return {"path": str(p), "sha256": digest}


def read_sidecar(path: str | os.PathLike) -> dict[str, Any]:
    return json.loads(sidecar_path(path).read_text(encoding="utf-8"))


def format_of(path: str | os.PathLike) -> str:
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise PointCloudError(f"{path}: unknown point-cloud format {ext!r}; allowed: "
                              f"{', '.join('.' + f for f in FORMATS)}")
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
        return _as_point_dtype(read_pcd(path))
    if fmt == "mcap":
        from .outputs.mcap import read_mcap
        return _as_point_dtype(read_mcap(path)[0])
    return read_npz(path)[0]


def _as_point_dtype(rec: np.ndarray) -> np.ndarray:
    # PCD and MCAP carry the POINT_DTYPE fields in their own widths; absent ones (MCAP has no
    # return_index/valid) are left at 0 / 1
    out = np.zeros(len(rec), POINT_DTYPE)
    out["valid"] = 1
    for name in POINT_DTYPE.names:
        if name in (rec.dtype.names or ()):
            out[name] = rec[name]
    return out
