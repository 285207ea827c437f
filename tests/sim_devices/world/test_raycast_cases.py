"""Hand-worked ray-casting cases: ties, inside/behind rules, bounded planes, boxes, arguments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.world.raycast import RayError, cast
from sim_devices.world.scene import Scene

Z = np.array([[0.0, 0.0, 1.0]])


def _unit(*v: float) -> np.ndarray:
    a = np.array(v, dtype=float)
    return (a / np.linalg.norm(a))[None, :]


def _scene(*targets: dict) -> Scene:
    return Scene.from_dict({"target": list(targets)}, source="case")


def _square(z: float, half: float = 0.1, **extra) -> dict:
    return {
        "kind": "polygon",
        "vertices": [[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]],
        **extra,
    }


WALL = {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1]}


def test_plane_range_and_incidence_for_tilted_ray() -> None:
    """Ray at angle a to the normal of z = 2: range 2 / cos a, incidence a."""
    a = math.radians(7.0)
    hits = _scene(WALL).cast(_unit(math.sin(a), 0, math.cos(a)))
    assert math.isclose(hits.range_m[0, 0], 2.0 / math.cos(a), rel_tol=1e-14)
    assert math.isclose(hits.incidence_rad[0, 0], a, rel_tol=1e-9)


def test_plane_behind_sensor_and_parallel_rays_miss() -> None:
    behind = _scene({"kind": "plane", "point": [0, 0, -1.0], "normal": [0, 0, 1]})
    assert behind.cast(Z).count[0] == 0
    assert _scene(WALL).cast(_unit(1, 0, 0)).count[0] == 0  # parallel to the wall


def test_target_through_origin_is_ignored() -> None:
    """A hit at range 0 (surface through the lens centre) is not a return."""
    scene = _scene({"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, -1]}, WALL)
    hits = scene.cast(Z)
    assert hits.count[0] == 1 and hits.target_index[0, 0] == 1


def test_bounded_plane_width_across_up_and_height_along_up() -> None:
    """size = [w, h]: w = 0.4 along x (perpendicular to up = +y), h = 0.1 along y."""
    scene = _scene({**WALL, "size": [0.4, 0.1]})
    z = 2.0
    d = np.vstack([_unit(0.19, 0, z), _unit(0.21, 0, z), _unit(0, 0.04, z), _unit(0, 0.06, z)])
    assert scene.cast(d).count.tolist() == [1, 0, 1, 0]
    # Rotating `up` to +x swaps the roles of the two sides.
    rotated = _scene({**WALL, "size": [0.4, 0.1], "up": [1, 0, 0]})
    d2 = np.vstack([_unit(0.04, 0, z), _unit(0.06, 0, z), _unit(0, 0.19, z), _unit(0, 0.21, z)])
    assert rotated.cast(d2).count.tolist() == [1, 0, 1, 0]


def test_box_rotated_about_y_incidence_equals_rotation() -> None:
    """Cube rotated by 30 deg about y: the +z ray enters the face whose normal is 30 deg off."""
    scene = _scene({"kind": "box", "center": [0, 0, 3.0], "size": [0.2, 0.2, 0.2],
                    "rotation_deg": [0, 30, 0]})
    hits = scene.cast(Z)
    assert math.isclose(hits.incidence_rad[0, 0], math.radians(30), rel_tol=1e-12)
    # Entry face at distance 0.1 from the centre along its normal n: t = 3 - 0.1 / cos 30.
    assert math.isclose(hits.range_m[0, 0], 3.0 - 0.1 / math.cos(math.radians(30)), rel_tol=1e-14)


def test_box_axis_aligned_front_face() -> None:
    scene = _scene({"kind": "box", "center": [0.05, 0, 3.0], "size": [0.4, 0.3, 1.0]})
    hits = scene.cast(Z)
    assert math.isclose(hits.range_m[0, 0], 2.5, rel_tol=1e-15)
    assert hits.incidence_rad[0, 0] == 0.0


def test_box_behind_origin_misses_and_box_containing_origin_returns_exit_wall() -> None:
    behind = _scene({"kind": "box", "center": [0, 0, -3.0], "size": [1, 1, 1]})
    assert behind.cast(Z).count[0] == 0
    room = _scene({"kind": "box", "center": [0, 0, 1.0], "size": [4, 4, 6]})  # z from -2 to 4
    hits = room.cast(np.vstack([Z, -Z[0], _unit(1, 0, 0)]))
    assert hits.range_m[:, 0].tolist() == [4.0 - 0.0, 2.0, 2.0]
    assert np.all(hits.incidence_rad[:, 0] == 0.0)


def test_sphere_containing_origin_returns_far_wall() -> None:
    scene = _scene({"kind": "sphere", "center": [0, 0, 0.5], "radius": 2.0})
    hits = scene.cast(np.vstack([Z, -Z[0]]))
    assert np.allclose(hits.range_m[:, 0], [2.5, 1.5], rtol=1e-15)
    assert np.allclose(hits.incidence_rad[:, 0], 0.0)


def test_sphere_tangent_ray_and_miss() -> None:
    scene = _scene({"kind": "sphere", "center": [0.5, 0, 2.0], "radius": 0.5})
    hits = scene.cast(np.vstack([Z, _unit(-0.01, 0, 1)]))
    assert hits.count.tolist() == [1, 0]
    assert math.isclose(hits.range_m[0, 0], 2.0, rel_tol=1e-12)
    assert math.isclose(hits.incidence_rad[0, 0], math.pi / 2, rel_tol=1e-9)


def test_coplanar_tie_first_listed_target_wins() -> None:
    """A letter lying on its background plane: the first listed of the two is the (only) hit."""
    letter_first = _scene(_square(2.0, reflectivity=2.0), WALL)
    plane_first = _scene(WALL, _square(2.0, reflectivity=2.0))
    h1, h2 = letter_first.cast(Z), plane_first.cast(Z)
    assert h1.target_index[0].tolist() == [0, -1, -1, -1] and h1.reflectivity[0, 0] == 2.0
    assert h2.target_index[0].tolist() == [0, -1, -1, -1] and h2.reflectivity[0, 0] == 0.1


def test_near_tie_within_tolerance_and_clear_order_beyond_it() -> None:
    # Letter listed second but 0.5 nm nearer: within 1e-9 m, so the first listed (wall) wins.
    near_tie = _scene(WALL, _square(2.0 - 0.5e-9, reflectivity=2.0))
    assert near_tie.cast(Z).target_index[0, 0] == 0
    # 1 um nearer is a real ordering: the letter comes first.
    apart = _scene(WALL, _square(2.0 - 1e-6, reflectivity=2.0))
    assert apart.cast(Z).target_index[0, 0] == 1


def test_transmissive_tie_keeps_both_in_listed_order() -> None:
    scene = _scene(_square(2.0, transmission=0.5), WALL)
    hits = scene.cast(Z)
    assert hits.target_index[0, :2].tolist() == [0, 1]
    assert hits.transmission[0, :2].tolist() == [1.0, 0.5]


def test_transmission_chain_and_opaque_cut() -> None:
    """Panes 0.5, 0.25, fully clear 1.0, then an opaque wall, then a hidden target."""
    scene = _scene(
        {"kind": "plane", "point": [0, 0, 5.0], "normal": [0, 0, -1]},  # hidden behind the wall
        WALL,
        _square(1.0, transmission=0.5),
        _square(1.5, transmission=1.0),
        _square(1.2, transmission=0.25),
    )
    hits = scene.cast(Z, max_hits=6)
    assert hits.count[0] == 4
    assert hits.target_index[0].tolist() == [2, 4, 3, 1, -1, -1]
    assert hits.range_m[0, :4].tolist() == [1.0, 1.2, 1.5, 2.0]
    assert hits.transmission[0, :4].tolist() == [1.0, 0.5, 0.125, 0.125]
    # max_hits cuts the list from the near end.
    short = scene.cast(Z, max_hits=2)
    assert short.target_index[0].tolist() == [2, 4] and short.count[0] == 2


def test_empty_slots_are_filled_with_documented_values() -> None:
    hits = _scene(WALL).cast(np.vstack([Z, -Z[0]]), max_hits=3)
    assert hits.count.tolist() == [1, 0]
    assert np.all(np.isinf(hits.range_m[0, 1:])) and np.all(np.isinf(hits.range_m[1]))
    assert np.all(np.isnan(hits.incidence_rad[1])) and np.all(np.isnan(hits.points_m[1]))
    assert np.all(hits.target_index[1] == -1)
    assert np.all(hits.reflectivity[1] == 0) and np.all(hits.transmission[1] == 0)
    assert np.all(hits.radial_velocity_mps[1] == 0)


def test_origin_offset_moves_the_rays() -> None:
    scene = _scene(WALL)
    hits = cast(scene, Z, origin=(0.3, -0.2, 0.5))
    assert hits.range_m[0, 0] == 1.5
    assert np.allclose(hits.points_m[0, 0], [0.3, -0.2, 2.0])


def test_zero_rays() -> None:
    hits = _scene(WALL).cast(np.zeros((0, 3)), max_hits=2)
    assert hits.range_m.shape == (0, 2) and hits.count.shape == (0,)


@pytest.mark.parametrize(
    ("directions", "kwargs", "message"),
    [
        (np.zeros(3), {}, r"directions must have shape \(n, 3\), got \(3,\)"),
        (np.ones((2, 2)), {}, r"shape \(n, 3\)"),
        (np.array([[0, 0, 1.0], [0, np.nan, 1.0]]), {}, r"directions\[1\] is not finite"),
        (np.array([[0, 0, 1.0], [0, 0, 2.0]]), {}, r"unit vectors; directions\[1\] has norm 2\.0"),
        (Z, {"max_hits": 0}, r"max_hits must be an integer >= 1, got 0"),
        (Z, {"max_hits": 1.5}, r"max_hits must be an integer >= 1"),
        (Z, {"origin": (0, 0)}, r"origin must be 3 finite numbers"),
        (Z, {"origin": (0, 0, np.inf)}, r"origin must be 3 finite numbers"),
    ],
)
def test_bad_cast_arguments(directions, kwargs, message) -> None:
    with pytest.raises(RayError, match=message):
        _scene(WALL).cast(directions, **kwargs)


def test_target_arrays_are_read_only() -> None:
    scene = _scene({"kind": "sphere", "center": [0, 0, 2.0], "radius": 0.5})
    with pytest.raises(ValueError):
        scene.targets[0].center[0] = 1.0


def test_mixed_scene_in_a_16_deg_scan() -> None:
    """Every target of mixed.toml is seen by a 128 x 128 beam grid over 16 x 16 deg (eq. 4-1)."""
    from pathlib import Path

    scene = Scene.from_toml(Path(__file__).resolve().parents[3] / "config/scenes/mixed.toml")
    f_m = 25e-3
    pitch_m = 2 * f_m * math.tan(math.radians(8.0)) / 128
    x = (np.arange(128) - 63.5) * pitch_m
    xx, yy = np.meshgrid(x, x)
    d = np.column_stack([-xx.ravel() / f_m, -yy.ravel() / f_m, np.ones(xx.size)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = scene.cast(d)
    seen = set(hits.target_index[hits.target_index >= 0].tolist())
    assert seen == set(range(len(scene)))
    assert np.all(hits.count >= 1)  # the back wall closes every ray
    ranges = hits.range_m[np.isfinite(hits.range_m)]
    assert ranges.min() >= 0.5 * 0.99 and ranges.max() <= 5.0 / math.cos(math.radians(8 * 1.5))
    # The 50 % pane gives double returns; the second one carries half the power.
    pane = [i for i, t in enumerate(scene.targets) if t.transmission == 0.5][0]
    through = hits.target_index[:, 0] == pane
    assert through.any() and np.all(hits.count[through] == 2)
    assert np.all(hits.transmission[through, 1] == 0.5)
    # The receding box (+z at 1.5 m/s) has a positive radial velocity v . d = 1.5 cos(angle).
    mover = [i for i, t in enumerate(scene.targets) if t.velocity[2] > 0][0]
    on = hits.target_index == mover
    assert on.any()
    assert np.allclose(hits.radial_velocity_mps[on], 1.5 * np.broadcast_to(d[:, 2:], on.shape)[on])
