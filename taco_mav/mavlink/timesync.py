"""Companion clock -> autopilot clock. The filter runs on autopilot time (IMU time_usec / time_boot_ms); camera
frames are stamped on the companion's monotonic clock and mapped across with the offset kept here.

autopilot_s = companion_s + offset. Sources, best first:
- TIMESYNC round trips (we send tc1 = 0, ts1 = our monotonic ns; the autopilot answers tc1 = its clock in ns):
  offset = tc1 - (ts1 + t_reply) / 2; of recent samples the one with the shortest round trip wins.
- SYSTEM_TIME.time_boot_ms on arrival (biased late by the link latency), used when TIMESYNC goes unanswered.
- IMU timestamps on arrival (same bias), until anything better is heard.
For the arrival-time sources the largest recent (autopilot - arrival) is kept: latency only ever makes the
offset look smaller.

The offset alone assumes both clocks run at the same rate. A simulated autopilot may run faster than real time
(SITL --speedup, `taco-mav sim --speed N` without lockstep): `ClockRate` estimates autopilot seconds per
companion second from the IMU stamps against their arrival (`ClockMap.speed`), so outputs can be paced on the
autopilot's clock (`scheduler.AutopilotPeriodic`). On a real vehicle it reads exactly 1.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections import deque
from typing import Callable

import numpy as np

log = logging.getLogger(__name__)

_PRIORITY = {"timesync": 3, "system_time": 2, "imu": 1}


def theil_sen_slope(y: np.ndarray, x: np.ndarray) -> float:
    """Theil-Sen's slope of y over x: the median of the slopes between all pairs of points with different x
    (NaN when there are none). The same numbers as `scipy.stats.theilslopes(y, x).slope`, without its
    intercept and confidence interval (a normal quantile per call: ten times the cost, at 10 Hz in the loop)."""
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if len(x) > 1 and bool(np.all(x[1:] > x[:-1])):  # increasing x (the clock fit's): the pairs i > j, cached
        i, j = _lower_pairs(len(x))
        return float(np.median((y[i] - y[j]) / (x[i] - x[j])))
    dx = x[:, np.newaxis] - x
    dy = y[:, np.newaxis] - y
    pos = dx > 0
    return float(np.median(dy[pos] / dx[pos])) if pos.any() else math.nan


@functools.lru_cache(maxsize=8)
def _lower_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) with i > j of n points, as two arrays: those with x_i > x_j when x increases."""
    return np.tril_indices(n, -1)


class ClockRate:
    """Autopilot seconds per companion second, from (arrival on the companion clock, autopilot stamp) pairs of
    the accepted IMU samples over the last `window_s` companion seconds (pairs `min_step_s` apart; of a batch
    handled at once, the newest stamp).

    Latency only ever delays an arrival, so the pairs that arrived with the least latency lie on the upper
    envelope of (companion, autopilot). The window is cut into `bin_s` bins of companion time, each keeps its
    pair furthest above a least-squares line (the least delayed), and the slope through those is Theil-Sen's
    (`theil_sen_slope`, the median of pairwise slopes), so a few pairs far off the line (a start-up
    stall that delays the first second of IMU, or a simulator that sends a sample just before it moves its clock
    to that sample's time) cannot tilt it. Measured on the in-process lockstep simulator (10 Hz IMU), the former
    least-squares fit read 0.80-1.26 at spans of 0.3-1.9 s in 3 of 20 runs, which paced GPS_INPUT below 5 Hz
    of autopilot time and stalled lockstep for its 5 s timeout.

    None until the pairs span `min_span_s`, or when the slope is outside [min_speed, max_speed] (clocks that
    jumped); exactly 1.0 when within `snap` + `jitter_s` / span of 1 (a real autopilot: wall pacing unchanged):
    10 %, widened by what an arrival `jitter_s` late or early at either end of the span does to the slope (one
    10 Hz step of the lockstep simulator). Speed-ups are 1 (a vehicle) or 2 and more (SITL --speedup, sim
    --speed), so a 5x clock is known from the first 0.1 s and a 1x one is never paced otherwise. Recomputed at
    most every `refit_s` companion seconds while the pairs span less than the window (the start, after a reset),
    then every `settled_refit_s`: a full window's median moves with a change of rate over seconds anyway, and the
    fit of 250 pairs (50 Hz IMU) at 10 Hz was a fifth of the daemon loop's CPU (py-spy, companion bench)."""

    def __init__(self, window_s: float = 5.0, min_span_s: float = 0.1, min_step_s: float = 0.01,
                 snap: float = 0.1, jitter_s: float = 0.1, refit_s: float = 0.1, settled_refit_s: float = 0.5,
                 min_speed: float = 0.02, max_speed: float = 100.0, bin_s: float = 0.1) -> None:
        self.window_s, self.min_span_s, self.min_step_s, self.bin_s = window_s, min_span_s, min_step_s, bin_s
        self.snap, self.jitter_s, self.refit_s, self.settled_refit_s = snap, jitter_s, refit_s, settled_refit_s
        self.min_speed, self.max_speed = min_speed, max_speed
        self._pairs: deque[tuple[float, float]] = deque()
        self._first_at = -math.inf  # companion s the first pair came in: a batch then is one pair
        self._value: float | None = None
        self._fitted_at = -math.inf
        self._dirty = False

    def reset(self) -> None:
        self._pairs.clear()
        self._value, self._fitted_at, self._dirty = None, -math.inf, False

    def add(self, t_companion: float, t_autopilot: float) -> None:
        """One accepted sample: autopilot stamp t_autopilot (s) handled at t_companion (s)."""
        q = self._pairs
        kept_before = q[-2][0] if len(q) >= 2 else self._first_at  # the pair the batch follows
        if q and t_companion - kept_before < self.min_step_s:
            q[-1] = (t_companion, t_autopilot)  # the newest of a batch: it waited least
        else:
            if not q:
                self._first_at = t_companion
            q.append((t_companion, t_autopilot))
        while q and t_companion - q[0][0] > self.window_s:
            q.popleft()
        self._dirty = True

    def value(self, now: float) -> float | None:
        """The current estimate (see the class docstring); `now`: companion s."""
        q = self._pairs
        settled = len(q) >= 2 and q[-1][0] - q[0][0] >= self.window_s - self.bin_s
        if self._dirty and now - self._fitted_at >= (self.settled_refit_s if settled else self.refit_s):
            self._value, self._fitted_at, self._dirty = self._fit(), now, False
        return self._value

    def _fit(self) -> float | None:
        n = len(self._pairs)
        if n < 3:
            return None
        c = np.fromiter((p[0] for p in self._pairs), float, n)
        a = np.fromiter((p[1] for p in self._pairs), float, n)
        span = c[-1] - c[0]
        if span < self.min_span_s:
            return None
        c = c - c[0]
        a = a - a[0]
        dc, c_mean, a_mean = c - c.mean(), c.mean(), a.mean()  # the least-squares line, in closed form
        slope = float(dc @ (a - a_mean)) / float(dc @ dc)
        above = a - (slope * c + (a_mean - slope * c_mean))
        bins = np.floor(c / self.bin_s).astype(np.int64)
        order = np.lexsort((-above, bins))  # by bin, the least delayed first
        first = order[np.r_[True, bins[order][1:] != bins[order][:-1]]]
        if len(first) >= 3:  # one pair per bin, so in increasing companion time
            slope = theil_sen_slope(a[first], c[first])
        if not (math.isfinite(slope) and self.min_speed <= slope <= self.max_speed):
            return None
        return 1.0 if abs(slope - 1.0) <= self.snap + self.jitter_s / span else slope


