"""Which bins hold a return: CFAR detection and the range gate (dissertation §2.4, §2.1.1, §4.4.3).

:mod:`.cfar` the detector (cell-averaging or ordered-statistic threshold, its false-alarm level and
the list of detections); :mod:`.os_cfar` the ordered-statistic noise estimate; :mod:`.os_gamma` its false-alarm
rate on spectra averaged over K records (Gamma(K) cells); :mod:`.gate` the
honest range gate and the per-point flags. The detector's post-processing of its list (widths,
harmonic ghosts, the strongest cells) is private (``_post``), reached through :mod:`.cfar`.
Built on :mod:`lidard.dsp.spectrum` only.
"""

__all__ = ["cfar", "gate", "os_cfar", "os_gamma"]
