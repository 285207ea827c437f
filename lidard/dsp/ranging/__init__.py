"""From a pixel's spectra to its returns by one model (dissertation §2.1-2.1.2, §2.4).

:mod:`.lines` says what a return (range, velocity) predicts on every segment of a chirp period;
:mod:`.tones` fits the K tones of a ramp jointly (maximum likelihood, no mutual leakage bias);
:mod:`.order` tests whether the fitted tones explain the spectrum around each peak (the model-order
test at a stated level that replaced the width and residual rules); :mod:`.ramp` runs them on a
ramp's detections for the frame DSP and grows the model by a return the detector missed;
:mod:`.assign` scores the joint (R, v) hypotheses of the two ramps' peaks by likelihood and takes the
assignment of largest total likelihood (every chirp shape's pairing).
"""
