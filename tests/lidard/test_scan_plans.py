"""Scan plans: bonded rows only, serpentine order, ROI bounds, pixel-list validation, adaptive."""

import numpy as np
import pytest

from lidard.config import load_profile
from lidard.instrument import POINT_DTYPE, ScanRequest
from lidard.instrument.plan import ScanPlanError, adaptive_plans, plan, planned_pixel_count


@pytest.fixture(scope="module")
def optics128():
    return load_profile("fpsa128").optics()


@pytest.fixture(scope="module")
def optics20():
    return load_profile("fpsa20").optics()


def test_raster_visits_only_bonded_rows(optics128):
    p = plan(ScanRequest(pattern="raster"), optics128)
    # §4.3.3: one row in four unbonded -> 96 x 128 pixels, rows 3, 7, 11, ... never visited
    assert p.shape == (96 * 128, 2)
    assert p.dtype.kind == "i"
    assert not np.any(p[:, 0] % 4 == 3)
    assert set(np.unique(p[:, 0])) == set(range(128)) - set(range(3, 128, 4))
    # row-major, left to right
    assert np.all(p[:128, 0] == 0) and np.array_equal(p[:128, 1], np.arange(128))
    assert np.array_equal(p[128:256, 1], np.arange(128))


def test_serpentine_alternates_direction(optics20):
    p = plan(ScanRequest(pattern="serpentine", rows=(2, 5), cols=(0, 4)), optics20)
    expected = [(2, 0), (2, 1), (2, 2), (2, 3), (3, 3), (3, 2), (3, 1), (3, 0), (4, 0), (4, 1), (4, 2), (4, 3)]
    assert [tuple(x) for x in p] == expected
    steps = np.abs(np.diff(p, axis=0)).sum(axis=1)
    assert np.all(steps == 1)  # always a neighbour


def test_serpentine_skips_unbonded_rows(optics128):
    p = plan(ScanRequest(pattern="serpentine", rows=(0, 8), cols=(0, 3)), optics128)
    assert sorted(set(p[:, 0].tolist())) == [0, 1, 2, 4, 5, 6]
    # the alternation counts scanned rows, not row numbers: row 4 is the 4th scanned row -> reversed
    assert p[p[:, 0] == 4][:, 1].tolist() == [2, 1, 0]
    assert p[p[:, 0] == 5][:, 1].tolist() == [0, 1, 2]


def test_roi_bounds_are_half_open(optics20):
    p = plan(ScanRequest(pattern="roi", rows=(5, 8), cols=(10, 20)), optics20)
    assert p[:, 0].min() == 5 and p[:, 0].max() == 7
    assert p[:, 1].min() == 10 and p[:, 1].max() == 19
    assert len(p) == 3 * 10


@pytest.mark.parametrize("rows,cols,word", [((0, 21), None, "rows"), ((5, 5), None, "rows"),
                                             (None, (-1, 3), "cols"), ((3, 2), None, "rows")])
def test_roi_out_of_bounds_is_an_error_naming_the_field(optics20, rows, cols, word):
    with pytest.raises(ScanPlanError, match=word):
        plan(ScanRequest(pattern="roi", rows=rows, cols=cols), optics20)


def test_roi_needs_a_range(optics20):
    with pytest.raises(ScanPlanError, match="roi"):
        plan(ScanRequest(pattern="roi"), optics20)


def test_roi_with_only_unbonded_rows_is_rejected(optics128):
    with pytest.raises(ScanPlanError, match="wire-bonded"):
        plan(ScanRequest(pattern="roi", rows=(3, 4)), optics128)


def test_pixel_list_keeps_order(optics128):
    px = ((10, 5), (0, 127), (10, 5), (126, 0))
    p = plan(ScanRequest(pattern="pixels", pixels=px), optics128)
    assert [tuple(x) for x in p] == list(px)


def test_pixel_list_unbonded_pixel_is_named(optics128):
    with pytest.raises(ScanPlanError, match=r"pixels\[1\].*\(7, 9\).*not wire-bonded"):
        plan(ScanRequest(pattern="pixels", pixels=((0, 0), (7, 9))), optics128)


def test_pixel_list_outside_array_is_named(optics20):
    with pytest.raises(ScanPlanError, match=r"\(3, 20\).*outside"):
        plan(ScanRequest(pattern="pixels", pixels=((3, 20),)), optics20)


def test_pixels_with_other_pattern_rejected(optics20):
    with pytest.raises(ScanPlanError, match="pixels"):
        plan(ScanRequest(pattern="raster", pixels=((0, 0),)), optics20)


def _points_at(pixels):
    pts = np.zeros(len(pixels), dtype=POINT_DTYPE)
    for i, (r, c) in enumerate(pixels):
        pts[i]["row"], pts[i]["col"], pts[i]["valid"], pts[i]["range"] = r, c, 1, 1.0
    return pts


def test_adaptive_coarse_pass_is_every_fourth_bonded_row_and_col(optics128):
    req = ScanRequest(pattern="adaptive", rows=(0, 32), cols=(0, 32))
    coarse = next(adaptive_plans(req, optics128))
    bonded = [r for r in range(32) if r % 4 != 3]          # 24 bonded rows
    assert sorted(set(coarse[:, 0].tolist())) == bonded[::4]
    assert sorted(set(coarse[:, 1].tolist())) == list(range(0, 32, 4))
    assert np.array_equal(plan(req, optics128), coarse)
    assert planned_pixel_count(req, optics128) == 24 * 32


def test_adaptive_refines_only_cells_with_returns(optics20):
    req = ScanRequest(pattern="adaptive")
    gen = adaptive_plans(req, optics20, margin_cells=0)
    coarse = next(gen)
    assert len(coarse) == 5 * 5
    dense = gen.send(_points_at([(8, 12)]))               # one return, in cell (2, 3)
    assert len(dense) == 4 * 4 - 1                          # the cell minus its already-scanned corner
    assert dense[:, 0].min() == 8 and dense[:, 0].max() == 11
    assert dense[:, 1].min() == 12 and dense[:, 1].max() == 15
    assert (8, 12) not in {tuple(x) for x in dense}


def test_adaptive_margin_includes_neighbour_cells(optics20):
    gen = adaptive_plans(ScanRequest(pattern="adaptive"), optics20, margin_cells=1)
    next(gen)
    dense = gen.send(_points_at([(0, 0)]))
    # cell (0,0) plus its neighbours (0,1), (1,0), (1,1): rows 0..7, cols 0..7, minus 4 coarse pixels
    assert len(dense) == 8 * 8 - 4
    assert dense[:, 0].max() == 7 and dense[:, 1].max() == 7


def test_adaptive_no_returns_no_dense_pass_and_invalid_points_ignored(optics20):
    gen = adaptive_plans(ScanRequest(pattern="adaptive"), optics20)
    next(gen)
    pts = _points_at([(4, 4)])
    pts["valid"] = 0
    assert len(gen.send(pts)) == 0
