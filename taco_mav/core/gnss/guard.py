"""Real-GNSS guard (not in the paper): is a receiver's reading fit to fuse? Spoofing and jamming detection, pure maths.

Once the filter fuses a slowly dragged receiver it follows it and its innovations stay small, so the guard
tests each reading against predictions the receiver has not pulled: *shadows* (gnss_shadow.py), the filter's
state `reference_lag_s` (and `velocity_lag_s`) earlier, carried to the reading by IMU dead reckoning alone. The
Localiser fuses a reading `fuse_delay_s` after it arrived, so the newest readings have not touched the filter
either. A shadow's error model (its anchor's covariance about the receiver's bias track, the receiver's white
noise and the change of its wandering bias, the dead reckoning's growth) is matched to what accepted readings
show (`ScaleMatcher`). While the receiver is held off the reference is the tighter of the filter's own
prediction and the shadow of the last trusted state.

Five tests; any one rejects the receiver:
1. jump: one reading's NIS against the filter's prediction (P + sigma_h^2) above hard_gate (2 dof, 99.99 %);
2. window: the mean NIS against the reference over `window_s` above chi2(2 N, 1 - window_alpha) / N, N one
   reading per window_corr_s (the errors are correlated): a receiver noisier than it says (jamming);
3. drift: the mean position innovation of the last `drift_window_s` against its covariance, a coherent 2-dof
   test: a drag moves every innovation the same way;
4. velocity: the same for the reading's velocity against the shadow's (a careful spoofer drags it too);
5. camera: `camera_disagree_n` camera fixes in a row disagree with the readings around their capture, from a
   camera that agreed with them before. A camera that never agreed cannot reject the receiver: two absolute
   sources that differ from the first look are a misregistered map or a camera that cannot read it far more often
   than a spoofer present from power-on, and only the camera has been shown wrong before (a map of another world
   over the same ground puts the answers 20-25 m off beside the road, with weights up to 1.0). Such a camera is
   *refuted* (`camera_refuted`) once `camera_disagree_n` checks in a row disagree, and stays so until one of its
   fixes agrees with the readings: a camera earns trust by agreeing with the receiver once.
A rejected receiver is used again only after every test has passed, with the drift and velocity statistics
below `suspect_gate`, for `reaccept_s`; and the first reading after a rejection or a loss only if its update
moves the estimate by at most 3 sigma of its covariance (`jump_gate`): the output never jumps further at a
hand-over.

Frames and units: ENU metres on the UTM grid relative to the origin (the Localiser's world), headings ENU
radians, velocities ENU m/s, times autopilot seconds; covariances m^2 or (m/s)^2.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from taco_mav.core.chi2 import chi2_isf_even
from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.gnss.shadow import Anchor, DrSnap, dr_displacement, interpolate, shadow, shadow_velocity

_RECENT_S = 10.0  # readings kept for camera fixes answered this late


@lru_cache(maxsize=512)
def window_threshold(n: int, alpha: float) -> float:
    """Mean-NIS threshold for n readings of a 2-dof innovation: chi2.ppf(1 - alpha, 2 n) / n, without
    scipy.special, which would cost a live daemon memory (`taco_mav.core.chi2`)."""
    return chi2_isf_even(2 * n, alpha) / n


def receiver_variances(sigma_h: float, p: GnssParams) -> tuple[float, float]:
    """(white, bias) variances, m^2 each axis, of a receiver reporting 1-sigma sigma_h (m)."""
    white = (p.white_fraction * sigma_h) ** 2
    return white, sigma_h * sigma_h - white


def bias_change_variance(sigma_h: float, age_s: float, p: GnssParams) -> float:
    """Variance (m^2, each axis) of the change of the receiver's Gauss-Markov bias over age_s seconds:
    2 sigma_bias^2 (1 - exp(-age / tau))."""
    return 2.0 * receiver_variances(sigma_h, p)[1] * (1.0 - math.exp(-max(age_s, 0.0) / p.bias_tau_s))


def filter_offset_variance(sigma_h: float, p: GnssParams, replace: bool) -> float:
    """Variance (m^2, each axis) of a GNSS-following filter's position about the receiver's bias track: the
    white noise left by a steady gain K (a replacement: K = 1; a Kalman update with the bias floor in P:
    K = sigma_bias^2 / (sigma_bias^2 + sigma_h^2)), sigma_white^2 K / (2 - K)."""
    white, bias = receiver_variances(sigma_h, p)
    k = 1.0 if replace else bias / (bias + sigma_h * sigma_h)
    return white * k / (2.0 - k)


def quad(e: np.ndarray, S: np.ndarray) -> float:
    """e^T S^-1 e for a 2-vector and a 2x2 covariance."""
    return float(e @ np.linalg.solve(S, e))


@dataclass
class ScaleMatcher:
    """Covariance matching for a modelled error growth G whose size is uncertain: with an error e whose
    covariance is K (known) + s G, E[|e|^2] = tr K + s tr G, so s = mean(|e|^2 - tr K) / mean(tr G) over about
    n samples (running means). One sample counts at most 3 s tr G, so errors the tests have not caught yet
    move s little. s is 1 until n samples, then clipped to [lo, hi]."""

    lo: float
    hi: float
    n: int
    scale: float = 1.0
    excess: float = 0.0
    growth: float = 0.0
    samples: int = 0

    def update(self, e: np.ndarray, known: np.ndarray, growth: np.ndarray) -> None:
        tr = float(np.trace(growth))
        a = 1.0 / self.n
        sample = min(float(e @ e) - float(np.trace(known)), 3.0 * self.scale * tr)
        self.excess += a * (sample - self.excess)
        self.growth += a * (tr - self.growth)
        self.samples += 1
        if self.samples >= self.n and self.growth > 1e-12:
            self.scale = min(max(self.excess / self.growth, self.lo), self.hi)


class GuardState(enum.Enum):
    OK = "ok"  # readings are accepted (and fused fuse_delay_s later)
    REJECTED = "rejected"  # held off until every test has passed for reaccept_s


@dataclass(frozen=True)
class GuardVerdict:
    """The guard's answer for one reading. accept: the reading may be fused; flags: the tests that failed
    ("jump", "window", "drift", "velocity", "camera"; "hold" while waiting for sustained agreement, or for a
    reading whose update would move the estimate by more than 3 sigma); nis: against the filter's prediction;
    ref_nis: against the reference; window_nis: the window's mean NIS and window_limit its threshold; drift:
    the coherent position statistic; velocity: the same for the velocity; innovation_m: |z - prediction|, m;
    reference: "shadow" or "filter"; newly_rejected: this reading rejected a receiver that was in use;
    reaccepted: this reading ends a rejection."""

    accept: bool
    flags: tuple[str, ...]
    nis: float
    ref_nis: float
    window_nis: float
    window_limit: float
    drift: float
    velocity: float
    innovation_m: float
    reference: str = "filter"
    newly_rejected: bool = False
    reaccepted: bool = False

    @property
    def detail(self) -> str:
        """One line with the figures, for the event log."""
        return (f"flags={','.join(self.flags) or '-'} nis={self.nis:.1f} ref_nis={self.ref_nis:.1f} "
                f"window_nis={self.window_nis:.2f}/{self.window_limit:.2f} drift={self.drift:.1f} "
                f"velocity={self.velocity:.1f} "
                f"innovation={self.innovation_m:.1f}m reference={self.reference}")


@dataclass(frozen=True, slots=True)
class _Reading:
    t: float
    e: np.ndarray  # innovation against the reference, m
    S: np.ndarray  # its covariance, m^2
    white: float  # the receiver's white-noise variance in S, m^2 each axis
    nis: float
    ev: np.ndarray | None = None  # velocity innovation against the shadow, m/s
    Sv: np.ndarray | None = None  # its covariance without the receiver's, (m/s)^2
    white_v: float = 0.0  # the receiver's speed variance, (m/s)^2


class GnssGuard:
    """The guard's state machine over GNSS readings (module docstring). For each reading the Localiser gives
    its prediction and its states reference_lag_s and velocity_lag_s earlier as anchors (`check`); it reports
    its camera fixes (`camera_check`)."""

    def __init__(self, p: GnssParams) -> None:
        self.p = p
        self.state = GuardState.OK
        self.t_accepted: float | None = None  # last accepted reading
        self.agree_since: float | None = None
        self.hold_anchor: Anchor | None = None  # the last trusted state while the receiver is held off
        self.rejections = 0
        self.camera_disagree = 0
        self.camera_gap: np.ndarray | None = None  # the last camera check: camera fix - readings, ENU m (2,)
        self.camera_agreed = False  # a camera fix has agreed with the readings: its disagreement may reject them
        self.external_flag: str | None = None  # set by another check (the camera's speed), taken at the next reading
        self.last: GuardVerdict | None = None
        self._window: deque[_Reading] = deque()
        self._recent: deque[tuple[float, np.ndarray, float, DrSnap]] = deque()  # t, z, sigma_h, snap
        # the scale on the shadows' dead-reckoning variance that their errors show (covariance matching on
        # accepted readings), for position and velocity
        self.dr_match = ScaleMatcher(p.dr_scale_min, p.dr_scale_max, p.dr_scale_n)
        self.vel_match = ScaleMatcher(p.dr_scale_min, p.dr_scale_max, p.dr_scale_n)
        self._learn: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # the last shadow, to learn from

    def healthy_at(self, t: float) -> bool:
        """In use, and a reading accepted within gap_s before t."""
        return self.state is GuardState.OK and self.t_accepted is not None and t - self.t_accepted <= self.p.gap_s

    @property
    def suspect(self) -> bool:
        """The drift or velocity statistic is above suspect_gate, or a camera fix disagreed: a camera fix soon
        would settle it."""
        last = self.last
        camera = self.camera_disagree > 0 and not self.camera_refuted  # a refuted camera casts no doubt
        return camera or (last is not None and max(last.drift, last.velocity) > self.p.suspect_gate)

    # -------------------------------------------------------------- the reference
    def _reference(self, t: float, sigma_h: float, pred_xy: np.ndarray, pred_cov: np.ndarray, snap: DrSnap,
                   anchor: Anchor | None) -> tuple[np.ndarray, np.ndarray, str]:
        """(position, covariance with the receiver's share, name) a reading is tested against. In use: the
        shadow of `anchor` (the filter reference_lag_s ago, which the readings since have not pulled), with
        the receiver's white noise and the change of its bias since; without an anchor, the filter. Held off:
        the tighter of the filter (with the receiver's whole variance) and the shadow of the last trusted
        state (its dead reckoning's growth scaled by at least held_scale_min: the learnt scale holds at the lag,
        and a receiver held off for long must get back in)."""
        p = self.p
        white, _ = receiver_variances(sigma_h, p)
        own = (pred_xy, pred_cov + sigma_h * sigma_h * np.eye(2), "filter")
        self._learn = None
        a = anchor if self.state is GuardState.OK else self.hold_anchor
        if a is None:
            return own
        xy, drift, own_growth = shadow(a, snap, p)
        known = a.cov + (white + bias_change_variance(sigma_h, snap.t - a.t, p)) * np.eye(2)
        growth = drift + own_growth
        C = known + self._scale(self.dr_match) * growth
        if self.state is GuardState.OK:
            self._learn = (xy, known, growth)
            return xy, C, "shadow"
        return (xy, C, "shadow") if np.trace(C) < np.trace(own[1]) else own

    def _scale(self, m: ScaleMatcher) -> float:
        """The learnt scale; held off, at least held_scale_min (the shadow ages past the lag it was learnt at)."""
        return m.scale if self.state is GuardState.OK else max(m.scale, self.p.held_scale_min)

    @property
    def dr_scale(self) -> float:
        """The learnt scale on the shadows' dead-reckoning variance (position)."""
        return self.dr_match.scale

    # -------------------------------------------------------------- the tests
    def check(self, t: float, z: np.ndarray, sigma_h: float, pred_xy: np.ndarray, pred_cov: np.ndarray,
              snap: DrSnap, anchor: Anchor | None, replace: bool = False, vel: np.ndarray | None = None,
              sigma_v: float = 0.0, vel_anchor: Anchor | None = None) -> GuardVerdict:
        """Test one reading. t: s; z: ENU m (2,); sigma_h: its 1-sigma, m; pred_xy, pred_cov: the filter's
        prediction at t (ENU m, m^2); snap: the dead reckoner at t; anchor: the filter's state
        reference_lag_s ago (None: no history yet); replace: the estimator replaces its position by the
        reading (paper mode) instead of a Kalman update with R = sigma_h^2 (for the jump gate); vel: the
        reading's ground velocity, ENU m/s (2,) or None, with 1-sigma sigma_v (m/s); vel_anchor: the
        filter's state velocity_lag_s ago, for the velocity test (default: anchor)."""
        p = self.p
        R = sigma_h * sigma_h * np.eye(2)
        white, _ = receiver_variances(sigma_h, p)
        self._recent.append((t, z.copy(), sigma_h, snap))
        while self._recent and t - self._recent[0][0] > p.camera_match_s + _RECENT_S:
            self._recent.popleft()
        since = None if self.t_accepted is None else t - self.t_accepted
        gap = since is None or since > p.gap_s
        nu = z - pred_xy
        nis = quad(nu, pred_cov + R)
        # the update's move in sigmas of the prediction: K nu for a Kalman update, nu itself for a replacement
        if replace:
            jump = quad(nu, pred_cov)
        else:
            w = np.linalg.solve(pred_cov + R, nu)
            jump = float(w @ pred_cov @ w)
        ref_xy, S, ref_name = self._reference(t, sigma_h, pred_xy, pred_cov, snap, anchor)
        e = z - ref_xy
        ref_nis = quad(e, S)
        ev = Sv = None
        a = (vel_anchor or anchor) if self.state is GuardState.OK else self.hold_anchor
        vel_learn = None
        if vel is not None and a is not None and float(np.hypot(*vel)) >= p.min_speed_mps:
            v_ref, G = shadow_velocity(a, snap, p)
            ev, Sv = vel - v_ref, self._scale(self.vel_match) * G
            vel_learn = (ev, sigma_v * sigma_v * np.eye(2), G)
        self._window.append(_Reading(t, e, S, white, ref_nis, ev, Sv, sigma_v * sigma_v))
        while self._window and t - self._window[0].t > p.window_s:
            self._window.popleft()
        n = len(self._window)
        window_nis = float(np.mean([r.nis for r in self._window]))
        span = t - self._window[0].t
        limit = window_threshold(max(1, min(n, 1 + int(span / p.window_corr_s))), p.window_alpha)
        # the mean innovation of the last drift_window_s: the white noise averages down, the rest does not
        recent = [r for r in self._window if t - r.t <= p.drift_window_s]
        m = len(recent)
        e_bar = np.mean([r.e for r in recent], axis=0)
        white_bar = float(np.mean([r.white for r in recent]))
        C_bar = np.mean([r.S for r in recent], axis=0) - white_bar * (1.0 - 1.0 / m) * np.eye(2)
        drift = quad(e_bar, C_bar)
        # the same for the velocity against the shadow's (a spoofer that drags the velocity too)
        rv = [r for r in recent if r.ev is not None]
        velocity = 0.0
        if rv:
            ev_bar = np.mean([r.ev for r in rv], axis=0)
            Cv = np.mean([r.Sv for r in rv], axis=0) + float(np.mean([r.white_v for r in rv])) / len(rv) * np.eye(2)
            velocity = quad(ev_bar, Cv)

        flags = []
        if nis > p.hard_gate:
            flags.append("jump")
        if n >= p.window_min_n and window_nis > limit:
            flags.append("window")
        if drift > p.drift_gate:
            flags.append("drift")
        if velocity > p.drift_gate:
            flags.append("velocity")
        if self.camera_agreed and self.camera_disagree >= p.camera_disagree_n:
            flags.append("camera")
            self.camera_disagree = 0
        if self.external_flag is not None:
            flags.append(self.external_flag.split(" ")[0])
            self.external_flag = None
        figures = dict(nis=nis, ref_nis=ref_nis, window_nis=window_nis, window_limit=limit, drift=drift,
                       velocity=velocity, innovation_m=float(np.hypot(*nu)), reference=ref_name)
        if self.state is GuardState.OK:
            if flags or (gap and jump > p.jump_gate):
                self.state = GuardState.REJECTED
                self.rejections += 1
                self.agree_since = None
                self.hold_anchor = anchor
                self._window.clear()
                return self._verdict(GuardVerdict(False, tuple(flags) or ("hold",), newly_rejected=True, **figures))
            self.t_accepted = t
            if self._learn is not None:
                xy, known, growth = self._learn
                self.dr_match.update(z - xy, known, growth)
            if vel_learn is not None:
                self.vel_match.update(*vel_learn)
            return self._verdict(GuardVerdict(True, (), **figures))
        if flags or max(drift, velocity) > p.suspect_gate:  # agreement: below the suspicion level
            self.agree_since = None
            return self._verdict(GuardVerdict(False, tuple(flags) or ("hold",), **figures))
        if self.agree_since is None:
            self.agree_since = t
        if t - self.agree_since >= p.reaccept_s and jump <= p.jump_gate:
            self.state = GuardState.OK
            self.agree_since = None
            self.hold_anchor = None
            self._window.clear()
            self.t_accepted = t
            return self._verdict(GuardVerdict(True, (), reaccepted=True, **figures))
        return self._verdict(GuardVerdict(False, ("hold",), **figures))

    def _verdict(self, v: GuardVerdict) -> GuardVerdict:
        self.last = v
        return v

    # -------------------------------------------------------------- camera cross-check
    def camera_check(self, t_capture: float, z: np.ndarray, R_cam: np.ndarray, anchor: Anchor,
                     snap_c: DrSnap | None = None) -> float | None:
        """Compare a camera fix (capture time s, ENU m (2,), 2x2 m^2) with the GNSS readings within
        camera_match_s of its capture, carried to the capture time by dead reckoning with `anchor`'s speed and
        biases; snap_c: the dead reckoner at the capture (the frame's; None: between the readings' own, which
        needs a reading after the capture: a 2 Hz receiver and a 0.25 s matcher in the daemon had none, and no
        check ever ran). Returns the NIS (None when there is nothing to compare); counts consecutive
        disagreements (NIS > camera_gate): camera_disagree_n of them reject the receiver at its next reading if the
        camera agreed once before, and refute the camera if it never did (module docstring)."""
        p = self.p
        near = [r for r in self._recent if abs(r[0] - t_capture) <= p.camera_match_s]
        if snap_c is None:
            snap_c = interpolate([r[3] for r in self._recent], t_capture)
        if not near or snap_c is None:
            return None
        moved = [r[1] + dr_displacement(anchor, r[3], snap_c) for r in near]
        z_g = np.mean(moved, axis=0)
        white, bias = receiver_variances(float(np.mean([r[2] for r in near])), p)
        S = R_cam + (white / len(near) + bias) * np.eye(2)
        nis = quad(z - z_g, S)
        self.camera_gap = z - z_g
        if nis > p.camera_gate:
            self.camera_disagree += 1
        else:
            self.camera_disagree = 0
            self.camera_agreed = True
        return nis

    @property
    def camera_refuted(self) -> bool:
        """The camera never agreed with the readings and its last camera_disagree_n checks disagreed: its fixes
        must not be used (module docstring)."""
        return not self.camera_agreed and self.camera_disagree >= self.p.camera_disagree_n

    @property
    def camera_floor_m(self) -> float:
        """What the last camera check says of the readings' error, m: the distance between the camera fix and the
        readings carried to its capture (0 before any). A filter that follows the readings is about that far off,
        whatever the cause: the receiver's wandering bias, which the readings cannot show, or a drag slower than
        the shadow tests see (0.2 m/s was not rejected within 30 s and reached 6.8 m with 1.3-1.5 m reported)."""
        return 0.0 if self.camera_gap is None else float(np.hypot(*self.camera_gap))
