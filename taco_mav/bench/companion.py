"""The companion budget: what `taco-mav run` costs a companion computer with a real camera path.

A flat synthetic world (`build_world`, seed `SEED`) is played by the autopilot simulator (`taco_mav.sim.Simulator`,
in this process, real time, GNSS denied after the start-up fix, no SIMSTATE unasked: a real autopilot has no true
pose to stream) to the daemon run as a user runs it, a separate process: `python -m taco_mav.cli run --profile
ardupilot_rover --estimator taco+ --log-dir ...` (the classical matcher, camera speed on, GPS_INPUT at 5 Hz), its
camera a 30 fps MJPG video file (OpenCV `VideoSource`, the path a USB camera takes) rendered beforehand at the
drive's true poses with the profile's camera model, its map the world's GeoTIFF. The daemon connects out
(`udpout:`, as to SITL), so its first HEARTBEAT, sent once it has opened its camera, starts the playback: the
video runs 0.02-0.08 s ahead of the drive (measured).

Measured from /proc (Linux): the daemon's CPU time (user + system, all threads) over the mission (from the first
played sample to the end of the drive) divided by its wall time, and its peak resident set (VmHWM) at the end.
CPU time is the process's own, so other load on the machine changes it little (caches, frequency); wall time
would not do. Keys:
- daemon_cpu_cores: cores, averaged over the mission (target <= 0.1 of one x86 core);
- daemon_rss_mb: peak RSS, MB of 10^6 bytes (target <= 250);
- daemon_startup_cpu_s: CPU seconds from the process's start to the first played sample (imports, the UKF
  kernels compiled ahead of time, built before the daemon starts as an install builds them; map and camera
  opened);
- daemon_budget_mission_s, daemon_budget_fixes_answered / _accepted, daemon_budget_camera_speed_used,
  daemon_budget_gps_input_hz (autopilot clock), daemon_budget_ate_m: what the mission did, so a budget met by a
  daemon that did nothing shows.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import taco_mav
from taco_mav.daemon.eventlog import read_events
from taco_mav.mavlink.connection import free_udp_port

log = logging.getLogger(__name__)

SEED = 4
LENGTH_KM = 0.4  # a ~70 s drive
MISSION_S = 65.0
VIDEO_FPS = 30.0
PROFILE = "ardupilot_rover"
CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process `pid`, all its threads (/proc/PID/stat fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def peak_rss_mb(pid: int) -> float:
    """Peak resident set of process `pid` (VmHWM), MB of 10^6 bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024 / 1e6
    raise RuntimeError(f"/proc/{pid}/status: no VmHWM")


def render_video(world: Path, path: Path, seconds: float, fps: float = VIDEO_FPS, profile: str = PROFILE) -> Path:
    """An MJPG video of `world`'s drive as the profile's camera sees it at the true poses, frame k at drive time
    k / fps, for `seconds` (the renderer draws it here, before the daemon starts; the daemon only reads the file)."""
    import cv2

    from taco_mav.camera.geometry import GroundCamera
    from taco_mav.config import load_profile
    from taco_mav.datasets.synthetic.world_camera import WorldSource
    from taco_mav.sim.source import open_drive

    drive = open_drive(world)
    cam = GroundCamera.from_config(load_profile(profile).camera)
    src = WorldSource(world, cam)
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (cam.width, cam.height))
    for k in range(int(seconds * fps)):
        t = k / fps
        i = min(round(t * drive.data_rate_hz), len(drive) - 1)
        src.feed_pose(t, float(drive.true_lat[i]), float(drive.true_lon[i]), float(drive.true_yaw_ned[i]))
        got = src.frame_near(t, 1.0)
        assert got is not None
        out.write(cv2.cvtColor(got[1], cv2.COLOR_RGB2BGR))
    out.release()
    src.close()
    return path


