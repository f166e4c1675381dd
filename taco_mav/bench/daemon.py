"""Bench section `daemon`: the daemon's IMU path without a network, then the live path over loopback UDP.

IMU path (no sockets, no threads): a Daemon that is never started is handed RAW_IMU messages (100 Hz) and
ATTITUDE (50 Hz) of the fusion bench's weaving 10 m/s drive, built with pymavlink, through the very handler its
loop calls for each IMU message (`Inputs.on_imu`: decode, timeline checks, `Localiser.add_imu`); each timed span is
that call plus `Localiser.estimate()`, i.e. from the IMU sample reaching the daemon's estimator to the estimate
being available. Keys (60 s of data after the kernels are compiled, every 10th sample closes a filter frame):
- daemon_imu_to_estimate_p99_ms / _median_ms: the profile's default estimator (paper mode);
- daemon_plus_imu_to_estimate_p99_ms / _median_ms: taco+;
- daemon_imu_to_estimate_cpu_p99_ms / daemon_plus_...: the same spans in this thread's CPU time (on a busy
  machine the wall-clock p99 is mostly the OS running other processes in the middle of a span).

Live path: a small autopilot player in this process (pymavlink, 127.0.0.1) streams HEARTBEAT, one GPS_RAW_INT
start fix, RAW_IMU at 100 Hz and ATTITUDE at 50 Hz of a straight 5 m/s drive for `DURATION_S`; the daemon runs in a
thread with the default output (GPS_INPUT at 5 Hz) and the emulator matcher fed by SIMSTATE. Keys:
- daemon_udp_imu_to_estimate_p99_ms / _median_ms: per IMU message, the daemon's receive (socket read) ->
  Localiser updated, p99 (the player runs in the same process, so this includes waiting for its thread);
- gps_input_interval_p99_ms / _mean_ms / _std_ms / _max_dev_ms: intervals between GPS_INPUT arrivals at the
  player (ideal 200 ms), max_dev = the largest |interval - 200 ms|; gps_input_jitter_p99_ms: p99 of
  |interval - 200 ms|;
- gps_input_rate_autopilot_hz_1x / _5x: GPS_INPUT per second of the player's (autopilot's) clock, the player
  at real time and 5x faster than real time (`SPEEDUP_S` wall seconds; the daemon on the machine's clock, as
  beside SITL --speedup 5); gps_input_interval_p99_ms_5x: p99 interval there, autopilot ms.

Recording: the live path again with a real camera path, a 30 fps video file of the profile's frame
size read by OpenCV (`VideoSource`), first without then with `--record` (5 Hz JPEGs into a temporary session
folder). Keys: gps_input_interval_p99_ms_camera, gps_input_interval_p99_ms_recording, and their difference,
recording_interval_p99_delta_ms (what recording costs the output's timing); recording_frames kept.

Companion budget (`taco_mav.bench.companion`): `taco-mav run` as a separate process (ardupilot_rover,
taco+, classical matcher, camera speed, 5 Hz GPS_INPUT) with a 30 fps MJPG video as its camera, over a 65 s
simulated mission: daemon_cpu_cores (CPU time / wall time, target <= 0.1 of one x86 core) and daemon_rss_mb (peak
RSS, target <= 250 MB), with what the mission did beside them (daemon_budget_*, daemon_startup_cpu_s).
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.bench.companion import companion_budget  # noqa: E402
from taco_mav.bench.fusion import _drive as _weaving_drive  # noqa: E402
from taco_mav.config import profile_from_dict  # noqa: E402
from taco_mav.core import ukf_kernels  # noqa: E402
from taco_mav.daemon.daemon import Daemon, DaemonOptions  # noqa: E402
from taco_mav.daemon.record import RecordOptions  # noqa: E402
from taco_mav.mavlink.connection import free_udp_port  # noqa: E402

log = logging.getLogger(__name__)
DURATION_S = 15.0
RECORD_S = 30.0  # each of the two camera runs (150 output intervals: a p99 that is not just the largest)
SPEEDUP, SPEEDUP_S = 5.0, 6.0


IMU_PATH_S = 60.0
G0 = 9.80665


def imu_path_latency(estimator: str = "paper", duration_s: float = IMU_PATH_S) -> tuple[np.ndarray, np.ndarray]:
    """(wall, CPU) seconds per RAW_IMU message from the daemon's IMU handler being called to
    `Localiser.estimate()` returned (only messages that reached the Localiser), without a network: see the module
    docstring. The CPU time (this thread's) leaves out the time the OS gave other processes meanwhile."""
    ukf_kernels.warm_up()
    mav = mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    daemon = Daemon(profile_from_dict({"matcher": "emulator", "estimator": estimator}),
                    DaemonOptions(connect="udpin:127.0.0.1:0"))
    daemon.state.anchor.set_origin(49.0, 8.4, 115.0, 10.0, 0.0)  # heading north at 10 m/s, as the drive starts
    wall, cpu = [], []
    for k, s in enumerate(_weaving_drive(duration_s)):
        t_ap = 100.0 + s.t  # autopilot boot time, s
        if k % 2 == 0:
            att = mav.attitude_encode(int(round(t_ap * 1e3)), s.roll, s.pitch, s.yaw, 0.0, 0.0, 0.0)
            daemon.inputs.on_attitude(att, 0.0)
        ax, ay, az = (int(round(a / G0 * 1e3)) for a in s.accel_frd)  # mG
        gx, gy, gz = (int(round(g * 1e3)) for g in s.gyro_frd)  # mrad/s
        msg = mav.raw_imu_encode(int(round(t_ap * 1e6)), ax, ay, az, gx, gy, gz, 0, 0, 0)
        n = daemon.stats.imu_samples
        c0, start = time.thread_time(), time.perf_counter()
        daemon.inputs.on_imu(msg, start)
        if daemon.state.loc is not None:
            daemon.state.loc.estimate()
        stop, c1 = time.perf_counter(), time.thread_time()
        if daemon.stats.imu_samples > n:
            wall.append(stop - start)
            cpu.append(c1 - c0)
    return np.array(wall), np.array(cpu)


def _play(port: int, duration: float, arrivals: list[float], speed: float = 1.0) -> None:
    """The autopilot for `duration` wall seconds, its clock `speed` x real time; arrivals: the autopilot time of
    each GPS_INPUT received, s."""
    m = mavutil.mavlink
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega")
    mav = conn.mav
    start = time.monotonic()
    k_imu = k_att = k_sim = k_hb = 0
    yaw = math.radians(30.0)
    lat0, lon0 = 49.0, 8.4
    while (el := time.monotonic() - start) < duration:
        t_ap = 100.0 + speed * el
        el = speed * el  # the drive below runs on the autopilot's clock
        if k_hb <= el:
            mav.heartbeat_send(m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, m.MAV_STATE_ACTIVE)
            if el < 2.0:
                mav.gps2_raw_send(int(t_ap * 1e6), 3, int(lat0 * 1e7), int(lon0 * 1e7), 115000, 80, 120, 500,
                                  3000, 12, 0, 0)  # a real receiver as GPS2 (GPS1 is the daemon's GPS_INPUT)
            k_hb += 1
        while k_imu / 100.0 <= el:
            mav.raw_imu_send(int((100.0 + k_imu / 100.0) * 1e6), 0, 0, -1000, 0, 0, 0, 0, 0, 0)
            k_imu += 1
        while k_att / 50.0 <= el:
            mav.attitude_send(int(t_ap * 1e3), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)
            k_att += 1
        if k_sim / 10.0 <= el:
            d = 5.0 * el
            lat = lat0 + d * math.cos(yaw) / 111_200.0
            lon = lon0 + d * math.sin(yaw) / (111_200.0 * math.cos(math.radians(lat0)))
            mav.simstate_send(0.0, 0.0, yaw, 0, 0, -9.8, 0, 0, 0, int(lat * 1e7), int(lon * 1e7))
            k_sim += 1
        while (msg := conn.recv_msg()) is not None:
            kind = msg.get_type()
            if kind == "GPS_INPUT":
                arrivals.append(100.0 + speed * (time.monotonic() - start))
            elif kind == "COMMAND_LONG":
                mav.command_ack_send(msg.command, m.MAV_RESULT_ACCEPTED)
            elif kind == "PARAM_REQUEST_READ" and msg.param_id == "GPS1_TYPE":
                mav.param_value_send(b"GPS1_TYPE", 14.0, m.MAV_PARAM_TYPE_INT8, 900, 1)
            elif kind == "TIMESYNC" and msg.tc1 == 0:
                mav.timesync_send(int((100.0 + speed * (time.monotonic() - start)) * 1e9), msg.ts1)
        time.sleep(0.001)
    conn.close()


def _drive(duration: float, speed: float, camera: str | None = None, log_dir: Path | None = None,
           record: RecordOptions | None = None) -> tuple[Daemon, list[float]]:
    """One daemon against the player at `speed`; (the stopped daemon, GPS_INPUT arrivals in autopilot s)."""
    port = free_udp_port()
    daemon = Daemon(profile_from_dict({"matcher": "emulator"}),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=camera, log_dir=log_dir, record=record))
    daemon.start()
    time.sleep(0.2)
    arrivals: list[float] = []
    player = threading.Thread(target=_play, args=(port, duration, arrivals, speed), daemon=True)
    player.start()
    player.join(duration + 10.0)
    daemon.stop()
    daemon.join(10.0)
    return daemon, arrivals


