"""A drive from a MAVLink telemetry log (.tlog) recorded with GNSS on: the autopilot's IMU and ATTITUDE as the
IMU stream, its GPS_RAW_INT 3D fixes as the ground truth. What a rover owner has after one drive with
`taco-mav run --log-dir` (or Mission Planner / QGroundControl's tlog); used to measure the vehicle's own
dead-reckoning drift (`taco-mav drift --tlog`).

- IMU: the first of HIGHRES_IMU, RAW_IMU (id 0), SCALED_IMU present (or `imu_message`), decoded and checked
  by `link.decoders` (body FRD, m/s^2 with gravity, rad/s; autopilot seconds). Each sample takes the ATTITUDE
  nearest to it in autopilot time, carried to the sample's time at its rates as the daemon does (NED radians).
- Truth: the real receiver's fixes (fix_type >= 3): GPS_RAW_INT (GPS1), or GPS2_RAW (GPS2) when GPS1 only
  echoes our own GPS_INPUT (set-up A, or a daemon on GPS1): an instance most of whose fixes repeat a GPS_INPUT
  position of the same tlog is an echo, never truth. Projected to the UTM zone of the first fix (ENU metres
  relative to it); heading = the GNSS course over ground (grid ENU radians) while faster than `course_min_speed_mps`,
  else the compass's. Each fix is stamped with its own time (the message's time_usec: ArduPilot's time of the
  fix on its boot clock, the IMU's), as the daemon stamps the receiver it fuses and the one its shadow twin is
  measured against (`daemon.gnss`). Where that is not on the IMU's clock (more than MAX_TIME_SKEW_S from the
  fix's receive time carried onto it by the median offset between IMU time and receive time: an autopilot that
  sends another clock), the fix takes that receive time instead. Receive times would not do for every fix: they
  wander with the link and the companion's load (in the in-process simulator, 0.05 s RMS: 0.4 m along the track
  at 8 m/s), and trail the fix by the stream's phase.
- Wheels: WHEEL_DISTANCE as decoded by the daemon (cumulative metres per wheel, autopilot seconds), with the
  autopilot's WENC_POS_Y / WENC2_POS_Y where a PARAM_VALUE of both was recorded; None without any.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.camera.geometry import GroundCamera  # noqa: E402
from taco_mav.core.preintegration import enu_heading  # noqa: E402
from taco_mav.daemon.gnss import MAX_TIME_SKEW_S  # noqa: E402
from taco_mav.datasets.base import GroundTruth, ImuStream, StartFix, WheelLog  # noqa: E402
from taco_mav.errors import DataError  # noqa: E402
from taco_mav.geo import UtmProjector, utm_epsg_for, wrap_angle  # noqa: E402
from taco_mav.mavlink.decoders import (IMU_MESSAGES, WHEEL_MESSAGE, WHEEL_POS_PARAMS, AttitudeReading,  # noqa: E402
                                       Decoders)

__all__ = ["TlogDrive", "load_tlog"]


@dataclass(frozen=True)
class TlogDrive:
    """A Drive (datasets.base) read from a tlog. convergence_rad: meridian convergence at the origin (grid
    heading = true heading + convergence). No camera frames, unless a recording's are added
    (`datasets.recording`: frame_paths, one JPEG per entry of frame_times, and the map it was matched on)."""

    name: str
    imu: ImuStream
    truth: GroundTruth
    start: StartFix
    utm_epsg: int
    origin_utm: np.ndarray
    convergence_rad: float
    rejected: dict[str, int] = field(default_factory=dict)
    receiver: str = "GPS_RAW_INT"  # the message the truth came from
    t0_unix: float = 0.0  # UTC unix s at the first IMU sample (from the tlog's receive times)
    sequence: str | None = None
    frame_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    camera: GroundCamera | None = None
    mosaic: Path | None = None
    frame_paths: tuple[Path, ...] = ()
    wheels: WheelLog | None = None

    def frame(self, index: int) -> np.ndarray:
        """Frame `index` as RGB uint8 (H, W, 3); DataError naming the file when it cannot be read."""
        if not self.frame_paths:
            raise DataError(f"{self.name}: a tlog has no camera frames")
        bgr = cv2.imread(str(self.frame_paths[index]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DataError(f"{self.frame_paths[index]}: recorded frame not readable")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def load_tlog(path: Path, imu_message: str | None = None, course_min_speed_mps: float = 2.0) -> TlogDrive:
    """Read `path` (see the module docstring). DataError naming the file when it cannot be read or lacks IMU,
    ATTITUDE or 3D GNSS fixes."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: tlog not found")
    if imu_message is not None and imu_message not in IMU_MESSAGES:
        raise DataError(f"--imu-message: {imu_message!r} is not one of {', '.join(IMU_MESSAGES)}")
    dec = Decoders()
    imu: dict[str, list] = {}
    att: list[AttitudeReading] = []
    # per receiver message: (receive time, lat, lon, alt, speed, course_ned, own time (time_usec) s)
    gps: dict[str, list[tuple[float, float, float, float, float, float | None, float]]] = {"GPS_RAW_INT": [],
                                                                                             "GPS2_RAW": []}
    ours: set[tuple[int, int]] = set()  # (lat, lon) degE7 of every GPS_INPUT we sent
    raw: dict[str, list[tuple[int, int]]] = {"GPS_RAW_INT": [], "GPS2_RAW": []}
    offsets: list[float] = []
    wheels: list[tuple[float, tuple[float, ...]]] = []
    wheel_params: dict[str, float] = {}
    try:
        conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega", robust_parsing=True)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot open as a tlog ({exc})") from None
    try:
        while (msg := conn.recv_match(blocking=False)) is not None:
            kind = msg.get_type()
            if kind in IMU_MESSAGES:
                if kind == "RAW_IMU" and getattr(msg, "id", 0) != 0:
                    continue
                r = dec.imu(msg)
                if r is not None:
                    imu.setdefault(kind, []).append(r)
                    offsets.append(r.t - float(getattr(msg, "_timestamp", 0.0)))
            elif kind == "ATTITUDE":
                a = dec.attitude(msg)
                if a is not None:
                    att.append(a)
            elif kind in gps:
                g = dec.gnss(msg)
                if g is not None:
                    gps[kind].append((float(getattr(msg, "_timestamp", 0.0)), g.lat, g.lon, g.alt, g.speed,
                                      g.course_ned, g.t))
                    raw[kind].append((int(msg.lat), int(msg.lon)))
            elif kind == "GPS_INPUT":
                ours.add((int(msg.lat), int(msg.lon)))
            elif kind == WHEEL_MESSAGE:
                w = dec.wheel_distance(msg)
                if w is not None:
                    wheels.append((w.t, w.distances))
            elif kind == "PARAM_VALUE":
                pid = str(msg.param_id).rstrip("\x00")
                if pid in WHEEL_POS_PARAMS and math.isfinite(float(msg.param_value)):
                    wheel_params[pid] = float(msg.param_value)
    finally:
        conn.close()
    kind = imu_message or next((k for k in IMU_MESSAGES if imu.get(k)), None)
    if kind is None or len(imu.get(kind, [])) < 20:
        raise DataError(f"{path}: fewer than 20 IMU samples ({', '.join(IMU_MESSAGES)}); "
                        f"rejected: {dict(dec.rejected)}")
    if len(att) < 2:
        raise DataError(f"{path}: no ATTITUDE messages")
    echo = {k: bool(v) and sum(p in ours for p in v) > 0.5 * len(v) for k, v in raw.items()}
    receiver = next((k for k in gps if len(gps[k]) >= 20 and not echo[k]), None)
    if receiver is None:
        echoes = [k for k in gps if echo[k]]
        raise DataError(f"{path}: fewer than 20 real-receiver 3D fixes (record with GNSS on)"
                        + (f"; {' and '.join(echoes)} only echo our GPS_INPUT" if echoes else "")
                        + f"; rejected: {dict(dec.rejected)}")
    samples = sorted(imu[kind], key=lambda r: r.t)
    t = np.array([r.t for r in samples])
    keep = np.concatenate([[True], np.diff(t) > 0])
    t = t[keep]
    accel = np.array([r.accel_frd for r in samples])[keep]
    gyro = np.array([r.gyro_frd for r in samples])[keep]
    att.sort(key=lambda a: a.t)
    ta = np.array([a.t for a in att])
    hi = np.clip(np.searchsorted(ta, t), 1, len(ta) - 1)
    j = np.where(np.abs(ta[hi - 1] - t) <= np.abs(ta[hi] - t), hi - 1, hi)  # nearest in autopilot time
    rpy = np.array([(c.roll, c.pitch, c.yaw) for c in (att[k].at(ti) for k, ti in zip(j, t))])  # as the daemon
    offset = float(np.median(offsets))

    G, tg = _fix_times(gps[receiver], offset)
    lat0, lon0, alt0 = G[0][1], G[0][2], G[0][3]
    proj = UtmProjector(utm_epsg_for(lat0, lon0))
    e0, n0 = proj.to_utm(lat0, lon0)
    conv = float(proj.grid_convergence(lat0, lon0))
    e, n = proj.to_utm(np.array([g[1] for g in G]), np.array([g[2] for g in G]))
    xy = np.column_stack([np.atleast_1d(e) - e0, np.atleast_1d(n) - n0])
    compass = np.array([enu_heading(float(y)) for y in np.interp(tg, t, np.unwrap(rpy[:, 2]))]) + conv
    heading = np.array([enu_heading(g[5]) + conv if g[5] is not None and g[4] >= course_min_speed_mps else c
                        for g, c in zip(G, compass)])
    heading = wrap_angle(heading)
    first = G[0]
    start = StartFix(float(tg[0]), lat0, lon0, alt0, first[4],
                     enu_heading(first[5]) + conv if first[5] is not None else float(compass[0]))
    return TlogDrive(name=path.stem, imu=ImuStream(t, accel, gyro, rpy), truth=GroundTruth(tg, xy, heading),
                     start=start, utm_epsg=proj.epsg, origin_utm=np.array([e0, n0]),
                     convergence_rad=conv if math.isfinite(conv) else 0.0, rejected=dict(dec.rejected),
                     receiver=receiver, t0_unix=float(t[0] - offset), wheels=_wheel_log(wheels, wheel_params))


