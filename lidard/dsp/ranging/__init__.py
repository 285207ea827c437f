"""From a pixel's spectra to its returns by one model (dissertation §2.1-2.1.2, §2.4).

:mod:`.tones` fits the K tones of a ramp jointly (maximum likelihood, no mutual leakage bias);
:mod:`.order` tests whether the fitted tones explain the spectrum around each peak (the model-order
test that replaces the shape and width rules: one tone against more, at a stated level).
"""
