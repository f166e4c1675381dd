"""Real GNSS in both estimators (not in the paper): fused while honest (taco+ calibrates speed error, accelerometer and
compass bias on it), dead reckoning after it is lost without a jump, a dragged receiver rejected, the camera at a
low duty while GNSS is healthy, and a real KITTI OXTS drive.

The receiver is built from the truth as the simulator builds it (taco_mav/sim/receiver.py): white noise of half
the reported sigma plus a first-order Gauss-Markov bias (tau 60 s) carrying the rest, 5 Hz."""

import math

import numpy as np
import pytest
from helpers import OracleMatcher, simulate

from taco_mav.core.localiser import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.aiding import PlusAids
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.types import GnssFix, ImuSample

PAPER = LocaliserParams()
PLUS = LocaliserParams(plus=PlusParams())
ACCEL_BIAS = 0.05  # m/s^2 on the forward accelerometer
COMPASS_BIAS = 0.02  # rad: the compass reads theta + this


def drive(seed: int = 1, duration: float = 100.0):
    """A 100 Hz drive (up to ~10 m/s, gentle curves and one turn) with white IMU noise and the biases above.
    Returns (truth SimDrive, IMU samples)."""
    d = simulate(lambda t: min(9.0, 2.0 + t) + math.sin(t / 9.0),
                 lambda t: 0.06 * math.sin(t / 6.0) + (0.12 if 40 < t < 50 else 0.0),
                 duration, accel_noise=0.05, gyro_noise=0.001, compass_noise=0.005, seed=seed)
    samples = []
    for s in d.samples:
        yaw = s.yaw - COMPASS_BIAS  # NED yaw: theta + beta in ENU
        samples.append(ImuSample(s.t, (s.accel_frd[0] + ACCEL_BIAS, s.accel_frd[1], s.accel_frd[2]), s.gyro_frd,
                                 s.roll, s.pitch, math.atan2(math.sin(yaw), math.cos(yaw))))
    return d, samples


def receiver(t, xy, heading, speed, sigma=1.5, seed=0, rate=5.0, spoof_after=None, drift=0.5, bearing=0.0,
             drag_velocity=True, until=math.inf):
    """GnssFix readings at `rate` Hz from truth arrays (t (N,), xy (N, 2) ENU m, heading (N,) rad, speed (N,)
    m/s). spoof: from spoof_after s the position is dragged at `drift` m/s towards `bearing` (deg from north,
    clockwise), and with drag_velocity the velocity carries the drag, as a careful spoofer's would."""
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, min(t[-1], until), 1.0 / rate)
    sw, sb = 0.5 * sigma, math.sqrt(0.75) * sigma
    phi = math.exp(-1.0 / rate / 60.0)
    bias = rng.normal(0.0, sb, 2)
    b = math.radians(bearing)
    towards = np.array([math.sin(b), math.cos(b)])
    out = []
    for tk in times:
        bias = phi * bias + rng.normal(0.0, sb * math.sqrt(1.0 - phi * phi), 2)
        i = min(int(np.searchsorted(t, tk - 1e-9)), len(t) - 1)
        z = xy[i] + bias + rng.normal(0.0, sw, 2)
        v = speed[i] * np.array([math.cos(heading[i]), math.sin(heading[i])])
        if spoof_after is not None and tk >= spoof_after:
            z = z + drift * (tk - spoof_after) * towards
            v = v + drift * towards * drag_velocity
        out.append(GnssFix(float(tk), z, v, sigma, 0.3))
    return out


def run(d, samples, fixes, params, matcher=None, latency=0.0, deny=(math.inf, math.inf)):
    """Feed IMU and readings (none in [deny[0], deny[1]) s); answer camera queries with `matcher` after `latency`
    s (else cancel them). Starts at the first reading, as the daemon does. Returns (loc, rec, outcomes, queries)
    with rec rows (t, error x, error y, sigma_h) every 0.1 s and outcomes (t, GnssOutcome)."""
    x0 = fixes[0].xy
    loc = make_localiser(params, 0.0, float(x0[0]), float(x0[1]), heading=float(d.theta[0]),
                         speed=float(d.speed[0]))
    k, rec, outs, queries, pending = 0, [], [], [], []
    for s in samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            queries.append(q)
            if matcher is None:
                loc.cancel_query(q.query_id)
            else:
                pending.append((q.capture_t + latency, q))
        while pending and pending[0][0] <= s.t + 1e-9:
            _, q = pending.pop(0)
            loc.add_fix(q.query_id, matcher.answer(q))
        while k < len(fixes) and fixes[k].t <= s.t + 1e-9:
            if not deny[0] <= fixes[k].t < deny[1]:
                outs.append((fixes[k].t, loc.add_gnss(fixes[k])))
            k += 1
        if abs(s.t * 10 - round(s.t * 10)) < 1e-6:
            est = loc.estimate()
            x, y, _ = d.pose_at(s.t)
            rec.append((s.t, est.xy[0] - x, est.xy[1] - y, est.sigma_h))
    return loc, np.array(rec), outs, queries


