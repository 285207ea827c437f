"""Eq. 2-11 against the single-photodiode circulator geometry of §4.4 (docs/physics.md)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config
from lidard.physics.budget import LinkParams, snr_db


def test_single_photodiode_mixing_term_is_twice_eq_2_11():
    p = LinkParams.table_2_2()
    p_rx = 3e-9
    r = p.responsivity_a_per_w
    # fields of power P_ref and P_rx on ONE detector, relative phase swept over a period
    dphi = np.linspace(0, 2 * np.pi, 4096, endpoint=False)
    e = np.sqrt(p.p_ref_w) + np.sqrt(p_rx) * np.exp(1j * dphi)
    i = r * np.abs(e) ** 2
    ac_single = (i.max() - i.min()) / 2
    assert ac_single == pytest.approx(2 * p.i_ac_a(p_rx), rel=1e-6)
    # a 50/50 coupler port (what eq. 2-11 counts) sees half of each power: eq. 2-11 exactly
    e_port = np.sqrt(p.p_ref_w / 2) + np.sqrt(p_rx / 2) * np.exp(1j * dphi)
    i_port = r * np.abs(e_port) ** 2
    assert (i_port.max() - i_port.min()) / 2 == pytest.approx(p.i_ac_a(p_rx), rel=1e-6)


def test_bench_keeps_eq_2_11_and_lands_on_fig_4_32():
    p = load_config(CONFIG_DIR / "sim.toml").link_params()
    snr = float(snr_db(p, 0.8))
    assert snr == pytest.approx(29.1, abs=0.1)        # docs/physics.md; Fig. 4-32: ~28 dB
    # the ideal single-diode factor would add 20 log10(2) = 6.02 dB: 35.1 dB, farther from 28 dB
    assert abs(snr + 20 * np.log10(2) - 28.0) > abs(snr - 28.0)
