"""Point files: every format writer and reader behind one registry, the point schema and the sidecar.

=================  ==============================================================================
``schema``         the point record (name, dtype, unit, meaning), the one source of every layout
``registry``       format name -> writer, reader, suffix, media type, stream use; the dispatch
``files``          :func:`atomic_write` and :class:`PointCloudError`, shared by every writer
``sidecar``        the JSON sidecar ``<file>.json``
``ply las npz``    PLY, LAS 1.4, NPZ
``pcd``            PCD v0.7 (PCL, Open3D)
``channels``       the Foxglove topics, shared by the MCAP writers and the live server
``mcap ros2``      MCAP (Foxglove ``foxglove.PointCloud``; rosbag2 ``sensor_msgs/msg/PointCloud2``)
``mcap_stream``    a stream's frames in one MCAP file
=================  ==============================================================================

Importing the package loads numpy only: each writer's library (plyfile, laspy, foxglove, mcap)
loads when its format is written or read.
"""

from __future__ import annotations

from .files import PointCloudError, atomic_write
from .registry import (FORMATS, FRAME_FORMATS, MEDIA_TYPE, REGISTRY, STREAM_FORMATS, FormatSpec, PointFormat,
                       StreamFormat, format_of, read_points, suffix_of, write_points)
from .schema import POINT_DTYPE, POINT_FIELDS, POINT_NAMES
from .sidecar import read_sidecar, scene_identity, sidecar_path, write_sidecar

__all__ = ["FORMATS", "FRAME_FORMATS", "MEDIA_TYPE", "POINT_DTYPE", "POINT_FIELDS", "POINT_NAMES", "REGISTRY",
           "STREAM_FORMATS", "FormatSpec", "PointCloudError", "PointFormat", "StreamFormat", "atomic_write",
           "format_of", "read_points", "read_sidecar", "scene_identity", "sidecar_path", "suffix_of",
           "write_points", "write_sidecar"]
