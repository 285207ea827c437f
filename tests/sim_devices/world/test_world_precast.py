"""The bench's look-ahead cast (World.precast): casting a run's next pixels in one call gives each
pixel the hits it gets when cast read by read, mixed (footprint-weighted) edge pixels included."""

from __future__ import annotations

import numpy as np

from lidard.config import CONFIG_DIR, load_config
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

CFG = load_config(CONFIG_DIR / "sim.toml")
WALL = {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1], "reflectivity": 0.2}
BOX = {"kind": "box", "center": [0.1, 0.0, 1.1], "size": [0.2, 0.2, 0.2], "reflectivity": 0.2}


def _world() -> World:
    scene = Scene.from_dict({"mixed_pixels": True, "target": [BOX, WALL]})
    return World(CFG, CFG.load_profile(), CFG.load_laser(), scene)


def test_precast_pixels_get_the_hits_of_a_read_by_read_cast():
    rows = np.repeat(np.arange(56, 72), 24)
    cols = np.tile(np.arange(50, 74), 16)
    by_read, ahead = _world(), _world()
    want = [e for i in range(0, rows.size, 20) for e in by_read._cast_pixels(rows[i:i + 20], cols[i:i + 20])]
    ahead.precast(rows, cols)
    assert ahead.rays_cast == rows.size             # every pixel cast by the look-ahead, once
    got = ahead._cast_pixels(rows, cols)
    assert ahead.rays_cast == rows.size             # ... and not again when the reads come
    assert len(ahead._mixed) == len(by_read._mixed) > 0
    for g, w in zip(got, want):
        assert len(g) == len(w)
        for a, b in zip(g, w):
            assert np.array_equal(a, b)