def _video(path: Path, seconds: float) -> Path:
    """A 30 fps MJPG video of the default profile's frame size (so the camera check accepts it), each frame
    different (seeded noise and its number)."""
    import cv2

    cam = profile_from_dict({}).camera
    size = (cam.width_px, cam.height_px)
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    for k in range(int(seconds * 30)):
        img = np.roll(base, 7 * k, axis=1)
        cv2.putText(img, str(k), (40, 200), cv2.FONT_HERSHEY_SIMPLEX, 4.0, (255, 255, 255), 8)
        out.write(img)
    out.release()
    return path


def _p99_gap_ms(arrivals: list[float]) -> float | None:
    gaps = np.diff(np.array(arrivals[2:])) * 1e3
    return round(float(np.percentile(gaps, 99)), 2) if len(gaps) >= 10 else None


def recording_cost() -> dict[str, float]:
    """GPS_INPUT interval p99 with a real camera path, without and with --record (module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        video = str(_video(Path(tmp) / "camera.avi", RECORD_S + 5.0))
        _, plain = _drive(RECORD_S, 1.0, camera=video)
        daemon, recorded = _drive(RECORD_S, 1.0, camera=video, log_dir=Path(tmp) / "session",
                                  record=RecordOptions())
        frames = (daemon.summary().get("recorded") or {}).get("frames", 0)
    a, b = _p99_gap_ms(plain), _p99_gap_ms(recorded)
    if a is None or b is None:
        log.warning("daemon bench: too few GPS_INPUT with the camera (%d, %d)", len(plain), len(recorded))
        return {}
    return {"gps_input_interval_p99_ms_camera": a, "gps_input_interval_p99_ms_recording": b,
            "recording_interval_p99_delta_ms": round(b - a, 2), "recording_frames": frames}


def _rate(arrivals: list[float]) -> float | None:
    """GPS_INPUT per autopilot second after the first two (start-up)."""
    t = np.array(arrivals[2:])
    return round(float((len(t) - 1) / (t[-1] - t[0])), 4) if len(t) > 10 and t[-1] > t[0] else None


def run(progress: bool = True) -> dict[str, float]:
    out: dict[str, float] = {}
    for prefix, estimator in (("daemon", "paper"), ("daemon_plus", "taco+")):
        wall_ms, cpu_ms = (a * 1e3 for a in imu_path_latency(estimator))
        out[f"{prefix}_imu_to_estimate_p99_ms"] = round(float(np.percentile(wall_ms, 99)), 4)
        out[f"{prefix}_imu_to_estimate_median_ms"] = round(float(np.median(wall_ms)), 4)
        out[f"{prefix}_imu_to_estimate_cpu_p99_ms"] = round(float(np.percentile(cpu_ms, 99)), 4)
    daemon, arrivals = _drive(DURATION_S, 1.0)
    lat_ms = np.array(daemon.stats.imu_to_estimate_s) * 1e3
    gaps_ms = np.diff(np.array(arrivals[2:])) * 1e3  # skip the first two (start-up)
    if len(lat_ms) < 100 or len(gaps_ms) < 10:
        log.warning("daemon bench: too little traffic (%d IMU, %d GPS_INPUT)", len(lat_ms), len(gaps_ms))
        return out
    out.update({
        "daemon_udp_imu_to_estimate_p99_ms": round(float(np.percentile(lat_ms, 99)), 3),
        "daemon_udp_imu_to_estimate_median_ms": round(float(np.median(lat_ms)), 3),
        "gps_input_interval_p99_ms": round(float(np.percentile(gaps_ms, 99)), 2),
        "gps_input_interval_mean_ms": round(float(gaps_ms.mean()), 2),
        "gps_input_interval_std_ms": round(float(gaps_ms.std()), 2),
        "gps_input_interval_max_dev_ms": round(float(np.abs(gaps_ms - 200.0).max()), 2),
        "gps_input_jitter_p99_ms": round(float(np.percentile(np.abs(gaps_ms - 200.0), 99)), 2),
    })
    rate_1x = _rate(arrivals)
    _, fast = _drive(SPEEDUP_S, SPEEDUP)
    rate_5x = _rate(fast)
    if rate_1x is not None and rate_5x is not None:
        out.update(gps_input_rate_autopilot_hz_1x=rate_1x, gps_input_rate_autopilot_hz_5x=rate_5x,
                   gps_input_interval_p99_ms_5x=round(float(np.percentile(np.diff(fast[2:]) * 1e3, 99)), 2))
    out.update(recording_cost())
    out.update(companion_budget())
    log.info("daemon bench: %s (%d IMU samples, %d GPS_INPUT, fixes %s)", out, len(lat_ms), len(arrivals),
             dict(daemon.stats.fixes))
    return out
