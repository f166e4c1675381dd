"""MAVLink sections of a profile: the link to the autopilot and what the daemon sends back."""

from __future__ import annotations

from dataclasses import dataclass, field

from taco_mav.config.fields import bounded

__all__ = ["LinkConfig", "OutputConfig"]


@dataclass(frozen=True)
class LinkConfig:
    """MAVLink link to the autopilot (the daemon's inputs; see docs/ardupilot.md)."""

    # Our system id; 0 = take the autopilot's (the usual choice for a companion computer on the vehicle).
    sysid: int = field(default=0, metadata=bounded(0, 255))
    compid: int = field(default=191, metadata=bounded(1, 255))  # MAV_COMP_ID_ONBOARD_COMPUTER
    # Autopilot system id to listen to; 0 = the first HEARTBEAT from an autopilot component.
    target_sysid: int = field(default=0, metadata=bounded(0, 255))
    baud: int = field(default=921600, metadata=bounded(1200))  # serial links only (a "path:baud" CONN overrides)
    # IMU message to use: "auto" (first seen of HIGHRES_IMU, RAW_IMU, SCALED_IMU, SCALED_IMU2, SCALED_IMU3),
    # or one of those names.
    imu_message: str = "auto"
    imu_rate_hz: float = field(default=50.0, metadata=bounded(1.0, 400.0))  # requested IMU and ATTITUDE rate
    attitude_rate_hz: float = field(default=50.0, metadata=bounded(1.0, 400.0))
    request_rates: bool = True  # send SET_MESSAGE_INTERVAL (fallback REQUEST_DATA_STREAM) at start-up
    heartbeat_hz: float = field(default=1.0, metadata=bounded(0.2, 10.0))
    timesync_hz: float = field(default=1.0, metadata=bounded(0.0, 10.0))  # TIMESYNC requests; 0 disables
    # Autopilot time stepping back by more than this is a reboot: the estimator is re-anchored.
    reboot_backstep_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    # Nothing from the autopilot for this long (companion clock, s) is a lost link: event + STATUSTEXT later.
    timeout_s: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    check_params: bool = True  # read GPS1_TYPE / GPS_TYPE at start-up and warn unless 14 (ArduPilot)


@dataclass(frozen=True)
class OutputConfig:
    """What the daemon sends back (GPS_INPUT for ArduPilot; HIL_GPS or ODOMETRY for PX4)."""

    # Any of "gps_input", "hil_gps", "odometry".
    messages: tuple[str, ...] = ("gps_input",)
    rate_hz: float = field(default=5.0, metadata=bounded(1.0, 20.0))  # steady, independent of fixes
    gps_id: int = field(default=0, metadata=bounded(0, 9))  # zero-based GPS instance (GPS1 = 0)
    # Virtual satellite count (there are no satellites; EKF3 wants >= 6).
    satellites_visible: int = field(default=10, metadata=bounded(0, 255))
    # HDOP = horiz_accuracy / hdop_uere_m, clipped to [hdop_min, 99.99]; 2.0 maps EKF3's 5 m gate to HDOP 2.5.
    hdop_uere_m: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    hdop_min: float = field(default=0.5, metadata=bounded(0.0, open_lo=True))
    # Reported speed accuracy, m/s: max(floor, fraction * speed) (the filter carries no speed covariance).
    speed_accuracy_floor_mps: float = field(default=0.3, metadata=bounded(0.0, open_lo=True))
    speed_accuracy_fraction: float = field(default=0.05, metadata=bounded(0.0))
    # fix_type 3 while sigma_h <= degrade_accuracy_m; above it fix_type 1 until sigma_h <= recover_accuracy_m.
    degrade_accuracy_m: float = field(default=10.0, metadata=bounded(0.0, open_lo=True))
    recover_accuracy_m: float = field(default=8.0, metadata=bounded(0.0, open_lo=True))
    stall_s: float = field(default=0.5, metadata=bounded(0.0, open_lo=True))  # no IMU this long: fix_type 1
    vertical_accuracy_m: float = field(default=5.0, metadata=bounded(0.0, open_lo=True))  # reported epv (flat ground)
    # GPS_INPUT.yaw from the compass heading (36000 = north). Never a yaw source (EK3_SRC1_YAW=2/3 would loop the
    # compass back, docs/ardupilot.md), but ArduPilot Rover SITL drove its square closer to our track with it
    # (error over reported accuracy 2.7 against 3.4 without, one mission each). The synthetic profiles leave it
    # off: the simulator only scores, and a reported first yaw turns the scored track by its compass error
    # (sim/score.py, docs/taco_plus.md "The map's offset").
    send_yaw: bool = True
    leap_seconds: int = field(default=18, metadata=bounded(0, 60))  # GPS - UTC for time_week/time_week_ms
    statustext_interval_s: float = field(default=5.0, metadata=bounded(0.0))  # rate limit of fix STATUSTEXTs
    # The point whose position the autopilot expects, relative to the vehicle reference point (the estimate's
    # point; camera.position_frd_m is measured from the same one), body FRD metres [x forward, y right, z down].
    # ArduPilot GPS_INPUT: the antenna of instance gps_id + 1, i.e. copy GPS{n}_POS_X/Y/Z (GPS_POS{n}_X/Y/Z before
    # 4.6; the daemon reads them and warns on a difference over 5 cm). PX4 HIL_GPS: copy EKF2_GPS_POS_X/Y/Z;
    # ODOMETRY: EKF2_EV_POS_X/Y/Z (docs/px4.md). Sent position = estimate +
    # R(heading) [x, -y] (forward, left); altitude = origin altitude - z.
    antenna_frd_m: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), metadata=bounded(-20.0, 20.0))
