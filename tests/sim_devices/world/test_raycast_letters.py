"""The "CAL" letters scene (§4.4.3): strokes hit the letters, counters and gaps hit the background.

Probe points are worked out by hand from the letter geometry documented in cal_letters.toml
(60 mm tall letters, 10 mm strokes; C centred at x = -48 mm, A at 0, L at +46 mm; z = 0.8 m;
cardboard background at z = 0.9 m).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sim_devices.world.scene import PolygonTarget, Scene

SCENES = Path(__file__).resolve().parents[3] / "config" / "scenes"
C, A_LEGS, A_BAR, L, BACKGROUND = range(5)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene.from_toml(SCENES / "cal_letters.toml")


def _rays_through(points_mm: list[tuple[float, float]], z_m: float = 0.8) -> np.ndarray:
    p = np.array([[x / 1000, y / 1000, z_m] for x, y in points_mm])
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _lens_directions(nx: int, ny: int, f_m: float = 25e-3, fov_deg: float = 16.0) -> np.ndarray:
    """Eq. 4-1: antenna offset (x, y) behind the lens -> direction (-x/f, -y/f, 1) normalised."""
    pitch_m = 2 * f_m * math.tan(math.radians(fov_deg / 2)) / 128
    x = (np.arange(nx) - (nx - 1) / 2) * pitch_m
    y = (np.arange(ny) - (ny - 1) / 2) * pitch_m
    xx, yy = np.meshgrid(x, y)
    d = np.column_stack([-xx.ravel() / f_m, -yy.ravel() / f_m, np.ones(xx.size)])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


STROKES = [
    ((-65.0, 0.0), C),  # left side of the C ring (outer rx 22, inner rx 12 around x = -48)
    ((-48.0, 25.0), C),  # top of the C
    ((-48.0, -25.0), C),  # bottom of the C
    ((-8.0, 0.0), A_LEGS),  # left leg of the A at mid height: x in [-13, -3] mm
    ((8.0, 0.0), A_LEGS),  # right leg
    ((0.0, 27.0), A_LEGS),  # apex
    ((0.0, -8.0), A_BAR),  # crossbar centre (between the legs' inner edges, +-5.4 mm)
    ((34.0, 10.0), L),  # L stem
    ((55.0, -25.0), L),  # L foot
]

HOLES = [
    (-40.0, 0.0),  # inside the C's opening (inner rx 12 around x = -48; opening toward +x)
    (-48.0, 0.0),  # centre of the C
    (-25.0, 0.0),  # between C and A
    (0.0, 0.0),  # the A's counter (inner edges at +-3 mm at y = 0; crossbar below y = -4)
    (0.0, 4.0),  # higher in the counter (apex of the counter at y = 10 mm)
    (0.0, -20.0),  # between the A's feet, below the crossbar
    (22.0, 10.0),  # between A and L
    (50.0, 0.0),  # in the L's notch (stem x <= 39, foot y <= -20)
    (0.0, 45.0),  # above the letters
]


@pytest.mark.parametrize(("point_mm", "letter"), STROKES)
def test_rays_through_strokes_hit_the_letter_first(scene: Scene, point_mm, letter: int) -> None:
    d = _rays_through([point_mm])
    hits = scene.cast(d)
    assert hits.count[0] == 1  # letters are opaque: the background behind is hidden
    assert hits.target_index[0, 0] == letter
    assert hits.reflectivity[0, 0] == 2.0
    x, y = point_mm[0] / 1000, point_mm[1] / 1000
    assert math.isclose(hits.range_m[0, 0], math.sqrt(x * x + y * y + 0.8**2), rel_tol=1e-12)
    # Incidence on the z = 0.8 plane equals the ray's angle off the optical axis.
    assert math.isclose(hits.incidence_rad[0, 0], math.acos(d[0, 2]), abs_tol=1e-9)


@pytest.mark.parametrize("point_mm", HOLES)
def test_rays_through_counters_and_gaps_hit_the_background(scene: Scene, point_mm) -> None:
    hits = scene.cast(_rays_through([point_mm]))
    assert hits.count[0] == 1
    assert hits.target_index[0, 0] == BACKGROUND
    assert hits.reflectivity[0, 0] == pytest.approx(0.1)
    x, y = point_mm[0] / 1000 * 0.9 / 0.8, point_mm[1] / 1000 * 0.9 / 0.8
    assert math.isclose(hits.range_m[0, 0], math.sqrt(x * x + y * y + 0.9**2), rel_tol=1e-12)


def test_crossbar_overlapping_a_leg_is_a_tie_won_by_the_legs(scene: Scene) -> None:
    """At (-8, -8) mm both A pieces lie on z = 0.8: the chevron is listed first and wins."""
    hits = scene.cast(_rays_through([(-8.0, -8.0)]))
    assert hits.target_index[0].tolist() == [A_LEGS, -1, -1, -1]


def test_letters_are_non_convex(scene: Scene) -> None:
    """The convex hull of each of C, A-legs and L contains points that are not in the letter."""
    hull_points_mm = {C: (-40.0, 0.0), A_LEGS: (0.0, 0.0), L: (50.0, 0.0)}
    for idx, p in hull_points_mm.items():
        tg = scene.targets[idx]
        assert isinstance(tg, PolygonTarget)
        hits = scene.cast(_rays_through([p]))
        assert hits.target_index[0, 0] != idx


def test_scan_of_128x96_beams_sees_three_letters_and_background(scene: Scene) -> None:
    d = _lens_directions(128, 96)
    hits = scene.cast(d)
    first = hits.target_index[:, 0]
    assert np.all(hits.count == 1)  # background covers the whole FoV; letters are opaque
    counts = np.bincount(first, minlength=5)
    assert np.all(counts > 0)
    # Letter areas (mm^2) from the drawn shapes, divided by the beam footprint at 0.8 m
    # (pitch / f * 0.8 m)^2, give the expected beam counts within pixelation error.
    footprint_mm = 2 * 25 * math.tan(math.radians(8)) / 128 / 25 * 800
    area_l = 10 * 60 + 24 * 10
    assert counts[L] == pytest.approx(area_l / footprint_mm**2, rel=0.15)
    # A: chevron = outer triangle-ish legs; compare the two A pieces against the shoelace area
    legs = scene.targets[A_LEGS].vertices_2d
    x, y = legs[:, 0], legs[:, 1]
    area_legs_mm2 = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) * 1e6
    assert counts[A_LEGS] == pytest.approx(area_legs_mm2 / footprint_mm**2, rel=0.15)
    # Letters (0.8 m) and background (0.9 m) ranges are separated by ~0.1 m.
    letter = first < BACKGROUND
    assert np.all(hits.range_m[letter, 0] < 0.82)
    assert np.all(hits.range_m[~letter, 0] > 0.89)


def test_staggered_letters_depths() -> None:
    """Fig. 4-33, letters on different planes: the on-axis depth of each letter differs."""
    scene = Scene.from_toml(SCENES / "cal_letters_staggered.toml")
    hits = scene.cast(_rays_through([(-65.0, 0.0), (-8.0, 0.0), (34.0, 10.0)], z_m=0.8))
    assert hits.target_index[:, 0].tolist() == [C, A_LEGS, L]
    z = hits.points_m[:, 0, 2]
    assert np.allclose(z, [0.78, 0.80, 0.82], atol=1e-12)
