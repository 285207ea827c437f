"""The simulated FPGA that drives the FPSA: its serial port, firmware, HV583 drivers and chip optics.

A byte-level peer of ``drivers.fpsa`` (the pty it serves carries the protocol of
``drivers.fpsa.protocol``).
"""

from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.fpsa.serial_port import PtyServer, SimSerial
from sim_devices.fpsa.triggers import PixelSchedule, TriggerBatch

__all__ = ["FpgaConfig", "FpgaSim", "HvDrive", "PixelSchedule", "PtyServer", "SimSerial", "TriggerBatch"]
