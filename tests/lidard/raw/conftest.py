"""Fixtures: small synthetic raw captures (tests.helpers.raw_capture)."""

from __future__ import annotations

import pytest

from tests.helpers.raw_capture import Synthetic, write_capture


@pytest.fixture
def capture(tmp_path) -> Synthetic:
    return write_capture(tmp_path / "raw.zarr")


@pytest.fixture
def capture_mzi(tmp_path) -> Synthetic:
    return write_capture(tmp_path / "raw_mzi.zarr", n_pix=12, chunk_pixels=5, with_mzi=True, batch=4)


@pytest.fixture
def make_capture(tmp_path):
    """``make_capture(name, **kw)``: :func:`write_capture` under tmp_path."""
    return lambda name, **kw: write_capture(tmp_path / name, **kw)
