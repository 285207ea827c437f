"""Scene loading: shipped scenes, defaults, round trip, every SceneError path with its message."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sim_devices.world.scene import (
    BoxTarget,
    PlaneTarget,
    PolygonTarget,
    Scene,
    SceneError,
    SphereTarget,
    rotation_matrix_deg,
)

SCENES = Path(__file__).resolve().parents[3] / "config" / "scenes"


# -- shipped scenes --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["cal_letters", "cal_letters_staggered", "mixed", "empty"])
def test_shipped_scene_loads_and_round_trips(name: str) -> None:
    scene = Scene.from_toml(SCENES / f"{name}.toml")
    assert scene.name == name
    assert scene.source.endswith(f"{name}.toml")
    again = Scene.from_dict(json.loads(json.dumps(scene.to_dict())), source="json")
    # Normals/up are stored normalised, so re-normalising may move the last bit: compare closely.
    _assert_same_tree(again.to_dict(), scene.to_dict())


def _assert_same_tree(a: object, b: object) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys()
        for k in a:
            _assert_same_tree(a[k], b[k])
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b)
        for x, y in zip(a, b):
            _assert_same_tree(x, y)
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-15, abs=1e-15)
    else:
        assert a == b


def test_empty_scene_has_no_targets_and_no_hits() -> None:
    scene = Scene.from_toml(SCENES / "empty.toml")
    assert len(scene) == 0
    hits = scene.cast(np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]), max_hits=3)
    assert hits.range_m.shape == (2, 3)
    assert np.all(np.isinf(hits.range_m))
    assert np.all(hits.target_index == -1)
    assert np.all(hits.count == 0)


def test_cal_letters_scene_matches_the_dissertation_setup() -> None:
    """§4.4.3: letters ~0.8 m away, reflective sheet (> 1), inside the 16 x 16 deg FoV."""
    scene = Scene.from_toml(SCENES / "cal_letters.toml")
    letters = [t for t in scene.targets if isinstance(t, PolygonTarget)]
    assert len(letters) >= 3
    half_fov = 0.8 * math.tan(math.radians(8.0))
    for t in letters:
        assert t.reflectivity > 1.0
        assert np.allclose(t.vertices[:, 2], 0.8)
        assert np.all(np.abs(t.vertices[:, :2]) < half_fov)
        assert abs(abs(t.normal[2]) - 1.0) < 1e-12  # facing the sensor
    heights = [np.ptp(t.vertices[:, 1]) for t in letters]
    assert 0.04 <= max(heights) <= 0.06
    background = scene.targets[-1]
    assert isinstance(background, PlaneTarget)
    assert background.reflectivity == pytest.approx(0.1)
    assert background.point[2] > 0.8
    assert background.size is not None
    assert np.all(background.size / 2 > 0.9 * math.tan(math.radians(8)))


def test_mixed_scene_contents() -> None:
    scene = Scene.from_toml(SCENES / "mixed.toml")
    kinds = {type(t) for t in scene.targets}
    assert kinds == {PlaneTarget, BoxTarget, SphereTarget, PolygonTarget}
    assert any(isinstance(t, BoxTarget) and np.any(t.rotation_deg != 0) for t in scene.targets)
    assert any(t.velocity[2] > 0 for t in scene.targets)  # a receding target
    assert any(t.transmission == 0.5 for t in scene.targets)


# -- defaults and parsing --------------------------------------------------------------------------


def test_defaults_and_normalisation() -> None:
    scene = Scene.from_toml_text(
        """
        [[target]]
        kind = "plane"
        point = [0, 0, 2]
        normal = [0, 0, -4]
        """
    )
    (t,) = scene.targets
    assert isinstance(t, PlaneTarget)
    assert t.reflectivity == 0.1 and t.transmission == 0.0
    assert np.array_equal(t.velocity, [0.0, 0.0, 0.0])
    assert np.allclose(t.normal, [0.0, 0.0, -1.0])
    assert t.size is None
    assert scene.source == "<body>"


def test_floor_plane_without_up_falls_back_to_z() -> None:
    scene = Scene.from_dict(
        {"target": [{"kind": "plane", "point": [0, -1, 0], "normal": [0, 1, 0], "size": [1, 2]}]}
    )
    u, v = scene.targets[0].axes
    assert np.allclose(v, [0, 0, 1])
    assert abs(u @ [0, 1, 0]) < 1e-12 and abs(u @ v) < 1e-12


def test_rotation_matrix_is_rz_ry_rx() -> None:
    """R = Rz.Ry.Rx: check single-axis right-handed rotations and the composition order."""
    assert np.allclose(rotation_matrix_deg((90, 0, 0)) @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(rotation_matrix_deg((0, 90, 0)) @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(rotation_matrix_deg((0, 0, 90)) @ [1, 0, 0], [0, 1, 0])
    # x first, then z: x-rotation leaves x alone, z-rotation then turns x into y.
    assert np.allclose(rotation_matrix_deg((90, 0, 90)) @ [1, 0, 0], [0, 1, 0])
    # y (x->-z... ) : +x about y by 90 -> -z; then z-rotation leaves -z alone.
    assert np.allclose(rotation_matrix_deg((0, 90, 90)) @ [1, 0, 0], [0, 0, -1])


def test_from_toml_missing_file_is_scene_error(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(SceneError, match=r"nope\.toml: cannot read scene file"):
        Scene.from_toml(path)


def test_from_toml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "scene.toml"
    path.write_text('[[target]]\nkind = "sphere"\ncenter = [0, 0, 1]\nradius = 0.5\n'
                    '[[target]]\nkind = "sphere"\ncenter = [0, 0, 1]\nradius = -1\n')
    with pytest.raises(SceneError) as info:
        Scene.from_toml(path)
    assert str(info.value) == f"{path}: target[1].radius: must be > 0, got -1"


def test_invalid_toml_syntax() -> None:
    with pytest.raises(SceneError, match=r"^req: invalid TOML"):
        Scene.from_toml_text("[[target]\nkind = ", source="req")


# -- every error path ------------------------------------------------------------------------------

SPHERE = 'kind = "sphere"\ncenter = [0, 0, 1]\nradius = 0.5\n'
PLANE = 'kind = "plane"\npoint = [0, 0, 1]\nnormal = [0, 0, -1]\n'
BOX = 'kind = "box"\ncenter = [0, 0, 1]\nsize = [1, 1, 1]\n'
POLY = 'kind = "polygon"\nvertices = [[0, 0, 1], [1, 0, 1], [0, 1, 1]]\n'


def _two(second: str) -> str:
    """A valid target[0] followed by the target under test as target[1]."""
    return f"[[target]]\n{SPHERE}\n[[target]]\n{second}"


ERROR_CASES = [
    # (scene body, exact message prefix after "<src>: ")
    ("mixed_pixels = 1\n", "mixed_pixels: must be true or false, got 1"),
    ("colour = 1\n", "colour: unknown top-level key; allowed: name, description, mixed_pixels, target"),
    ("name = 3\n", "name: must be a string, got 3"),
    ("description = [1]\n", "description: must be a string"),
    ("target = 3\n", "target: must be an array of tables"),
    (_two("radius = 1\n"), "target[1].kind: missing; allowed: plane, box, sphere, polygon"),
    (
        _two('kind = "cone"\n'),
        "target[1].kind: unknown kind 'cone'; allowed: plane, box, sphere, polygon",
    ),
    (_two(SPHERE + "colour = 1\n"), "target[1].colour: unknown key for kind 'sphere'; allowed:"),
    (_two(SPHERE + "normal = [0, 0, 1]\n"), "target[1].normal: unknown key for kind 'sphere'"),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\n'),
        "target[1].radius: missing (required for kind 'sphere')",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\nradius = -1\n'),
        "target[1].radius: must be > 0, got -1",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\nradius = 0\n'),
        "target[1].radius: must be > 0, got 0",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\nradius = nan\n'),
        "target[1].radius: must be finite, got nan",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\nradius = "1"\n'),
        "target[1].radius: must be a number, got '1'",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 0, 1]\nradius = true\n'),
        "target[1].radius: must be a number, got True",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, 1]\nradius = 1\n'),
        "target[1].center: must be a list of 3 numbers, got 2 values",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, inf, 1]\nradius = 1\n'),
        "target[1].center: must contain finite numbers, element 1 is inf",
    ),
    (
        _two('kind = "sphere"\ncenter = 5\nradius = 1\n'),
        "target[1].center: must be a list of 3 numbers, got 5",
    ),
    (
        _two('kind = "sphere"\ncenter = [0, "a", 1]\nradius = 1\n'),
        "target[1].center: must be a list of 3 numbers, element 1 is 'a'",
    ),
    (_two(SPHERE + "reflectivity = -0.1\n"), "target[1].reflectivity: must be >= 0, got -0.1"),
    (_two(SPHERE + "transmission = 1.5\n"), "target[1].transmission: must be in [0, 1], got 1.5"),
    (_two(SPHERE + "transmission = -0.5\n"), "target[1].transmission: must be in [0, 1], got -0.5"),
    (
        _two(SPHERE + "velocity = [1, 2]\n"),
        "target[1].velocity: must be a list of 3 numbers, got 2 values",
    ),
    (_two(SPHERE + "velocity = [1, 2, -inf]\n"), "target[1].velocity: must contain finite numbers"),
    (
        _two(PLANE.replace("[0, 0, -1]", "[0, 0, 0]")),
        "target[1].normal: must be a non-zero vector, got [0.0, 0.0, 0.0]",
    ),
    (
        _two('kind = "plane"\npoint = [0, 0, 1]\n'),
        "target[1].normal: missing (required for kind 'plane')",
    ),
    (_two(PLANE + "size = [1, 0]\n"), "target[1].size: all elements must be > 0, got [1.0, 0.0]"),
    (
        _two(PLANE + "size = [1, 2, 3]\n"),
        "target[1].size: must be a list of 2 numbers, got 3 values",
    ),
    (
        _two(PLANE + "size = [1, 1]\nup = [0, 0, 2]\n"),
        "target[1].up: must not be parallel to normal",
    ),
    (_two(PLANE + "up = [0, 0, 0]\n"), "target[1].up: must be a non-zero vector"),
    (_two(PLANE + "center = [0, 0, 0]\n"), "target[1].center: unknown key for kind 'plane'"),
    (
        _two(BOX.replace("[1, 1, 1]", "[1, -1, 1]")),
        "target[1].size: all elements must be > 0, got [1.0, -1.0, 1.0]",
    ),
    (
        _two(BOX + "rotation_deg = [0, 0]\n"),
        "target[1].rotation_deg: must be a list of 3 numbers, got 2 values",
    ),
    (
        _two(BOX + "rotation_deg = [0, nan, 0]\n"),
        "target[1].rotation_deg: must contain finite numbers",
    ),
    (
        _two('kind = "polygon"\nvertices = [[0, 0, 1], [1, 0, 1]]\n'),
        "target[1].vertices: must be a list of >= 3 [x, y, z] vertices, got 2 vertices",
    ),
    (
        _two('kind = "polygon"\nvertices = [[0, 0, 1], [1, 0, 1], [1, 1]]\n'),
        "target[1].vertices[2]: must be a list of 3 numbers, got 2 values",
    ),
    (
        _two('kind = "polygon"\nvertices = [[0, 0, 1], [1, 0, 1], [2, 0, 1]]\n'),
        "target[1].vertices: polygon is degenerate",
    ),
    (
        _two('kind = "polygon"\nvertices = [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1.001]]\n'),
        "target[1].vertices: polygon must be planar (within 1e-09 m); vertex",
    ),
]


@pytest.mark.parametrize(("body", "message"), ERROR_CASES)
def test_scene_error_messages(body: str, message: str) -> None:
    with pytest.raises(SceneError) as info:
        Scene.from_toml_text(body, source="scene.toml")
    assert str(info.value).startswith(f"scene.toml: {message}"), str(info.value)


def test_non_table_target_from_dict() -> None:
    with pytest.raises(SceneError, match=r"^api: target\[0\]: must be a table of keys, got int$"):
        Scene.from_dict({"target": [3]}, source="api")


def test_non_dict_scene() -> None:
    with pytest.raises(SceneError, match=r"^api: scene must be a table/object, got list$"):
        Scene.from_dict([], source="api")


def test_first_error_wins_and_nothing_is_loaded() -> None:
    """Two bad targets: one error, about the first; no scene object comes back."""
    body = (
        f"[[target]]\n{SPHERE}\n"
        '[[target]]\nkind = "sphere"\ncenter = [0, 0, 1]\nradius = -2\n'
        '[[target]]\nkind = "box"\ncenter = [0, 0, 1]\nsize = [0, 1, 1]\n'
    )
    result = None
    with pytest.raises(SceneError) as info:
        result = Scene.from_toml_text(body, source="s")
    assert result is None
    assert str(info.value) == "s: target[1].radius: must be > 0, got -2"


def test_scene_error_is_a_value_error() -> None:
    assert issubclass(SceneError, ValueError)
