"""GNSS bookkeeping on the link side (taco_mav/daemon/gnss.py) and its neighbours: which GPS instance is ours
(ParamCheck, GPSn_TYPE), reading -> GnssFix conversion (ENU metres, grid velocity, accuracies), loss and
return after 1 s, the spoofing-guard events, and the origin's order of sources (OriginChooser)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from taco_mav.core.types import GnssOutcome  # noqa: E402
from taco_mav.daemon.anchor import OriginCandidate, OriginChooser  # noqa: E402
from taco_mav.daemon.gnss import FALLBACK_SIGMA_H_M, GnssTracker, gnss_fix, moved_from_origin, sigma_h_of  # noqa: E402
from taco_mav.mavlink.decoders import GnssReading  # noqa: E402
from taco_mav.mavlink.encoders import Origin  # noqa: E402
from taco_mav.mavlink.requests import MessageRequest, ParamCheck  # noqa: E402

ORIGIN = Origin.from_latlon(49.0, 8.4, 115.0)
TX = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


def reading(north_m: float = 0.0, east_m: float = 0.0, *, instance: int = 2, h_acc: float | None = 0.8,
            hdop: float | None = 0.9, speed: float = 5.0, course_deg: float | None = 90.0, t: float = 10.0,
            vel_acc: float | None = None) -> GnssReading:
    """A 3D fix north_m / east_m (true, flat earth) from ORIGIN."""
    lat = 49.0 + north_m / 111_320.0
    lon = 8.4 + east_m / (111_320.0 * math.cos(math.radians(49.0)))
    return GnssReading(t, lat, lon, 115.0, speed, None if course_deg is None else math.radians(course_deg), 3, 12,
                       instance, h_acc, vel_acc, hdop, True)


def param_value(name: str, value: float):
    return mavlink.MAVLink(None).parse_buffer(bytes(TX.param_value_encode(name.encode(), value, 2, 900, 1).pack(TX)))[0]


# --------------------------------------------------------------------------------------------- conversion

def test_fix_in_enu_metres_and_grid_velocity() -> None:
    """100 m north, 50 m east (true) lands there on the UTM grid (within the flat-earth step's cm); an eastward
    5 m/s course comes out on the grid turned by the meridian convergence."""
    f = gnss_fix(reading(100.0, 50.0), ORIGIN, hdop_uere_m=2.0)
    true_to_grid = np.array([[math.cos(ORIGIN.convergence), -math.sin(ORIGIN.convergence)],
                             [math.sin(ORIGIN.convergence), math.cos(ORIGIN.convergence)]])
    assert f.xy == pytest.approx(true_to_grid @ [50.0, 100.0], abs=0.3)
    assert f.vel_en == pytest.approx(5.0 * np.array([math.cos(ORIGIN.convergence), math.sin(ORIGIN.convergence)]),
                                     abs=1e-9)
    assert f.sigma_h_m == 0.8 and f.sigma_v_mps == 0.5 and f.t == 10.0
    assert gnss_fix(reading(vel_acc=0.2), ORIGIN, 2.0).sigma_v_mps == 0.2


def test_accuracy_fallbacks() -> None:
    """h_acc when reported; HDOP x UERE when h_acc is 0/absent; a conservative 10 m with neither."""
    assert sigma_h_of(reading(h_acc=1.2), 2.0) == 1.2
    assert sigma_h_of(reading(h_acc=None, hdop=1.5), 2.0) == pytest.approx(3.0)
    assert sigma_h_of(reading(h_acc=None, hdop=None), 2.0) == FALLBACK_SIGMA_H_M
    assert gnss_fix(reading(h_acc=None, hdop=0.7), ORIGIN, hdop_uere_m=3.0).sigma_h_m == pytest.approx(2.1)


def test_velocity_unknown_course() -> None:
    assert gnss_fix(reading(course_deg=None, speed=3.0), ORIGIN, 2.0).vel_en is None
    assert gnss_fix(reading(course_deg=None, speed=0.0), ORIGIN, 2.0).vel_en == pytest.approx([0.0, 0.0])


def test_moved_from_origin() -> None:
    assert not moved_from_origin(gnss_fix(reading(4.0, 0.0), ORIGIN, 2.0))
    assert moved_from_origin(gnss_fix(reading(30.0, 0.0), ORIGIN, 2.0))
    assert not moved_from_origin(gnss_fix(reading(30.0, 0.0, h_acc=12.0), ORIGIN, 2.0))  # within 3 sigma


# --------------------------------------------------------------------------------------------- instances

def test_our_instance_is_never_real() -> None:
    """gps_id 0: GPS1 is ours until GPS1_TYPE says otherwise; a type-14 GPS2 is someone else's GPS_INPUT;
    without GPS_INPUT output (PX4) every instance is a receiver."""
    types: dict[int, int] = {}
    g = GnssTracker(gps_id=0, writes_gps=True, hdop_uere_m=2.0, types=types)
    assert g.role(1) == "ours" and g.role(2) == "real"
    types.update({1: 14, 2: 14})
    assert g.role(1) == "ours" and g.role(2) == "mav"
    types.update({1: 1, 2: 0})
    assert g.role(1) == "real" and g.role(2) == "none"  # GPS_INPUT misconfigured: GPS1 is a receiver
    g2 = GnssTracker(gps_id=1, writes_gps=True, hdop_uere_m=2.0)
    assert g2.role(1) == "real" and g2.role(2) == "ours"
    assert GnssTracker(0, False, 2.0).role(1) == "real"
    r, ev = g2.on_message(2, reading(instance=2), 3, 0.0)
    assert r is None and ev == [] and g2.counts["gps2_ours"] == 1 and g2.state == "none"


def test_param_check_reads_our_instance() -> None:
    """gps_id 1 (GPS2): GPS1_TYPE=1 is fine (a receiver), GPS2_TYPE=1 is the warning, naming GPS2_TYPE."""
    sent = []
    pc = ParamCheck(sent.append, TX, gps_id=1)
    pc.tick(0.0, 1, 1)
    assert [m.param_id for m in sent] == ["GPS1_TYPE", "GPS_TYPE", "GPS2_TYPE", "GPS_TYPE2"]
    assert pc.on_message(param_value("GPS1_TYPE", 1.0)) is None
    assert pc.is_mav(1) is False and pc.is_mav(2) is None and not pc.done
    text = pc.on_message(param_value("GPS2_TYPE", 1.0))
    assert text == "GPS2_TYPE=1, GPS_INPUT needs GPS2_TYPE=14 (MAV): it will be ignored"
    assert pc.done and pc.types == {1: 1, 2: 1} and pc.answered_by == "GPS2_TYPE"
    old = ParamCheck(sent.append, TX, gps_id=0)  # firmware before 4.6
    assert old.on_message(param_value("GPS_TYPE", 14.0)) is None and old.value == 14.0
    assert old.on_message(param_value("GPS_TYPE2", 1.0)) is None and old.types == {1: 14, 2: 1}
    sent.clear()
    pc2 = ParamCheck(sent.append, TX, gps_id=0)
    pc2.on_message(param_value("GPS1_TYPE", 14.0))
    pc2.tick(0.0, 1, 1)  # only what is still missing is asked again
    assert [m.param_id for m in sent] == ["GPS2_TYPE", "GPS_TYPE2"]


def test_param_check_reads_the_antenna_offset() -> None:
    """With output.antenna_frd_m the check also asks for our instance's GPSn_POS_X/Y/Z (and the pre-4.6
    GPS_POSn_X/Y/Z); answers within 5 cm of the profile are quiet, a larger difference is the warning."""
    sent = []
    pc = ParamCheck(sent.append, TX, gps_id=1, antenna_frd_m=(0.5, 0.0, -0.3))
    pc.tick(0.0, 1, 1)
    assert [m.param_id for m in sent] == ["GPS1_TYPE", "GPS_TYPE", "GPS2_TYPE", "GPS_TYPE2", "GPS2_POS_X", "GPS_POS2_X",
                                          "GPS2_POS_Y", "GPS_POS2_Y", "GPS2_POS_Z", "GPS_POS2_Z"]
    for name, value in (("GPS1_TYPE", 1.0), ("GPS2_TYPE", 14.0), ("GPS2_POS_X", 0.52), ("GPS2_POS_Y", -0.04)):
        assert pc.on_message(param_value(name, value)) is None
    assert not pc.done  # Z still missing
    assert pc.on_message(param_value("GPS2_POS_Z", -0.3)) is None and pc.done and pc.antenna_warning is None
    assert pc.antenna == {"X": pytest.approx(0.52), "Y": pytest.approx(-0.04), "Z": pytest.approx(-0.3)}
    old = ParamCheck(sent.append, TX, gps_id=0, antenna_frd_m=(0.0, 0.0, 0.0))  # firmware before 4.6
    assert old.on_message(param_value("GPS_POS1_X", 1.08)) is None
    assert old.on_message(param_value("GPS_POS1_Y", 0.25)) is None
    text = old.on_message(param_value("GPS_POS1_Z", -0.73))
    assert text == old.antenna_warning and text in old.warnings
    assert text.startswith("antenna off 1.08 m: GPS_POS1_X/Y/Z=1.08,0.25,-0.73 but output.antenna_frd_m=0.00,0.00,")
    assert ParamCheck(sent.append, TX, gps_id=0).antenna_names == {}  # no antenna_frd_m: not asked


def test_message_request_repeats_while_wanted() -> None:
    sent = []
    req = MessageRequest(sent.append, TX, ("GPS_GLOBAL_ORIGIN", "HOME_POSITION"), retry_s=2.0)
    for now in (0.0, 1.0, 2.0, 3.0):
        req.tick(now, 1, 1)
    req.tick(4.0, 1, 1, wanted=False)
    assert [(m.command, m.param1) for m in sent] == [(512, 49), (512, 242)] * 2


# --------------------------------------------------------------------------------------------- loss and return

def test_lost_after_one_second_and_back_after_one_second() -> None:
    g = GnssTracker(gps_id=0, writes_gps=True, hdop_uere_m=2.0)
    t = 0.0
    for _ in range(4):  # 2 Hz of 3D fixes
        r, ev = g.on_message(2, reading(), 3, t)
        assert r is not None and ev == []
        t += 0.5
    assert g.state == "ok" and g.steady
    assert g.tick(2.5) == []  # last fix at 1.5 s: 1.0 s is not yet "for 1 s"
    ev = g.tick(2.51)
    assert [e.kind for e in ev] == ["gnss_lost"] and ev[0].fields["reason"] == "silent" and ev[0].severity == 4
    assert "GPS2 lost" in ev[0].text and g.tick(3.0) == []
    # back: fixes again, reported once they have run for 1 s
    kinds = []
    for k in range(4):
        kinds += [e.kind for e in g.on_message(2, reading(), 3, 5.0 + 0.5 * k)[1]]
    assert kinds == ["gnss_back"] and g.state == "ok"
    # NO_FIX messages (receiver still talking): lost for "no_3d_fix" 1 s after the last fix
    assert g.on_message(2, None, 1, 7.0)[1] == []
    ev = g.on_message(2, None, 1, 7.6)[1]
    assert [e.kind for e in ev] == ["gnss_lost"] and ev[0].fields["reason"] == "no_3d_fix"


def test_flapping_fix_type_changes_only_counters() -> None:
    """3D / NO_FIX alternating at 4 Hz: never 1 s without a fix, so no loss; once lost, a flapping receiver
    never runs 1 s without NO_FIX, so no return."""
    g = GnssTracker(gps_id=0, writes_gps=True, hdop_uere_m=2.0)
    events = []
    for k in range(40):
        r = reading() if k % 2 == 0 else None
        events += g.on_message(2, r, 3 if r else 1, 0.25 * k)[1]
        events += g.tick(0.25 * k)
    assert events == [] and g.state == "ok" and g.counts["gps2_no_fix"] == 20
    events = g.tick(20.0)
    assert [e.kind for e in events] == ["gnss_lost"]
    for k in range(40):
        r = reading() if k % 2 == 0 else None
        events += g.on_message(2, r, 3 if r else 1, 21.0 + 0.25 * k)[1]
    assert [e.kind for e in events] == ["gnss_lost"] and g.state == "lost"


def test_far_fix_is_garbage() -> None:
    g = GnssTracker(gps_id=0, writes_gps=True, hdop_uere_m=2.0)
    r, ev = g.on_message(2, reading(north_m=200_000.0), 3, 0.0, ORIGIN)
    assert r is None and ev == [] and g.state == "none" and g.counts["far_from_origin"] == 1


def test_fix_time_kept_or_replaced() -> None:
    g = GnssTracker(gps_id=0, writes_gps=True, hdop_uere_m=2.0)
    assert g.fix(reading(t=10.0), ORIGIN, 10.4).t == 10.0
    assert g.fix(reading(t=1e9), ORIGIN, 10.4).t == 10.4 and g.counts["time_replaced"] == 1


# --------------------------------------------------------------------------------------------- guard events

def test_rejection_run_reported_once_then_accepted_again() -> None:
    g = GnssTracker(gps_id=1, writes_gps=True, hdop_uere_m=2.0)
    g.on_message(1, reading(instance=1), 3, 0.0)
    assert g.outcome(GnssOutcome(True, "fused", 0.5, 0.4, 0.6), 1.0) == []
    ev = g.outcome(GnssOutcome(False, "rejected", 40.0, 22.0, 7.6), 2.0)
    assert [e.kind for e in ev] == ["gnss_rejected"] and ev[0].severity == 4
    assert ev[0].fields == {"instance": 1, "reason": "rejected", "nis": 40.0, "window_nis": 22.0, "innovation_m": 7.6}
    assert ev[0].text == "GPS1 REJECTED: 8m off, spoofed?" and len("TACO: " + ev[0].text) <= 50
    assert g.outcome(GnssOutcome(False, "rejected", 50.0, 30.0, 9.0), 2.5) == []
    assert g.outcome(GnssOutcome(False, "stale"), 3.0) == []
    ev = g.outcome(GnssOutcome(True, "fused", 1.0, 1.0, 0.7), 12.0)
    assert [e.kind for e in ev] == ["gnss_accepted_again"] and ev[0].fields["rejected_s"] == pytest.approx(10.0)
    assert g.counts["outcome_rejected"] == 2 and g.counts["outcome_fused"] == 2


# --------------------------------------------------------------------------------------------- origin order

def _c(source: str, lat: float = 49.0) -> OriginCandidate:
    return OriginCandidate(lat, 8.4, 115.0, 0.0, None, source)


def test_origin_order_and_grace() -> None:
    """EKF origin at once; home or GNSS wait until 0.5 s after the autopilot was heard (the EKF origin and home
    asked for) for something better, then the best source's latest offer."""
    ch = OriginChooser(grace_s=0.5)
    ch.heard(0.0)
    assert ch.offer(_c("GPS2_RAW"), 0.1) is None
    assert ch.offer(_c("HOME_POSITION", 49.1), 0.2) is None
    assert ch.offer(_c("HOME_POSITION", 49.2), 0.3) is None
    assert ch.poll(0.49) is None
    assert ch.poll(0.5) == _c("HOME_POSITION", 49.2)
    assert ch.offer(_c("GPS_GLOBAL_ORIGIN"), 1.1) is None  # chosen already
    late = OriginChooser(grace_s=0.5, settle_s=0.2)  # heard long ago: home still waits 0.2 s for the EKF origin
    late.heard(0.0)
    assert late.offer(_c("HOME_POSITION"), 30.0) is None and late.poll(30.19) is None
    assert late.offer(_c("GPS_GLOBAL_ORIGIN", 48.5), 30.01) == _c("GPS_GLOBAL_ORIGIN", 48.5)
    ch2 = OriginChooser()
    ch2.offer(_c("GPS_RAW_INT"), 0.0)
    assert ch2.offer(_c("GPS_GLOBAL_ORIGIN", 48.0), 0.2) == _c("GPS_GLOBAL_ORIGIN", 48.0)


