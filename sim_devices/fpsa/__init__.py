"""The simulated FPGA that drives the FPSA: its serial port, firmware, HV583 board and chip optics.

A byte-level peer of ``drivers.fpsa`` (the pty it serves carries the protocol of
``drivers.fpsa.protocol``). :class:`FpgaSim` holds a :class:`FpsaBoard` (HV583 registers, drive log),
the :class:`Firmware` that commands it and the :class:`ChipOptics` that read it.
"""

from sim_devices.fpsa.beams import ChipOptics
from sim_devices.fpsa.board import FpgaConfig, FpsaBoard
from sim_devices.fpsa.device import FpgaSim
from sim_devices.fpsa.firmware import Firmware
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.fpsa.serial_port import PtyServer, SimSerial
from sim_devices.fpsa.triggers import PixelSchedule, TriggerBatch

__all__ = ["ChipOptics", "Firmware", "FpgaConfig", "FpgaSim", "FpsaBoard", "HvDrive", "PixelSchedule", "PtyServer",
           "SimSerial", "TriggerBatch"]
