"""raycast.cast with one origin per ray (the footprint sub-rays leave the lens off its centre):
the same hits as casting each ray alone from its own origin, and a clear error for a wrong shape."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import CONFIG_DIR
from sim_devices.world.raycast import RayError
from sim_devices.world.scene import Scene


def test_per_ray_origins_give_each_rays_own_cast():
    scene = Scene.from_toml(CONFIG_DIR / "scenes" / "mixed.toml")
    rng = np.random.default_rng(3)
    d = rng.normal([0, 0, 1], [0.08, 0.08, 0.0], size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = rng.uniform(-0.01, 0.01, size=(40, 3))
    batch = scene.cast(d, max_hits=3, origin=o)
    assert np.any(batch.count > 0)
    for i in range(40):
        one = scene.cast(d[i:i + 1], max_hits=3, origin=o[i])
        np.testing.assert_array_equal(batch.target_index[i], one.target_index[0])
        np.testing.assert_allclose(batch.range_m[i], one.range_m[0], rtol=1e-12)
        np.testing.assert_allclose(batch.points_m[i], one.points_m[0], rtol=1e-12, equal_nan=True)


def test_origins_of_the_wrong_shape_are_refused():
    scene = Scene.from_toml(CONFIG_DIR / "scenes" / "mixed.toml")
    d = np.tile([0.0, 0.0, 1.0], (4, 1))
    with pytest.raises(RayError, match=r"origin must be 3 finite numbers \(or one row of 3 per ray\), got shape \(3, 3\)"):
        scene.cast(d, origin=np.zeros((3, 3)))
