"""OS-CFAR's screens (issue 18) are necessary conditions of the exact test: the detector's cells, with
the compiled block screen (lidard.dsp.spectrum._kernels) and with the numpy screens (os_cfar._os_screened),
are those of a brute-force OS-CFAR that sorts every cell's reference cells (§2.4: the k-th smallest
of N, alpha for the design Pfa), on spectra made to trip a screen that dropped a passing cell:
targets at the edges and at every offset within a block, next to strong clutter, equal powers,
all-zero and constant rows, a spectrum full of peaks, tiny and huge powers."""

import numpy as np
import pytest

from lidard.dsp.detect import cfar
from lidard.dsp.detect import os_cfar
from lidard.dsp.spectrum import jit

_needs_numba = pytest.mark.skipif(jit._compiled() is None, reason="numba is not installed")


def _brute_force(p, n_side, guard, pfa, rank, floor_factor=1e-20):
    """(rows, bins, noise) of the local maxima above alpha x the k-th smallest of their 2 n_side
    reference cells (guards skipped, numpy's "reflect" at the edges) and above the floor."""
    k, mean_kth, scaled_alpha, _ = os_cfar._os_constants(n_side, pfa, rank)
    reach = guard + n_side
    pp = np.pad(p, [(0, 0), (reach, reach)], mode="reflect")
    win = np.lib.stride_tricks.sliding_window_view(pp, 2 * reach + 1, axis=-1)
    ref = np.concatenate([win[..., :n_side], win[..., -n_side:]], axis=-1)
    noise = np.sort(ref, axis=-1)[..., k - 1] / mean_kth
    edge = np.full((p.shape[0], 1), -np.inf)
    local_max = (p >= np.hstack([edge, p[:, :-1]])) & (p > np.hstack([p[:, 1:], edge]))
    floor = floor_factor * p.max(axis=-1, keepdims=True)
    r, c = np.nonzero(local_max & (p > scaled_alpha * noise) & (noise > 0) & (p > floor))
    return r, c, noise[r, c]


