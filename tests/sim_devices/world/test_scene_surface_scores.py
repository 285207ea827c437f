"""Scene.surface_distance and Scene.range_error: scores against the true surfaces (issue 13 item 3)."""

import numpy as np

from sim_devices.world.scene import Scene

WALL_AND_BALL = {"target": [
    {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1]},
    {"kind": "sphere", "center": [0.3, 0, 1.0], "radius": 0.1},
]}


def test_surface_distance_is_the_nearest_surface():
    sc = Scene.from_dict(WALL_AND_BALL)
    pts = np.array([[0.0, 0.5, 2.01],     # 1 cm behind the wall (the ball is far)
                    [0.3, 0.0, 0.88],     # 2 cm in front of the ball (wall 1.12 m away)
                    [0.3, 0.0, 1.0]])     # the ball's centre: 0.1 to its skin
    np.testing.assert_allclose(sc.surface_distance(pts), [0.01, 0.02, 0.1], rtol=1e-9)


def test_range_error_along_the_points_own_ray():
    sc = Scene.from_dict(WALL_AND_BALL)
    # on the axis the ray meets the wall at 2 m; off-axis at angle a it meets it at 2 / cos a
    a = np.radians(5.0)
    d = np.array([[0, 0, 1.0], [np.sin(a), 0, np.cos(a)]])
    r_meas = np.array([2.003, 2.0 / np.cos(a) - 0.001])
    pts = d * r_meas[:, None]
    np.testing.assert_allclose(sc.range_error(pts), [0.003, -0.001], atol=1e-12)
    # a ray that misses everything (backwards) is NaN
    assert np.isnan(sc.range_error(np.array([[0, 0, -1.0]])))[0]


def test_sideways_displacement_off_a_letter_shows_in_the_surface_distance():
    # a 10 mm wide polygon stroke at z = 0.8 in front of a background at 0.9: a point measured at the
    # right depth but 3 mm beside the stroke is 3 mm from the letter (and 0.1 m from the background)
    sc = Scene.from_dict({"target": [
        {"kind": "polygon", "vertices": [[-0.005, -0.03, 0.8], [0.005, -0.03, 0.8], [0.005, 0.03, 0.8],
                                         [-0.005, 0.03, 0.8]]},
        {"kind": "plane", "point": [0, 0, 0.9], "normal": [0, 0, -1]}]})
    np.testing.assert_allclose(sc.surface_distance(np.array([[0.008, 0.0, 0.8], [0.0, 0.0, 0.8]])),
                               [0.003, 0.0], atol=1e-12)
