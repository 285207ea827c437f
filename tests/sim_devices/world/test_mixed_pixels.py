"""Mixed pixels at a box edge (issue 15 item 5): where the beam footprint straddles the edge of a box
in front of a wall, the pixel gives two weaker returns whose beat amplitudes are the shares of the
Gaussian beam power on each side (0.5 erfc(sqrt(2) s / w) for an edge at s from the beam centre);
pixels away from the edge keep their single ray; a scene without outlines casts no sub-ray; and the
bench models mixed pixels on a scene that does not ask for them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erfc

from lidard.config import CONFIG_DIR, load_config
from lidard.physics.constants import C_M_PER_S
from sim_devices.world import footprint as fp
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

WALL = {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1], "reflectivity": 0.2}
# box face at z = 1.0 m; its -x edge lies at x = 0 (the optical axis)
BOX = {"kind": "box", "center": [0.1, 0.0, 1.1], "size": [0.2, 0.2, 0.2], "reflectivity": 0.2}
CFG = load_config(CONFIG_DIR / "sim.toml")


def _world(targets=(BOX, WALL), **top) -> World:
    scene = Scene.from_dict({**top, "target": list(targets)})
    return World(CFG, CFG.load_profile(), CFG.load_laser(), scene)


def _w_m(range_m: float) -> float:
    """1/e^2 footprint radius from the profile's optics (§4.1.2): waist lambda f / (pi W) + r W / 2f."""
    prof = CFG.load_profile()
    lens = prof.lenses[CFG.lens or prof.default_lens]
    w_emit, f = prof.emission_w_m, lens.focal_m
    return CFG.chirp.wavelength_m * f / (np.pi * w_emit) + range_m * w_emit / (2 * f)


def _centre_beam_shares(world: World, rows, cols):
    """Box / wall beat amplitude of each beam over the amplitude of a beam fully on that surface."""
    single = World(CFG, CFG.load_profile(), CFG.load_laser(),
                   Scene(world.scene.targets, mixed_pixels=False))
    full_box = single.beam_hits([64], [40], [1.0]).amplitude_v[0]      # col 40: well inside the box
    full_wall = single.beam_hits([64], [90], [1.0]).amplitude_v[0]     # col 90: well off it
    h = world.beam_hits(rows, cols, np.ones(len(rows)))
    on_box = np.abs(h.range_m - 1.0) < 0.01
    box = np.bincount(h.beam[on_box], h.amplitude_v[on_box], minlength=len(rows)) / full_box
    wall = np.bincount(h.beam[~on_box], h.amplitude_v[~on_box], minlength=len(rows)) / full_wall
    return box, wall, h


@pytest.mark.parametrize("rot_deg", [0.0, 30.0])
def test_box_edge_gives_two_weaker_returns_with_the_footprints_power_shares(rot_deg):
    w = _w_m(1.0)
    axis = np.array([np.cos(np.deg2rad(rot_deg)), np.sin(np.deg2rad(rot_deg))])   # the box's local x
    rows = []
    for s in np.linspace(-1.5, 1.5, 31) * w:
        # the box (rotated about the optical axis: a tilted edge) slides along its local x so that
        # its -x face's edge passes the axial beam at distance ~s (s > 0: the beam is on the box)
        centre = [*((0.1 - s) * axis), 1.1]
        world = _world(({**BOX, "center": centre, "rotation_deg": [0.0, 0.0, rot_deg]}, WALL))
        d = world.optics.directions(np.array([64]), np.array([64]))[0]
        x_edge = (d[:2] / d[2] - np.array(centre[:2])) @ axis + 0.1   # the beam's exact offset at z = 1 m
        box, wall, h = _centre_beam_shares(world, np.array([64]), np.array([64]))
        rows.append((x_edge, box[0], wall[0], sorted(np.round(h.range_m, 2))))
    x, got_box, got_wall = (np.array([r[k] for r in rows]) for k in range(3))
    expect = 0.5 * erfc(-np.sqrt(2) * x / w)          # Gaussian power on the box side of the edge
    assert np.max(np.abs(got_box - expect)) <= 0.16    # N = 16 equal-power samples (footprint.py)
    assert np.sqrt(np.mean((got_box - expect) ** 2)) <= 0.06
    np.testing.assert_allclose(got_box + got_wall, 1.0, atol=0.02)   # the shares fill the footprint
    assert np.all(np.diff(got_box) >= -1e-9)           # more of the box as the beam moves onto it
    straddle = (got_box > 0.01) & (got_wall > 0.01)
    assert straddle.sum() >= 10                        # two weaker returns, each below a full one
    for (_, b, wl, ranges), both in zip(rows, straddle):
        if both:
            assert ranges == [1.0, 2.0] and b < 1 and wl < 1


def test_returns_of_one_edge_pixel_are_at_the_two_surfaces_and_sum_to_one():
    w = _world()
    rows, cols = np.full(30, 64), np.arange(49, 79)
    box, wall, h = _centre_beam_shares(w, rows, cols)
    mixed = w.is_mixed(rows, cols)
    assert 1 <= mixed.sum() <= 5                       # only beams within ~1.3 w (3.7 mm) of the edge
    np.testing.assert_allclose((box + wall)[mixed], 1.0, atol=0.02)
    assert np.all(np.bincount(h.beam, minlength=30)[mixed] == 2)
    assert np.all(np.bincount(h.beam, minlength=30)[~mixed] == 1)


