"""From a pixel's spectra to its returns by one model (dissertation §2.1-2.1.2, §2.4).

:mod:`.lines` says what a return (range, velocity) predicts on every segment of a chirp period;
:mod:`.tones` fits the K tones of a ramp jointly (maximum likelihood, no mutual leakage bias);
:mod:`.pixeltone` fits one return's beat to all the records of a pixel (maximum likelihood, with the
drift of a moving return's beat);
:mod:`.order` tests whether the fitted tones explain the spectrum around each peak (the model-order
test at a stated level that replaced the width and residual rules); :mod:`.ramp` runs them on a
ramp's detections for the frame DSP and grows the model by a return the detector missed;
:mod:`.assign` scores the joint (R, v) hypotheses of the two ramps' peaks by likelihood and takes the
assignment of largest total likelihood (every chirp shape's pairing).

The estimators of a single tone and their bound sit beside them: :mod:`.estimators` (sub-bin beat
frequency), :mod:`.crlb` (its Cramer-Rao bound); the chirp shapes' pairings: :mod:`.velocity` (up/down
ramps), :mod:`.threeseg` (the three-segment chirp) with :mod:`.cwhold` (the held segment's drift);
:mod:`.iqbalance` the coherent receiver's I/Q model. Built on :mod:`lidard.dsp.spectrum` and
:mod:`lidard.dsp.detect`.
"""

__all__ = [
    "assign", "crlb", "cwhold", "estimators", "iqbalance", "lines", "order", "pixeltone", "points", "ramp", "threeseg",
    "tones", "velocity",
]
