"""The stream watch (mavlink/stream_watch.py): a granted stream that comes at under half its rate is named once a
2 s window is over; a window with a silent link, or one the grant did not cover, is not judged."""

from taco_mav.mavlink.stream_watch import StreamWatch


def _feed(w: StreamWatch, t0: float, t1: float, rates: dict[str, float]) -> None:
    """Messages of each kind at its rate (Hz) from t0 to t1, plus a 10 Hz background (the link is alive)."""
    events = [(t0 + k / hz, kind) for kind, hz in rates.items() for k in range(int((t1 - t0) * hz))]
    events += [(t0 + k / 10.0, "VFR_HUD") for k in range(int((t1 - t0) * 10))]
    for t, kind in sorted(events):
        w.arrived(kind, t)


def test_a_stream_at_one_hz_of_forty_granted_is_named():
    w = StreamWatch(("RAW_IMU", "ATTITUDE"))
    granted = {"RAW_IMU": 40.0, "ATTITUDE": 40.0, "VFR_HUD": 5.0}
    assert w.check(0.0, granted) == []  # the first window starts
    _feed(w, 0.0, 2.0, {"RAW_IMU": 1.0, "ATTITUDE": 40.0})
    assert w.check(1.9, granted) == []  # not over yet
    slow = w.check(2.0, granted)
    assert [(n, round(hz, 2), g) for n, hz, g in slow] == [("RAW_IMU", 1.0, 40.0)] and w.slow_found == 1
    _feed(w, 2.0, 4.0, {"RAW_IMU": 40.0, "ATTITUDE": 40.0})
    assert w.check(4.0, granted) == []  # back at its rate


def test_at_the_edge_of_half_the_rate():
    w = StreamWatch(("RAW_IMU",))
    w.check(0.0, {"RAW_IMU": 40.0})
    _feed(w, 0.0, 2.0, {"RAW_IMU": 20.0})
    assert w.check(2.0, {"RAW_IMU": 40.0}) == []  # 20 Hz of 40: not under half
    _feed(w, 2.0, 4.0, {"RAW_IMU": 19.0})
    assert [n for n, _, _ in w.check(4.0, {"RAW_IMU": 40.0})] == ["RAW_IMU"]


def test_a_silent_link_is_not_judged():
    w = StreamWatch(("RAW_IMU",))
    w.check(0.0, {"RAW_IMU": 40.0})
    _feed(w, 0.0, 0.5, {"RAW_IMU": 40.0})
    _feed(w, 1.8, 2.0, {"RAW_IMU": 40.0})  # 1.3 s of nothing at all: the link, not the stream
    assert w.check(2.0, {"RAW_IMU": 40.0}) == []
    _feed(w, 2.0, 3.0, {"RAW_IMU": 40.0})
    assert w.check(4.0, {"RAW_IMU": 40.0}) == []  # silent since 3.0 s, at the check: not judged either
    assert w.slow_found == 0


def test_a_grant_made_during_a_window_is_judged_from_the_next():
    w = StreamWatch(("RAW_IMU",))
    w.check(0.0, {})
    _feed(w, 0.0, 2.0, {"RAW_IMU": 5.0})  # granted at 40 Hz late in the window
    assert w.check(2.0, {"RAW_IMU": 40.0}) == []
    _feed(w, 2.0, 4.0, {"RAW_IMU": 5.0})
    assert [n for n, _, _ in w.check(4.0, {"RAW_IMU": 40.0})] == ["RAW_IMU"]
    _feed(w, 4.0, 6.0, {"RAW_IMU": 5.0})
    assert w.check(6.0, {"RAW_IMU": 32.0}) == []  # granted again at another rate in the window: not judged
