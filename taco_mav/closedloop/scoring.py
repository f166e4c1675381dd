"""The figures of a closed-loop mission and the bounds they are held to.

- `score`: from the ground station's log: the EKF (GLOBAL_POSITION_INT) and our instance's report (GPS_RAW_INT
  or GPS2_RAW) against the simulator's truth, the rover's true speed, how often the EKF stayed within the bound
  of what we reported while moving;
- `sent_score`: our reports scored where they were made, in the daemon's own tlog, with the 1-sigma we claimed;
- `shadow_score`: the `--shadow` twin's figures;
- `daemon_summary`: what the daemon's event log says it did (answers by outcome, outages, GNSS guard);
- `accuracy_failures`: what breaks "the reported accuracy covers the error" in `sent_score`'s figures.

Defaults are ArduPilot's (truth SIMSTATE, longitude field `lng`); PX4 passes its own (HIL_STATE_QUATERNION, `lon`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
import numpy as np  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from taco_mav.closedloop.geometry import metres_between  # noqa: E402
from taco_mav.daemon.eventlog import read_events  # noqa: E402


def score(log: list[tuple[float, Any]], spec: Any, auto_t: float | None, out: Path | None = None, *,
          truth_kind: str = "SIMSTATE", truth_lon: str = "lng", ours_kind: str | None = None,
          cruise_mps: float | None = None) -> dict[str, Any]:
    """Figures from the GCS log: truth (`truth_kind`, lat and `truth_lon` in degE7: ArduPilot's SIMSTATE, PX4's
    HIL_STATE_QUATERNION) at 10 Hz, stamped by arrival wall time, the EKF (GLOBAL_POSITION_INT) and our
    instance's report (`ours_kind`; default GPS_RAW_INT in solo, GPS2_RAW in handover) each paired with the
    latest truth before it; errors are horizontal metres about spec.home. The speed limit is 1.5 x cruise_mps
    (default spec.wp_speed), m/s. With `out`, truth.csv, ekf_error.csv and ours_error.csv go there (from AUTO
    on)."""
    lat0, lon0 = spec.home[0], spec.home[1]
    truth = [(t, *metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)) for t, m in log
             if m.get_type() == truth_kind]
    if len(truth) < 10:
        return {"error": f"no {truth_kind}"}
    T = np.array(truth)
    if ours_kind is None:
        ours_kind = "GPS_RAW_INT" if spec.setup == "solo" else "GPS2_RAW"
    if cruise_mps is None:
        cruise_mps = spec.wp_speed

    def paired(kind: str, lat: str, lon: str, scale: float) -> np.ndarray:
        rows = []
        for t, m in log:
            if m.get_type() != kind or (auto_t is not None and t < auto_t):
                continue
            if kind != "GLOBAL_POSITION_INT" and m.fix_type < 3 or m.lat == 0 and m.lon == 0:
                continue  # no fix, or an EKF without an origin
            i = int(np.searchsorted(T[:, 0], t)) - 1
            if i < 0:
                continue
            e, n = metres_between(lat0, lon0, getattr(m, lat) * scale, getattr(m, lon) * scale)
            acc = getattr(m, "h_acc", 0) * 1e-3 if kind != "GLOBAL_POSITION_INT" else 0.0
            rows.append((t, math.hypot(e - T[i, 1], n - T[i, 2]), acc))
        return np.array(rows).reshape(-1, 3)

    ekf = paired("GLOBAL_POSITION_INT", "lat", "lon", 1e-7)
    ours = paired(ours_kind, "lat", "lon", 1e-7)
    bounded = _ekf_bounded_share(log, T, ekf, ours_kind, auto_t)
    live = T[T[:, 0] >= auto_t] if auto_t is not None else T
    dt = np.diff(live[:, 0])
    speed = np.hypot(np.diff(live[:, 1]), np.diff(live[:, 2])) / np.maximum(dt, 1e-3)
    speed = speed[dt > 0.05]
    # a 1 s median keeps the truth's arrival jitter out of the speed
    k = 10
    smooth = np.array([np.median(speed[i:i + k]) for i in range(max(len(speed) - k, 0))]) if len(speed) > k else speed
    res: dict[str, Any] = {
        "ekf_rms_m": float(np.sqrt(np.mean(ekf[:, 1] ** 2))) if len(ekf) else None,
        "ekf_max_m": float(ekf[:, 1].max()) if len(ekf) else None,
        "true_speed_max_mps": float(smooth.max()) if len(smooth) else None,
        "true_speed_limit_mps": 1.5 * cruise_mps,
        "ours_reports": int(len(ours)),
        "ours_rms_m": float(np.sqrt(np.mean(ours[:, 1] ** 2))) if len(ours) else None,
        "ours_max_m": float(ours[:, 1].max()) if len(ours) else None,
        # error over reported 1-sigma (h_acc); > 3 means we claimed far more than we had
        "ours_error_over_hacc_max": float((ours[:, 1] / np.maximum(ours[:, 2], 0.1)).max()) if len(ours) else None,
        "ours_hacc_median_m": float(np.median(ours[:, 2])) if len(ours) else None,
        "ekf_within_bound_moving_share": bounded,
    }
    if out is not None:
        np.savetxt(out / "truth.csv", T, fmt="%.3f", delimiter=",", header="wall_s,east_m,north_m")
        np.savetxt(out / "ekf_error.csv", ekf[:, :2], fmt="%.3f", delimiter=",", header="wall_s,error_m")
        np.savetxt(out / "ours_error.csv", ours, fmt="%.3f", delimiter=",", header="wall_s,error_m,h_acc_m")
    return res


def _ekf_bounded_share(log: list[tuple[float, Any]], T: np.ndarray, ekf: np.ndarray, ours_kind: str,
                       auto_t: float | None, moving_mps: float = 0.5) -> float | None:
    """Share of the EKF's samples taken while the rover moves (truth faster than moving_mps) whose error is within
    max(3 m, 2 x the 1-sigma we last reported): `ours_kind`'s h_acc, whatever its fix type (a degraded report's
    accuracy counts: it told the autopilot how little to trust it): the bound for never following a wrong fix,
    for a camera that cannot read the ground (docs/sitl.md). None without such samples."""
    acc = [(t, m.h_acc * 1e-3) for t, m in log if m.get_type() == ours_kind and (auto_t is None or t >= auto_t)]
    if not acc or len(ekf) == 0 or len(T) < 3:
        return None
    A = np.array(acc)
    dt = np.maximum(np.diff(T[:, 0]), 1e-3)
    v = np.r_[0.0, np.hypot(np.diff(T[:, 1]), np.diff(T[:, 2])) / dt]
    v = np.convolve(v, np.ones(10) / 10.0, mode="same")  # 1 s mean: the truth's arrival jitter out
    ok = []
    for t, err, _ in ekf:
        i, j = int(np.searchsorted(T[:, 0], t)) - 1, int(np.searchsorted(A[:, 0], t)) - 1
        if i < 0 or j < 0 or v[i] < moving_mps:
            continue
        ok.append(err <= max(3.0, 2.0 * A[j, 1]))
    return float(np.mean(ok)) if ok else None


def sent_score(daemon_dir: Path, spec: Any, auto_t: float | None, out: Path | None = None, *,
               truth_kind: str = "SIMSTATE", truth_lon: str = "lng") -> dict[str, Any]:
    """Our reports scored where they were made: every GPS_INPUT / HIL_GPS (fix type >= 3) in the daemon's own
    tlog (daemon_dir/*/mav.tlog, both directions stamped on the daemon's wall clock) against the truth the daemon
    heard (`truth_kind`, interpolated to the send time), with the 1-sigma it claimed (GPS_INPUT horiz_accuracy m,
    HIL_GPS eph cm). The ground station's echo (`score`) adds the autopilot's store-and-forward delay to the error,
    up to a metre at 3 m/s; this does not. Figures: ours_sent_* (error m, error over 1-sigma max / median, share
    within 2 and 3 sigma); with `out`, ours_sent_error.csv."""
    tlogs = sorted(Path(daemon_dir).glob("*/mav.tlog"))
    if not tlogs:
        return {"ours_sent_error": f"no daemon tlog under {daemon_dir}"}
    lat0, lon0 = spec.home[0], spec.home[1]
    truth: list[tuple[float, float, float]] = []
    sent: list[tuple[float, float, float, float]] = []
    gaps: list[float] = []  # s between consecutive position messages of one session
    for path in tlogs:
        mlog = mavutil.mavlink_connection(str(path))
        last_sent = None
        while (m := mlog.recv_match(type=[truth_kind, "GPS_INPUT", "HIL_GPS"])) is not None:
            kind, t = m.get_type(), float(m._timestamp)
            if kind != truth_kind:
                if last_sent is not None and (auto_t is None or t >= auto_t):
                    gaps.append(t - last_sent)
                last_sent = t
            if kind == truth_kind:
                if m.lat or getattr(m, truth_lon):
                    truth.append((t, *metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)))
            elif m.fix_type >= 3 and (auto_t is None or t >= auto_t):
                acc = float(m.horiz_accuracy) if kind == "GPS_INPUT" else m.eph * 1e-2
                sent.append((t, *metres_between(lat0, lon0, m.lat * 1e-7, m.lon * 1e-7), acc))
    if len(truth) < 10 or not sent:
        return {"ours_sent_error": f"{len(truth)} {truth_kind}, {len(sent)} reports in the daemon tlog"}
    T, S = np.array(sorted(truth)), np.array(sent)
    S = S[(S[:, 0] >= T[0, 0]) & (S[:, 0] <= T[-1, 0])]
    te, tn = np.interp(S[:, 0], T[:, 0], T[:, 1]), np.interp(S[:, 0], T[:, 0], T[:, 2])
    err = np.hypot(S[:, 1] - te, S[:, 2] - tn)
    ratio = err / np.maximum(S[:, 3], 0.1)
    if out is not None:
        np.savetxt(out / "ours_sent_error.csv", np.column_stack([S[:, 0], err, S[:, 3]]), fmt="%.3f",
                   delimiter=",", header="wall_s,error_m,h_acc_m")
    return {"ours_sent_reports": int(len(err)), "ours_sent_rms_m": float(np.sqrt(np.mean(err**2))),
            "ours_sent_interval_p50_ms": float(np.percentile(gaps, 50) * 1e3) if gaps else None,
            "ours_sent_interval_p99_ms": float(np.percentile(gaps, 99) * 1e3) if gaps else None,
            "ours_sent_error_over_hacc_max": float(ratio.max()),
            "ours_sent_error_over_hacc_median": float(np.median(ratio)),
            # a calibrated 2-D Gaussian puts 86.5 % within 2 sigma (Rayleigh) and 98.9 % within 3
            "ours_sent_within_2_hacc": float(np.mean(ratio <= 2.0)),
            "ours_sent_within_3_hacc": float(np.mean(ratio <= 3.0))}


