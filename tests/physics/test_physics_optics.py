"""FPSA optics against the dissertation's numbers (§4.2.1 eqs. 4-17..4-19, §4.3.1 eqs. 4-20..4-22, §4.4.1)."""

import numpy as np
import pytest
from hypothesis import given, strategies as st

from lidard.config import load_profile
from lidard.physics.optics import FpsaOptics, bonded_rows_skip


def _round(x, nd):
    return round(float(x), nd)


def test_fpsa20_matches_eqs_4_17_to_4_19():
    o = load_profile("fpsa20").optics()
    assert _round(o.fov_deg[0], 0) == 32          # eq. 4-17
    assert _round(o.resolution_deg[0], 1) == 1.7  # eq. 4-18
    assert _round(o.divergence_deg[0], 3) == 0.064  # eq. 4-19
    assert o.rows == o.cols == 20 and len(o.bonded_rows) == 20


def test_fpsa128_compound_5mm_matches_eqs_4_20_to_4_22():
    o = load_profile("fpsa128").optics("compound_5mm")
    assert _round(o.fov_deg[0], 0) == 70
    assert _round(o.resolution_deg[0], 1) == 0.6
    assert _round(o.divergence_deg[0], 2) == 0.05


def test_fpsa128_lidar_lens_matches_section_4_4_1():
    o = load_profile("fpsa128").optics("lidar_25mm")
    assert _round(o.fov_deg[0], 0) == 16
    assert _round(o.resolution_deg[0], 2) == 0.13


def test_gaussian_fwhm_is_1_18_w_over_f():
    o = load_profile("fpsa128").optics("compound_5mm")
    ratio = o.gaussian_fwhm_deg[0] / o.divergence_deg[0]
    assert ratio == pytest.approx(np.sqrt(2 * np.log(2)), rel=1e-12)
    assert _round(ratio, 2) == 1.18


def test_96_of_128_rows_bonded_one_in_four_skipped():
    rows = load_profile("fpsa128").bonded_rows
    assert len(rows) == 96
    skipped = sorted(set(range(128)) - set(rows))
    assert len(skipped) == 32 and all(b - a == 4 for a, b in zip(skipped, skipped[1:]))


def test_beam_angle_is_minus_arctan_x_over_f():
    o = FpsaOptics(rows=5, cols=5, pitch_m=1e-3, emission_w_m=5e-6, focal_m=10e-3)
    tx, ty = o.beam_angles_rad(2, 4)  # centre row, rightmost column: x = +2 mm
    assert tx == pytest.approx(-np.arctan(2e-3 / 10e-3))
    assert ty == pytest.approx(0.0)
    d = o.directions(2, 4)
    assert np.arctan2(d[0], d[2]) == pytest.approx(tx)
    # edge resolution is finer than the centre's, eq. 4-3
    assert o.resolution_at_deg(2e-3) < o.resolution_at_deg(0.0)


@given(st.integers(0, 127), st.integers(0, 127))
def test_direction_pixel_round_trip(row, col):
    o = load_profile("fpsa128").optics()
    d = o.directions(row, col)
    assert np.linalg.norm(d) == pytest.approx(1.0)
    r, c = o.pixel_from_direction(d)
    assert (int(r), int(c)) == (row, col)


def test_fov_spans_the_outermost_beams():
    o = load_profile("fpsa128").optics()
    tx0, _ = o.beam_angles_rad(0, 0)
    tx1, _ = o.beam_angles_rad(0, 127)
    assert np.degrees(abs(tx1 - tx0)) == pytest.approx(o.fov_deg[0], rel=1e-12)


def test_bad_geometry_is_refused_with_the_field_named():
    with pytest.raises(ValueError, match="focal_m"):
        FpsaOptics(rows=4, cols=4, pitch_m=1e-4, emission_w_m=5e-6, focal_m=0.0)
    assert bonded_rows_skip(8, 4, 3) == (0, 1, 2, 4, 5, 6)
