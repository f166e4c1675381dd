"""How ArduPilot takes GPS_INPUT: the AP_GPS_MAV driver, AP_GPS's timing health and EKF3's GPS quality gates.

Modelled behaviour (ArduPilot 4.5/4.6, written from its documented rules, not its code):
- AP_GPS_MAV keeps a message only when `gps_id` equals the GPS instance (0 for GPS1); others vanish silently.
  Every kept message is one GPS update. A field flagged in `ignore_flags` is not taken: an ignored HDOP stays
  at the "unknown" 99.99, an ignored horizontal accuracy is "not reported" (EKF3 then skips that check).
- AP_GPS timing: per update the gap since the previous one (autopilot clock, ms) feeds a running average
  (avg = 0.98 avg + 0.02 gap, started at the first gap; gaps of 2 s or more are left out) and a count of consecutive gaps over 245 ms. The instance is unhealthy while
  the average is >= 215 ms or two gaps in a row exceed 245 ms, or when nothing arrived for 4 s.
- EKF3 uses the GPS only after its checks have passed continuously for 10 s: 3D fix, satellites >= 6,
  HDOP <= 2.5, horizontal accuracy <= 5 m (EK3_CHECK_SCALE 100 %). Its speed-accuracy check (<= 1 m/s) is
  reported separately.
Times are the autopilot clock at arrival, seconds since boot.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["AVG_MAX_S", "GAP_MAX_S", "GpsInputMonitor", "GpsUpdate", "GATE_HDOP_MAX", "GATE_HACC_MAX_M",
           "GATE_SACC_MAX_MPS", "GATE_SATS_MIN"]

GAP_MAX_S = 0.245
AVG_MAX_S = 0.215
TIMEOUT_S = 4.0
GATE_SATS_MIN = 6
GATE_HDOP_MAX = 2.5
GATE_HACC_MAX_M = 5.0
GATE_SACC_MAX_MPS = 1.0
GATE_HOLD_S = 10.0
IGNORE_HDOP = 2  # GPS_INPUT_IGNORE_FLAG_HDOP
IGNORE_SPEED_ACCURACY = 32  # GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
IGNORE_HORIZONTAL_ACCURACY = 64  # GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
UNKNOWN_HDOP = 99.99


def _pairs_over(gaps_ms: np.ndarray, limit_ms: float) -> int:
    """How many times a run of gaps over `limit_ms` reached two in a row (AP_GPS's delayed_count == 2)."""
    count, run = 0, 0
    for g in gaps_ms:
        run = run + 1 if g > limit_ms else 0
        count += run == 2
    return count


@dataclass(frozen=True)
class GpsUpdate:
    """One GPS_INPUT the driver kept. t: autopilot clock at arrival, s; lat/lon degrees; hdop; h_acc m or None
    (not reported); s_acc m/s or None; yaw_deg true heading or None (0 on the wire = unknown); stamp_unix_s: the
    message's own time (GPS week/ms, or time_usec when it looks like unix time), None when absent."""

    t: float
    fix_type: int
    lat: float
    lon: float
    satellites: int
    hdop: float
    h_acc: float | None
    s_acc: float | None
    vn: float
    ve: float
    yaw_deg: float | None
    stamp_unix_s: float | None
    gates_ok: bool
    healthy: bool


@dataclass
class GpsInputMonitor:
    """Feed it every received GPS_INPUT with `handle(msg, t)`; read `updates` and `summary()`.

    instance: the GPS instance the driver serves (0 = GPS1); leap_seconds: GPS - UTC used to read time_week/ms.
    """

    instance: int = 0
    leap_seconds: int = 18
    updates: list[GpsUpdate] = field(default_factory=list)
    dropped_wrong_id: int = 0
    _avg_gap: float = 0.0
    _delayed: int = 0
    _max_delayed: int = 0
    _gates_since: float | None = None
    _ekf_ready_at: float | None = None

    def handle(self, msg: Any, t: float) -> GpsUpdate | None:
        """Process one GPS_INPUT arriving at autopilot time t (s); returns the update, None when dropped."""
        if int(msg.gps_id) != self.instance:
            self.dropped_wrong_id += 1
            if self.dropped_wrong_id == 1:
                log.warning("GPS_INPUT with gps_id %d dropped (the driver serves instance %d)", msg.gps_id, self.instance)
            return None
        flags = int(msg.ignore_flags)
        hdop = UNKNOWN_HDOP if flags & IGNORE_HDOP else float(msg.hdop)
        h_acc = None if flags & IGNORE_HORIZONTAL_ACCURACY else float(msg.horiz_accuracy)
        s_acc = None if flags & IGNORE_SPEED_ACCURACY else float(msg.speed_accuracy)
        fix, sats = int(msg.fix_type), int(msg.satellites_visible)

        if self.updates:
            gap = t - self.updates[-1].t
            if gap < 2.0:  # longer silences are outages, not rate (they still count as delayed)
                self._avg_gap = gap if self._avg_gap <= 0 else 0.98 * self._avg_gap + 0.02 * gap
            if gap > GAP_MAX_S:
                self._delayed += 1
            else:
                self._delayed = 0
            self._max_delayed = max(self._max_delayed, self._delayed)
        healthy = len(self.updates) >= 1 and self._delayed < 2 and self._avg_gap < AVG_MAX_S

        gates = (fix >= 3 and sats >= GATE_SATS_MIN and hdop <= GATE_HDOP_MAX
                 and (h_acc is None or h_acc <= GATE_HACC_MAX_M) and math.isfinite(msg.lat) and healthy)
        if gates:
            if self._gates_since is None:
                self._gates_since = t
            if self._ekf_ready_at is None and t - self._gates_since >= GATE_HOLD_S:
                self._ekf_ready_at = t
        else:
            self._gates_since = None

        update = GpsUpdate(t=t, fix_type=fix, lat=msg.lat * 1e-7, lon=msg.lon * 1e-7, satellites=sats, hdop=hdop,
                           h_acc=h_acc, s_acc=s_acc, vn=float(msg.vn), ve=float(msg.ve),
                           yaw_deg=(msg.yaw * 0.01) % 360.0 if getattr(msg, "yaw", 0) else None,
                           stamp_unix_s=self._stamp(msg), gates_ok=gates, healthy=healthy)
        self.updates.append(update)
        return update

    def _stamp(self, msg: Any) -> float | None:
        if int(msg.time_week) > 0:
            from taco_mav.geo import unix_from_gps_week_ms

            return unix_from_gps_week_ms(int(msg.time_week), int(msg.time_week_ms), self.leap_seconds)
        if int(msg.time_usec) > 10**15:  # after 2001: unix microseconds rather than time since boot
            return int(msg.time_usec) * 1e-6
        return None

    @property
    def ekf_ready_at(self) -> float | None:
        """Autopilot time at which EKF3's 10 s of passing checks completed, s (None: never)."""
        return self._ekf_ready_at

    def summary(self, end_t: float | None = None, start_t: float | None = None) -> dict[str, Any]:
        """Rate and gate figures (results.json keys) over the updates that arrived between start_t and end_t
        (autopilot clock, s; None: unbounded). A silence longer than 4 s before end_t is a GPS timeout. The
        health and EKF figures come from the driver model run over every update."""
        lo = -math.inf if start_t is None else start_t
        hi = math.inf if end_t is None else end_t
        updates = [u for u in self.updates if lo <= u.t <= hi]
        n = len(updates)
        t = np.array([u.t for u in updates])
        gaps_ms = np.diff(t) * 1e3 if n > 1 else np.zeros(0)
        fix_counts: dict[str, int] = {}
        for u in updates:
            fix_counts[str(u.fix_type)] = fix_counts.get(str(u.fix_type), 0) + 1
        timeout = bool(n == 0 or (end_t is not None and end_t - t[-1] > TIMEOUT_S)
                       or (gaps_ms.size and gaps_ms.max() > TIMEOUT_S * 1e3))
        gate_pass = float(np.mean([u.gates_ok for u in updates])) if n else 0.0
        s_acc = [u.s_acc for u in updates if u.s_acc is not None]
        h_acc = [u.h_acc for u in updates if u.h_acc is not None]
        out: dict[str, Any] = {
            "gps_input_count": n,
            "gps_input_dropped_wrong_id": self.dropped_wrong_id,
            "gps_input_rate_hz": float((n - 1) / (t[-1] - t[0])) if n > 1 and t[-1] > t[0] else 0.0,
            "gps_input_interval_p50_ms": float(np.percentile(gaps_ms, 50)) if gaps_ms.size else None,
            "gps_input_interval_p99_ms": float(np.percentile(gaps_ms, 99)) if gaps_ms.size else None,
            "gps_input_interval_max_ms": float(gaps_ms.max()) if gaps_ms.size else None,
            "gps_input_interval_avg_ms": float(gaps_ms.mean()) if gaps_ms.size else None,
            "consecutive_gaps_over_245ms": _pairs_over(gaps_ms, GAP_MAX_S * 1e3),
            "gaps_over_245ms": int((gaps_ms > GAP_MAX_S * 1e3).sum()),
            "gps_unhealthy_updates": sum(1 for u in updates[1:] if not u.healthy),
            "gps_timeout": timeout,
            "fix_type_counts": fix_counts,
            "ekf_gate_pass_fraction": gate_pass,
            "ekf_ready_after_s": (self._ekf_ready_at - t[0]) if self._ekf_ready_at is not None else None,
            "ekf_gates_ok": bool(self._ekf_ready_at is not None and not timeout),
            "speed_accuracy_max_mps": float(max(s_acc)) if s_acc else None,
            "ekf_speed_accuracy_ok": bool(not s_acc or max(s_acc) <= GATE_SACC_MAX_MPS),
            "horiz_accuracy_p50_m": float(np.median(h_acc)) if h_acc else None,
            "horiz_accuracy_max_m": float(max(h_acc)) if h_acc else None,
            "hdop_p50": float(np.median([u.hdop for u in updates])) if n else None,
            "hdop_max": float(max(u.hdop for u in updates)) if n else None,
            "satellites_min": min(u.satellites for u in updates) if n else None,
        }
        return out
