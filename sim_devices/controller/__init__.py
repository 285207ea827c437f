"""The simulated laser / TEC / HV controller: a Modbus TCP peer of ``drivers.controller``."""

from sim_devices.controller.device import ControllerSim
from sim_devices.controller.model import ControllerModel, ControllerSpec, ControllerState, Dynamics

__all__ = ["ControllerModel", "ControllerSim", "ControllerSpec", "ControllerState", "Dynamics"]
