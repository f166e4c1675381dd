"""MAVLink, the protocol only: the connection (UDP, TCP, serial; reconnect, signing, a tlog of both directions),
input decoders, output encoders (GPS_INPUT, HIL_GPS, ODOMETRY, ...), stream requests, time sync and the
message-id constants. Nothing here knows what the daemon does with a message (taco_mav/daemon).
"""

from __future__ import annotations

import os

# MAVLink 2 everywhere (GPS_INPUT.yaw is a MAVLink 2 extension); set before pymavlink is first imported.
os.environ.setdefault("MAVLINK20", "1")
# pymavlink loads its default dialect ("all") when mavutil is first imported, though every connection made here
# asks for ardupilotmega: 12 MB of a companion's memory for nothing (docs/companion.md). A user's own setting is kept.
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")
