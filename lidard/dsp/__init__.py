"""Pure DSP core of lidard: range FFT, sub-bin estimators, CFAR, up/down-ramp velocity (§2.1, §2.4).

numpy/scipy only: no I/O, no logging, no clock. The rooms by concern, each floor importing only those
below it (the layers contract in pyproject.toml): :mod:`.spectrum` (windows, range FFT, DTFT,
instantaneous frequency, compiled passes) at the ground; :mod:`.detect` (CFAR, range gate),
:mod:`.phasenoise` (laser phase rebuilt and compensated) and :mod:`.linearize` (the chirp's ILC) on it;
:mod:`.ranging` (estimators, the tones' model, pairings) on detection; :mod:`.chain` the detection
chain; :mod:`.pnframe` and :mod:`.frame` the front ends the scan engine runs.
"""

from lidard.dsp.detect.cfar import CfarMethod, CfarSettings, Detections, ca_cfar_alpha, cfar_detect_with
from lidard.dsp.detect.os_cfar import os_cfar_alpha
from lidard.dsp.ranging.crlb import crlb_freq_var, crlb_freq_var_post_fft, post_fft_snr
from lidard.dsp.chain import PeakMeasurements, measure_peaks
from lidard.dsp.ranging.estimators import DEFAULT_METHOD, ESTIMATORS, EstimatorName, estimate
from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT
from lidard.dsp.ranging.velocity import pair_up_down
from lidard.dsp.spectrum.window import DspInputError, WindowInfo, WindowName, get_window, window_info

__all__ = [
    "C_M_PER_S",
    "DEFAULT_METHOD",
    "ESTIMATORS",
    "CfarMethod",
    "CfarSettings",
    "Detections",
    "DspInputError",
    "EstimatorName",
    "PeakMeasurements",
    "RangeFFT",
    "WindowInfo",
    "WindowName",
    "ca_cfar_alpha",
    "cfar_detect_with",
    "crlb_freq_var",
    "crlb_freq_var_post_fft",
    "estimate",
    "get_window",
    "measure_peaks",
    "os_cfar_alpha",
    "pair_up_down",
    "post_fft_snr",
    "window_info",
]
