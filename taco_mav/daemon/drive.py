"""Whether the autopilot drives the vehicle: taco+ vetoes zero-velocity updates while it does, and keeps asking
the camera at apparent stops (a smooth cruise looks still to the IMU).

ArduPilot: armed (HEARTBEAT) with a throttle output (VFR_HUD.throttle, %) of at least DRIVE_THROTTLE_MIN_PCT.
PX4: its VFR_HUD.throttle comes from `vehicle_thrust_setpoint`, which PX4's rover modules never publish (always
0 on a driving rover, read at PX4 main a70a558, streams/VFR_HUD.hpp), so armed in any mode but those that hold
the vehicle (AUTO.READY, AUTO.LOITER = Hold, AUTO.LAND; HEARTBEAT.custom_mode) counts as driving. That errs on
the safe side: a stop while armed in a driving mode is taken as driving (no zero-velocity update), never a
cruise as a stop. Decided at each VFR_HUD (5 Hz), so the answer is never older than the Localiser's
`plus.drive_command_timeout_s`.
"""

from __future__ import annotations

from typing import Any

from taco_mav.mavlink.mavconst import MAV_AUTOPILOT_PX4, MAV_MODE_FLAG_SAFETY_ARMED

__all__ = ["DRIVE_THROTTLE_MIN_PCT", "PX4_HOLDING_MODES", "DriveCommand"]

DRIVE_THROTTLE_MIN_PCT = 3  # ArduPilot: VFR_HUD throttle at or above this (armed) means the autopilot drives
PX4_MAIN_AUTO = 4  # PX4_CUSTOM_MAIN_MODE_AUTO
# PX4 AUTO sub modes that hold the vehicle where it is: READY 1, LOITER 3 (Hold), LAND 6
PX4_HOLDING_MODES = frozenset({(PX4_MAIN_AUTO, 1), (PX4_MAIN_AUTO, 3), (PX4_MAIN_AUTO, 6)})


class DriveCommand:
    """The adopted autopilot's HEARTBEATs and VFR_HUDs in, `driving(VFR_HUD)` out (None: not known yet)."""

    def __init__(self) -> None:
        self.armed: bool | None = None
        self.px4 = False
        self._px4_mode: tuple[int, int] = (0, 0)  # (main mode, sub mode) of PX4's custom_mode

    def on_heartbeat(self, msg: Any) -> None:
        """The autopilot's own HEARTBEAT: armed flag, autopilot type and (PX4) its custom mode."""
        self.armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        self.px4 = msg.autopilot == MAV_AUTOPILOT_PX4
        mode = int(msg.custom_mode)
        self._px4_mode = ((mode >> 16) & 0xFF, (mode >> 24) & 0xFF)

    def driving(self, throttle_pct: int) -> bool | None:
        """At a VFR_HUD with this throttle (%): True when the autopilot drives, False when it does not, None
        before its first HEARTBEAT."""
        if self.armed is None:
            return None
        if self.px4:
            return self.armed and self._px4_mode not in PX4_HOLDING_MODES
        return self.armed and abs(throttle_pct) >= DRIVE_THROTTLE_MIN_PCT
