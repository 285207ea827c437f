"""The one registry of point-file formats: name -> writer, reader, suffix, media type, stream use.

Everything that names a format takes it from here: the scan request's ``formats``
(:data:`lidard.instrument.types.OutputFormat` is :data:`PointFormat`), the API's ``FileFormat`` and
``GET /scans/{id}/points?format=`` (their media types), the daemon's writing of a finished scan or
stream (:func:`write_points`), the CLI's ``--format`` choices and ``--out`` suffix parsing
(:func:`format_of`), and the formats table of docs/api.md (``python tools/gen_point_docs.py``).
A new format is one module of this package (``write_<fmt>``/``read_<fmt>`` over
:func:`lidard.outputs.files.atomic_write`, its layout from :data:`lidard.outputs.schema.POINT_FIELDS`)
and one :class:`FormatSpec` entry below.

The writers are imported on first use (plyfile, laspy, foxglove and mcap load only when their
format is written), so the API and the scan request can import this module at no cost.

"mcap" is the Foxglove flavour (``foxglove.PointCloud``, protobuf), "ros2" the rosbag2 flavour
(``sensor_msgs/msg/PointCloud2``, CDR): both are MCAP files, told apart by the suffix ``.ros2.mcap``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast, get_args

import numpy as np

from .files import PointCloudError, as_points
from .sidecar import write_sidecar

__all__ = ["FORMATS", "FRAME_FORMATS", "MEDIA_TYPE", "REGISTRY", "STREAM_FORMATS", "FormatSpec",
           "PointFormat", "StreamFormat", "format_of", "read_points", "registry_table", "suffix_of", "write_points"]

# Static spellings of the registry's names, for the type checker and for pydantic's request
# validation; the import-time check below keeps them equal to the registry.
PointFormat = Literal["ply", "las", "npz", "pcd", "mcap", "ros2"]
# what a stream can write: one file per frame, or (mcap) one file holding every frame
StreamFormat = Literal["ply", "las", "npz", "pcd", "mcap"]

Writer = Callable[[Path, np.ndarray, dict[str, Any]], object]
Reader = Callable[[Path], np.ndarray]


@dataclass(frozen=True)
class FormatSpec:
    """One point-file format. ``stream``: how a stream writes it (``"frames"``: a file per frame,
    ``"one_file"``: every frame in one file, ``None``: not for streams)."""

    name: PointFormat
    suffix: str
    media_type: str            # x-: no IANA registration exists (LAS has vnd.las)
    description: str
    stream: Literal["frames", "one_file"] | None
    load: Callable[[], tuple[Writer, Reader]]

    def write(self, path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any]) -> None:
        self.load()[0](Path(path), points, meta)

    def read(self, path: str | os.PathLike) -> np.ndarray:
        return self.load()[1](Path(path))


def _ply() -> tuple[Writer, Reader]:
    from .ply import read_ply, write_ply
    return (lambda path, pts, meta: write_ply(path, pts)), read_ply


def _las() -> tuple[Writer, Reader]:
    from .las import read_las, write_las
    return (lambda path, pts, meta: write_las(path, pts)), read_las


def _npz() -> tuple[Writer, Reader]:
    from .npz import read_npz, write_npz
    return write_npz, (lambda path: read_npz(path)[0])


def _pcd() -> tuple[Writer, Reader]:
    from .pcd import read_pcd, write_pcd
    # a writable array, not a view of the file's bytes
    return (lambda path, pts, meta: write_pcd(path, pts)), (lambda path: as_points(read_pcd(path)).copy())


def _mcap() -> tuple[Writer, Reader]:
    from .mcap import read_mcap, write_mcap
    return write_mcap, (lambda path: as_points(read_mcap(path)[0]).copy())


def _ros2() -> tuple[Writer, Reader]:
    from .ros2 import read_ros2_mcap, write_ros2_mcap
    return write_ros2_mcap, (lambda path: as_points(read_ros2_mcap(path)).copy())


REGISTRY: dict[str, FormatSpec] = {f.name: f for f in (
    FormatSpec("ply", ".ply", "model/x-ply", "PLY, binary little-endian (Open3D, PCL, CloudCompare)",
               "frames", _ply),
    FormatSpec("las", ".las", "application/vnd.las", "LAS 1.4, point format 6, extra bytes (PDAL, GIS)",
               "frames", _las),
    FormatSpec("npz", ".npz", "application/x-npz", "numpy record array and the metadata as JSON",
               "frames", _npz),
    FormatSpec("pcd", ".pcd", "application/x-pcd", "PCD v0.7, binary (PCL, Open3D)", "frames", _pcd),
    FormatSpec("mcap", ".mcap", "application/x-mcap", "MCAP, foxglove.PointCloud (Foxglove, Lichtblick)",
               "one_file", _mcap),
    FormatSpec("ros2", ".ros2.mcap", "application/x-mcap",
               "MCAP rosbag2, sensor_msgs/msg/PointCloud2 (ros2 bag, rosbags)", None, _ros2),
)}

FORMATS: tuple[PointFormat, ...] = tuple(f.name for f in REGISTRY.values())
# (the cast is checked at import by _check_literals)
STREAM_FORMATS = cast("tuple[StreamFormat, ...]", tuple(f.name for f in REGISTRY.values() if f.stream))
FRAME_FORMATS: tuple[str, ...] = tuple(f.name for f in REGISTRY.values() if f.stream == "frames")
MEDIA_TYPE: dict[str, str] = {f.name: f.media_type for f in REGISTRY.values()}


def _check_literals() -> None:
    # A Literal cannot be built from data for the type checker; fail at import, not in a request.
    if get_args(PointFormat) != FORMATS:
        raise RuntimeError(f"PointFormat {get_args(PointFormat)} differs from the registry {FORMATS}")
    if get_args(StreamFormat) != STREAM_FORMATS:
        raise RuntimeError(f"StreamFormat {get_args(StreamFormat)} differs from the registry {STREAM_FORMATS}")


_check_literals()


def suffix_of(fmt: str) -> str:
    """The file suffix of format ``fmt`` (``.ros2.mcap`` for the ROS 2 flavour of MCAP)."""
    return _entry(fmt, "format").suffix


def _entry(fmt: str, where: str | os.PathLike) -> FormatSpec:
    try:
        return REGISTRY[fmt]
    except KeyError:
        raise PointCloudError(f"{where}: unknown point-cloud format {fmt!r}; allowed: {', '.join(FORMATS)}") from None


def format_of(path: str | os.PathLike) -> str:
    """The format of ``path`` from its suffix (the longest registered suffix that ends the name)."""
    name = Path(path).name.lower()
    for f in sorted(REGISTRY.values(), key=lambda f: -len(f.suffix)):
        if name.endswith(f.suffix):
            return f.name
    ext = Path(path).suffix.lower().lstrip(".")
    raise PointCloudError(f"{path}: unknown point-cloud format {ext!r}; allowed: "
                          f"{', '.join(f.suffix for f in REGISTRY.values())}")


def write_points(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any],
                 fmt: str | None = None) -> list[Path]:
    """Write ``points`` in ``fmt`` (default: from the extension) plus its JSON sidecar."""
    fmt = fmt or format_of(path)
    _entry(fmt, path).write(path, points, meta)
    return [Path(path), write_sidecar(path, {**meta, "format": fmt, "points": int(len(points))})]


def read_points(path: str | os.PathLike) -> np.ndarray:
    """The POINT_DTYPE records of a point file of any registered format (from its suffix)."""
    return REGISTRY[format_of(path)].read(path)


def registry_table() -> str:
    """Markdown: the registry itself (docs/api.md)."""
    streams = {"frames": "a file per frame", "one_file": "one file, a message per frame", None: "-"}
    rows = ["| format | suffix | media type | streams | what |", "|---|---|---|---|---|"]
    rows += [f"| `{f.name}` | `{f.suffix}` | `{f.media_type}` | {streams[f.stream]} | {f.description} |"
             for f in REGISTRY.values()]
    return "\n".join(rows)
