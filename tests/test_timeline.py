"""The filter's timeline (core/timeline.py): a correction applied late, through a rewind to its frame and a replay,
leaves the filter where the same correction applied on time does, with every later correction applied again on
the way; a correction forgotten leaves it where it would be without it. One place for what every correction
kind relies on."""

import math

import numpy as np
import pytest
from helpers import simulate

from taco_mav.core.corrections import GnssCorrection, GnssMeasurement
from taco_mav.core.frames import Tick
from taco_mav.core.localiser import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.params import PlusParams

DRIVE = simulate(lambda t: 5.0, lambda t: 0.05 * math.sin(t), 6.0, accel_noise=0.02, gyro_noise=0.001, seed=3)


def _frame_at(loc, t: float) -> Tick:
    return next(h for h in loc.timeline.history if abs(h.t - t) < 1e-6)


def _run(params: LocaliserParams, fix_late: bool, gnss: bool, forget_gnss: bool = False) -> np.ndarray:
    """Drive 6 s; a camera fix captured at 1.0 s (applied at 1.0 s, or late at 3.0 s), a GNSS reading at the 2.0 s
    frame (applied at 2.0 s), optionally forgotten at 3.5 s. Returns the final UKF state."""
    loc = make_localiser(params, 0.0, heading=float(DRIVE.theta[0]), speed=5.0)
    tl = loc.timeline
    fix_xy = np.array([5.8, 0.9])
    done = set()
    for s in DRIVE.samples:
        loc.add_imu(s)
        loc.poll_query()  # the trigger's queries go unanswered
        if s.t >= 1.0 and "fix" not in done and (not fix_late or s.t >= 3.0):
            tl.fix(_frame_at(loc, 1.0), fix_xy, 1.5, 3.0)
            done.add("fix")
        if gnss and s.t >= 2.0 and "gnss" not in done:
            base = _frame_at(loc, 2.0)
            tl.correct_batch(base, [(base, GnssCorrection(GnssMeasurement(2.0, np.array([10.6, 1.1]), 4.0),
                                                          loc.estimator.gnss))])
            done.add("gnss")
        if forget_gnss and s.t >= 3.5 and "forget" not in done:
            assert tl.forget(_frame_at(loc, 1.5), Tick.drop_gnss)
            done.add("forget")
    return np.concatenate([tl.ukf.x, tl.ukf.P.ravel()])


# taco+ feeds its speed error back into the preintegrator after every frame, so frames integrated before a late
# fix arrived carry a slightly different speed than had it come on time: equal to 1e-3, not to rounding
CASES = [(LocaliserParams(), 1e-9), (LocaliserParams(plus=PlusParams()), 1e-3)]


@pytest.mark.parametrize("params,atol", CASES, ids=["paper", "taco+"])
def test_a_late_fix_replays_every_later_correction(params, atol):
    on_time = _run(params, fix_late=False, gnss=True)
    late = _run(params, fix_late=True, gnss=True)
    assert np.allclose(late, on_time, rtol=0.0, atol=atol)
    # the GNSS reading moved the filter: had the replay dropped it, the late run would differ by far more
    assert np.abs(_run(params, fix_late=True, gnss=False) - on_time).max() > 0.05


@pytest.mark.parametrize("params,atol", CASES, ids=["paper", "taco+"])
def test_a_forgotten_correction_leaves_the_filter_as_if_it_never_came(params, atol):
    forgotten = _run(params, fix_late=True, gnss=True, forget_gnss=True)
    never = _run(params, fix_late=True, gnss=False)
    assert np.allclose(forgotten, never, rtol=0.0, atol=atol)


def test_corrections_keep_their_stage_order_on_a_frame():
    loc = make_localiser(LocaliserParams(), 0.0, speed=5.0)
    for s in DRIVE.samples[:150]:
        loc.add_imu(s)
    tl = loc.timeline
    tick = tl.history[-1]
    tl.correct_batch(tick, [(tick, GnssCorrection(GnssMeasurement(1.4, np.array([7.0, 0.2]), 4.0), loc.estimator.gnss))])
    tl.fix(tick, np.array([7.1, 0.3]), 1.5, 3.0, heading=(0.01, 0.05))
    assert [type(c).__name__ for c in tick.corrections] == ["PositionFix", "HeadingFix", "GnssCorrection"]
    assert [m.t for m in tick.gnss] == [1.4]