class ClockMap:
    """Offset between the companion's monotonic clock and the autopilot's clock, seconds.

    clock: the companion clock (seconds, monotonic); max_rtt_s: TIMESYNC round trips longer than this are
    ignored; window: samples kept per source; stale_s: a source not heard for this long gives way to lower ones.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, max_rtt_s: float = 0.5, window: int = 20,
                 stale_s: float = 5.0) -> None:
        self.clock = clock
        self.max_rtt_s = max_rtt_s
        self.stale_s = stale_s
        self._samples: dict[str, deque[tuple[float, float, float]]] = {k: deque(maxlen=window) for k in _PRIORITY}
        self.last_rtt_s: float | None = None
        self.rate = ClockRate()

    def reset(self) -> None:
        """Forget everything (autopilot reboot)."""
        for q in self._samples.values():
            q.clear()
        self.last_rtt_s = None
        self.rate.reset()

    # ---------------------------------------------------------------- samples
    def request_ns(self) -> int:
        """ts1 for an outgoing TIMESYNC request: our clock in ns."""
        return int(self.clock() * 1e9)

    def on_timesync_reply(self, tc1_ns: int, ts1_ns: int) -> bool:
        """A TIMESYNC answer to one of our requests; False when it is implausible (ignored)."""
        now = self.clock()
        sent = ts1_ns * 1e-9
        rtt = now - sent
        if tc1_ns <= 0 or not 0.0 <= rtt <= self.max_rtt_s:
            return False
        self.last_rtt_s = rtt
        self._samples["timesync"].append((now, tc1_ns * 1e-9 - (sent + now) / 2.0, rtt))
        return True

    def on_system_time(self, time_boot_ms: int) -> None:
        """SYSTEM_TIME arrived now."""
        if time_boot_ms > 0:
            now = self.clock()
            self._samples["system_time"].append((now, time_boot_ms * 1e-3 - now, 0.0))

    def on_autopilot_time(self, t_autopilot: float) -> None:
        """A timestamped input (IMU) arrived now."""
        now = self.clock()
        self._samples["imu"].append((now, t_autopilot - now, 0.0))
        self.rate.add(now, t_autopilot)

    # ---------------------------------------------------------------- queries
    @property
    def source(self) -> str | None:
        """The source the offset currently comes from ("timesync", "system_time", "imu") or None."""
        now = self.clock()
        for name in sorted(_PRIORITY, key=_PRIORITY.get, reverse=True):
            q = self._samples[name]
            if q and now - q[-1][0] <= self.stale_s:
                return name
        for name in sorted(_PRIORITY, key=_PRIORITY.get, reverse=True):
            if self._samples[name]:
                return name
        return None

    @property
    def offset(self) -> float | None:
        """autopilot_s - companion_s, or None before any sample."""
        name = self.source
        if name is None:
            return None
        q = self._samples[name]
        if name == "timesync":
            return min(q, key=lambda s: s[2])[1]
        return max(s[1] for s in q)

    def speed(self) -> float | None:
        """Autopilot seconds per companion second (`ClockRate`; 1.0 on a real vehicle), None while unknown."""
        return self.rate.value(self.clock())

    def to_autopilot(self, t_companion: float) -> float | None:
        """Companion monotonic seconds -> autopilot seconds (None before any sample)."""
        off = self.offset
        return None if off is None else t_companion + off

    def to_companion(self, t_autopilot: float) -> float | None:
        """Autopilot seconds -> companion monotonic seconds (None before any sample)."""
        off = self.offset
        return None if off is None else t_autopilot - off

    def now_autopilot(self) -> float | None:
        """The autopilot clock now, seconds (None before any sample)."""
        return self.to_autopilot(self.clock())