def _spectra(case, rows=120, n=70, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.exponential(size=(rows, n))
    if case == "targets at every offset":          # one per row, at each bin in turn (edges, block borders)
        p[np.arange(rows), np.arange(rows) % n] *= rng.uniform(30, 3000, rows)
    elif case == "edges":
        p[:, [0, 1, n - 2, n - 1]] *= rng.uniform(1, 500, (rows, 4))
    elif case == "next to clutter":                 # a strong cell within reach of a weaker target
        t = rng.integers(0, n, rows)
        p[np.arange(rows), t] *= 200.0
        p[np.arange(rows), np.clip(t + rng.integers(-12, 13, rows), 0, n - 1)] = 1e6
    elif case == "equal powers":                    # ties everywhere: plateaus, equal references
        p = rng.integers(0, 4, (rows, n)).astype(float)
        p[:, rng.integers(0, n, 40)] = 100.0
        p[::2, 20:24] = 100.0
        p[1::2, -2:] = 100.0                        # the last cell is a local maximum (>= its neighbour)
    elif case == "zero and constant rows":
        p[::3] = 0.0
        p[1::3] = 2.5
        p[2::3, 30] = 1e3
    elif case == "full of peaks":                   # a local maximum every other cell, all strong
        p[:, ::2] *= 1e4
    elif case == "tiny and huge":
        p[::2] *= 1e-310                            # subnormal powers
        p[1::2] *= 1e300
        p[:, 35] *= 1e3
    elif case == "signed zeros":
        p[:, ::5] = -0.0
        p[:, 7] = 1e4
    return p


CASES = ["noise", "targets at every offset", "edges", "next to clutter", "equal powers", "zero and constant rows",
         "full of peaks", "tiny and huge", "signed zeros"]


@pytest.fixture(params=[False, pytest.param(True, marks=_needs_numba)], ids=["numpy", "compiled"])
def kern(request, monkeypatch):
    """The compiled kernels, or None with them turned off (the numpy screens, os_cfar._os_screened)."""
    if not request.param:
        monkeypatch.setenv("LIDARD_DSP_JIT", "0")
    return jit.kernels()


def _assert_cells(got, want):
    assert len(got) == 3
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("case", CASES)
def test_the_screened_detector_finds_the_brute_force_cells(case, kern):
    p = _spectra(case)
    for n_side, guard, rank, pfa in ((8, 2, None, 1e-6), (4, 1, 6, 1e-3), (3, 0, 1, 1e-2)):
        got = cfar._os_detected(p, n_side, guard, pfa, rank, 1e-20, kern)
        _assert_cells(got, _brute_force(p, n_side, guard, pfa, rank))


def test_the_screens_keep_cells_just_over_the_threshold_and_the_floor(kern):
    # a screen that is slightly too strict loses exactly these: a cell a hair above alpha x its
    # k-th smallest reference (a flat floor), or a hair above 1e-20 of the row's strongest cell
    n = 70
    for n_side, guard, rank, pfa in ((8, 2, None, 1e-6), (4, 1, 6, 1e-3)):
        k, mean_kth, scaled_alpha, _ = os_cfar._os_constants(n_side, pfa, rank)
        rows = []
        for f in (1 - 1e-7, 1 - 1e-15, 1 + 1e-15, 1 + 1e-7):
            flat = np.full((n, n), f * mean_kth / scaled_alpha)     # alpha x floor = f x the target
            flat[np.arange(n), np.arange(n)] = 1.0                  # the target at every bin in turn
            rows.append(flat)
        for g in (1 - 1e-9, 1 + 1e-9):
            low = np.full((n, n), 1e-24)
            low[np.arange(n), np.arange(n)] = g * 1e-20             # at the dynamic-range floor
            low[np.arange(n), (np.arange(n) + n // 2) % n] = 1.0    # of the strong cell half a row away
            rows.append(low)
        p = np.vstack(rows)
        want = _brute_force(p, n_side, guard, pfa, rank)
        found = set(zip(want[0].tolist(), want[1].tolist()))
        target = lambda block: {(block * n + i, i) for i in range(n)}      # noqa: E731
        assert target(0) <= found and not target(3) & found                 # f < 1: every one found; f > 1: none
        assert target(5) <= found and not target(4) & found                 # over the floor: found; under: not
        _assert_cells(cfar._os_detected(p, n_side, guard, pfa, rank, 1e-20, kern), want)


@_needs_numba
@pytest.mark.parametrize("n", [3, 11, 16, 17, 40, 47, 48, 100])
def test_the_compiled_screen_at_any_length_and_a_reach_past_its_fixed_loop(n):
    # short rows (one partial block), lengths about the block size, and references wider than the
    # kernel's fixed-length count (a neighbourhood over 48 cells): the same cells as by brute force
    p = _spectra("targets at every offset", rows=60, n=n, seed=n)
    kern = jit.kernels()
    for n_side, guard in ((1, 0), (2, 0), (8, 2), (20, 3)):
        if n <= n_side + guard:
            continue
        rank = max(1, int(round(1.5 * n_side)))
        got = cfar._os_detected(p, n_side, guard, 1e-3, rank, 1e-20, kern)
        _assert_cells(got, _brute_force(p, n_side, guard, 1e-3, rank))


@_needs_numba
def test_the_compiled_detector_finds_real_targets_it_would_lose_to_a_sloppy_screen():
    # a positive control: the cases above hold detections at edges and next to clutter to lose
    p = _spectra("next to clutter")
    r, c, _ = cfar._os_detected(p, 8, 2, 1e-6, None, 1e-20, jit.kernels())
    assert r.size > 100
    p = _spectra("edges")
    r, c, _ = cfar._os_detected(p, 8, 2, 1e-3, None, 1e-20, jit.kernels())
    assert np.isin(c, [0, p.shape[1] - 1]).sum() > 20


@_needs_numba
@pytest.mark.parametrize("bad, what", [(np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"),
                                       (-np.inf, "NaN or infinite"), (-1.0, "negative"), (-1e-300, "negative")])
def test_the_compiled_pass_names_bad_values_as_the_numpy_check_does(monkeypatch, bad, what):
    p = np.ones((3, 300))
    p[2, 299] = bad                                 # in the last row's last (partial) block
    for jit_env in ("1", "0"):
        monkeypatch.setenv("LIDARD_DSP_JIT", jit_env)
        with pytest.raises(cfar.DspInputError, match=what):
            cfar.cfar_detect_with(p)
    monkeypatch.setenv("LIDARD_DSP_JIT", "1")
    assert jit.os_detect(p, 8, 2, 12, 0.05, 2.0, 20.0, 1e-20, jit.kernels()) is None


def test_signed_zeros_are_not_bad_values():
    p = np.zeros((2, 40))
    p[0, ::3] = -0.0
    assert not cfar.cfar_detect_with(p).valid.any()
