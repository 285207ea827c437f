"""The point-file registry is the one list of formats: the API's request models, lidarctl's choices and
the suffix parsing all follow it, and a format outside it is refused with the allowed ones named."""

import argparse
from typing import get_args

import numpy as np
import pytest
from pydantic import ValidationError

from lidard.api.routers.streams import StreamCreate
from lidard.api.schemas import ScanCreate
from lidard.cli.lidarctl import build_parser
from lidard.instrument.types import OutputFormat
from lidard.outputs import (FORMATS, FRAME_FORMATS, REGISTRY, STREAM_FORMATS, PointCloudError, format_of,
                            suffix_of, write_points)
from lidard.outputs.registry import PointFormat, StreamFormat


def test_the_static_literals_are_the_registry():
    assert get_args(PointFormat) == tuple(REGISTRY) == FORMATS
    assert get_args(OutputFormat) == FORMATS
    assert set(get_args(StreamFormat)) == {f.name for f in REGISTRY.values() if f.stream is not None}
    assert set(FRAME_FORMATS) == {f.name for f in REGISTRY.values() if f.stream == "frames"}


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_suffix_parses_back_to_its_format(fmt):
    assert format_of(f"/tmp/scan{suffix_of(fmt)}") == fmt
    assert format_of(f"/tmp/SCAN{suffix_of(fmt).upper()}") == fmt


def test_an_unknown_suffix_or_format_names_the_allowed_ones(tmp_path):
    with pytest.raises(PointCloudError, match=r"'xyz'.*\.ply.*\.ros2\.mcap"):
        format_of(tmp_path / "scan.xyz")
    with pytest.raises(PointCloudError, match=r"'xyz'.*ply, las, npz, pcd, mcap, ros2"):
        write_points(tmp_path / "scan.ply", np.zeros(0), {}, fmt="xyz")
    assert not list(tmp_path.iterdir())   # nothing half-written


def test_the_api_accepts_exactly_the_registry():
    assert ScanCreate(formats=list(FORMATS)).formats == list(FORMATS)
    with pytest.raises(ValidationError, match="ros2"):
        ScanCreate(formats=["xyz"])
    for fmt in STREAM_FORMATS:
        assert StreamCreate(format=fmt).format == fmt
    with pytest.raises(ValidationError):
        StreamCreate(format="ros2")   # a rosbag2 file is written per scan, not per stream


def _choices(parser: argparse.ArgumentParser, command: str, option: str) -> list[str]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    action = next(a for a in sub.choices[command]._actions if option in a.option_strings)
    return list(action.choices)


def test_lidarctl_offers_the_registry():
    parser = build_parser()
    assert _choices(parser, "stream", "--format") == list(FRAME_FORMATS)
    assert _choices(parser, "scans", "--format") == list(FORMATS)


def test_the_registry_loads_a_writer_library_only_when_its_format_is_used(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys, lidard.outputs, lidard.api.schemas; "
            "libs = ('plyfile', 'laspy', 'foxglove', 'mcap'); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in libs)); "
            "import numpy as np; from lidard.outputs import POINT_DTYPE, write_points; "
            f"write_points({str(tmp_path / 'a.ply')!r}, np.zeros(2, POINT_DTYPE), {{}}); "
            "print(sorted({m.split('.')[0] for m in sys.modules if m.split('.')[0] in libs}))")
    root = Path(__file__).resolve().parents[3]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == ["[]", "['plyfile']"]
