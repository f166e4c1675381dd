"""Dead-reckoning drift of a vehicle's IMU and compass, measured against ground truth, and the taco+ process
noise it implies (`taco-mav drift`).

taco+ models the IMU's error growth between fixes with random walks (core/plus/noise.py): a speed error driven at
`q_speed_mps` (m/s)/sqrt(s) and integrating an accelerometer bias that walks at `q_bias_mps2`
(m/s^2)/sqrt(s); a heading error walking at `q_theta_rad` rad/sqrt(s) plus a compass bias, first-order
Gauss-Markov with std `compass_bias_sigma_rad` and correlation time `compass_bias_tau_s`. The defaults are
an RT3003's (KITTI OXTS); a rover's MEMS IMU and magnetometer drift much faster. This module measures the
drift on a drive with ground truth (a KITTI drive, a synthetic world, or a tlog recorded with GNSS on) and
fits those parameters to it:

- speed: the forward acceleration (gravity removed with roll and pitch, as the preintegrator does) is
  integrated over the whole drive; its error against the truth's speed (a Savitzky-Golay derivative of the
  truth track) is sampled in windows of H seconds. Var(Δe_v(H)) = q_speed² H + σ_b0² H² + q_bias² H³/3,
  fitted by non-negative least squares (σ_b0: the spread of the accelerometer bias at a window's start, a
  value for `initial_bias_sigma_mps2`).
- heading: the compass heading (grid, ENU) minus the truth heading. Var(Δe_θ(H)) = q_theta² H +
  2 σ_β² (1 - exp(-H/τ)), fitted for each τ of a grid and the best fit kept; the mean is the compass's
  constant offset (a mounting or declination error to correct on the vehicle, not noise).
- position: for reference, the along- and cross-track error of dead reckoning started on the truth (pose
  and speed) after H seconds, RMS over windows.

Windows start every `stride_s` seconds and are used only while the truth speed stays above `min_speed_mps`
(a stopped vehicle has no heading truth and its speed is clamped at zero). All times are seconds, angles
radians, positions ENU metres.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.signal import savgol_filter

from taco_mav.core.preintegration import enu_heading, level_forward_accel
from taco_mav.errors import DataError
from taco_mav.evaluation.metrics import along_cross, rmse
from taco_mav.geo import wrap_angle

__all__ = ["DriftReport", "measure_drift", "speed_model_std", "heading_model_std", "HORIZONS_S", "TAU_GRID_S"]

HORIZONS_S: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0)
TAU_GRID_S: tuple[float, ...] = (10.0, 20.0, 30.0, 60.0, 120.0, 300.0)


@dataclass(frozen=True)
class DriftReport:
    """Measured drift per horizon and the fitted taco+ process noise (see the module docstring).

    horizons_s: H, s; windows: windows used per H; speed_rms_mps, heading_rms_rad, along_rms_m, cross_rms_m:
    RMS over windows of the speed-error and heading-error increments and of the dead-reckoning position error
    after H. The fitted values are named as in the profile's `plus:` section; heading_offset_rad is the mean
    compass-minus-truth heading; truth_speed_noise_mps: the truth speed's own noise, an upper bound
    (difference between the smoothed and the raw derivative)."""

    drive: str
    duration_s: float
    distance_m: float
    horizons_s: list[float]
    windows: list[int]
    speed_rms_mps: list[float]
    heading_rms_rad: list[float]
    along_rms_m: list[float]
    cross_rms_m: list[float]
    q_speed_mps: float
    q_bias_mps2: float
    initial_bias_sigma_mps2: float
    q_theta_rad: float
    compass_bias_sigma_rad: float
    compass_bias_tau_s: float
    heading_offset_rad: float
    truth_speed_noise_mps: float
    heading_measurable: bool = True
    notes: list[str] = field(default_factory=list)

    def plus_values(self) -> dict[str, float]:
        """The fitted values under their `plus:` keys (round numbers, for a profile); the heading terms only
        when the compass and the truth are different sensors."""
        keys = ("q_speed_mps", "q_bias_mps2", "initial_bias_sigma_mps2")
        if self.heading_measurable:
            keys += ("q_theta_rad", "compass_bias_sigma_rad")
        out = {k: float(f"{getattr(self, k):.2g}") for k in keys if getattr(self, k) > 0.0}  # 0: not seen here
        if out.get("compass_bias_sigma_rad"):
            out["compass_bias_tau_s"] = self.compass_bias_tau_s
        return out

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "plus": self.plus_values()}


def speed_model_std(h: np.ndarray, q_speed_mps: float, q_bias_mps2: float) -> np.ndarray:
    """1-sigma speed-error growth over h seconds, m/s, of the taco+ model (random walk + integrated bias walk)."""
    h = np.asarray(h, dtype=float)
    return np.sqrt(q_speed_mps**2 * h + q_bias_mps2**2 * h**3 / 3.0)


def heading_model_std(h: np.ndarray, q_theta_rad: float, sigma_rad: float, tau_s: float) -> np.ndarray:
    """1-sigma heading-error change over h seconds, rad, of the taco+ model (random walk + Gauss-Markov bias)."""
    h = np.asarray(h, dtype=float)
    gm = 2.0 * sigma_rad**2 * (1.0 - np.exp(-h / tau_s)) if tau_s > 0 else 0.0
    return np.sqrt(q_theta_rad**2 * h + gm)


def _fit(h: np.ndarray, var: np.ndarray, columns: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """Non-negative least squares of var ~ columns, weighted by 1/var (relative errors); (coefs, residual)."""
    w = 1.0 / np.maximum(var, 1e-12)
    A = np.column_stack(columns) * w[:, None]
    coef, res = nnls(A, var * w)
    return coef, float(res)


def measure_drift(drive: Any, horizons_s: tuple[float, ...] = HORIZONS_S, stride_s: float = 1.0,
                  min_speed_mps: float = 2.0, tau_grid_s: tuple[float, ...] = TAU_GRID_S) -> DriftReport:
    """Measure `drive`'s dead-reckoning drift (a `datasets.base.Drive`: imu, truth, name; optional
    convergence_rad) and fit the taco+ process noise. DataError when the drive is too short or too slow for
    the smallest horizon."""
    imu, truth = drive.imu, drive.truth
    t = np.asarray(imu.t, dtype=float)
    if len(t) < 20 or len(truth.t) < 20:
        raise DataError(f"drive {drive.name}: too few IMU or truth samples for a drift measurement")
    conv = float(getattr(drive, "convergence_rad", 0.0) or 0.0)
    a = np.array([level_forward_accel(tuple(f), r[0], r[1]) for f, r in zip(imu.accel_frd, imu.rpy_ned)])
    theta_c = np.array([enu_heading(float(y)) for y in imu.rpy_ned[:, 2]]) + conv

    # truth on the IMU clock: position, heading, and speed along the heading (smoothed derivative)
    tt = np.asarray(truth.t, dtype=float)
    head = np.unwrap(truth.heading)
    dt_truth = float(np.median(np.diff(tt)))
    grid = np.arange(tt[0], tt[-1], dt_truth)  # Savitzky-Golay needs even spacing; dataset clocks jitter
    xy_g = np.column_stack([np.interp(grid, tt, truth.xy[:, k]) for k in (0, 1)])
    win = max(5, int(round(1.0 / dt_truth)) | 1)  # ~1 s window, odd
    vxy = np.column_stack([savgol_filter(xy_g[:, k], win, 2, deriv=1, delta=dt_truth) for k in (0, 1)])
    raw = np.gradient(xy_g, grid, axis=0)
    noise = float(np.sqrt(np.mean(np.sum((raw - vxy) ** 2, axis=1))))
    th_g = np.interp(grid, tt, head)
    v_truth = vxy[:, 0] * np.cos(th_g) + vxy[:, 1] * np.sin(th_g)
    x_t, y_t = np.interp(t, tt, truth.xy[:, 0]), np.interp(t, tt, truth.xy[:, 1])
    th_t = np.interp(t, tt, head)
    v_t = np.interp(t, grid, v_truth)

    dt = np.diff(t)
    v_int = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)])
    e_v = v_int - v_t
    e_th = wrap_angle(theta_c - th_t)
    moving = v_t > min_speed_mps

    starts = np.arange(t[0], t[-1], stride_s)
    i0s = np.searchsorted(t, starts)
    rows: dict[str, list] = {k: [] for k in ("h", "n", "sv", "sth", "al", "cr")}
    for h in horizons_s:
        dv, dth, err, head = [], [], [], []
        for i0 in i0s:
            i1 = int(np.searchsorted(t, t[i0] + h))
            if i1 >= len(t) or not moving[i0:i1 + 1].all() or np.any(dt[i0:i1] > 0.5):
                continue
            dv.append(e_v[i1] - e_v[i0])
            dth.append(wrap_angle(float(e_th[i1] - e_th[i0])))
            # dead reckoning from the truth pose and speed at i0
            v = v_t[i0] + (v_int[i0:i1 + 1] - v_int[i0])
            step = 0.5 * (v[1:] + v[:-1]) * dt[i0:i1]
            # mid-step heading, as Preintegrator.add; vectorised over the window
            mid = theta_c[i0:i1] + 0.5 * wrap_angle(theta_c[i0 + 1:i1 + 1] - theta_c[i0:i1])
            mid = mid - theta_c[i0] + th_t[i0]  # start on the true heading, as after a perfect fix
            err.append((x_t[i0] + np.sum(step * np.cos(mid)) - x_t[i1], y_t[i0] + np.sum(step * np.sin(mid)) - y_t[i1]))
            head.append(th_t[i1])
        if len(dv) >= 3:
            split = along_cross(np.array(err), np.array(head))
            for key, val in (("h", h), ("n", len(dv)), ("sv", rmse(np.array(dv))), ("sth", rmse(np.array(dth))),
                             ("al", rmse(split[:, 0])), ("cr", rmse(split[:, 1]))):
                rows[key].append(val)
    if len(rows["h"]) < 3:
        raise DataError(f"drive {drive.name}: fewer than 3 horizons with 3 windows moving above "
                        f"{min_speed_mps} m/s; drive longer or lower --min-speed")
    h = np.array(rows["h"])
    var_v = np.square(rows["sv"])
    (qv2, b02, qb2), _ = _fit(h, var_v, [h, h**2, h**3 / 3.0])
    var_th = np.square(rows["sth"])
    best = None
    for tau in tau_grid_s:
        coef, res = _fit(h, var_th, [h, 2.0 * (1.0 - np.exp(-h / tau))])
        if best is None or res < best[2]:
            best = (coef, tau, res)
    assert best is not None
    (qth2, sb2), tau, _ = best
    notes = []
    if noise > 0.5 * rows["sv"][0]:
        notes.append(f"the truth speed's noise ({noise:.3f} m/s) is comparable to the shortest horizon's speed "
                     "error: q_speed_mps is an upper bound")
    measurable = max(rows["sth"]) > 1e-4
    if not measurable:
        notes.append("the compass heading equals the truth heading (one sensor, as KITTI's OXTS): the heading "
                     "terms cannot be measured on this drive; keep the profile's")
    return DriftReport(
        drive=str(drive.name), duration_s=float(t[-1] - t[0]), distance_m=float(truth.length_m()),
        horizons_s=[float(x) for x in h], windows=[int(n) for n in rows["n"]], speed_rms_mps=rows["sv"],
        heading_rms_rad=rows["sth"], along_rms_m=rows["al"], cross_rms_m=rows["cr"],
        q_speed_mps=math.sqrt(qv2), q_bias_mps2=math.sqrt(qb2), initial_bias_sigma_mps2=math.sqrt(b02),
        q_theta_rad=math.sqrt(qth2), compass_bias_sigma_rad=math.sqrt(sb2), compass_bias_tau_s=float(tau),
        heading_offset_rad=float(np.mean(e_th[moving])) if moving.any() else 0.0, truth_speed_noise_mps=noise,
        heading_measurable=measurable, notes=notes)


def report_text(report: DriftReport, profile_plus: Any, profile_name: str) -> str:
    """A plain-text table of `report` beside what the profile's `plus:` section (a PlusParams) predicts, a
    verdict per term, and the fitted values as a `plus:` snippet."""
    h = np.array(report.horizons_s)
    pv = speed_model_std(h, profile_plus.q_speed_mps, profile_plus.q_bias_mps2)
    fv = speed_model_std(h, report.q_speed_mps, report.q_bias_mps2)
    ph = heading_model_std(h, profile_plus.q_theta_rad, profile_plus.compass_bias_sigma_rad,
                           profile_plus.compass_bias_tau_s)
    fh = heading_model_std(h, report.q_theta_rad, report.compass_bias_sigma_rad, report.compass_bias_tau_s)
    lines = [f"drive {report.drive}: {report.duration_s:.0f} s, {report.distance_m / 1000:.2f} km; "
             f"dead reckoning from the truth, windows every second while moving",
             f"{'H s':>5} {'windows':>7} | {'speed error m/s: measured':>25} {'profile':>8} {'fit':>7} | "
             f"{'heading error deg: measured':>27} {'profile':>8} {'fit':>7} | {'along m':>7} {'cross m':>7}"]
    for k in range(len(h)):
        lines.append(f"{h[k]:5.1f} {report.windows[k]:7d} | "
                     f"{report.speed_rms_mps[k]:25.3f} {pv[k]:8.3f} {fv[k]:7.3f} | "
                     f"{math.degrees(report.heading_rms_rad[k]):27.3f} {math.degrees(ph[k]):8.3f} "
                     f"{math.degrees(fh[k]):7.3f} | {report.along_rms_m[k]:7.2f} {report.cross_rms_m[k]:7.2f}")
    lines.append("")
    terms = [("speed", np.array(report.speed_rms_mps), pv)]
    if report.heading_measurable:
        terms.append(("heading", np.array(report.heading_rms_rad), ph))
    for name, measured, predicted in terms:
        ratio = predicted / np.maximum(measured, 1e-12)
        if ratio.min() >= 1.0:
            lines.append(f"{name}: profile '{profile_name}' covers the measured drift at every horizon "
                         f"(profile/measured {ratio.min():.1f}-{ratio.max():.1f}x)")
        else:
            worst = int(np.argmin(ratio))
            lines.append(f"{name}: profile '{profile_name}' is OPTIMISTIC: it predicts {ratio[worst]:.2f}x the "
                         f"measured drift at {h[worst]:g} s; a filter that trusts its IMU too much rejects good "
                         "fixes and can lose lock. Raise the terms below.")
    if report.heading_measurable:
        # the mean of a Gauss-Markov bias over T seconds scatters by about sigma sqrt(2 tau / T)
        spread = report.compass_bias_sigma_rad * math.sqrt(2.0 * report.compass_bias_tau_s
                                                           / max(report.duration_s, 1.0))
        verdict = ("beyond what the fitted bias explains: a mounting or declination error, correct it on the vehicle"
                   if abs(report.heading_offset_rad) > 3.0 * spread + 1e-3 else "within what the fitted bias explains")
        lines.append(f"compass offset (mean compass - truth): {math.degrees(report.heading_offset_rad):+.2f} deg, "
                     f"{verdict}")
    lines.extend(f"note: {n}" for n in report.notes)
    lines.append("")
    lines.append(f"plus:  # fitted on {report.drive} ({profile_name}'s value in the comment; a term the drive "
                 "did not show is left out)")
    for key, value in report.plus_values().items():
        lines.append(f"  {key}: {value:g}  # {getattr(profile_plus, key):g}")
    return "\n".join(lines)
