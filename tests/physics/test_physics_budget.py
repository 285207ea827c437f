"""Link budget against the dissertation: Fig. 2-8 (SNR = 1 near 220 m), eqs. 4-29/4-33, Fig. 4-32."""

import numpy as np
import pytest

from lidard.config import load_config
from lidard.physics.budget import (LinkParams, asd_components, budget_report, max_range_m,
                                   quantization_asd, shot_limited_ref_window_w, snr_db)
from lidard.physics.constants import C_M_PER_S, E_CHARGE_C


def test_signal_meets_shot_noise_near_220_m():
    d = max_range_m(LinkParams.table_2_2(), against="shot")
    assert 210 < d < 230


def test_shot_limited_reference_window_eqs_4_29_and_4_33():
    lo, hi = shot_limited_ref_window_w(LinkParams.table_2_2())
    assert round(lo * 1e6, 2) == 3.40
    assert round(hi * 1e6) == 337


def test_signal_asd_follows_eq_2_14_by_hand():
    p = LinkParams.table_2_2()
    d = 50.0
    p_rx = 31.5e-3 * 0.1 * (10e-3) ** 2 / (4 * d**2) * 0.5   # eq. 2-10 with Table 2-2
    i_ac = 0.95 * np.sqrt(5e-3 * p_rx)
    tau = 2 * d / C_M_PER_S
    expected = 1.6e4 * np.sqrt(i_ac**2 / 2 * 80e-6 * np.exp(-2 * tau / 0.64e-6))
    assert float(asd_components(p, d)["signal"]) == pytest.approx(expected, rel=1e-12)
    shot = 1.6e4 * np.sqrt(2 * E_CHARGE_C * 0.95 * (5e-3 + p_rx))
    assert float(asd_components(p, d)["shot"]) == pytest.approx(shot, rel=1e-12)


def test_pedestal_vanishes_for_short_range_and_an_ideal_laser():
    p = LinkParams.table_2_2()
    c = asd_components(p, np.array([1e-6, 1.0, 100.0]))
    assert np.all(np.diff(c["pedestal"] / c["signal"]) > 0)  # grows with tau/tau_c
    ideal = asd_components(p.with_(coherence_time_s=np.inf), 100.0)
    assert float(ideal["pedestal"]) == 0.0


def test_pedestal_dominates_at_high_power_and_adc_at_low_power_fig_2_9():
    p = LinkParams.table_2_2()
    high = budget_report(p.with_(source_power_w=1.0), 50.0)
    low = budget_report(p.with_(source_power_w=1e-5), 50.0)
    assert high["dominant_noise"] == "pedestal"
    assert low["dominant_noise"] == "adc"


def test_snr_decreases_with_distance_and_max_range_is_the_crossing():
    p = LinkParams.table_2_2()
    d = np.geomspace(1, 500, 50)
    s = snr_db(p, d)
    assert np.all(np.diff(s) < 0)
    r = max_range_m(p)
    assert float(snr_db(p, r)) == pytest.approx(0.0, abs=1e-6)


def test_default_fpsa_lidar_setup_gives_about_28_db_on_the_cal_target():
    cfg = load_config("config/sim.toml")
    p = cfg.link_params()
    assert p.p_ref_w == pytest.approx(39.8e-6, rel=0.01)   # §4.4.2: -34 dB of 100 mW
    assert p.cmrr_db == 0.0                                 # single photodiode
    snr = float(snr_db(p, 0.8))
    assert 25.0 < snr < 32.0                                # Fig. 4-32: ~28 dB


def test_quantization_asd_is_lsb_over_sqrt12_spread_over_nyquist():
    q = quantization_asd(1.0, 8, 1e9)
    assert q == pytest.approx((1 / 256) / np.sqrt(12) / np.sqrt(0.5e9))


def test_bad_reference_component_is_named():
    with pytest.raises(ValueError, match="against"):
        max_range_m(LinkParams.table_2_2(), against="bogus")
