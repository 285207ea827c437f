"""The simulated bench: every device wired to one world and one virtual clock (``lidar-sim``).

``bench.py`` assembles the bench; ``capture.py`` synthesizes the digitizer's segments from the world;
``fault_injector.py`` injects and clears faults; ``control.py`` is the bench's JSON control port.
"""

from sim_devices.bench.bench import Bench, main
from sim_devices.bench.control import BenchControlClient

__all__ = ["Bench", "BenchControlClient", "main"]