def shadow_score(daemon_dir: Path, spec: Any, truth_kind: str = "SIMSTATE", truth_lon: str = "lng") -> dict[str, Any]:
    """`--shadow` figures: the `shadow` events' gnss_err_m (the GNSS-free twin's distance to the receiver) beside
    the twin's true error (its lat, lon against the truth in the daemon's tlog at the event's wall time); none
    without shadow events."""
    events = [e for e in read_events(daemon_dir) if e.get("event") == "shadow"]
    if not events:
        return {}
    lat0, lon0 = spec.home[0], spec.home[1]
    truth = []
    for path in sorted(Path(daemon_dir).glob("*/mav.tlog")):
        mlog = mavutil.mavlink_connection(str(path))
        while (m := mlog.recv_match(type=[truth_kind])) is not None:
            if m.lat or getattr(m, truth_lon):
                east_north = metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)
                truth.append((float(m._timestamp), *east_north))
    T = np.array(sorted(truth))
    tw = np.array([e["t_wall"] for e in events])
    twin = np.array([metres_between(lat0, lon0, e["lat"], e["lon"]) for e in events])
    true_err = np.hypot(twin[:, 0] - np.interp(tw, T[:, 0], T[:, 1]), twin[:, 1] - np.interp(tw, T[:, 0], T[:, 2]))
    told = np.array([e["gnss_err_m"] for e in events])
    return {"shadow_reports": len(events), "shadow_gnss_err_median_m": float(np.median(told)),
            "shadow_true_err_median_m": float(np.median(true_err)),
            "shadow_true_err_p95_m": float(np.percentile(true_err, 95))}


