"""Mixed pixels at a box edge (issue 15 item 5): where the beam footprint straddles the edge of a box
in front of a wall, the pixel gives two weaker returns whose beat amplitudes are the covered shares
of the footprint; pixels away from the edge keep their single ray, and a scene without bounded
targets casts no sub-ray."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config
from sim_devices.world import footprint as fp
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

WALL = {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1], "reflectivity": 0.2}
# box face at z = 1.0 m; its -x edge lies at x = 0 (the optical axis)
BOX = {"kind": "box", "center": [0.1, 0.0, 1.1], "size": [0.2, 0.2, 0.2], "reflectivity": 0.2}


def _world(mixed: bool, targets=(BOX, WALL)) -> World:
    cfg = load_config(CONFIG_DIR / "sim.toml")
    scene = Scene.from_dict({"mixed_pixels": mixed, "target": list(targets)})
    return World(cfg, cfg.load_profile(), cfg.load_laser(), scene)


def _row_across_the_edge(world: World):
    rows = np.full(30, 64)
    cols = np.arange(49, 79)  # beams from -x to +x across the axis (eq. 4-1: column 0 points +x)
    return rows, cols


def test_edge_pixels_give_two_weaker_returns_that_share_the_footprint():
    single, mixed = _world(False), _world(True)
    rows, cols = _row_across_the_edge(single)
    hs = single.beam_hits(rows, cols, np.ones(cols.size))
    hm = mixed.beam_hits(rows, cols, np.ones(cols.size))
    # single ray: one return per beam (box at ~1.0 m or wall at ~2.0 m)
    assert np.all(np.bincount(hs.beam, minlength=cols.size) == 1)
    amp_box = hs.amplitude_v[np.abs(hs.range_m - 1.0) < 0.01].max()
    amp_wall = hs.amplitude_v[np.abs(hs.range_m - 2.0) < 0.05].max()
    per_beam = np.bincount(hm.beam, minlength=cols.size)
    edge = np.flatnonzero(per_beam == 2)
    assert 1 <= edge.size <= 3           # only beams within a footprint radius (~3 mm) of the edge
    for b in edge:
        sel = hm.beam == b
        r, a = hm.range_m[sel], hm.amplitude_v[sel]
        near, far = np.argmin(r), np.argmax(r)
        assert r[near] == pytest.approx(1.0, abs=0.01) and r[far] == pytest.approx(2.0, abs=0.05)
        share_box, share_wall = a[near] / amp_box, a[far] / amp_wall
        # each return carries its share of the 1 + RING samples, and the shares add up to one
        assert share_box + share_wall == pytest.approx(1.0, abs=0.02)
        assert 0 < share_box < 1 and 0 < share_wall < 1
        assert share_box * (1 + fp.RING) == pytest.approx(round(share_box * (1 + fp.RING)), abs=0.05)
    # beams away from the edge are exactly the single-ray beams
    away = np.setdiff1d(np.arange(cols.size), edge)
    np.testing.assert_array_equal(hm.range_m[np.isin(hm.beam, away)], hs.range_m[np.isin(hs.beam, away)])


def test_footprint_radius_follows_the_optics():
    # 128x128 behind the 25 mm F/1.4 lens: waist lambda f / (pi W) = 2.80 mm, divergence W/f
    r1 = fp.footprint_radius_m(1.0, emission_w_m=4.4e-6, focal_m=25e-3, wavelength_m=1.55e-6,
                               aperture_m=25e-3 / 1.4)
    assert float(r1) == pytest.approx(1.55e-6 * 25e-3 / (np.pi * 4.4e-6) + 0.5 * 4.4e-6 / 25e-3, rel=1e-9)
    # a small aperture caps the waist
    r_cap = fp.footprint_radius_m(0.0, emission_w_m=4.4e-6, focal_m=25e-3, wavelength_m=1.55e-6,
                                  aperture_m=2e-3)
    assert float(r_cap) == pytest.approx(1e-3)


def test_scene_without_bounded_targets_casts_no_sub_ray():
    w = _world(True, targets=(WALL,))
    d = w.optics.directions(np.arange(128), np.arange(128))
    assert not fp.edge_candidates(w.scene.targets, d, w._footprint_radius).any()