def test_scene_without_outlines_casts_one_ray_per_pixel():
    rows, cols = np.divmod(np.arange(128 * 128), 128)
    far_wall = Scene.from_toml(CONFIG_DIR / "scenes" / "far_wall.toml")   # 120 m wide: no edge in view
    for world in (_world((WALL,)), World(CFG, CFG.load_profile(), CFG.load_laser(), far_wall)):
        assert world.scene.mixed_pixels                # modelled by default ...
        h = world.beam_hits(rows, cols, np.ones(rows.size))
        assert world.rays_cast == rows.size and world.sub_rays_cast == 0   # ... but nothing to sample
        assert h.mixed_beams == 0 and np.all(np.bincount(h.beam) == 1)


def test_box_scene_samples_only_around_the_outline():
    world = _world()
    rows, cols = np.divmod(np.arange(128 * 128), 128)
    world.beam_hits(rows, cols, np.ones(rows.size))
    candidates = world.sub_rays_cast // fp.SAMPLES
    assert world.sub_rays_cast == candidates * fp.SAMPLES
    mixed = world.is_mixed(rows, cols).sum()
    assert 0 < mixed <= candidates < 0.2 * rows.size


def test_default_models_mixed_pixels_on_a_scene_that_does_not_ask():
    rows, cols = np.full(30, 64), np.arange(49, 79)
    default, off = _world(), _world(mixed_pixels=False)
    assert default.scene.mixed_pixels and not off.scene.mixed_pixels
    assert default.beam_hits(rows, cols, np.ones(30)).mixed_beams > 0
    h_off = off.beam_hits(rows, cols, np.ones(30))
    assert h_off.mixed_beams == 0 and off.sub_rays_cast == 0 and np.all(np.bincount(h_off.beam) == 1)
    assert Scene.from_dict(off.scene.to_dict()).mixed_pixels is False
    assert "mixed_pixels" not in default.scene.to_dict()


def test_ground_truth_of_a_mixed_pixel_is_the_surface_nearest_the_measurement():
    world = _world()
    rows, cols = np.full(30, 64), np.arange(49, 79)
    m = np.flatnonzero(world.is_mixed(rows, cols))
    r, c = rows[m], cols[m]
    central = world.ground_truth(r, c)                  # the single-ray truth is unchanged
    single = _world(mixed_pixels=False).ground_truth(r, c)
    np.testing.assert_array_equal(central, single)
    near_wall = world.ground_truth(r, c, measured_m=np.full(m.size, 1.97))
    near_box = world.ground_truth(r, c, measured_m=np.full(m.size, 1.004))
    np.testing.assert_allclose(near_wall, 2.0, atol=2e-3)
    np.testing.assert_allclose(near_box, 1.0, atol=1e-3)
    # a pixel that is not mixed keeps its central truth whatever was measured
    assert world.ground_truth([64], [40], measured_m=[1.9])[0] == pytest.approx(1.0, abs=3e-3)


def test_returns_closer_than_a_range_bin_blend_into_one_interval():
    from sim_devices.world.mixed_returns import nearest_truth
    bin_m = C_M_PER_S / (2 * CFG.chirp.excursion_hz)
    r = np.array([1.0, 1.0 + 0.5 * bin_m, 1.5])
    assert nearest_truth(1.0 + 0.2 * bin_m, r, bin_m) == pytest.approx(1.0 + 0.2 * bin_m)  # inside the blend
    assert nearest_truth(1.0 + 0.9 * bin_m, r, bin_m) == pytest.approx(1.0 + 0.5 * bin_m)
    assert nearest_truth(1.45, r, bin_m) == 1.5
    assert nearest_truth(1.2, np.array([np.inf]), bin_m) == np.inf


def test_footprint_radius_follows_the_optics():
    # 128x128 behind the 25 mm F/1.4 lens: waist lambda f / (pi W) = 2.80 mm, divergence W/f
    r1 = fp.footprint_radius_m(1.0, emission_w_m=4.4e-6, focal_m=25e-3, wavelength_m=1.55e-6,
                               aperture_m=25e-3 / 1.4)
    assert float(r1) == pytest.approx(1.55e-6 * 25e-3 / (np.pi * 4.4e-6) + 0.5 * 4.4e-6 / 25e-3, rel=1e-9)
    # a small aperture caps the waist
    r_cap = fp.footprint_radius_m(0.0, emission_w_m=4.4e-6, focal_m=25e-3, wavelength_m=1.55e-6,
                                  aperture_m=2e-3)
    assert float(r_cap) == pytest.approx(1e-3)


def test_sunflower_samples_split_the_gaussian_power_evenly():
    # power of a Gaussian (1/e^2 radius w) inside radius rho w: 1 - exp(-2 rho^2); sample i sits at
    # the (i + 1/2) / N quantile
    enclosed = 1 - np.exp(-2 * fp.SAMPLE_RADII ** 2)
    np.testing.assert_allclose(enclosed, (np.arange(fp.SAMPLES) + 0.5) / fp.SAMPLES, rtol=1e-12)
