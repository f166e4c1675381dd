"""IMU timestamp checks: reboots and gaps are believed only when the next sample confirms them."""

from taco_mav.daemon.imu_timeline import ImuTimeline, TimelineVerdict

OK, OUT_OF_ORDER, UNCONFIRMED = TimelineVerdict.OK, TimelineVerdict.OUT_OF_ORDER, TimelineVerdict.UNCONFIRMED


def _run(times, anchored=True):
    tl = ImuTimeline(backstep_s=1.0, max_dt_s=0.5)
    return [tl.check(t, anchored) for t in times]


def test_steady_stream_and_out_of_order():
    checks = _run([10.0, 10.02, 10.04, 10.03, 10.04, 10.06])
    assert [c.verdict for c in checks] == [OK] * 3 + [OUT_OF_ORDER] * 2 + [OK]


def test_lone_corrupt_timestamp_is_dropped_not_believed():
    checks = _run([10.0, 10.02, 5000.0, 10.04, 10.06, 0.5, 10.08])
    assert [c.verdict for c in checks] == [OK, OK, UNCONFIRMED, OK, OK, UNCONFIRMED, OK]
    assert [c.outlier for c in checks] == [False, False, False, True, False, False, True]


def test_reboot_confirmed_by_the_next_sample():
    checks = _run([100.0, 100.02, 1.0, 1.02, 1.04])
    assert [c.verdict for c in checks] == [OK, OK, UNCONFIRMED, TimelineVerdict.REBOOT, OK]
    assert (checks[3].t_from, checks[3].t_to) == (100.02, 1.0)


def test_gap_only_once_anchored():
    checks = _run([10.0, 20.0, 20.02, 20.04])
    assert [c.verdict for c in checks] == [OK, UNCONFIRMED, TimelineVerdict.GAP, OK]
    assert (checks[2].t_from, checks[2].t_to) == (10.0, 20.0)
    assert [c.verdict for c in _run([10.0, 20.0, 20.02], anchored=False)] == [OK] * 3
