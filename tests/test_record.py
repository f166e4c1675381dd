"""Recording the camera's frames (daemon/record.py): a real OpenCV video played by `VideoSource` on the
companion clock, kept as JPEGs with both clocks in frames.csv, read back by `FolderSource` on the autopilot
clock; the disk budget; and `--record` through the daemon beside the simulator over UDP."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from taco_mav.camera.sources import FolderSource, VideoSource
from taco_mav.config import Estimator, load_profile
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.daemon.record import FRAMES_HEADER, FrameRecorder, RecordOptions
from taco_mav.errors import DataError
from taco_mav.mavlink.timesync import ClockMap
from taco_mav.sim import Simulator
from tests.sim_helpers import free_udp_port, play

OFFSET_S = 1234.5  # autopilot s - companion s in the unit tests


def _video(path: Path, frames: int = 400, size: tuple[int, int] = (320, 240)) -> Path:
    """An MJPG video whose frame k shows the number k (each frame differs from the last)."""
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    rng = np.random.default_rng(0)
    for k in range(frames):
        img = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
        cv2.putText(img, str(k), (20, 120), cv2.FONT_HERSHEY_SIMPLEX, 3.0, (255, 255, 255), 6)
        out.write(img)
    out.release()
    return path


def _clockmap() -> ClockMap:
    cm = ClockMap(time.monotonic)
    cm.on_autopilot_time(time.monotonic() + OFFSET_S)  # an IMU stamp on arrival: the offset
    return cm


def _record(tmp_path: Path, options: RecordOptions, seconds: float) -> tuple[FrameRecorder, list[str]]:
    cam = VideoSource(str(_video(tmp_path / "drive.avi")))
    cam.start()
    warnings: list[str] = []
    rec = FrameRecorder(tmp_path / "frames", cam, _clockmap(), options, warnings.append)
    try:
        rec.start()
        time.sleep(seconds)
    finally:
        rec.stop()
        cam.close()
    return rec, warnings


def test_frames_kept_with_both_clocks_and_read_back(tmp_path: Path) -> None:
    rec, warnings = _record(tmp_path, RecordOptions(rate_hz=5.0, width=160), 2.0)
    lines = (tmp_path / "frames" / "frames.csv").read_text().splitlines()
    assert lines[0] == FRAMES_HEADER and not warnings
    rows = [line.split(",") for line in lines[1:]]
    assert 7 <= len(rows) == rec.frames <= 11  # 5 Hz for 2 s
    t_ap = np.array([float(r[1]) for r in rows])
    t_comp = np.array([float(r[2]) for r in rows])
    assert np.allclose(t_ap - t_comp, OFFSET_S, atol=0.02)  # the capture time on the autopilot clock
    assert np.all(np.diff(t_comp) > 0.1) and np.all(np.diff(t_comp) < 0.35)  # about 0.2 s apart
    img = cv2.imread(str(tmp_path / "frames" / rows[0][3]))
    assert img is not None and img.shape == (120, 160, 3)  # scaled to --record-width, aspect kept
    assert rec.bytes == sum((tmp_path / "frames" / r[3]).stat().st_size for r in rows)
    back = FolderSource(tmp_path / "frames")
    assert back.times == pytest.approx(sorted(t_ap))
    t, rgb = back.frame_near(float(t_ap[3]) + 0.01, 0.05)
    assert t == pytest.approx(t_ap[3]) and rgb.shape == (120, 160, 3)
    assert back.frame_near(float(t_ap[-1]) + 1.0, 0.15) is None


def test_budget_stops_recording_once_with_a_warning(tmp_path: Path) -> None:
    rec, warnings = _record(tmp_path, RecordOptions(rate_hz=20.0, budget_mb=0.1), 2.0)
    assert rec.full and len(warnings) == 1 and "0.1 MB budget" in warnings[0]
    assert 0.05e6 < rec.bytes <= 0.1e6  # stopped before the frame that would pass it
    rows = (tmp_path / "frames" / "frames.csv").read_text().splitlines()[1:]
    assert len(rows) == rec.frames and all((tmp_path / "frames" / r.split(",")[3]).is_file() for r in rows)


def test_bad_frame_index_is_named(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "frames.csv").write_text(FRAMES_HEADER + "\n0,12.5,1.0,data/000000.jpg\n1,oops,1.2,data/1.jpg\n")
    with pytest.raises(DataError, match=r"frames.csv:3: expected index,t_autopilot_s"):
        FolderSource(tmp_path)


def test_record_through_the_daemon(tmp_path: Path) -> None:
    """`--record` beside the simulator (world camera, lockstep 5x, 25 s): frames on the autopilot clock within
    the drive, the output still meets ArduPilot's rate rules, and the summary counts what was kept."""
    from taco_mav.datasets.synthetic import build_world

    world = build_world(tmp_path / "w", seed=2, length_km=0.2, progress=False)
    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True, wait_companion_s=10.0, drain_s=0.3,
                    duration_s=25.0)
    log_dir = tmp_path / "session"
    daemon = Daemon(load_profile("synthetic"),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}", log_dir=log_dir,
                                  estimator=Estimator.TACO_PLUS, record=RecordOptions(rate_hz=10.0)),
                    clock=sim.clock, wall_clock=sim.utc_now)
    play(sim, daemon)
    seq = sim.results()["sequences"][sim.drive.name]
    assert seq["gps_input_rate_hz"] >= 4.9 and seq["consecutive_gaps_over_245ms"] == 0
    rec = daemon.summary()["recorded"]
    back = FolderSource(log_dir / "frames")
    assert rec["frames"] == len(back.times) >= 100  # 10 Hz of the sim clock for most of 25 s
    assert sim.play_start - 0.5 <= back.times[0] and back.times[-1] <= sim.play_end + 0.5  # the autopilot clock
