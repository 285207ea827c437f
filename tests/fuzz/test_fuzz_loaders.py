"""Fuzz the configuration loader and the scene loader: any input -> a value or the defined error.

``lidard.config.load_config`` must raise only ``ConfigError`` (one line naming file and key) and
``sim_devices.world.scene.Scene.from_toml_text`` / ``from_dict`` only ``SceneError``, whatever the
text or structure: random text, byte-level mutations of the shipped files, and structural
mutations (a value replaced by one of another type or an extreme value, keys added or removed).
A file that loads must give a usable object (a Config whose optics can be built; a Scene whose
targets can be cast against).
"""

import copy
import tomllib

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from lidard.config import CONFIG_DIR, Config, ConfigError, load_config
from sim_devices.world.scene import Scene, SceneError
from tests.helpers.toml_emit import dumps

FUZZ = settings(max_examples=100, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

SIM_TOML = (CONFIG_DIR / "sim.toml").read_text()
SIM_DOC = tomllib.loads(SIM_TOML)
SCENE_TOML = (CONFIG_DIR / "scenes" / "mixed.toml").read_text()
SCENE_DOC = tomllib.loads(SCENE_TOML)

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-2**63, 2**63 - 1), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12), st.sampled_from(["", "fpsa20", "fpsa128", "bench", "child", "../../etc/passwd",
                                           "lidar_25mm", "scenes/empty.toml", "plane", "sphere", "box"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=8), inner, max_size=3)),
                      max_leaves=8)


def _paths(doc, prefix=()):
    """Every (path, value) in a nested dict/list document."""
    yield prefix, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated(draw, base):
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p, _ in _paths(doc) if p]
        path = draw(st.sampled_from(paths))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(["replace", "delete", "add"]))
        if op == "replace":
            parent[path[-1]] = draw(values)
        elif op == "delete" and isinstance(parent, dict):
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=10))] = draw(values)
    return doc


def _emit(doc):
    try:
        return dumps({k: v for k, v in doc.items()})
    except TypeError:  # None has no TOML spelling: such a document cannot be a file
        return None


def _one_clear_line(exc):
    # a refused file says why in one line: not empty, no multi-line pydantic dump
    msg = str(exc).strip()
    assert msg and "\n" not in msg, msg


def _load_text(tmp_path, text):
    path = tmp_path / "fuzz.toml"
    path.write_text(text, encoding="utf-8")
    try:
        cfg = load_config(path, environ={})
    except ConfigError as exc:
        _one_clear_line(exc)
        return None
    assert isinstance(cfg, Config)
    cfg.optics()  # a configuration that loads can be used
    return cfg


def test_shipped_config_loads(tmp_path):
    assert _load_text(tmp_path, SIM_TOML) is not None


@FUZZ
@given(text=st.text(max_size=200))
def test_config_random_text_only_config_error(tmp_path, text):
    _load_text(tmp_path, text)


@FUZZ
@given(data=st.data())
def test_config_byte_mutations_only_config_error(tmp_path, data):
    raw = bytearray(SIM_TOML.encode())
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(raw) - 1))
        op = data.draw(st.sampled_from(["flip", "delete", "insert"]))
        if op == "flip":
            raw[i] = data.draw(st.integers(0, 255))
        elif op == "delete":
            del raw[i]
        else:
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=4))
    path = tmp_path / "fuzz.toml"
    path.write_bytes(bytes(raw))
    try:
        load_config(path, environ={})
    except ConfigError as exc:
        _one_clear_line(exc)


@FUZZ
@given(doc=mutated(SIM_DOC))
def test_config_structural_mutations_only_config_error(tmp_path, doc):
    text = _emit(doc)
    assume(text is not None)
    _load_text(tmp_path, text)


@FUZZ
@given(environ=st.dictionaries(st.sampled_from(["LIDARD_PROFILE", "LIDARD_SCAN__AVERAGES", "LIDARD_DAEMON__PORT",
                                                 "LIDARD_CHIRP__RAMP_S", "LIDARD_SIM", "LIDARD_DAEMON__MAX_BODY_BYTES",
                                                 "LIDARD_X__Y__Z"]),
                               st.text(max_size=10), max_size=3))
def test_config_env_overrides_only_config_error(environ):
    try:
        load_config(CONFIG_DIR / "sim.toml", environ=environ)
    except ConfigError as exc:
        _one_clear_line(exc)


# --------------------------------------------------------------------------------------- scenes
def _scene_usable(scene):
    dirs = np.array([[0.0, 0.0, 1.0], [0.1, -0.05, 1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = scene.cast(dirs)
    assert hits.count.shape == (2,) and np.all((hits.count >= 0) & (hits.count <= len(scene)))
    # every reported hit is a finite positive range (a loaded scene never yields nan geometry)
    for i in range(2):
        r = hits.range_m[i, :hits.count[i]]
        assert np.all(np.isfinite(r) & (r > 0)), r


def test_shipped_scene_loads():
    _scene_usable(Scene.from_toml_text(SCENE_TOML, source="mixed.toml"))


@FUZZ
@given(text=st.text(max_size=200))
def test_scene_random_text_only_scene_error(text):
    try:
        Scene.from_toml_text(text)
    except SceneError:
        pass


@FUZZ
@given(doc=mutated(SCENE_DOC))
def test_scene_structural_mutations_only_scene_error(doc):
    try:
        scene = Scene.from_dict(doc)
    except SceneError as exc:
        assert "<dict>" in str(exc)  # names the source
        return
    _scene_usable(scene)


@FUZZ
@given(doc=values)
def test_scene_from_any_json_value_only_scene_error(doc):
    try:
        Scene.from_dict(doc)
    except SceneError:
        pass


@FUZZ
@given(targets=st.lists(st.fixed_dictionaries(
    {"kind": st.sampled_from(["plane", "box", "sphere", "polygon", "cone"])},
    optional={"point": values, "normal": values, "center": values, "radius": values, "size": values,
              "vertices": values, "rotation_deg": values, "reflectivity": values, "transmission": values,
              "velocity": values, "up": values}), max_size=3))
def test_scene_targets_with_random_fields_only_scene_error(targets):
    try:
        scene = Scene.from_dict({"target": targets})
    except SceneError:
        return
    _scene_usable(scene)