def used(outs, t0=0.2, t1=math.inf) -> float:
    return float(np.mean([o.used for t, o in outs if t0 <= t < t1]))


def window(rec, t0, t1):
    w = (rec[:, 0] >= t0) & (rec[:, 0] <= t1)
    return rec[w]


def test_taco_plus_calibrates_on_gnss_and_dead_reckons_after_it_is_lost():
    """60 s of honest 1.5 m GNSS: every reading accepted, the speed error, accelerometer bias (0.05 m/s^2) and
    compass bias (0.02 rad) estimated; then 20 s without: the dead-reckoned error grows by less than 1.5 m
    (uncalibrated, the bias alone would move it 10 m), the reported accuracy covers the error, and the output
    moves by no more than its motion plus 3 sigma at the hand-over."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, until=60.0)
    loc, rec, outs, _ = run(d, samples, fixes, PLUS)
    assert isinstance(loc.estimator.aids, PlusAids) and used(outs) == 1.0
    assert all(o.reason == "fused" for t, o in outs if t > 0.1)
    at = window(rec, 59.95, 60.05)[0]
    # at 100 s: the biases learnt on the GNSS (the compass bias, a Gauss-Markov state, decays with tau 60 s)
    extra = loc.estimate().extra
    assert abs(extra["accel_bias"] - ACCEL_BIAS) < 0.015
    assert 0.4 * COMPASS_BIAS < extra["compass_bias"] < 1.5 * COMPASS_BIAS
    assert at[3] < 2.0 and np.hypot(at[1], at[2]) < 3.0 * at[3]
    after = window(rec, 60.0, 80.0)
    grew = np.hypot(after[:, 1] - at[1], after[:, 2] - at[2])
    assert grew.max() < 1.5
    assert np.all(np.hypot(after[:, 1], after[:, 2]) <= 3.0 * after[:, 3])
    steps = np.hypot(*np.diff(window(rec, 58.0, 63.0)[:, 1:3], axis=0).T)  # error changes frame to frame
    assert steps.max() < 3.0 * window(rec, 58.0, 63.0)[:, 3].min()


def test_paper_mode_re_anchors_on_gnss():
    """Paper mode keeps its maths: each accepted reading re-anchors (reason "anchored"); the error while fused is
    the receiver's, and nothing jumps more than 3 sigma when it stops."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, until=60.0)
    loc, rec, outs, _ = run(d, samples, fixes, PAPER)
    assert used(outs) == 1.0 and all(o.reason == "anchored" for t, o in outs if t > 0.1)
    fused = window(rec, 10.0, 60.0)
    assert np.sqrt(np.mean(fused[:, 1] ** 2 + fused[:, 2] ** 2)) < 2.5
    steps = np.hypot(*np.diff(window(rec, 58.0, 63.0)[:, 1:3], axis=0).T)
    assert steps.max() < 3.0 * window(rec, 58.0, 63.0)[:, 3].min()
    assert loc.gnss.state == "ok" and not loc.gnss.in_use


@pytest.mark.parametrize("bearing, drag_velocity, limit_s", [(0.0, True, 3.0), (270.0, True, 3.0),
                                                               (90.0, False, 12.0)])
