"""Targets that move during a scan (sim_devices.world.motion): a beam fired at time t sees the scene
moved to t. Checked against the plain ray cast of ``Scene.moved(t)`` (a pure geometric query), beam
by beam: ranges, radial velocities v . d, the transmission chain through a moving glass pane, and
the order of the hits."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_config
from sim_devices.world.raycast import intersect_target
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

SCENE = {"target": [
    {"kind": "plane", "point": [0, 0, 3.0], "normal": [0, 0, -1], "reflectivity": 0.5},
    {"kind": "plane", "point": [0.05, 0, 1.5], "normal": [0, 0, -1], "size": [0.2, 0.2], "transmission": 0.6,
     "reflectivity": 0.05, "velocity": [1.5, 0.0, 0.0]},                      # glass sliding across
    {"kind": "box", "center": [-0.1, 0.05, 2.0], "size": [0.15, 0.15, 0.1], "velocity": [0.0, 0.0, -1.5]},
    {"kind": "sphere", "center": [0.0, -0.1, 2.5], "radius": 0.08, "velocity": [0.7, 0.7, 0.7]},
    {"kind": "polygon", "vertices": [[-0.2, -0.2, 1.0], [-0.1, -0.2, 1.0], [-0.15, -0.1, 1.0]],
     "velocity": [0.5, 0.5, 0.0], "transmission": 0.3},
]}


@pytest.fixture(scope="module")
def world():
    cfg = load_config("config/sim.toml")
    return World(cfg, cfg.load_profile(), cfg.load_laser(), Scene.from_dict(SCENE))


def test_per_ray_origins_match_one_cast_per_origin():
    scene = Scene.from_dict(SCENE)
    rng = np.random.default_rng(3)
    d = rng.normal([0, 0, 1], 0.08, (64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = rng.normal(0, 0.05, (64, 3))
    for tg in scene.targets:
        t_all, n_all = intersect_target(tg, d, o)
        for i in range(0, 64, 7):
            t1, n1 = intersect_target(tg, d[i:i + 1], o[i])
            assert t_all[i] == pytest.approx(t1[0]) or (np.isinf(t_all[i]) and np.isinf(t1[0]))


def test_each_beam_sees_the_scene_at_its_own_time(world):
    rows, cols = np.meshgrid(np.arange(40, 88, 3), np.arange(40, 88, 3), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    t = np.linspace(0.0, 0.12, rows.size)
    bh = world.beam_hits(rows, cols, np.ones(rows.size), t_s=t)
    d = world.optics.directions(rows, cols)
    moved_hits = 0
    for i in range(rows.size):
        truth = world.scene.moved(t[i]).cast(d[i:i + 1], max_hits=world.max_hits)
        n = int(truth.count[0])
        mine = bh.beam == i
        assert mine.sum() == n
        assert np.allclose(bh.range_m[mine], truth.range_m[0, :n], atol=1e-12)
        assert np.allclose(bh.velocity_mps[mine], truth.radial_velocity_mps[0, :n], atol=1e-12)
        assert np.array_equal(bh.return_index[mine], np.arange(n))
        # amplitude carries the one-way chain squared (out and back): compare with a static world
        moved_hits += int(np.any(truth.target_index[0, :n] > 0))
    assert moved_hits > 20        # the moving targets are really on the beams
    # far apart in time the same pixel sees different things
    a = world.ground_truth([64], [60], [0.0])[0]
    b = world.ground_truth([64], [60], [0.1])[0]
    assert a != b


def test_transmission_chain_through_a_moving_pane_matches_a_static_world(world):
    cfg = world.cfg
    rows, cols = np.arange(50, 80), np.full(30, 62)
    t = np.full(rows.size, 0.04)
    bh = world.beam_hits(rows, cols, np.ones(rows.size), t_s=t)
    frozen = World(cfg, world.profile, world.laser, _still(world.scene.moved(0.04)))
    ref = frozen.beam_hits(rows, cols, np.ones(rows.size))
    assert np.array_equal(bh.beam, ref.beam)
    assert np.allclose(bh.amplitude_v, ref.amplitude_v, rtol=1e-12)


def _still(scene: Scene) -> Scene:
    d = scene.to_dict()
    for tg in d["target"]:
        tg["velocity"] = [0.0, 0.0, 0.0]
    return Scene.from_dict(d)
