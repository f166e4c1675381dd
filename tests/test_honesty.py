"""Never confident and wrong: a run of planted bad fixes (30 m off, yet passing the yaw gate: zero yaw residual,
high weight) in an otherwise clean drive. At every 5 Hz output the true horizontal error must lie within 3 x
the reported 1-sigma (sigma_h) for at least 95 % of the outputs.

The estimator comes in as a parameter: paper mode fails (strict xfail, figures below); taco+ passes (its
chi-square gate rejects the planted fixes until lock is declared lost after 8 s; the relocalisation onto the
liars keeps half its jump in the reported sigma until three fixes agree, and the honest fixes pull it back).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import OracleMatcher, SimDrive, simulate

from taco_mav.config import localiser_params, profile_from_dict
from taco_mav.core.localiser import make_localiser
from taco_mav.core.search import body_to_world

DRIVE_S = 300.0
PLANT = (120.0, 130.0)  # capture times, s, of the planted stretch: 5 queries at the 2 s time trigger
OFFSET_M = 30.0
COVER = 3.0  # error <= 3 sigma
SHARE = 0.95
# Measured (seed 4): the paper estimator accepts all 6 planted fixes (no innovation gate), its sigma stays ~2-5 m
# while it sits 30 m off, and the honest fixes that follow miss (truth outside the 20 m capture radius of its
# crops), so it never recovers: 41.7 % of outputs covered, worst error 94 m = 12 sigma. With a 15 m offset it
# recovers: 98.5 % covered. The assertion stands; paper mode is expected to fail it.
ESTIMATORS = [pytest.param("paper", marks=pytest.mark.xfail(
    strict=True, reason="paper mode is confident and wrong after 30 m planted fixes: 41.7 % covered (need 95 %)")),
              "taco+"]  # measured (seed 4): 97.9 % covered, 4 of 15 planted fixes accepted, worst error 30 m


def _drive(seed: int = 4) -> SimDrive:
    return simulate(lambda t: min(8.0, 1.0 + t), lambda t: 0.08 if 60 < t < 80 else (-0.05 if 200 < t < 230 else 0.0),
                    DRIVE_S, accel_noise=0.05, gyro_noise=0.001, compass_noise=0.01, seed=seed)


def honesty_run(estimator: str, seed: int = 4) -> dict[str, float]:
    """Play the drive with honest fixes (OracleMatcher) except PLANT, where every crop answers the truth
    shifted OFFSET_M metres to the vehicle's left with w ~0.95 and no yaw residual. Returns the share of 5 Hz
    outputs with error <= COVER x sigma_h, the worst error/sigma ratio, the largest error (m) and how many
    planted fixes were accepted."""
    drive = _drive(seed)
    params = localiser_params(profile_from_dict({"estimator": estimator}))
    loc = make_localiser(params, 0.0, heading=float(drive.theta[0]), speed=float(drive.speed[0]), record=True)
    honest = OracleMatcher(drive, sigma_fwd=0.5, sigma_lat=1.0, seed=seed)
    liar = OracleMatcher(drive, sigma_fwd=0.3, sigma_lat=0.3, w=0.95, capture_radius=1e6, seed=seed + 1)
    errors, sigmas = [], []
    next_out = 0.0
    for s in drive.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            if PLANT[0] <= q.capture_t <= PLANT[1]:
                _, _, th = drive.pose_at(q.capture_t)
                answer = liar.answer(q, bias_world=body_to_world(th, np.array([0.0, OFFSET_M])))
            else:
                answer = honest.answer(q)
            loc.add_fix(q.query_id, answer)
        if s.t >= next_out - 1e-9:
            next_out += 0.2
            est = loc.estimate()
            x, y, _ = drive.pose_at(s.t)
            errors.append(math.hypot(est.xy[0] - x, est.xy[1] - y))
            sigmas.append(est.sigma_h)
    err, sig = np.array(errors), np.array(sigmas)
    planted = [o for o in loc.record.outcomes if PLANT[0] <= o.capture_t <= PLANT[1]]
    return {"covered": float(np.mean(err <= COVER * sig)), "worst_ratio": float(np.max(err / sig)),
            "max_error_m": float(err.max()), "planted": len(planted),
            "planted_accepted": sum(o.accepted for o in planted), "outputs": len(err)}


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_reported_sigma_covers_the_error_through_bad_fixes(estimator: str) -> None:
    r = honesty_run(estimator)
    assert r["planted"] >= 4 and r["outputs"] >= 1400  # the stretch really happened, at 5 Hz
    assert r["covered"] >= SHARE, r


def test_clean_run_is_covered() -> None:
    """Control: without planted fixes the paper estimator's sigma covers its error everywhere."""
    global PLANT
    saved, PLANT = PLANT, (-2.0, -1.0)
    try:
        r = honesty_run("paper")
    finally:
        PLANT = saved
    assert r["planted"] == 0 and r["covered"] >= 0.99, r
