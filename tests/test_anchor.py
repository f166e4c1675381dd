"""The daemon's anchoring: origin, first heading, generations, re-anchoring after a reboot and an IMU gap."""

import math

import numpy as np
import pytest

from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.aiding import PlusAids
from taco_mav.core.plus.params import PlusParams
from taco_mav.daemon.anchor import LocaliserAnchor


def test_first_heading_from_course_when_moving_else_from_attitude():
    a = LocaliserAnchor(LocaliserParams())
    origin = a.set_origin(49.0, 8.4, 115.0, speed=5.0, course=0.0)  # moving north
    conv = origin.convergence
    loc = a.localiser(10.0, attitude_yaw=1.0)
    assert loc.timeline.ukf.x[2] == pytest.approx(math.pi / 2 + conv)  # the course wins over the attitude's yaw
    assert a.generation == 1 and loc.t == 10.0
    a.set_origin(49.0, 8.4, 115.0, speed=0.2, course=0.0)  # standing: the course is noise
    loc = a.localiser(11.0, attitude_yaw=math.pi / 2)  # facing east
    assert loc.timeline.ukf.x[2] == pytest.approx(conv, abs=1e-9)
    assert a.generation == 2


def test_reanchoring_keeps_the_estimate_and_grows_sigma_over_a_gap():
    a = LocaliserAnchor(LocaliserParams(plus=PlusParams()))
    a.set_origin(49.0, 8.4, 115.0, speed=10.0, course=math.pi / 2)  # east at 10 m/s
    loc = a.localiser(0.0, attitude_yaw=math.pi / 2, xy=(100.0, 50.0), sigma_xy=2.0)
    assert isinstance(loc.estimator.aids, PlusAids)
    est = loc.estimate()
    c = a.carried(loc, t_last=0.0, t_new=4.0)  # 4 s without IMU at 10 m/s
    assert c.carried_m == pytest.approx(40.0)
    assert np.allclose(c.xy, (est.xy[0] + 40.0 * math.cos(est.theta), est.xy[1] + 40.0 * math.sin(est.theta)))
    assert c.sigma == pytest.approx(math.hypot(est.sigma_h, 0.5 * 11.0 * 4.0))  # (|v| + 1 m/s) / 2 x gap
    again = a.restarted(loc, attitude_yaw=math.pi / 2, t_new=0.5)  # reboot: new clock, same place and sigma
    assert a.generation == 2 and again.t == 0.5
    assert np.allclose(again.estimate().xy, est.xy) and again.estimate().sigma_h == pytest.approx(est.sigma_h, rel=1e-6)
