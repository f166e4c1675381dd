"""Soak: hours of simulated driving through the real daemon, to show that memory, queues and logs stay bounded
and the GPS_INPUT rate stays steady.

The simulator (`taco_mav.sim.Simulator`, lockstep) plays an endless-looking drive, laps of a circle (constant
speed, exact IMU, so the run can last any number of hours without a seam), to an in-process daemon over
loopback UDP; the daemon runs on the simulator's clock with the FG2-statistics emulator as its matcher and logs
to disk (tlog + events). Every `sample_wall_s` wall seconds the run records, against data time: the process
RSS (/proc/self/status VmRSS), the sizes of the daemon's growing structures with their bounds, and the log
sizes. Results: the RSS growth after warm-up, the largest size of each structure, GPS_INPUT messages per data
minute, the fix-type counts and the daemon's summary.

    doc = soak(hours=1.0, speed=20.0)        # or: python tools/soak.py --hours 1 --speed 20 --out soak.json
"""

from __future__ import annotations

import logging
import math
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from taco_mav.datasets.base import GroundTruth
from taco_mav.geo import UtmProjector, utm_epsg_for
from taco_mav.sim.source import SimDrive

log = logging.getLogger(__name__)

__all__ = ["circle_drive", "rss_mb", "soak", "structure_sizes"]

G = 9.80665


def circle_drive(duration_s: float, rate_hz: float = 10.0, radius_m: float = 150.0, speed_mps: float = 8.0,
                 lat0: float = 49.0, lon0: float = 8.4, utc0: float = 1.6e9) -> SimDrive:
    """Counter-clockwise laps of a circle of `radius_m` m at `speed_mps` m/s for `duration_s` s, sampled at
    `rate_hz`: level, noise-free IMU (FRD specific force with gravity, FRD gyro), true attitude and GNSS.
    Starts at (lat0, lon0) heading east on the UTM grid; the centre is radius_m north of the start."""
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    w = speed_mps / radius_m  # CCW yaw rate, rad/s
    theta = w * t  # grid heading, ENU rad
    xy = np.c_[radius_m * np.sin(theta), radius_m * (1.0 - np.cos(theta))]
    epsg = utm_epsg_for(lat0, lon0)
    proj = UtmProjector(epsg)
    origin = np.array(proj.to_utm(lat0, lon0), dtype=float)
    lat, lon = (np.atleast_1d(np.asarray(a, dtype=float)) for a in proj.to_latlon(origin[0] + xy[:, 0],
                                                                                  origin[1] + xy[:, 1]))
    conv = np.asarray(proj.grid_convergence(lat, lon), dtype=float)
    theta_true = theta - conv
    yaw_ned = np.arctan2(np.sin(np.pi / 2 - theta_true), np.cos(np.pi / 2 - theta_true))
    accel = np.tile([0.0, -speed_mps * w, -G], (n, 1))  # forward, right (centripetal to the left), down
    gyro = np.tile([0.0, 0.0, -w], (n, 1))
    rpy = np.c_[np.zeros(n), np.zeros(n), yaw_ned]
    vn, ve = speed_mps * np.sin(theta_true), speed_mps * np.cos(theta_true)
    wrapped = np.arctan2(np.sin(theta), np.cos(theta))
    return SimDrive(name="circle", path=Path("circle"), t=t, accel_frd=accel, gyro_frd=gyro, rpy_ned=rpy, lat=lat,
                    lon=lon, alt=np.full(n, 115.0), vn=vn, ve=ve, true_lat=lat, true_lon=lon, true_yaw_ned=yaw_ned,
                    truth=GroundTruth(t, xy, wrapped), origin_utm=origin, utm_epsg=epsg, utc0=utc0)