def daemon_command(connect: str, video: Path, mosaic: Path, log_dir: Path, profile: str = PROFILE) -> list[str]:
    """`taco-mav run` as a user starts it (the profile's matcher and output; taco+ with camera speed)."""
    return [sys.executable, "-m", "taco_mav.cli", "-q", "run", "--profile", profile, "--connect", connect,
            "--camera", str(video), "--map", str(mosaic), "--estimator", "taco+", "--log-dir", str(log_dir)]


def measure(tmp: Path, mission_s: float = MISSION_S, profile: str = PROFILE) -> dict[str, float]:
    """Build the world and the video in `tmp`, play the mission to a daemon process, return the keys (module
    docstring). profile: the daemon's `--profile` (a name or a YAML file: what a knob saves, docs/companion.md)."""
    from taco_mav.core import ukf_aot
    from taco_mav.datasets.synthetic import build_world
    from taco_mav.sim import Simulator

    ukf_aot.ensure_built()  # the install step (docs/real_rover.md): the daemon's kernels without numba

    world = build_world(tmp / "world", seed=SEED, length_km=LENGTH_KM, progress=False, realism="flat")
    video = render_video(world, tmp / "camera.avi", mission_s + 5.0, profile=profile)
    port = free_udp_port()
    sim = Simulator(world, f"udpin:127.0.0.1:{port}", speed=1.0, duration_s=mission_s, wait_companion_s=300.0,
                    drain_s=0.5, pose_stream=False)
    log_dir = tmp / "logs"
    log_dir.mkdir()
    cmd = daemon_command(f"udpout:127.0.0.1:{port}", video, world / "mosaic.tif", log_dir, profile)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(taco_mav.__file__).resolve().parents[1]), *filter(None, [os.environ.get("PYTHONPATH")])])}
    sim.start()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while sim.play_start is None:
            if proc.poll() is not None:
                raise RuntimeError(f"daemon exited with {proc.returncode}: {proc.stderr.read()[-2000:]}")
            time.sleep(0.05)
        cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
        while not sim.join(timeout=0.2):
            if proc.poll() is not None:
                raise RuntimeError(f"daemon exited with {proc.returncode}: {proc.stderr.read()[-2000:]}")
        cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
        rss = peak_rss_mb(proc.pid)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=30.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        sim.stop()
    if proc.returncode != 0:
        raise RuntimeError(f"daemon exited with {proc.returncode}: {err[-2000:]}")
    events = read_events(log_dir)
    fixes = [e for e in events if e["event"] == "fix"]
    stop = next((e for e in events if e["event"] == "stop"), {})
    motion = (stop.get("stats") or {}).get("camera_motion") or {}
    seq = next(iter(sim.results()["sequences"].values()))
    out = {"daemon_cpu_cores": round((cpu1 - cpu0) / (wall1 - wall0), 4), "daemon_rss_mb": round(rss, 1),
           "daemon_startup_cpu_s": round(cpu0, 2), "daemon_budget_mission_s": round(wall1 - wall0, 1),
           "daemon_budget_fixes_answered": sum(1 for f in fixes if f.get("results") is not None),
           "daemon_budget_fixes_accepted": sum(1 for f in fixes if f.get("accepted")),
           "daemon_budget_camera_speed_used": sum(v for k, v in motion.items() if k.startswith("used_")),
           "daemon_budget_gps_input_hz": seq.get("gps_input_rate_hz"), "daemon_budget_ate_m": seq.get("ate_m")}
    log.info("companion budget: %s (camera speed %s; daemon stderr: %s)", out, motion, err.strip()[-500:])
    return out


def companion_budget(mission_s: float = MISSION_S) -> dict[str, float]:
    """The keys of the module docstring, measured in a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        return measure(Path(tmp), mission_s)


if __name__ == "__main__":  # pragma: no cover - `python -m taco_mav.bench.companion [PROFILE]`: these keys alone
    logging.basicConfig(level=logging.INFO)
    with tempfile.TemporaryDirectory() as tmp_dir:
        print(json.dumps(measure(Path(tmp_dir), profile=sys.argv[1] if len(sys.argv) > 1 else PROFILE), indent=2))
