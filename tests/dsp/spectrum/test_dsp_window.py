"""Window figures of merit against their textbook values (derived here from the definitions)."""

import numpy as np
import pytest

from lidard.dsp.spectrum.window import DspInputError, get_window, window_info


@pytest.mark.parametrize(
    ("name", "enbw", "cg"),
    [
        ("rectangular", 1.0, 1.0),
        # Hann: w = 0.5 - 0.5 cos -> mean 0.5, mean(w^2) = 0.25 + 0.125 = 0.375, ENBW = 0.375/0.25.
        ("hann", 1.5, 0.5),
        # 4-term Blackman-Harris a0..a3: mean a0, mean(w^2) = a0^2 + (a1^2 + a2^2 + a3^2)/2.
        ("blackmanharris", None, 0.35875),
    ],
)
def test_enbw_and_coherent_gain_from_definition(name, enbw, cg):
    info = window_info(name, 512)
    if enbw is None:
        a = np.array([0.35875, 0.48829, 0.14128, 0.01168])
        enbw = (a[0] ** 2 + 0.5 * np.sum(a[1:] ** 2)) / a[0] ** 2
    assert info.enbw_bins == pytest.approx(enbw, rel=1e-9)
    assert info.coherent_gain == pytest.approx(cg, rel=1e-9)


def test_mainlobe_widths_are_ordered_and_match_closed_forms():
    rect = window_info("rectangular", 512)
    hann = window_info("hann", 512)
    bh = window_info("blackmanharris", 512)
    # Rectangular: |sinc(u)| = 1/2 at u = 0.6034 -> full width 1.207 bins.
    assert rect.mainlobe_6db_bins == pytest.approx(1.2067, abs=2e-3)
    # Hann: |W(u)| = |sinc(u)| / |1 - u^2| = 1/2 at u = 1 exactly -> width 2.0 bins.
    assert hann.mainlobe_6db_bins == pytest.approx(2.0, abs=2e-3)
    assert rect.first_null_bins == pytest.approx(1.0, abs=0.01)
    assert hann.first_null_bins == pytest.approx(2.0, abs=0.01)
    assert bh.first_null_bins == pytest.approx(4.0, abs=0.01)
    assert rect.mainlobe_6db_bins < hann.mainlobe_6db_bins < bh.mainlobe_6db_bins


def test_leakage_envelope_matches_first_sidelobe_levels():
    # Hann: tone half a bin off, next-but-one bin: |W(1.5)|^2/|W(0.5)|^2 = ((1-0.25)/(1.5^2-1)*0.5/1.5)^2
    hann = window_info("hann", 512)
    expect = ((1 - 0.25) / (1.5**2 - 1) * 0.5 / 1.5) ** 2
    assert hann.leakage_envelope[2] == pytest.approx(expect, rel=0.02)
    assert np.all(np.diff(window_info("blackmanharris", 512).leakage_envelope[2:6]) < 0)


def test_window_is_periodic_and_validated():
    w = get_window("hann", 8)
    assert w[0] == 0.0 and w[4] == pytest.approx(1.0)
    with pytest.raises(DspInputError, match="kaiser"):
        get_window("kaiser", 8)
    with pytest.raises(DspInputError, match="n=1"):
        get_window("hann", 1)
