"""Point-to-surface distances (lidard.physics.surfaces) against closed forms worked by hand."""

import numpy as np
import pytest

from lidard.physics import surfaces as sf


def test_plane_infinite_and_signed():
    pts = np.array([[0.0, 0.0, 1.0], [3.0, -2.0, 0.5], [1.0, 1.0, -0.25]])
    # plane z = 0.5, normal +z (given unnormalised): distance is |z - 0.5|
    d = sf.distance_to_plane(pts, origin=[7.0, 1.0, 0.5], normal=[0, 0, 2.0])
    np.testing.assert_allclose(d, [0.5, 0.0, 0.75], atol=1e-15)
    s = sf.distance_to_plane(pts, [0, 0, 0.5], [0, 0, 1], signed=True)
    np.testing.assert_allclose(s, [0.5, 0.0, -0.75], atol=1e-15)


def test_plane_tilted_closed_form():
    # plane x + y + z = 1: distance |x + y + z - 1| / sqrt(3)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(20, 3))
    d = sf.distance_to_plane(pts, [1.0, 0, 0], [1, 1, 1])
    np.testing.assert_allclose(d, np.abs(pts.sum(axis=1) - 1) / np.sqrt(3), rtol=1e-12)


def test_finite_plane_beside_the_rectangle():
    # 0.4 x 0.2 rectangle at z = 1 facing -z, up = +y: half extents 0.2 (x), 0.1 (y)
    o, n = [0, 0, 1.0], [0, 0, -1]
    pts = np.array([[0.1, 0.05, 1.3],      # above the inside: perpendicular 0.3
                    [0.5, 0.0, 1.0],       # in-plane, 0.3 beyond the x edge
                    [0.5, 0.5, 1.4]])      # beyond a corner: (0.3, 0.4, 0.4)
    d = sf.distance_to_plane(pts, o, n, size=(0.4, 0.2))
    np.testing.assert_allclose(d, [0.3, 0.3, np.sqrt(0.09 + 0.16 + 0.16)], rtol=1e-12)


def test_sphere():
    pts = np.array([[0, 0, 3.0], [0, 0, 2.5], [1.0, 0, 2.0]])
    d = sf.distance_to_sphere(pts, [0, 0, 2.0], 0.5)
    np.testing.assert_allclose(d, [0.5, 0.0, 0.5], atol=1e-15)
    s = sf.distance_to_sphere(np.array([[0, 0, 2.0], [0, 0, 4.0]]), [0, 0, 2.0], 0.5, signed=True)
    np.testing.assert_allclose(s, [-0.5, 1.5])
    with pytest.raises(ValueError, match="radius"):
        sf.distance_to_sphere(pts, [0, 0, 0], -1.0)


def test_box_axis_aligned_and_rotated():
    size = (2.0, 1.0, 0.5)           # half extents 1, 0.5, 0.25
    pts = np.array([[3.0, 0, 0],     # 2 beyond the +x face
                    [0, 0, 0],       # centre: nearest face is z at 0.25
                    [2.0, 1.5, 0],   # beyond an edge: (1, 1, 0) -> sqrt 2
                    [0.9, 0, 0]])    # inside, 0.1 from the +x face
    np.testing.assert_allclose(sf.distance_to_box(pts, [0, 0, 0], size), [2.0, 0.25, np.sqrt(2), 0.1],
                               rtol=1e-12)
    # rotated 90 deg about z (box-local x -> sensor y): a point at (0, 3, 0) is 2 beyond the long face
    rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    centre = np.array([1.0, 2.0, 3.0])
    d = sf.distance_to_box(centre + np.array([[0, 3.0, 0], [3.0, 0, 0]]), centre, size, rz)
    np.testing.assert_allclose(d, [2.0, 2.5], rtol=1e-12)
    assert sf.distance_to_box(np.zeros((1, 3)), [0, 0, 0], size, signed=True)[0] == pytest.approx(-0.25)


def test_polygon_non_convex_L():
    # an L in the plane z = 2: [0,3]x[0,1] union [0,1]x[0,3]; the notch corner (1, 1) is concave
    L = np.array([[0, 0, 2], [3, 0, 2], [3, 1, 2], [1, 1, 2], [1, 3, 2], [0, 3, 2.0]])
    pts = np.array([[0.5, 0.5, 2.2],    # over the L: perpendicular 0.2
                    [2.0, 2.0, 2.0],    # in the notch, in-plane: nearest edge point (2, 1) or (1, 2): 1
                    [2.0, 2.0, 2.75],   # same, 0.75 off the plane: hypot(1, 0.75)
                    [4.0, 0.5, 2.0],    # beyond the right end: 1
                    [-3.0, -4.0, 2.0]])  # beyond corner (0, 0): 5
    d = sf.distance_to_polygon(pts, L)
    np.testing.assert_allclose(d, [0.2, 1.0, 1.25, 1.0, 5.0], rtol=1e-12, atol=1e-15)
    # the same in a tilted frame: distances do not depend on the frame
    rot = np.array([[np.cos(0.3), 0, np.sin(0.3)], [0, 1, 0], [-np.sin(0.3), 0, np.cos(0.3)]])
    np.testing.assert_allclose(sf.distance_to_polygon(pts @ rot.T, L @ rot.T), d, rtol=1e-12, atol=1e-12)


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="points must have shape"):
        sf.distance_to_plane(np.zeros((4, 2)), [0, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match="normal"):
        sf.distance_to_plane(np.zeros((1, 3)), [0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="orthonormal"):
        sf.distance_to_box(np.zeros((1, 3)), [0, 0, 0], (1, 1, 1), np.ones((3, 3)))
