"""Wheel odometry (not in the paper): the one definition of its parameters, their defaults and where each comes
from. A profile's `wheels:` section loads into it (config/profile.py); the daemon's wheel handler
(daemon/wheels.py), the odometry (core/wheel_odometry.py) and taco+'s wheel speed (core/plus/wheel_speed.py) read
it. Without `enabled` nothing reads it and nothing changes. Lengths metres, speeds m/s, times autopilot seconds.

Where the numbers come from: ArduPilot Rover reads its encoders at 50 Hz (`update_wheel_encoder` in its scheduler)
and sends `WHEEL_DISTANCE` (cumulative metres per wheel, `time_usec` the send time in whole milliseconds) at its
stream group's rate (EXTRA1 at 03494bd, which refuses SET_MESSAGE_INTERVAL for it); its SITL quadrature encoders
(`WENC_TYPE 10`) count ticks of the true speed and yaw rate at `WENC_CPR` per turn of `WENC_RADIUS`
(docs/ardupilot.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from taco_mav.core.fields import bounded

__all__ = ["WheelParams"]


@dataclass(frozen=True)
class WheelParams:
    """The wheel encoders as the autopilot sends them (`WHEEL_DISTANCE`) and as taco+ fuses them (paper mode
    ignores them)."""

    enabled: bool = False  # ask for WHEEL_DISTANCE and fuse it (taco+)
    # WHEEL_DISTANCE rate asked for, Hz: ArduPilot updates the distances at 50 Hz; 20 Hz gives two samples per
    # 10 Hz filter frame and a speed over 50 ms holds 16 ticks of a 3200-count, 5 cm wheel at 1 m/s.
    rate_hz: float = field(default=20.0, metadata=bounded(1.0, 50.0))
    # Each wheel's lateral position, body FRD y (right positive), metres, as the autopilot's WENC_POS_Y and
    # WENC2_POS_Y (ArduPilot's SITL pair: 0.075 and -0.075; its encoder 1 turns as the wheel at +y). Two wheels
    # at different y give a yaw rate (the slip check against the gyro); (0, 0): no yaw rate.
    wheel_pos_y_m: tuple[float, float] = field(default=(0.0, 0.0), metadata=bounded(-5.0, 5.0))
    # True: read WENC_POS_Y / WENC2_POS_Y from the autopilot at start-up (PARAM_REQUEST_READ) instead.
    pos_y_from_autopilot: bool = False
    # White 1-sigma of one wheel speed over a filter frame, m/s: encoder quantisation (a 3200-count 5 cm wheel
    # over 50 ms: 2 mm/s), ground roughness and the differencing of two 1 ms time stamps (ArduPilot sends whole
    # milliseconds: 2 % of a 50 ms interval).
    speed_sigma_mps: float = field(default=0.05, metadata=bounded(0.0, open_lo=True))
    # The wheel radius's relative 1-sigma before any fix taught it: tyre pressure, load and wear put a few per cent
    # on a nominal radius (a 5 mm error on a 10 cm wheel is 5 %); learnt online from the camera's fixes.
    scale_sigma: float = field(default=0.05, metadata=bounded(0.0, 1.0, open_lo=True))
    # Random walk of the scale, 1-sigma per sqrt(km): a radius that changes slowly (a tyre warming, losing air).
    scale_walk_per_sqrt_km: float = field(default=0.005, metadata=bounded(0.0))
    # A fix pair teaches the scale only over at least this much wheel-driven displacement, m: over less the fixes'
    # own metre of noise says nothing about a few per cent.
    scale_min_span_m: float = field(default=10.0, metadata=bounded(0.0))
    # Nothing new from the encoders for this long (autopilot s): the source is quiet (event, STATUSTEXT).
    quiet_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    # A distance step implying more than this speed is a jump (an encoder that skipped, a reset): refused, m/s.
    max_speed_mps: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))
    # A wheel speed whose middle is older than this at the frame it would be fused in is stale, s.
    max_age_s: float = field(default=0.3, metadata=bounded(0.0, open_lo=True))
    # Innovation gate against the filter's speed (chi-square, 1 dof, 99.9 %, as the camera speed's) ...
    gate_chi2: float = field(default=10.83, metadata=bounded(0.0, open_lo=True))
    # ... this many refused speeds in a row refuse the source (slip, a wheel in the air, a stuck encoder) ...
    refuse_after: int = field(default=3, metadata=bounded(1))
    # ... until this many in a row agree again.
    agree_to_resume: int = field(default=10, metadata=bounded(1))
    # The wheels' yaw rate against the gyro's: a difference beyond this, rad/s, is slip (a wheel in the air spins
    # freely; a skid turns the vehicle without the wheels).
    yaw_rate_gate_rps: float = field(default=0.3, metadata=bounded(0.0, open_lo=True))
    # taco+'s time trigger (plus.trigger_time_s) while the wheel speed is in use, s: between fixes the speed is
    # known and only the heading drifts, so the covariance trigger asks for the fixes the drift needs.
    trigger_time_s: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))
