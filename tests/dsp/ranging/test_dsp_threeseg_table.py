"""The three-segment pairing's shared range-max table (issue 18) answers as a table of its own."""

import numpy as np

from lidard.dsp.ranging.threeseg import _RangeMax, _range_max_table, cw_band_power


def test_shared_table_levels_are_the_full_tables_levels():
    p = np.random.default_rng(1).exponential(size=(5, 300))
    full = _range_max_table(p)
    lazy = _RangeMax(p)
    for level in (3, 0, 8, 5):                      # any order: deeper levels are built on demand
        np.testing.assert_array_equal(lazy[level], full[level])


def test_band_power_with_a_shared_table_is_the_band_maximum():
    rng = np.random.default_rng(2)
    p = rng.exponential(size=(6, 200))
    centre = rng.uniform(0, 200, (6, 4))
    half = rng.uniform(0, 40, (6, 4))
    table = _RangeMax(p)
    for _ in range(2):                              # the second query reuses the built levels
        peak, in_guard = cw_band_power(p, 1.0, centre, half, 3, table)
        want, want_guard = cw_band_power(p, 1.0, centre, half, 3)
        np.testing.assert_array_equal(peak, want)
        np.testing.assert_array_equal(in_guard, want_guard)
    lo = np.clip(np.floor(centre - half).astype(int), 3, 200)
    hi = np.clip(np.ceil(centre + half).astype(int) + 1, 3, 200)
    for r in range(6):
        for c in range(4):
            if hi[r, c] > lo[r, c]:
                assert peak[r, c] == p[r, lo[r, c]:hi[r, c]].max()