def accuracy_failures(res: dict[str, Any], within_2: float | None = 0.8, within_3: float = 0.95,
                      max_ratio: float = 5.0) -> list[str]:
    """What breaks "the reported accuracy covers the error" in `sent_score`'s figures (empty when it holds): at
    least `within_2` of the reports within 2 sigma (None: not asked) and `within_3` within 3 (a calibrated
    isotropic Gaussian: 86.5 and 98.9 %), none beyond `max_ratio` (never again 1.2 m reported at 53 m)."""
    if "ours_sent_reports" not in res:
        return [str(res.get("ours_sent_error", "no at-send figures"))]
    bounds = [("ours_sent_within_3_hacc", within_3, 1), ("ours_sent_error_over_hacc_max", max_ratio, -1)]
    if within_2 is not None:
        bounds.insert(0, ("ours_sent_within_2_hacc", within_2, 1))
    return [f"{key} {res[key]:.3f} (bound {bound})" for key, bound, sign in bounds if sign * (res[key] - bound) < 0]


def daemon_summary(daemon_dir: Path) -> dict[str, Any]:
    """From the daemon's event logs (daemon_dir/*/events.jsonl): its last `stats` line's counters (answers by
    outcome, camera-speed measurements by outcome, link outages, stuck matchers) and how often its GNSS guard
    rejected or re-accepted the receiver."""
    stats: dict[str, Any] = {}
    kinds: dict[str, int] = {}
    for e in read_events(daemon_dir):
        kind = e.get("event")
        if kind == "stats":
            stats = e
        elif kind in ("gnss_rejected", "gnss_accepted_again", "gnss_lost", "lock"):
            key = kind if kind != "lock" else f"lock_{e.get('kind')}"
            kinds[key] = kinds.get(key, 0) + 1
    return {"daemon_fixes": stats.get("fixes", {}), "daemon_camera_motion": stats.get("camera_motion", {}),
            "daemon_link_outages": stats.get("link_outages"),
            "daemon_stuck_matchers": stats.get("stuck_matchers"), "daemon_events": kinds}
