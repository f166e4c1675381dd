"""The live daemon, the application beside the autopilot: its loop, the origin, IMU and attitude inputs, camera
fixes through the matcher worker, real GNSS and its guard, the outputs and their health, and the ground
station's view. `Daemon` / `run_daemon` (daemon.py) are the entry points. It speaks MAVLink through
taco_mav/mavlink.
"""

from __future__ import annotations

import os

# MAVLink 2 everywhere (taco_mav/mavlink sets it too); set before pymavlink is first imported.
os.environ.setdefault("MAVLINK20", "1")
