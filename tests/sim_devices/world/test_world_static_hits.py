"""The world's per-beam static hits (issue 18): a batch's beams repeat pixels (a pixel's averages,
the two beams of a switch transition), and the hits of each distinct pixel are cast once and gathered
from the world's store. Checked against the per-beam concatenation of each pixel's hits cast afresh
(the central ray's; the footprint's returns on a mixed pixel), on a scene with mixed (edge) pixels."""

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


def _entries(w: World, rows, cols) -> list[tuple]:
    """Each pixel's hits cast afresh, apart from the world's store: the footprint-weighted returns of
    a mixed pixel, else the central ray's hits (weight 1)."""
    out = []
    for r, c in zip(rows, cols):
        key = int(r) * 4096 + int(c)
        if key in w._mixed:
            out.append(tuple(np.asarray(v, np.float64) for v in w._mixed[key]))
            continue
        h = w._static_cast(w.optics.directions(np.array([r]), np.array([c])))
        n = int(h.count[0])
        out.append((h.range_m[0, :n], h.incidence_rad[0, :n], h.reflectivity[0, :n], h.radial_velocity_mps[0, :n],
                    h.transmission[0, :n], h.target_index[0, :n].astype(np.float64), np.ones(n)))
    return out


def test_each_beam_gets_its_own_pixels_hits_in_order():
    w = _world()
    rng = np.random.default_rng(2)
    # pixels across the box edge (mixed), on the box, on the wall; each repeated, in a shuffled order
    px = np.array([(62, c) for c in range(58, 72)] + [(10, 10), (64, 64)])
    pick = rng.integers(0, len(px), 300)
    rows, cols = px[pick, 0], px[pick, 1]
    cat, beam = w._hits(rows, cols, None)
    entries = _entries(w, rows, cols)
    expect = [np.concatenate([e[j] for e in entries]) for j in range(7)]
    counts = [len(e[0]) for e in entries]
    assert np.array_equal(beam, np.repeat(np.arange(rows.size), counts))
    for got, want in zip(cat, expect):
        assert np.array_equal(got, want)
    assert len(set(counts)) > 1                      # mixed pixels (two returns) and single ones
    mixed = w.is_mixed(rows, cols)
    assert np.array_equal(mixed, [(int(r) * 4096 + int(c)) in w._mixed for r, c in zip(rows, cols)])
    assert mixed.any() and not mixed.all()


def test_no_beams_no_hits():
    cat, beam = _world()._hits(np.zeros(0, np.int64), np.zeros(0, np.int64), None)
    assert beam.size == 0 and all(c.size == 0 for c in cat)


# The bench's look-ahead cast (World.precast): casting a run's next pixels in one call gives each
# pixel the hits it gets when cast read by read, mixed (footprint-weighted) edge pixels included.

def test_precast_pixels_get_the_hits_of_a_read_by_read_cast():
    rows = np.repeat(np.arange(56, 72), 24)
    cols = np.tile(np.arange(50, 74), 16)
    by_read, ahead = _world(), _world()
    want = [by_read._static_hits(rows[i:i + 20], cols[i:i + 20], True) for i in range(0, rows.size, 20)]
    ahead.precast(rows, cols)
    assert ahead.rays_cast == rows.size             # every pixel cast by the look-ahead, once
    got = [ahead._static_hits(rows[i:i + 20], cols[i:i + 20], True) for i in range(0, rows.size, 20)]
    assert ahead.rays_cast == rows.size             # ... and not again when the reads come
    assert len(ahead._mixed) == len(by_read._mixed) > 0
    for (g_cat, g_beam), (w_cat, w_beam) in zip(got, want):
        assert np.array_equal(g_beam, w_beam)
        for a, b in zip(g_cat, w_cat):
            assert np.array_equal(a, b)
    # and each read's hits are the pixels' own, cast afresh
    for i, (cat, _) in zip(range(0, rows.size, 20), got):
        expect = _entries(ahead, rows[i:i + 20], cols[i:i + 20])
        assert all(np.array_equal(cat[j], np.concatenate([e[j] for e in expect])) for j in range(7))


def test_the_kept_white_noise_asd_follows_a_new_link():
    from dataclasses import replace

    from lidard.physics.budget import asd_components
    from sim_devices.world.world import WHITE_NOISES

    def direct(link):
        c = asd_components(link, 1.0)
        return float(np.sqrt(sum(float(c[k]) ** 2 for k in WHITE_NOISES)))

    w = _world()
    assert w.white_noise_asd_v() == direct(w.link) == w.white_noise_asd_v()
    w.link = replace(w.link, tia_gain_v_per_a=3.0 * w.link.tia_gain_v_per_a)   # e.g. another TIA fitted
    assert w.white_noise_asd_v() == direct(w.link) != direct(replace(w.link, tia_gain_v_per_a=w.link.tia_gain_v_per_a / 3))
