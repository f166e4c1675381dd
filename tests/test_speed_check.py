"""GNSS ground speed against the camera's (core/plus/speed_check.py): the camera's scale error is learnt while the
receiver is honest; a velocity drag along the track (a careful spoofer) is flagged within seconds."""

import math

import numpy as np

from taco_mav.core.plus.speed_check import SpeedCheck


def _run(seed: int, drag_from: float | None, drag_mps: float = 0.5, duration: float = 120.0, scale: float = 1.04):
    """GNSS at 5 Hz (speed noise 0.1 m/s), camera at 2 Hz reading `scale` x too slow (noise 0.08 m/s); the
    truth cruises at 8-12 m/s. Returns the times (s) the check flagged."""
    rng = np.random.default_rng(seed)
    chk = SpeedCheck()
    flags = []
    for k in range(int(duration * 5)):
        t = k / 5.0
        v = 10.0 + 2.0 * math.sin(t / 15.0)
        drag = drag_mps if drag_from is not None and t >= drag_from else 0.0
        chk.add_gnss(t, v + drag + rng.normal(0, 0.1), 0.1)
        if k % 5 == 2 and t > 0.5:  # 2 Hz (every 2.5th GNSS reading, rounded), middle time 0.2 s back
            tm = t - 0.2
            vm = 10.0 + 2.0 * math.sin(tm / 15.0)
            trusted = drag_from is None or not flags
            if chk.add_camera(tm, vm / scale + rng.normal(0, 0.08), 0.08, trusted) is not None:
                flags.append(tm)
    return chk, flags


def test_honest_receiver_is_never_flagged_and_the_scale_is_learnt():
    for seed in range(5):
        chk, flags = _run(seed, None)
        assert flags == [], seed
        assert abs(chk.scale - 1.04) < 0.005


def test_a_drag_along_the_track_is_flagged_within_seconds():
    for seed in range(5):
        _, flags = _run(seed, 60.0)
        assert flags and 60.0 < flags[0] < 66.0, (seed, flags[:3])


def test_slow_or_missing_pairs_are_not_used():
    chk = SpeedCheck()
    chk.add_gnss(0.0, 1.0, 0.1)
    assert chk.add_camera(0.0, 1.0, 0.05, True) is None and chk.pairs == 0  # below min_speed_mps
    assert chk.add_camera(5.0, 10.0, 0.05, True) is None and chk.pairs == 0  # no GNSS reading near 5 s