def _wheel_log(samples: list[tuple[float, tuple[float, ...]]], params: dict[str, float]) -> WheelLog | None:
    """The recorded WHEEL_DISTANCE samples in time order (a repeated time, or a wheel count other than the
    first's, dropped), or None without two."""
    samples = sorted(samples, key=lambda s: s[0])
    if len(samples) < 2:
        return None
    n = len(samples[0][1])
    kept = [s for k, s in enumerate(samples) if len(s[1]) == n and (k == 0 or s[0] > samples[k - 1][0])]
    pos_y = (params[WHEEL_POS_PARAMS[0]], params[WHEEL_POS_PARAMS[1]]) if set(WHEEL_POS_PARAMS) <= set(params) \
        else None
    return WheelLog(np.array([s[0] for s in kept]), np.array([s[1] for s in kept], dtype=float), pos_y)


def _fix_times(fixes: list[tuple[float, float, float, float, float, float | None, float]], offset: float
               ) -> tuple[list[tuple[float, float, float, float, float, float | None, float]], np.ndarray]:
    """The receiver's fixes (receive time s, lat, lon, alt, speed, course, own time s) in time order with their
    times on the autopilot clock, s: each its own time, or its receive time + offset (autopilot minus receive time,
    s) where the two are more than MAX_TIME_SKEW_S apart (module docstring). A fix repeating an earlier one's time
    is dropped."""
    stamped = sorted(((f[6] if abs(f[6] - (f[0] + offset)) <= MAX_TIME_SKEW_S else f[0] + offset, f)
                      for f in fixes), key=lambda p: p[0])
    kept = [p for k, p in enumerate(stamped) if k == 0 or p[0] > stamped[k - 1][0]]
    return [f for _, f in kept], np.array([t for t, _ in kept])
