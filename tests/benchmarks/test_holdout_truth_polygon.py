"""The hold-out truth (benchmarks/holdout_truth.py) intersects non-convex polygons by the even-odd rule:
the CAL letters and any L- or U-shaped target are scored against the outline the scene file gives, not
its convex hull (the convex-only test counted a ray through an L's notch as a hit)."""

import numpy as np

from benchmarks import holdout_truth as ht


def _l_shape(z: float) -> ht.Surface:
    # an L in the plane z: the unit square [0, 2] x [0, 2] without its top-right quarter [1, 2] x [1, 2]
    verts = [[0, 0, z], [2, 0, z], [2, 1, z], [1, 1, z], [1, 2, z], [0, 2, z]]
    return ht.Surface(0, "polygon", {"vertices": verts}, np.zeros(3), 0.0)


def _rays(xy: list[tuple[float, float]], z: float) -> tuple[np.ndarray, np.ndarray]:
    p = np.array([[x, y, z] for x, y in xy])
    return p / np.linalg.norm(p, axis=1, keepdims=True), np.linalg.norm(p, axis=1)


def test_rays_through_an_ls_arms_hit_and_through_its_notch_miss():
    z = 4.0
    d, dist = _rays([(0.5, 0.5), (1.5, 0.5), (0.5, 1.5), (1.5, 1.5), (2.5, 0.5), (-0.5, 0.5)], z)
    r = ht.ranges([_l_shape(z)], d, np.zeros(len(d)))[:, 0]
    np.testing.assert_allclose(r[:3], dist[:3], rtol=1e-12)        # the two arms and the corner
    assert np.all(np.isnan(r[3:]))                                  # the notch, and outside the outline


def test_a_collinear_first_vertex_triple_still_gives_the_plane():
    z = 2.0
    # the first three vertices lie on one line (a square with a vertex on an edge)
    sq = ht.Surface(0, "polygon", {"vertices": [[0, 0, z], [1, 0, z], [2, 0, z], [2, 2, z], [0, 2, z]]},
                    np.zeros(3), 0.0)
    d, dist = _rays([(1.0, 1.0), (3.0, 1.0)], z)
    r = ht.ranges([sq], d, np.zeros(2))[:, 0]
    assert abs(r[0] - dist[0]) < 1e-12 and np.isnan(r[1])


def test_a_tilted_outline_with_collinear_vertices_in_floating_point():
    # z = 3 + 0.3 x: the first three vertices on one edge, their cross product ~1e-16, not 0
    def pt(x, y):
        return [x, y, 3.0 + 0.3 * x]
    sq = ht.Surface(0, "polygon", {"vertices": [pt(0.1, 0.1), pt(0.4, 0.1), pt(0.7, 0.1), pt(0.7, 0.7), pt(0.1, 0.7)]},
                    np.zeros(3), 0.0)
    hits = np.array([pt(0.3, 0.3), pt(0.6, 0.6)])
    d = hits / np.linalg.norm(hits, axis=1, keepdims=True)
    r = ht.ranges([sq], d, np.zeros(2))[:, 0]
    np.testing.assert_allclose(r, np.linalg.norm(hits, axis=1), rtol=1e-12)
