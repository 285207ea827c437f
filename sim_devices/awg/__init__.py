"""The simulated arbitrary waveform generator: a USBTMC/SCPI peer of ``drivers.awg``."""

from sim_devices.awg.device import SimAwg

__all__ = ["SimAwg"]