def test_a_dragged_receiver_is_rejected_and_the_output_stays_within_5_m(bearing, drag_velocity, limit_s):
    """Honest for 60 s, then dragged at 0.5 m/s (velocity too, as a careful spoofer's; or the position alone):
    taco+ rejects it (reason "rejected", a gnss_rejected event with the figures) within limit_s and its output
    stays within 5 m of the truth for the 20 s after the drag starts."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, spoof_after=60.0, bearing=bearing,
                     drag_velocity=drag_velocity)
    loc, rec, outs, _ = run(d, samples, fixes, PLUS)
    first = next(t for t, o in outs if t >= 60.0 and o.reason == "rejected")
    assert first - 60.0 <= limit_s
    assert used(outs, 0.2, 60.0) == 1.0
    assert used(outs, first, 80.0) < 0.05
    err = window(rec, 55.0, 80.0)
    assert np.hypot(err[:, 1], err[:, 2]).max() < 5.0
    events = loc.gnss.take_events()
    assert events and events[0][1] == "gnss_rejected" and "innovation=" in events[0][2]
    assert abs(events[0][0] - first) < 0.15


@pytest.mark.parametrize("bearing, drag_velocity, rate, latency", [(270.0, True, 5.0, 0.5), (90.0, False, 2.0, 0.25),
                                                                  (None, None, 5.0, 0.5)])
def test_a_drag_too_slow_for_the_shadow_tests_is_covered_by_the_reported_accuracy(bearing, drag_velocity, rate,
                                                                                   latency):
    """Honest for 60 s, then dragged at 0.2 m/s (the shadow tests do not see it; with a camera check every 20 s
    it was 6.8 m off 30 s later with 1.3-1.5 m reported, 44-79 % within 2 sigma): a camera check every
    camera_interval_s floors the reported accuracy at the camera fix's distance from the readings, so the reports
    cover the error while the drag lasts. (None: an honest receiver, whose wandering bias the floor covers too.
    2 Hz readings and a 0.25 s matcher, as the daemon beside ArduPilot SITL has them: no reading after a capture
    when its answer comes.)"""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, spoof_after=None if bearing is None else 60.0,
                     bearing=bearing or 0.0, drag_velocity=bool(drag_velocity), drift=0.2, rate=rate)
    _, rec, _, queries = run(d, samples, fixes, PLUS, matcher=OracleMatcher(d, seed=2), latency=latency)
    w = window(rec, 10.0, 100.0)
    ratio = np.hypot(w[:, 1], w[:, 2]) / w[:, 3]
    assert np.mean(ratio <= 2.0) >= 0.95 and ratio.max() <= 3.0, (np.mean(ratio <= 2.0), ratio.max())
    checks = sum(q.reason == "gnss_check" for q in queries if q.capture_t < 60.0)
    assert checks >= 60.0 / PLUS.gnss.camera_interval_s - 2


def test_paper_mode_rejects_a_velocity_drag():
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, spoof_after=60.0, bearing=90.0)
    loc, rec, outs, _ = run(d, samples, fixes, PAPER)
    first = next(t for t, o in outs if t >= 60.0 and o.reason == "rejected")
    assert first - 60.0 <= 3.0 and used(outs, first, 80.0) < 0.05
    err = window(rec, 55.0, 65.0)
    assert np.hypot(err[:, 1], err[:, 2]).max() < 5.0


def test_gnss_back_after_a_denial_moves_the_output_by_at_most_3_sigma():
    """Denied from 30 to 70 s: readings come back, are used again, and the output moves by at most 3 sigma
    (of its covariance then) when the first one is fused."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=2)
    loc, rec, outs, _ = run(d, samples, fixes, PLUS, deny=(30.0, 70.0))
    assert used(outs, 75.0) > 0.95
    around = window(rec, 69.5, 73.0)
    steps = np.hypot(*np.diff(around[:, 1:3], axis=0).T)
    assert steps.max() <= 3.0 * around[:-1, 3][np.argmax(steps)]
    assert np.hypot(*window(rec, 90.0, 100.0)[-1, 1:3]) < 4.0


