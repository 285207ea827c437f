"""The cheap outline test of sim_devices.world.footprint misses no mixed pixel (issue 15 item 5).

Brute force: every pixel of the frame is re-cast with its footprint samples; any pixel whose samples
disagree with its central ray (other targets along a sample, e.g. the wall beside a box) must have been
flagged by ``edge_candidates`` (which only looks at each target's silhouette), and the flags must be
few (the point of the test is to cast sub-rays only there)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config
from sim_devices.world import footprint as fp
from sim_devices.world import mixed_returns as mr
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

CFG = load_config(CONFIG_DIR / "sim.toml")
EXTRA = [  # a tilted sized plane and a tilted triangle, besides the shipped scenes' kinds
    {"kind": "plane", "point": [0.08, 0.1, 1.4], "normal": [0.4, 0.2, -1.0], "size": [0.1, 0.06],
     "up": [0.3, 1.0, 0.0]},
    {"kind": "polygon", "vertices": [[-0.12, -0.02, 1.7], [-0.05, -0.1, 1.9], [-0.02, 0.0, 1.6]]},
    {"kind": "plane", "point": [0, 0, 3.0], "normal": [0, 0, -1]},
]


@pytest.mark.parametrize("scene_name", ["mixed", "cal_letters"])
def test_every_pixel_whose_footprint_disagrees_was_flagged(scene_name):
    raw = Scene.from_toml(CONFIG_DIR / "scenes" / f"{scene_name}.toml").to_dict()
    static = [t for t in raw["target"] if not any(t.get("velocity", [0, 0, 0]))]
    scene = Scene.from_dict({"target": static + (EXTRA if scene_name == "mixed" else [])})
    world = World(CFG, CFG.load_profile(), CFG.load_laser(), scene)
    rows, cols = np.divmod(np.arange(128 * 128), 128)
    d = world.optics.directions(rows, cols)
    flagged = fp.edge_candidates(scene.targets, d, world._footprint_radius)
    b = world._beam()
    o, sd = fp.sub_rays(d, fp.beam_waist_m(**b),
                        fp.divergence_half_angle_rad(emission_w_m=b["emission_w_m"], focal_m=b["focal_m"]))
    sub = scene.cast(sd.reshape(-1, 3), max_hits=4, origin=o.reshape(-1, 3))
    central = scene.cast(d, max_hits=4)
    agree = mr.agreeing(sub.target_index.reshape(d.shape[0], fp.SAMPLES, -1), central.target_index)
    missed = np.flatnonzero(~agree & ~flagged)
    assert missed.size == 0, [(int(rows[i]), int(cols[i])) for i in missed[:5]]
    assert (~agree).sum() > 100                         # there are outlines to find ...
    assert flagged.sum() <= 2.0 * (~agree).sum()        # ... and the flags are mostly true ones
