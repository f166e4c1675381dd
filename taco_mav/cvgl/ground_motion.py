"""Ground-plane motion between two camera frames: speed from the camera as well as the IMU.

Both frames are projected to the same heading-up bird's-eye view (`BevProjector`, the IPM the classical matcher
uses); the second is first rotated about the vehicle by the compass's heading change, so what is left between
the two views is the vehicle's translation, which normalised cross-correlation (cv2.matchTemplate) of a patch of
frame 0 within frame 1 measures to a fraction of a BEV pixel. Both views are high-passed first (lighting drops
out).

The patch is split into side-by-side strips, each correlated on its own, and the answer is that of the largest
group of strips that agree (at least two, and more than in any other group). Something that moves with the
vehicle (a car followed at a constant distance, and its shadow) fills one strip and makes it measure zero
motion; the strips on either side still see the ground and outvote it. Strips that disagree with no majority
give no answer. (Masking vertical structure as the classical matcher does, `cvgl.masks`, cost 2 x 19 ms per
measurement, 8x the rest, and changed no measurement on nine 3-D worlds: the strips do that job.)

Frames and units: BEV pixel (i, j) shows ground at forward = (v0 - j) m, left = (u0 - i) m (module ipm).
When the vehicle moves forward by d metres, the ground in the second view moves down the image by d / m
pixels; left by l metres moves it right by l / m pixels. Headings ENU radians (CCW), times seconds.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.cvgl.ipm import BevProjector

log = logging.getLogger(__name__)

__all__ = ["GroundMotion", "HeadingHistory", "Motion", "MIN_GAP_S"]

MIN_GAP_S = 0.05  # the shortest time between the two frames (a 20 Hz camera's period), s


class HeadingHistory:
    """The compass headings (ENU rad) at recent times (s), for the heading change between two frames. Thread-safe
    (the daemon adds on its loop thread and reads on the motion worker); the newest `maxlen` kept."""

    def __init__(self, maxlen: int = 4000) -> None:
        self._h: deque[tuple[float, float]] = deque(maxlen=maxlen)
        self._lock = threading.Lock()

    def add(self, t: float, theta: float) -> None:
        """The heading theta (ENU rad) at time t (s); a time not after the last is ignored, unless more than 1 s
        before it (the clock went back, e.g. an autopilot reboot: the history restarts)."""
        with self._lock:
            if self._h and t <= self._h[-1][0]:
                if t < self._h[-1][0] - 1.0:
                    self._h.clear()
                else:
                    return
            self._h.append((t, theta))

    def at(self, t: float) -> float | None:
        """The heading at time t (s), interpolated; None more than 0.1 s outside the history."""
        with self._lock:
            h = self._h
            i = bisect.bisect_left(h, (t, -math.inf))
            if not h or i == 0 and h[0][0] - t > 0.1 or i == len(h) and t - h[-1][0] > 0.1:
                return None
            a, b = h[max(i - 1, 0)], h[min(i, len(h) - 1)]
        if b[0] == a[0]:
            return a[1]
        w = (t - a[0]) / (b[0] - a[0])
        return a[1] + w * math.remainder(b[1] - a[1], 2 * math.pi)

    def change(self, t0: float, t1: float) -> float | None:
        """The heading change from t0 to t1 (s), rad in [-pi, pi]; None when either is outside the history."""
        h0, h1 = self.at(t0), self.at(t1)
        return None if h0 is None or h1 is None else math.remainder(h1 - h0, 2 * math.pi)


@dataclass(frozen=True)
class Motion:
    """Vehicle translation from frame 0 to frame 1 in frame 0's body axes: d_fwd, d_left metres; response:
    phase-correlation peak strength (0..1); sigma_m: 1-sigma of the translation, metres."""

    d_fwd: float
    d_left: float
    response: float
    sigma_m: float


class GroundMotion:
    """Measures vehicle translation between two frames of `camera` over flat ground.

    m_per_px: BEV resolution; band_m: the (near, far) forward distances, metres, of the patch of frame 0 that is
    looked for in frame 1 (default: a `band_depth_m` deep band starting `max_shift_m` beyond the nearest ground
    the camera sees across the whole search width above its bottom `ego_rows` rows, which show the vehicle itself
    (profile key `classical.ego_mask_rows`)); half_width_m: the patch's half width; strips: how many
    side-by-side strips the patch is split into (module docstring); agree_m: how close two strips' translations
    must be to agree, metres; max_shift_m: the largest forward motion looked for (backwards: a quarter of it);
    min_response: a weaker normalised correlation peak (texture-less ground, a blurred or occluded view) leaves a
    strip out.
    """

    def __init__(self, camera: GroundCamera, m_per_px: float = 0.05, band_m: tuple[float, float] | None = None,
                 half_width_m: float = 4.0, max_shift_m: float = 3.0, min_response: float = 0.5,
                 band_depth_m: float = 3.0, strips: int = 5, agree_m: float = 0.15,
                 ego_rows: int = 0) -> None:
        if strips < 1 or agree_m <= 0.0:
            raise ValueError(f"ground motion: strips must be >= 1 and agree_m > 0, got {strips}, {agree_m}")
        self.m_per_px, self.max_shift_m = m_per_px, max_shift_m
        if band_m is None:
            near = nearest_ground_m(camera, half_width_m + max_shift_m / 2.0,
                                    bottom_row=camera.height - 1 - ego_rows)
            band_m = (near + max_shift_m + 0.2, near + max_shift_m + 0.2 + band_depth_m)
        self.band_m = band_m
        far = band_m[1] + 1.0
        n = int(round(far / m_per_px))
        width = int(round(2.0 * (half_width_m + max_shift_m / 2.0 + 1.0) / m_per_px)) | 1
        self.bev = BevProjector(camera, (width, n), m_per_px, max_range_m=far * 1.5)
        u0, v0 = self.bev.vehicle_px
        self.rows = (int(v0 - band_m[1] / m_per_px), int(v0 - band_m[0] / m_per_px))  # template rows [a, b)
        hw = int(round(half_width_m / m_per_px))
        self.cols = (int(round(u0)) - hw, int(round(u0)) + hw + 1)
        self.down = int(round(max_shift_m / m_per_px))  # forward motion moves the ground down the view
        self.up = max(int(round(0.25 * max_shift_m / m_per_px)), 2)
        self.side = int(round((max_shift_m / 2.0) / m_per_px))
        a, b = self.rows
        if a - self.up < 0 or b + self.down > self.bev.height or not self.bev.mask[a:b, self.cols[0]:self.cols[1]].all():
            raise ValueError(f"ground motion: the camera does not see the ground {band_m[0]}-{band_m[1]} m ahead, "
                             f"+-{half_width_m} m wide (mount height / pitch / intrinsics?)")
        if not self.bev.mask[a:b + self.down, self.cols[0] - self.side:self.cols[1] + self.side].all():
            log.debug("ground motion: part of the search region is outside the view; shifts there score low")
        self.min_response, self.agree_m = min_response, agree_m
        edges = np.linspace(self.cols[0], self.cols[1], strips + 1).round().astype(int)
        self.strip_cols = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]

    def _prepare(self, image: np.ndarray, rotate_rad: float = 0.0) -> np.ndarray:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        bev, _ = self.bev.project(gray)
        if rotate_rad:
            # the view turns with the vehicle: a CCW turn by dtheta turns the ground CW in the view; turn it back
            u0, v0 = self.bev.vehicle_px
            R = cv2.getRotationMatrix2D((u0, v0), math.degrees(rotate_rad), 1.0)
            bev = cv2.warpAffine(bev, R, (bev.shape[1], bev.shape[0]), flags=cv2.INTER_LINEAR)
        return (bev - cv2.GaussianBlur(bev, (0, 0), 8.0)).astype(np.float32)  # local contrast: lighting drops out

    def frame_gap(self, speed_mps: float, longest_s: float) -> float:
        """Time between the two frames, s: longest_s, shorter at speed so that the ground moves at most half the
        largest shift looked for (speed in m/s), and at least MIN_GAP_S."""
        return min(longest_s, max(MIN_GAP_S, 0.5 * self.max_shift_m / max(abs(float(speed_mps)), 0.1)))

    def measure(self, image0: np.ndarray, image1: np.ndarray, dtheta: float = 0.0) -> Motion | None:
        """Translation from frame 0 to frame 1 (camera images of this camera's size); dtheta: heading change
        between them, ENU rad (the compass's). None when no group of strips outvotes the others (module
        docstring) or, with one strip textured, its peak is weak or at the edge of the search."""
        b0 = self._prepare(image0)
        b1 = self._prepare(image1, dtheta)
        textured = [m for m in (self._strip(b0, b1, c0, c1) for c0, c1 in self.strip_cols) if m is not None]
        found = [m for m in textured if isinstance(m, Motion)]
        if len(textured) <= 1:
            return found[0] if found else None  # one strip with texture (or one strip): its own answer
        best = self._largest_group(found)
        rest = [m for m in found if all(m is not b for b in best)]
        if len(best) < 2 or len(self._largest_group(rest)) >= len(best):
            return None  # no group outvotes the others: something in view moves unlike the ground, or it repeats
        w = np.array([m.response for m in best])
        peak = float(w.mean())
        return Motion(float(np.average([m.d_fwd for m in best], weights=w)),
                      float(np.average([m.d_left for m in best], weights=w)), peak, self._sigma(peak))

    def _sigma(self, peak: float) -> float:
        """1-sigma of a translation, metres, from its correlation peak: sub-pixel at a clean peak, a few pixels at
        a poor one."""
        return float(self.m_per_px * (0.2 + 0.5 * (1.0 - peak)))

    def _largest_group(self, found: list[Motion]) -> list[Motion]:
        """The most strips whose translations agree with one of them to within agree_m on both axes."""
        best: list[Motion] = []
        for m in found:
            group = [o for o in found
                     if abs(o.d_fwd - m.d_fwd) <= self.agree_m and abs(o.d_left - m.d_left) <= self.agree_m]
            if len(group) > len(best):
                best = group
        return best

    def _strip(self, b0: np.ndarray, b1: np.ndarray, c0: int, c1: int) -> Motion | bool | None:
        """One strip's translation (columns [c0, c1) of the patch in frame 0's view b0, looked for in frame 1's
        b1); None when it has no texture, False when its peak is weak or at the edge of the search."""
        a, b = self.rows
        tpl = b0[a:b, c0:c1]
        if float(tpl.std()) < 1.0:
            return None
        region = b1[a - self.up:b + self.down, c0 - self.side:c1 + self.side]
        score = cv2.matchTemplate(region, tpl, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (x, y) = cv2.minMaxLoc(score)
        if not math.isfinite(peak) or peak < self.min_response:
            return False
        if not (0 < y < score.shape[0] - 1 and 0 < x < score.shape[1] - 1):
            return False  # at the edge of the search: the motion may be larger than looked for
        dy = y + _vertex(score[y - 1, x], score[y, x], score[y + 1, x]) - self.up
        dx = x + _vertex(score[y, x - 1], score[y, x], score[y, x + 1]) - self.side
        return Motion(float(dy * self.m_per_px), float(dx * self.m_per_px), float(peak), self._sigma(peak))


def nearest_ground_m(camera: GroundCamera, half_width_m: float, step_m: float = 0.1, limit_m: float = 60.0,
                     bottom_row: float | None = None) -> float:
    """The nearest forward distance, metres, at which the camera sees the ground across +-half_width_m at or
    above image row bottom_row (default: the last row)."""
    bottom = camera.height - 1 if bottom_row is None else bottom_row
    G = camera.ground_to_image
    for f in np.arange(step_m, limit_m, step_m):
        pts = np.array([[f, -half_width_m, 1.0], [f, half_width_m, 1.0]]) @ G.T
        if np.all(pts[:, 2] > 1e-6):
            u, v = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
            if np.all((u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= bottom)):
                return float(f)
    raise ValueError(f"ground motion: the camera sees no ground +-{half_width_m} m wide within {limit_m} m")


def _vertex(left: float, mid: float, right: float) -> float:
    """Offset of a parabola's vertex through three equally spaced samples, in samples (within +-0.5)."""
    den = left - 2.0 * mid + right
    return 0.0 if den >= 0.0 else float(np.clip(0.5 * (left - right) / den, -0.5, 0.5))
