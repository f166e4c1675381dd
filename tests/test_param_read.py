"""Reading named autopilot parameters once (mavlink/param_read.py), as the daemon reads WENC_POS_Y / WENC2_POS_Y."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.mavlink.param_read import ParamRead


def _value(name: str, value: float):
    tx = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    return apm.MAVLink(None).parse_buffer(bytes(tx.param_value_encode(name.encode(), value, 9, 900, 1).pack(tx)))[0]


def test_asks_for_what_is_missing_until_answered() -> None:
    sent = []
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=191)
    r = ParamRead(sent.append, mav, ("WENC_POS_Y", "WENC2_POS_Y"))
    r.tick(0.0, 1, 1)
    assert [m.param_id for m in sent] == ["WENC_POS_Y", "WENC2_POS_Y"]
    assert r.on_message(_value("WENC_POS_Y", 0.15)) == ("WENC_POS_Y", 0.15000000596046448)
    assert r.on_message(_value("GPS1_TYPE", 14.0)) is None  # not ours
    r.tick(1.0, 1, 1)  # not yet due
    r.tick(2.0, 1, 1)
    assert [m.param_id for m in sent[2:]] == ["WENC2_POS_Y"]
    r.on_message(_value("WENC2_POS_Y", -0.15))
    assert r.complete and r.done and r.values["WENC2_POS_Y"] == -0.15000000596046448
    assert r.on_message(_value("WENC2_POS_Y", 3.0)) is None  # answered once


def test_gives_up_after_its_tries() -> None:
    sent = []
    r = ParamRead(sent.append, apm.MAVLink(None), ("WENC_POS_Y",), retry_s=1.0, tries=2)
    gave_up = [r.tick(now, 1, 1) for now in (0.0, 1.0, 2.0, 3.0)]
    assert gave_up == [[], ["WENC_POS_Y"], [], []]  # the last round says what stays unanswered, once
    assert len(sent) == 2 and r.done and not r.complete


def test_a_value_under_two_names_counts_the_first_answer() -> None:
    """A value renamed by a firmware release (GPS_TYPE before ArduPilot 4.6, GPS1_TYPE after): both names are
    asked for until one answers; the value is kept under the first name, with the name that answered. A
    non-finite answer is not taken."""
    sent = []
    r = ParamRead(sent.append, apm.MAVLink(None), [("GPS1_TYPE", "GPS_TYPE"), "WENC_POS_Y"])
    r.tick(0.0, 1, 1)
    assert [m.param_id for m in sent] == ["GPS1_TYPE", "GPS_TYPE", "WENC_POS_Y"]
    assert r.on_message(_value("GPS_TYPE", float("nan"))) is None and r.missing == ["GPS1_TYPE", "WENC_POS_Y"]
    assert r.on_message(_value("GPS_TYPE", 14.0)) == ("GPS1_TYPE", 14.0)
    assert r.on_message(_value("GPS1_TYPE", 1.0)) is None  # the other name answering later changes nothing
    assert r.values == {"GPS1_TYPE": 14.0} and r.answered_by == {"GPS1_TYPE": "GPS_TYPE"}
    r.tick(2.0, 1, 1)
    assert [m.param_id for m in sent[3:]] == ["WENC_POS_Y"]
