"""The companion budget (`taco_mav.bench.companion`): what a `taco-mav run` with a real camera loads,
the /proc readings the bench divides, and the simulator that streams no true pose unasked. Behaviour only: the
figures themselves (CPU cores, peak RSS) live in `taco-mav bench`'s JSON."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fault_helpers import ORIGIN_LAT, ORIGIN_LON, write_geotiff

import taco_mav
from taco_mav.bench.companion import cpu_seconds, peak_rss_mb
from taco_mav.core import ukf_aot
from taco_mav.mavlink.connection import free_udp_port
from taco_mav.mavlink.encoders import Origin

# What a run with a video or a device camera, the classical matcher and a GeoTIFF never uses: the FG2 matcher and
# torch, plotting, the simulation renderers (world: cameras), the offline evaluation and the simulator, the offline
# smoother's gtsam; scipy beyond the LAPACK the filter's kernels call (scipy.linalg): the matcher's FFT is OpenCV's
# and the GNSS guard's chi2 quantile taco_mav.core.chi2 (scipy.fft and scipy.special cost 8 MB more); filterpy (the
# UKF computes its sigma-point weights by filterpy's arithmetic); with the filter's kernels built ahead of time (the
# install step, core/ukf_aot.py) numba and its LLVM (llvmlite); and pymavlink's default dialect "all" (12 MB), where
# every connection asks for ardupilotmega (taco_mav/mavlink).
NEVER_LOADED = ("numba", "llvmlite", "torch", "matplotlib", "moderngl", "pandas", "taco_mav.cvgl.fg2", "taco_mav.cvgl.emulator",
                "taco_mav.evaluation", "taco_mav.sim", "taco_mav.datasets.synthetic.render",
                "taco_mav.datasets.synthetic.render3d", "taco_mav.datasets.synthetic.world3d", "gtsam", "filterpy",
                "scipy.fft", "scipy.special", "scipy.stats", "scipy.signal", "scipy.spatial", "scipy.optimize",
                "scipy.ndimage", "pymavlink.dialects.v20.all")


def _imported(stderr: str) -> set[str]:
    """Module names from `python -X importtime` lines ("import time: self | cumulative | name")."""
    return {line.rsplit("|", 1)[1].strip() for line in stderr.splitlines() if line.startswith("import time:")
            and line.count("|") == 2}


def test_a_run_with_a_video_camera_and_the_classical_matcher_loads_no_model_plot_or_renderer(tmp_path: Path) -> None:
    """`taco-mav run` as a user starts it (ardupilot_rover: taco+, classical, camera speed) opens its camera, map
    and matcher; `-X importtime` lists every module it imported by then: none of NEVER_LOADED."""
    ukf_aot.ensure_built()  # as the install does (docs/real_rover.md)
    video = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (160, 90))
    if not writer.isOpened():
        pytest.skip("OpenCV build cannot write MJPG")
    rng = np.random.default_rng(0)
    for _ in range(30):
        writer.write(rng.integers(0, 256, (90, 160, 3), dtype=np.uint8))
    writer.release()
    mosaic = write_geotiff(tmp_path / "map.tif", Origin.from_latlon(ORIGIN_LAT, ORIGIN_LON, 110.0))
    env = {**os.environ, "PYTHONPATH": str(Path(taco_mav.__file__).resolve().parents[1])}
    proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "taco_mav.cli", "run", "--profile",
                             "ardupilot_rover", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", "--camera",
                             str(video), "--map", str(mosaic)], env=env, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # until the daemon has opened camera, map, matcher and link ("started")
            lines.append(line)
            if "STATUSTEXT: started" in line:
                break
    finally:
        proc.send_signal(signal.SIGTERM)
        _, rest = proc.communicate(timeout=60.0)
    text = "".join(lines) + rest
    assert proc.returncode == 0, text[-3000:]
    assert "MJPEG kept undecoded until used" in text  # the camera path the budget was measured with
    imported = _imported(text)
    assert {"taco_mav.cvgl.classical", "taco_mav.daemon.motion", "cv2", "rasterio"} <= imported, sorted(imported)
    assert not {m for m in imported if m in NEVER_LOADED or m.split(".")[0] in NEVER_LOADED}


def test_proc_readings_of_a_process() -> None:
    """The bench's readings of a process: CPU seconds grow with work done, peak RSS is at least the current RSS."""
    pid = os.getpid()
    c0 = cpu_seconds(pid)
    end = time.process_time() + 0.2
    while time.process_time() < end:
        pass
    assert cpu_seconds(pid) >= c0 + 0.1
    rss_kb = next(int(line.split()[1]) for line in Path("/proc/self/status").read_text().splitlines()
                  if line.startswith("VmRSS:"))
    assert peak_rss_mb(pid) >= rss_kb * 1024 / 1e6 > 10.0
