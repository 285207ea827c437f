"""One pixel's spectra from a raw capture: the peak at the target's range, the threshold, the plot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidard.dsp.detect.cfar import os_cfar_alpha
from lidard.raw import RawCaptureError, ReprocessSettings, reprocess
from lidard.raw.spectrum import PixelSpectrum, pixel_spectrum, plot_pixel_spectrum

plt = pytest.importorskip("matplotlib.pyplot")


def test_the_detected_bin_is_the_targets_range_and_clears_the_threshold(capture):
    i = 21
    row, col = (int(v) for v in capture.pixels[i])
    spec = pixel_spectrum(capture.path, row, col)
    r_true = capture.range_true_m[i]
    bin_m = spec.range_m[1] - spec.range_m[0]
    for ramp in ("up", "down"):
        det = [d for d in spec.detections if d["ramp"] == ramp]
        assert det, ramp
        b = det[0]["bin"]
        assert abs(spec.range_m[b] - r_true) <= bin_m                # nearest bin of the tone
        assert spec.power[ramp][b] > spec.threshold[ramp][b]
        # a tone of 3000 codes: |X|^2 = (A/2)^2 at the peak up to the window's scalloping loss (< 1.5 dB, hann)
        a_v = 3000 * 2.0 / 2**16
        assert (a_v / 2) ** 2 / 1.42 < spec.power[ramp][b] <= (a_v / 2) ** 2 * 1.01
    # away from the peak the noise stays under the threshold almost everywhere (pfa 1e-6)
    lo, hi = spec.gate
    far = np.abs(np.arange(len(spec.range_m)) - b) > 8
    sel = far & (np.arange(len(spec.range_m)) >= lo) & (np.arange(len(spec.range_m)) <= hi)
    assert np.mean(spec.power["up"][sel] > spec.threshold["up"][sel]) < 0.01
    # the threshold is alpha times an order-statistic noise level: well above the median noise power
    # (alpha of the pixel's averaged spectrum: Gamma(K) cells, K its records)
    from lidard.raw.capture import RawCapture
    k = RawCapture(capture.path).averages
    alpha = os_cfar_alpha(16, 12, 1e-6, k)
    assert np.median(spec.threshold["up"][sel]) > 0.5 * alpha * np.median(spec.power["up"][sel])
    whole = reprocess(capture.path).points
    assert np.array_equal(spec.points, whole[(whole["row"] == row) & (whole["col"] == col)])


def test_overrides_change_what_the_spectrum_shows(capture):
    row, col = (int(v) for v in capture.pixels[5])
    hann = pixel_spectrum(capture.path, row, col)
    loose = pixel_spectrum(capture.path, row, col, ReprocessSettings(pfa=1e-2))
    assert loose.dsp["pfa"] == 1e-2
    # a higher false-point rate lowers the threshold by the ratio of the OS-CFAR alphas at the two
    # per-ramp levels sqrt(pfa / m) (lidard.dsp.ranging.points)
    from lidard.raw.capture import RawCapture
    from lidard.raw.replay import replay_dsp
    attrs = RawCapture(capture.path).attrs
    q0, q1 = (replay_dsp(attrs, s).dsp.ramp_pfa for s in (None, ReprocessSettings(pfa=1e-2)))
    assert q1 / q0 == pytest.approx(np.sqrt(1e-2 / replay_dsp(attrs).dsp.pfa))
    k = RawCapture(capture.path).averages     # the records the pixel's spectrum averages (Gamma(K) cells)
    ratio = os_cfar_alpha(16, 12, q1, k) / os_cfar_alpha(16, 12, q0, k)
    assert np.allclose(loose.threshold["up"], ratio * hann.threshold["up"], rtol=1e-9)
    bh = pixel_spectrum(capture.path, row, col, ReprocessSettings(window="blackmanharris"))
    assert bh.dsp["window"] == "blackmanharris" and not np.array_equal(bh.power["up"], hann.power["up"])


def test_phase_noise_capture_shows_the_compensated_spectrum(capture_mzi):
    row, col = (int(v) for v in capture_mzi.pixels[4])
    spec = pixel_spectrum(capture_mzi.path, row, col)
    assert spec.dsp["phase_noise_compensation"] is True
    b = [d for d in spec.detections if d["ramp"] == "up"][0]["bin"]
    assert abs(spec.range_m[b] - capture_mzi.range_true_m[4]) <= spec.range_m[1] - spec.range_m[0]


def test_unknown_pixel_is_named(capture):
    with pytest.raises(RawCaptureError, match=r"pixel \(40, 40\)"):
        pixel_spectrum(capture.path, 40, 40)


def test_plot_writes_a_png_with_content(capture, tmp_path):
    row, col = (int(v) for v in capture.pixels[3])
    out = plot_pixel_spectrum(pixel_spectrum(capture.path, row, col), tmp_path / "s.png")
    img = plt.imread(out)
    assert img.shape[0] == 600 and img.shape[1] == 800
    assert img[..., :3].std() > 0.05                 # not a blank canvas
    spec = pixel_spectrum(capture.path, row, col)
    d = json.loads(json.dumps(spec.to_dict()))
    assert len(d["power_v2"]["up"]) == len(d["range_m"]) and d["detections"]
    back = PixelSpectrum.from_dict(d)
    assert np.array_equal(back.points, spec.points) and np.array_equal(back.threshold["down"], spec.threshold["down"])
    assert back.gate == spec.gate and back.detections == spec.detections
