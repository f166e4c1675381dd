"""Recording what the daemon's camera saw, so a drive made with GNSS on can be replayed and scored
offline, or played again to a newer daemon: `taco-mav run --log-dir DIR --record` keeps frames in the session
folder beside mav.tlog, SESSION/frames/:

- `data/NNNNNN.jpg`, the frames (scaled to `width` px when set, JPEG `jpeg_quality`);
- `frames.csv`: `index,t_autopilot_s,t_companion_s,file`, one line per frame, written as it is kept: the capture
  time on the autopilot clock (the filter's time, as the IMU in mav.tlog) and on the companion's monotonic clock.

`--camera folder:SESSION/frames` plays such a folder back on the recorded autopilot clock
(`camera.sources.FolderSource`).

`FrameRecorder` is a thread of its own: every 1 / rate_hz companion seconds it takes the camera's frame nearest
now, skips it when it is the one already kept, scales, encodes (OpenCV, which releases the GIL while it works)
and appends, so the daemon loop never waits on the disk. Once the frames reach `budget_mb` it stops, with one
warning (log, event `record_budget`, STATUSTEXT); what it wrote stays valid.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2

from taco_mav.camera.sources import CameraSource, ClockDomain, FrameRejected
from taco_mav.core.fields import bounded
from taco_mav.daemon.reporter import Reporter
from taco_mav.mavlink.mavconst import SEV_WARNING
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

__all__ = ["FRAMES_CSV", "FRAMES_HEADER", "FrameRecorder", "RecordOptions", "start_recording"]

FRAMES_CSV = "frames.csv"
FRAMES_HEADER = "index,t_autopilot_s,t_companion_s,file"
WAKE_S = 0.02  # wall s the recorder sleeps at most between looks at its clock


@dataclass(frozen=True)
class RecordOptions:
    """rate_hz: frames kept per companion second (at most the camera's own rate; 5 Hz keeps every frame the
    camera-speed pairs need, 0.3-0.5 s apart, and every trigger within 0.1 s of a frame); width: px the frames
    are scaled to (0: as captured); budget_mb: stop recording at this many MB of frames (a 640 px JPEG is
    about 60 kB: 2000 MB hold about 1.8 h at 5 Hz); jpeg_quality: OpenCV's IMWRITE_JPEG_QUALITY."""

    rate_hz: float = field(default=5.0, metadata=bounded(0.0, open_lo=True))
    width: int = field(default=0, metadata=bounded(0))
    budget_mb: float = field(default=2000.0, metadata=bounded(0.0, open_lo=True))
    jpeg_quality: int = field(default=90, metadata=bounded(1, 100))


class FrameRecorder:
    """folder: SESSION/frames (made here); camera: the daemon's source; clockmap: companion <-> autopilot;
    warn: called once with the text when the budget is reached (the daemon's event and STATUSTEXT);
    clock: companion monotonic seconds."""

    def __init__(self, folder: Path, camera: CameraSource, clockmap: ClockMap, options: RecordOptions,
                 warn: Callable[[str], None], clock: Callable[[], float] = time.monotonic) -> None:
        self.folder, self.camera, self.clockmap, self.opt = Path(folder), camera, clockmap, options
        self.warn, self.clock = warn, clock
        (self.folder / "data").mkdir(parents=True, exist_ok=True)
        self._index = open(self.folder / FRAMES_CSV, "a", buffering=1)  # noqa: SIM115 - closed in stop()
        if self._index.tell() == 0:
            self._index.write(FRAMES_HEADER + "\n")
        self.frames = 0
        self.bytes = 0
        self.skipped: dict[str, int] = {}
        self.full = False
        self._last_t: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="taco-record", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop and close the index (every kept frame is already on disk and in frames.csv)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._index.close()

    def summary(self) -> dict[str, object]:
        return {"frames": self.frames, "mb": round(self.bytes / 1e6, 3), "full": self.full, "skipped": self.skipped}

    def _run(self) -> None:
        period = 1.0 / self.opt.rate_hz
        next_at = self.clock()
        while not self._stop.is_set() and not self.full:
            now = self.clock()
            if now >= next_at:
                try:
                    self._keep_one()
                except Exception as exc:  # noqa: BLE001 - recording must never take the daemon down
                    self._skip("error")
                    log.debug("record: %s", exc)
                next_at = max(next_at + period, now)  # fell behind (a slow disk): skip slots, never burst
            # short waits: `clock` may be a simulator's, faster than the wall clock this thread sleeps on
            self._stop.wait(min(max(next_at - self.clock(), 0.0), WAKE_S))

    def _skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def _keep_one(self) -> None:
        """The camera's frame nearest now, unless it is the one kept last."""
        now = self.clock()
        on_autopilot = self.camera.clock is ClockDomain.AUTOPILOT
        t_src = self.clockmap.to_autopilot(now) if on_autopilot else now
        if t_src is None:
            self._skip("clock_unmapped")
            return
        try:
            got = self.camera.frame_near(t_src, 1.0 / self.opt.rate_hz)
        except FrameRejected as exc:
            self._skip(exc.reason)
            return
        if got is None:
            self._skip("no_frame")
            return
        t_frame, rgb = got
        if t_frame == self._last_t:
            return
        t_ap = t_frame if on_autopilot else self.clockmap.to_autopilot(t_frame)
        t_comp = self.clockmap.to_companion(t_frame) if on_autopilot else t_frame
        if t_ap is None or t_comp is None:
            self._skip("clock_unmapped")
            return
        if self.opt.width and rgb.shape[1] != self.opt.width:
            h = max(1, round(rgb.shape[0] * self.opt.width / rgb.shape[1]))
            rgb = cv2.resize(rgb, (self.opt.width, h), interpolation=cv2.INTER_AREA)
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                [cv2.IMWRITE_JPEG_QUALITY, self.opt.jpeg_quality])
        if not ok:
            self._skip("encode")
            return
        if self.bytes + len(jpeg) > self.opt.budget_mb * 1e6:
            self.full = True
            self.warn(f"recording stopped: frames reached the {self.opt.budget_mb:g} MB budget "
                      f"({self.frames} frames kept in {self.folder})")
            return
        name = f"{self.frames:06d}.jpg"
        (self.folder / "data" / name).write_bytes(jpeg.tobytes())
        self._index.write(f"{self.frames},{t_ap:.6f},{t_comp:.6f},data/{name}\n")
        self.frames += 1
        self.bytes += len(jpeg)
        self._last_t = t_frame


def start_recording(*, log_dir: Path | None, camera: CameraSource | None, clockmap: ClockMap,
                    options: RecordOptions, reporter: Reporter, clock: Callable[[], float]) -> FrameRecorder | None:
    """--record: a started `FrameRecorder` into log_dir/frames, whose budget warning goes to the log, the events
    (`record_budget`) and the ground station; None (with a warning) without a session folder or a camera."""
    if log_dir is None or camera is None:
        log.warning("--record needs --log-dir and a camera: not recording")
        return None

    def full(text: str) -> None:
        log.warning("%s", text)
        reporter.event("record_budget", text=text)
        reporter.status(SEV_WARNING, "recording stopped: disk budget")

    recorder = FrameRecorder(log_dir / "frames", camera, clockmap, options, full, clock)
    recorder.start()
    log.info("recording frames at %g Hz into %s (budget %g MB)", options.rate_hz, log_dir / "frames",
             options.budget_mb)
    return recorder
