"""The IMU stillness detector (core/plus/stationary.py): a stop, a smooth steady acceleration (SITL's rover pulling
away has no vibration at all) and a rough cruise."""

import numpy as np

from taco_mav.core.plus.stationary import StationaryDetector

G = 9.80665


def _feed(det: StationaryDetector, accel_fwd: float, noise: float, seconds: float = 1.5, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for i in range(int(seconds * 50)):
        f = (accel_fwd + rng.normal(0, noise), rng.normal(0, noise), -G + rng.normal(0, noise))
        det.add(i / 50.0, f, (0.0, 0.0, 0.0), f[0])


def test_a_stop_is_still_and_a_smooth_acceleration_is_not():
    for accel, noise, bias, still in ((0.0, 0.005, 0.0, True), (1.0, 0.0, 0.0, False), (0.3, 0.001, 0.0, False),
                                      (0.1, 0.001, 0.1, True), (0.0, 0.3, 0.0, False)):
        det = StationaryDetector(1.0, 0.02, 0.05, 0.15)
        _feed(det, accel, noise)
        assert det.still(bias) is still, (accel, noise, bias)


def test_without_the_mean_check_a_smooth_acceleration_looks_still():
    det = StationaryDetector(1.0, 0.02, 0.05)  # accel_mean_max: inf, no mean check
    _feed(det, 1.0, 0.0)
    assert det.stationary


def test_rotation_and_short_windows_are_not_still():
    det = StationaryDetector(1.0, 0.02, 0.05, 0.15)
    for i in range(30):
        det.add(i / 50.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0))
    assert not det.still()  # 0.6 s of samples in a 1 s window
    for i in range(30, 80):
        det.add(i / 50.0, (0.0, 0.0, -G), (0.0, 0.0, 0.05))
    assert not det.still()
