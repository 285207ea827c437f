"""The simulated laser / TEC / HV controller: a Modbus TCP peer of ``drivers.controller``."""

from sim_devices.controller.device import ControllerSim
from sim_devices.controller.model import ControllerModel, ControllerState, Dynamics

__all__ = ["ControllerModel", "ControllerSim", "ControllerState", "Dynamics"]
