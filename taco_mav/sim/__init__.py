"""The autopilot simulator: an ArduPilot rover played from a drive over MAVLink (`taco-mav sim`), with
ArduPilot's GPS_INPUT acceptance rules and scoring of what it receives.

`Simulator` (start/stop/join/results) is the importable object; `simulate` the command's use case.
"""

from __future__ import annotations

from taco_mav.sim.run import simulate, write_results
from taco_mav.sim.simulator import SimOptions, Simulator
from taco_mav.sim.source import SimDrive, open_drive

__all__ = ["SimDrive", "SimOptions", "Simulator", "open_drive", "simulate", "write_results"]