def test_no_origin_notice_every_ten_seconds() -> None:
    ch = OriginChooser(notice_first_s=3.0, notice_every_s=10.0)
    assert not ch.notice_due(100.0)  # the autopilot not heard yet
    ch.heard(0.0)
    ch.heard(5.0)  # only the first counts
    due = [t for t in np.arange(0.0, 30.0, 0.5) if ch.notice_due(float(t))]
    assert due == [3.0, 13.0, 23.0] and ch.notices == 3
    ch.offer(_c("--origin"), 30.0)
    assert not ch.notice_due(40.0)


def test_start_fix_carried_to_the_first_imu_sample() -> None:
    """A GNSS origin read 0.5 s before the first IMU sample of a rover doing 5 m/s east: the Localiser starts
    2.5 m east (grid), not where the fix was; a far fix from home starts there; no carry beyond 2 s."""
    from taco_mav.config import localiser_params, profile_from_dict
    from taco_mav.daemon.anchor import LocaliserAnchor

    a = LocaliserAnchor(localiser_params(profile_from_dict({})))
    origin = a.set_origin(49.0, 8.4, 115.0, 5.0, math.pi / 2)
    a.set_start((0.0, 0.0), 5.0, math.pi / 2, None, t=10.0)
    est = a.localiser(10.5, math.pi / 2).estimate()
    assert est.xy == pytest.approx([2.5 * math.cos(origin.convergence), 2.5 * math.sin(origin.convergence)], abs=1e-6)
    assert est.speed == pytest.approx(5.0)
    a.set_start((30.0, -4.0), 0.0, None, 1.5, t=10.0)
    est = a.localiser(13.0, 0.0).estimate()
    assert est.xy == pytest.approx([30.0, -4.0]) and est.sigma_h == pytest.approx(1.5, rel=0.05)