def test_camera_at_a_low_duty_while_gnss_is_healthy_and_late_fixes_replay_the_gnss():
    """While GNSS is fused a camera fix is asked for every camera_interval_s ("gnss_check"); 1 s late answers
    rewind and replay over frames that hold GNSS measurements; after the GNSS stops the covariance/time triggers
    take over at once."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, until=60.0)
    loc, rec, outs, queries = run(d, samples, fixes, PLUS, matcher=OracleMatcher(d, seed=3), latency=1.0)
    during = [q for q in queries if q.capture_t < 60.0]
    due = 60.0 / PLUS.gnss.camera_interval_s  # asked for whether or not the covariance trigger wants one
    assert due - 2 <= len(during) <= due + 1 and all(q.reason == "gnss_check" for q in during[1:])
    gaps = np.diff([q.capture_t for q in during])
    assert np.all(gaps >= PLUS.gnss.camera_interval_s - 0.2)
    after = [q for q in queries if q.capture_t >= 60.0 + PLUS.gnss.gap_s]  # the receiver is lost gap_s after
    assert after and after[0].capture_t < 72.0 and all(q.reason != "gnss_check" for q in after)
    assert sum(o.accepted for o in loc.record.outcomes if o.capture_t < 60.0) >= 2
    assert used(outs) == 1.0
    assert np.sqrt(np.mean(np.sum(window(rec, 60.0, 100.0)[:, 1:3] ** 2, axis=1))) < 2.0


class OffsetMap:
    """A camera that reads its map well, on a map misregistered by `offset` (ENU m): every answer is that far from
    the truth, the same way, with the weight of a good match."""

    def __init__(self, d, offset: tuple[float, float], seed: int = 0) -> None:
        self.oracle = OracleMatcher(d, capture_radius=80.0, seed=seed)
        self.offset = np.array(offset, dtype=float)

    def answer(self, q):
        return self.oracle.answer(q, bias_world=self.offset)


def test_a_camera_on_a_misregistered_map_is_refuted_by_gnss_and_never_followed():
    """Honest GNSS for 60 s, then none; the camera's answers are 25 m off the same way every time (its map
    misregistered): the readings refute it, so it rejects none of them, none of its answers is fused before or
    after the receiver is lost (refused as "refuted"), the Localiser says so once, and the reported accuracy
    covers the dead-reckoned error (2 sigma)."""
    d, samples = drive()
    fixes = receiver(d.t, d.xy, d.theta, d.speed, seed=1, until=60.0)
    loc, rec, outs, queries = run(d, samples, fixes, PLUS, matcher=OffsetMap(d, (-20.0, 15.0), seed=3), latency=0.5)
    outcomes = loc.record.outcomes
    assert used(outs) == 1.0
    assert not any(o.accepted for o in outcomes), [(o.capture_t, o.reason) for o in outcomes if o.accepted]
    late = [o.reason for o in outcomes if o.capture_t > 60.0]
    assert late.count("refuted") >= 3, late
    assert [k for _, k, _ in loc.estimator.aids.lock.events].count("camera_refuted") == 1
    after = window(rec, 60.0, 100.0)
    assert np.all(np.hypot(after[:, 1], after[:, 2]) <= 2.0 * after[:, 3])


def test_real_kitti_drive_both_estimators(kitti_root):
    """KITTI 07 (OXTS at 10 Hz, real IMU): 1.5 m readings made from the OXTS truth for 60 s, then none: >= 95 %
    accepted by both estimators, and 20 s of dead reckoning after it within a few metres."""
    from taco_mav.datasets.kitti import load_sequence

    drv = load_sequence(kitti_root, "07")
    tr = drv.truth
    t = np.arange(0.0, float(tr.t[-1]), 0.01)
    xy = np.column_stack([np.interp(t, tr.t, tr.xy[:, 0]), np.interp(t, tr.t, tr.xy[:, 1])])
    heading = np.interp(t, tr.t, np.unwrap(tr.heading))
    speed = np.hypot(*np.gradient(xy, 0.01, axis=0).T)
    fixes = receiver(t, xy, heading, speed, seed=5, until=60.0)
    for params in (PLUS, PAPER):
        x0 = fixes[0].xy
        loc = make_localiser(params, float(drv.imu.t[0]), float(x0[0]), float(x0[1]), float(tr.heading[0]),
                             drv.start.speed, heading_offset=drv.convergence_rad)
        k, outs, err = 0, [], []
        for s in drv.imu.samples():
            loc.add_imu(s)
            q = loc.poll_query()
            if q is not None:
                loc.cancel_query(q.query_id)
            while k < len(fixes) and fixes[k].t <= s.t + 1e-9:
                outs.append((fixes[k].t, loc.add_gnss(fixes[k])))
                k += 1
            x, y, _ = tr.pose_at(s.t)
            err.append((s.t, *(loc.estimate().xy - (x, y))))
        err = np.array(err)
        assert used(outs) >= 0.95, (params.plus is not None, used(outs))
        fused = err[(err[:, 0] > 10.0) & (err[:, 0] <= 60.0)]
        after = err[(err[:, 0] > 60.0) & (err[:, 0] <= 80.0)]
        assert np.sqrt(np.mean(fused[:, 1] ** 2 + fused[:, 2] ** 2)) < 2.5
        assert np.hypot(after[:, 1], after[:, 2]).max() < 6.0
