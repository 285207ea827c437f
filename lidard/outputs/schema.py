"""The point record: one schema (name, dtype, unit, meaning) for memory, every file format and the docs.

A scan's output is one record per detected return, the per-beam products of the FMCW processing of
dissertation §2.1/§4.4 (range, radial velocity and intensity per beam, the 3D imaging of §4.4.3;
x, y, z in the sensor frame of §4.1.1, +z the optical axis). :data:`POINT_FIELDS` is the single
source of truth: :data:`POINT_DTYPE` (the in-memory record, NPZ's array) is built from it, and so is
every file writer's layout (PLY properties, PCD ``FIELDS/TYPE/SIZE``, the MCAP ``foxglove.PointCloud``
packed fields, ROS 2 ``sensor_msgs/msg/PointField``s, LAS extra bytes) and the field tables of
README.md and docs/api.md (``python tools/gen_point_docs.py`` rewrites them; a test fails when they
drift).

Every field keeps its dtype in every format, so a reader sees the same type everywhere. ``row`` and
``col`` are int32: the one integer width that every target keeps (Open3D drops PLY ``ushort``
properties; PCD, foxglove and ROS 2 all have a 32-bit signed type) and wide enough for any FPSA.

LAS is the exception that must use its own standard dimensions for a few fields
(:data:`LAS_STANDARD`): X/Y/Z are scaled integers, ``gps_time`` is ``t``, ``return_number`` is
``return_index + 1``, ``intensity`` a uint16 display copy of the amplitude, and an invalid point is
withheld and classified as noise (class 7). Every field except x, y, z and t also travels as an extra
byte of its own dtype, so the file holds each value exactly.

Pure: numpy only, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

@dataclass(frozen=True)
class PointField:
    name: str
    dtype: str          # numpy, little-endian
    unit: str           # SI; "" for a count, index or flag
    meaning: str


POINT_FIELDS: tuple[PointField, ...] = (
    PointField("x", "<f4", "m", "sensor frame (§4.1.1), right of the optical axis"),
    PointField("y", "<f4", "m", "sensor frame, up"),
    PointField("z", "<f4", "m", "sensor frame, along the optical axis"),
    PointField("range", "<f4", "m", "distance along the beam"),
    PointField("velocity", "<f4", "m/s", "radial velocity, positive when the target recedes"),
    PointField("intensity", "<f4", "V", "peak amplitude of the beat, ADC volts-equivalent"),
    PointField("snr_db", "<f4", "dB", "peak over local noise (20 log10 of amplitudes)"),
    PointField("row", "<i4", "", "FPSA pixel row of the beam"),
    PointField("col", "<i4", "", "FPSA pixel column of the beam"),
    PointField("return_index", "u1", "", "0 = first (nearest) return of that beam"),
    PointField("t", "<f8", "s", "since scan start (a stream: its first frame's): hardware time of the pixel's first trigger"),
    PointField("valid", "u1", "", "1 = a clean point; 0 = the DSP flagged it (see flags)"),
    PointField("flags", "u1", "", "why not valid, bits: 1 unresolved, 2 aliased, 4 harmonic, "
                                  "8 ambiguous pairing, 16 clipped, 32 out of band (radial speed past the "
                                  "scan's max_speed_mps); 0 on a clean point"),
    PointField("frame", "<i4", "", "frame index inside a stream (0 for a single scan)"),
)

POINT_DTYPE = np.dtype([(f.name, f.dtype) for f in POINT_FIELDS])
FIELD_BY_NAME = {f.name: f for f in POINT_FIELDS}
POINT_NAMES: tuple[str, ...] = tuple(f.name for f in POINT_FIELDS)
# each field's byte offset in a POINT_DTYPE record (the packed layout of the binary formats)
POINT_OFFSETS: dict[str, int] = {name: POINT_DTYPE.fields[name][1] for name in POINT_NAMES}  # type: ignore[index]

# Format type codes of each numpy dtype used above.
PLY_TYPE = {"<f4": "float", "<f8": "double", "<i4": "int", "u1": "uchar"}
PCD_TYPE = {"<f4": ("F", 4), "<f8": ("F", 8), "<i4": ("I", 4), "u1": ("U", 1)}
# foxglove.PackedElementFieldNumericType and sensor_msgs/msg/PointField datatype constants
FOXGLOVE_TYPE = {"u1": 1, "<i4": 6, "<f4": 7, "<f8": 8}
FOXGLOVE_TYPE_NAME = {1: "UINT8", 6: "INT32", 7: "FLOAT32", 8: "FLOAT64"}
ROS2_TYPE = {"u1": 2, "<i4": 5, "<f4": 7, "<f8": 8}
ROS2_TYPE_NAME = {2: "UINT8", 5: "INT32", 7: "FLOAT32", 8: "FLOAT64"}

# LAS 1.4 point format 6: where a field goes besides (or instead of) its extra byte
LAS_STANDARD = {
    "x": "X (scaled int32, 0.1 mm; offset at the cloud's minimum)",
    "y": "Y (as X)",
    "z": "Z (as X)",
    "t": "gps_time (float64)",
    "return_index": "return_number = return_index + 1 (clipped to 15); number_of_returns per pixel",
    "intensity": "intensity (uint16) = amplitude / volts-per-count, peak at half scale (VLR lidard/1)",
    "valid": "valid 0: classification 7 (noise) and the withheld flag; 1: classification 1",
}
# extra-bytes name of a field when it differs (LAS owns the name ``intensity``)
LAS_EXTRA_NAME = {"intensity": "amplitude"}
LAS_EXTRA_FIELDS = tuple(f.name for f in POINT_FIELDS if f.name not in ("x", "y", "z", "t"))


def las_extra_name(field: str) -> str:
    return LAS_EXTRA_NAME.get(field, field)


def las_description(f: PointField) -> str:
    """The extra byte's 32-byte LAS description: unit and name."""
    return (f"{f.name} [{f.unit}]" if f.unit else f.name)[:31]


# ----------------------------------------------------------------------------------- doc tables
def fields_table() -> str:
    """Markdown: the schema itself."""
    rows = ["| field | dtype | unit | meaning |", "|---|---|---|---|"]
    rows += [f"| `{f.name}` | {np.dtype(f.dtype).name} | {f.unit or '-'} | {f.meaning} |" for f in POINT_FIELDS]
    return "\n".join(rows)


def formats_table() -> str:
    """Markdown: how each field is typed in each file format."""
    rows = ["| field | PLY | PCD | MCAP `foxglove.PointCloud` | ROS 2 `PointField` | LAS 1.4 |",
            "|---|---|---|---|---|---|"]
    for f in POINT_FIELDS:
        pcd = "{}{}".format(*PCD_TYPE[f.dtype])
        las = []
        if f.name in LAS_STANDARD:
            las.append(LAS_STANDARD[f.name])
        if f.name in LAS_EXTRA_FIELDS:
            las.append(f"extra byte `{las_extra_name(f.name)}` ({np.dtype(f.dtype).name})")
        rows.append(f"| `{f.name}` | {PLY_TYPE[f.dtype]} | {pcd} | {FOXGLOVE_TYPE_NAME[FOXGLOVE_TYPE[f.dtype]]} "
                    f"| {ROS2_TYPE_NAME[ROS2_TYPE[f.dtype]]} | {'; '.join(las)} |")
    return "\n".join(rows)
