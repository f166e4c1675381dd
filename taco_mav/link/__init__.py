"""MAVLink link of the daemon: connection and logs, input decoders, output encoders, time sync, the loop.

`Daemon` / `run_daemon` (daemon.py) are the entry points; everything else is a one-idea helper they compose.
"""

from __future__ import annotations

import os

# MAVLink 2 everywhere (GPS_INPUT.yaw is a MAVLink 2 extension); set before pymavlink is first imported.
os.environ.setdefault("MAVLINK20", "1")
