"""MAVLink enum values the link modules share, under one name each (MAV_SEVERITY, heartbeat fields).

Plain ints rather than pymavlink lookups so that modules without a connection (tests, the GCS health model)
use the same names.
"""

from __future__ import annotations

__all__ = ["GPS_TYPE_MAV", "GPS_TYPE_NONE", "MAV_AUTOPILOT_INVALID", "MAV_AUTOPILOT_PX4", "MAV_MODE_FLAG_SAFETY_ARMED",
           "MAV_TYPE_GCS", "MAV_TYPE_ONBOARD_CONTROLLER", "SEV_ERROR", "SEV_INFO", "SEV_NOTICE", "SEV_WARNING"]

# MAV_SEVERITY of STATUSTEXTs.
SEV_ERROR, SEV_WARNING, SEV_NOTICE, SEV_INFO = 3, 4, 5, 6
# HEARTBEAT.autopilot: PX4; and that of a component that is no autopilot (ground station, companion computer).
MAV_AUTOPILOT_PX4, MAV_AUTOPILOT_INVALID = 12, 8
# HEARTBEAT.type of components that are never the autopilot we serve.
MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER = 6, 18
# HEARTBEAT.base_mode bit: the vehicle is armed.
MAV_MODE_FLAG_SAFETY_ARMED = 128
# ArduPilot GPSn_TYPE values: no receiver, and MAVLink (GPS_INPUT: the instance that carries our output).
GPS_TYPE_NONE, GPS_TYPE_MAV = 0, 14