def rss_mb() -> float:
    """Resident set size of this process, MiB (VmRSS from /proc/self/status; ru_maxrss where absent)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def structure_sizes(daemon: Any, before: frozenset[int] = frozenset()) -> dict[str, tuple[int, int | None]]:
    """(size, bound) of each daemon structure that grows with time or traffic; bound None = unbounded.
    "threads" counts the live threads whose ident is not in `before` (those alive when the run began)."""
    out: dict[str, tuple[int, int | None]] = {}
    st, fx = daemon.stats, daemon.fixes
    for name, dq in (("stats.imu_to_estimate_s", st.imu_to_estimate_s), ("stats.output_times", st.output_times)):
        out[name] = (len(dq), dq.maxlen)
    if daemon.truth is not None:
        out["truth.poses"] = (len(daemon.truth.poses), daemon.truth.poses.maxlen)
    if fx.service is not None:
        dq = fx.service.stats.per_trigger_s
        out["service.per_trigger_s"] = (len(dq), getattr(dq, "maxlen", None))
    if daemon.loc is not None:
        h = daemon.loc.timeline.history
        out["localiser.history"] = (len(h), h.maxlen)
        rec = daemon.loc.record  # the daemon keeps no offline record (record=False)
        out["localiser.track"] = (0 if rec is None else len(rec.track), 1)
    out["fixes.results_queue"] = (fx._results.qsize(), None)
    out["fixes.stuck_workers"] = (len(fx._stuck), 2)
    out["counter_keys"] = (len(st.fixes) + len(st.dropped) + len(daemon.decoders.rejected), None)
    out["threads"] = (sum(t.ident not in before for t in threading.enumerate()), None)
    return out


def soak(hours: float = 1.0, speed: float = 20.0, log_dir: Path | None = None, sample_wall_s: float = 1.0,
         progress: bool = False) -> dict[str, Any]:
    """Run the soak for `hours` of data time at up to `speed` x real time (lockstep); returns the results
    document (see the module docstring). log_dir: where the daemon writes its logs (a temporary folder by
    default, removed afterwards)."""
    from taco_mav.config import load_profile, replace_in
    from taco_mav.daemon.daemon import Daemon, DaemonOptions
    from taco_mav.mavlink.connection import free_udp_port
    from taco_mav.sim import Simulator
    from taco_mav.sim.simulator import SimOptions

    duration = hours * 3600.0
    drive = circle_drive(duration + 2.0)
    with tempfile.TemporaryDirectory(prefix="taco-soak-") as tmp:
        logs = Path(log_dir) if log_dir is not None else Path(tmp)
        port = free_udp_port()
        sim = Simulator(drive, f"udpout:127.0.0.1:{port}", speed=speed,
                        options=SimOptions(lockstep=True, duration_s=duration, wait_companion_s=10.0, drain_s=0.3))
        profile = replace_in(load_profile("kitti"), "matcher", "emulator")
        daemon = Daemon(profile, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=logs), clock=sim.clock,
                        wall_clock=sim.utc_now)
        samples: list[dict[str, Any]] = []
        wall0 = time.monotonic()
        before = frozenset(t.ident for t in threading.enumerate() if t.ident is not None)
        daemon.start()
        try:
            sim.start()
            while not sim.join(timeout=sample_wall_s):
                samples.append(_sample(daemon, sim, logs, wall0, before))
                if progress and len(samples) % 30 == 0:
                    log.info("soak: %.0f of %.0f data s, RSS %.0f MiB", samples[-1]["data_s"], duration,
                             samples[-1]["rss_mb"])
            samples.append(_sample(daemon, sim, logs, wall0, before))
        finally:
            daemon.stop()
            daemon.join(5.0)
        wall = time.monotonic() - wall0
        doc = sim.results()
    return _report(hours, speed, wall, samples, sim, doc, daemon)


def _sample(daemon: Any, sim: Any, logs: Path, wall0: float, before: frozenset[int]) -> dict[str, Any]:
    start = sim.play_start
    files = {p.name: p.stat().st_size for p in logs.iterdir() if p.is_file()} if logs.is_dir() else {}
    return {"wall_s": time.monotonic() - wall0, "data_s": 0.0 if start is None else sim.clock.now() - start,
            "rss_mb": rss_mb(), "sizes": {k: v[0] for k, v in structure_sizes(daemon, before).items()},
            "log_bytes": sum(files.values())}


def _report(hours: float, speed: float, wall: float, samples: list[dict[str, Any]], sim: Any, doc: dict[str, Any],
            daemon: Any) -> dict[str, Any]:
    seq = doc["sequences"][sim.drive.name]
    data_s = max(s["data_s"] for s in samples) if samples else 0.0
    rss = np.array([s["rss_mb"] for s in samples])
    t = np.array([s["data_s"] for s in samples])
    warm = rss[np.searchsorted(t, 0.1 * data_s)] if len(rss) else math.nan  # after 10 % of the run
    start = sim.play_start or 0.0
    stamps = np.array([u.t - start for u in sim.monitor.updates])
    minutes = int(data_s // 60)
    per_min = [int(np.sum((stamps >= 60 * m) & (stamps < 60 * (m + 1)))) for m in range(minutes)]
    bounds = structure_sizes(daemon)
    return {
        "hours": hours, "speed_asked": speed, "wall_s": wall, "data_s": data_s,
        "speed_achieved": data_s / wall if wall > 0 else None,
        "rss_mb": {"first": float(rss[0]) if len(rss) else None, "after_warmup": float(warm),
                   "end": float(rss[-1]) if len(rss) else None, "max": float(rss.max()) if len(rss) else None},
        "rss_growth_pct": float(100.0 * (rss[-1] - warm) / warm) if len(rss) else None,
        "sizes_max": {k: max(s["sizes"].get(k, 0) for s in samples) for k in bounds},
        "sizes_bound": {k: v[1] for k, v in bounds.items()},
        "log_bytes_end": samples[-1]["log_bytes"] if samples else 0,
        "gps_input_per_min": per_min,
        "gps_input_per_min_range": [min(per_min), max(per_min)] if per_min else None,
        "gps_input_rate_hz": seq.get("gps_input_rate_hz"), "consecutive_gaps_over_245ms":
            seq.get("consecutive_gaps_over_245ms"), "lockstep_timeouts": seq.get("lockstep_timeouts"),
        "fix_type_counts": seq.get("fix_type_counts"), "ate_m": seq.get("ate_m"), "max_error_m": seq.get("max_error_m"),
        "daemon": daemon.summary(),
        "samples": [{"data_s": s["data_s"], "wall_s": s["wall_s"], "rss_mb": s["rss_mb"], "log_bytes": s["log_bytes"],
                     **s["sizes"]} for s in samples[:: max(1, len(samples) // 200)]],
    }
