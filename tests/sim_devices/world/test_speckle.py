"""Fully developed speckle (issue 15 item 6): Rayleigh amplitude (KS test), uniform phase,
independent between pixels, frozen on a static surface, new per chirp on a moving one, so that
averaging N chirps of a moving surface's return power divides the fading variance by N."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from lidard.config import CONFIG_DIR, load_config
from sim_devices.world.scene import Scene, SceneError
from sim_devices.world.speckle import speckle_factors
from sim_devices.world.world import World

N = 20000


def _draw(seed=7, n=N, chirp=None, target=0):
    i = np.arange(n)
    ch = np.zeros(n, np.int64) if chirp is None else chirp
    return speckle_factors(seed, i % 128, i // 128 % 128, np.full(n, target), ch)


def test_amplitude_is_rayleigh_with_unit_mean_power_and_phase_uniform():
    a, ph = _draw()
    # circular complex Gaussian field of unit power: |E| ~ Rayleigh(sigma = 1/sqrt(2))
    assert stats.kstest(a, stats.rayleigh(scale=1 / np.sqrt(2)).cdf).pvalue > 0.01
    assert np.mean(a**2) == pytest.approx(1.0, abs=4 / np.sqrt(N))      # power kept (eq. 2-10 mean)
    assert stats.kstest(ph, stats.uniform(0, 2 * np.pi).cdf).pvalue > 0.01
    # a wrong law fails the same test (the test can fail): an exponential amplitude
    assert stats.kstest(np.sqrt(2) * a**2 / 2, stats.rayleigh(scale=1 / np.sqrt(2)).cdf).pvalue < 1e-6


def test_pixels_decorrelate_and_draws_are_reproducible():
    a, ph = _draw()
    # neighbouring pixels (consecutive rows) of the intensity are uncorrelated
    intensity = a**2
    r = np.corrcoef(intensity[:-1], intensity[1:])[0, 1]
    assert abs(r) < 4 / np.sqrt(N)
    np.testing.assert_array_equal(_draw()[0], a)                      # same seed, same speckle
    assert not np.array_equal(_draw(seed=8)[0], a)
    assert not np.array_equal(_draw(target=1)[0], a)                  # another target, another field


def _scene_world(velocity):
    scene = Scene.from_dict({"target": [{"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1],
                                         "speckle": True, "velocity": velocity}]})
    cfg = load_config(CONFIG_DIR / "sim.toml")
    return World(cfg, cfg.load_profile(), cfg.load_laser(), scene, seed=3)


def test_averaging_chirps_of_a_moving_surface_reduces_fading_variance_as_1_over_n():
    n_pix, n_chirps = 400, 16
    rows = np.repeat(np.arange(20) * 4, 20)
    cols = np.tile(np.arange(20) * 4, 20)
    moving, static = _scene_world([0, 0, 0.5]), _scene_world([0, 0, 0])
    powers = {}
    for name, world in (("moving", moving), ("static", static)):
        p = np.empty((n_chirps, n_pix))
        for k in range(n_chirps):
            bh = world.beam_hits(rows, cols, np.ones(n_pix), chirp=np.full(n_pix, k))
            p[k] = bh.amplitude_v**2
        powers[name] = p / p.mean()
    # single chirp: exponential intensity, contrast (var / mean^2) = 1
    assert np.var(powers["moving"][0]) == pytest.approx(1.0, rel=0.3)
    for n in (4, 16):
        var_n = np.var(powers["moving"][:n].mean(axis=0))
        assert var_n == pytest.approx(1.0 / n, rel=0.35)
    # a static surface keeps its speckle: averaging chirps leaves the fading as it was
    np.testing.assert_array_equal(powers["static"][0], powers["static"][-1])
    assert np.var(powers["static"].mean(axis=0)) == pytest.approx(np.var(powers["static"][0]))


def test_speckle_key_is_checked_and_off_by_default_in_shipped_scenes():
    with pytest.raises(SceneError, match=r"target\[0\]\.speckle: must be true or false"):
        Scene.from_dict({"target": [{"kind": "sphere", "center": [0, 0, 1], "radius": 0.1,
                                     "speckle": "yes"}]})
    for path in (CONFIG_DIR / "scenes").glob("*.toml"):
        scene = Scene.from_toml(path)
        if path.stem == "speckle_wall":
            assert all(t.speckle for t in scene.targets)
            assert Scene.from_dict(scene.to_dict()).targets[0].speckle
        else:
            assert not any(t.speckle for t in scene.targets), path.name
