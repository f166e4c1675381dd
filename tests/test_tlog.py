"""A drive read back from a real tlog (pymavlink packets written by TlogWriter): IMU, attitude, GNSS truth on
the autopilot clock, and clear errors for tlogs that cannot be used."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from taco_mav.datasets.tlog import load_tlog
from taco_mav.errors import DataError
from taco_mav.reliability.soak import circle_drive
from tests.sim_helpers import BOOT, UTC, write_tlog


def test_tlog_drive_matches_what_was_recorded(tmp_path: Path) -> None:
    d = circle_drive(60.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    drive = load_tlog(write_tlog(tmp_path / "lap.tlog", d))
    assert drive.name == "lap" and len(drive.imu) == len(d)
    assert np.allclose(drive.imu.t, BOOT + d.t, atol=1e-6)
    assert np.allclose(drive.imu.accel_frd, d.accel_frd, atol=0.01)  # RAW_IMU carries mG
    assert np.allclose(drive.imu.rpy_ned[:, 2], np.angle(np.exp(1j * d.rpy_ned[:, 2])), atol=1e-6)
    gi = np.arange(0, len(d), 2)
    assert len(drive.truth.t) == len(gi)
    assert np.allclose(drive.truth.t, BOOT + d.t[gi], atol=1e-6)  # its own time, not its receive time 0.1 s later
    assert np.allclose(drive.truth.xy, d.truth.xy[gi] - d.truth.xy[0], atol=0.03)  # degE7 is 1 cm
    err = np.angle(np.exp(1j * (drive.truth.heading - d.truth.heading[gi])))
    assert np.abs(err).max() < 1e-3  # course over ground, on the UTM grid
    assert drive.start.speed == pytest.approx(8.0, abs=0.01)
    assert drive.utm_epsg == d.utm_epsg and math.isfinite(drive.convergence_rad)


def test_receiver_truth_keeps_its_own_time_whatever_the_link_did(tmp_path: Path) -> None:
    """Each fix is stamped with its own time (time_usec, the IMU's clock), as the daemon stamps the receiver its
    shadow twin is measured against: receive times that wander 0.05-0.35 s after the fix (a busy link and
    companion) move the truth neither along the track nor in time. Stamped by receive time, the same fixes were
    up to 0.35 s late: 2.8 m (1.75 m RMS) along an 8 m/s track from where the receiver put them."""
    d = circle_drive(60.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    gi = np.arange(0, len(d), 2)
    lags = np.random.default_rng(7).uniform(0.05, 0.35, len(gi))
    drive = load_tlog(write_tlog(tmp_path / "busy.tlog", d, gps_latency_s=lags))
    assert np.allclose(drive.truth.t, BOOT + d.t[gi], atol=1e-6)
    at = np.column_stack([np.interp(drive.truth.t - BOOT, d.t, d.truth.xy[:, k]) for k in (0, 1)])
    assert np.abs(drive.truth.xy - (at - d.truth.xy[0])).max() < 0.03  # degE7 is 1 cm


def test_receiver_on_another_clock_is_stamped_by_its_receive_time(tmp_path: Path) -> None:
    """An autopilot whose fixes carry another clock (here UNIX time) than its IMU: each fix takes its receive time
    on the IMU's clock (the median offset between IMU and receive time), its latency included."""
    d = circle_drive(30.0, rate_hz=10.0)
    drive = load_tlog(write_tlog(tmp_path / "unix.tlog", d, gps_latency_s=0.1, gps_clock_s=UTC - BOOT))
    assert np.allclose(drive.truth.t, BOOT + d.t[::2] + 0.1, atol=1e-6)


def test_tlog_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="nope.tlog: tlog not found"):
        load_tlog(tmp_path / "nope.tlog")
    d = circle_drive(10.0, rate_hz=10.0)
    with pytest.raises(DataError, match="3D fixes .record with GNSS on.*no_3d_fix"):
        load_tlog(write_tlog(tmp_path / "denied.tlog", d, fix=False))
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(bytes(range(256)) * 40)
    with pytest.raises(DataError, match="junk.tlog: fewer than 20 IMU samples"):
        load_tlog(junk)
    with pytest.raises(DataError, match="--imu-message: 'IMU9'"):
        load_tlog(write_tlog(tmp_path / "ok.tlog", d), imu_message="IMU9")


def test_wheel_distance_and_the_wheel_positions_are_read_from_the_tlog(tmp_path: Path) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as apm

    from taco_mav.mavlink.tlog import TlogWriter
    from tests.sim_helpers import BOOT, UTC

    d = circle_drive(30.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    path = write_tlog(tmp_path / "wheels.tlog", d)
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    log = TlogWriter(path)  # appended after the drive: the reader orders by time
    for k in (3, 1, 2, 2):  # out of order and one repeated, as a link may deliver them
        dist = [8.0 * 0.1 * k, 8.0 * 0.1 * k] + [0.0] * 14
        log.write(mav.wheel_distance_encode(int((BOOT + 0.1 * k) * 1e6), 2, dist).pack(mav), UTC + 0.1 * k)
    for name, value in (("WENC_POS_Y", 0.2), ("WENC2_POS_Y", -0.2)):
        log.write(mav.param_value_encode(name.encode(), value, 9, 900, 1).pack(mav), UTC)
    log.close()
    drive = load_tlog(path)
    assert drive.wheels is not None
    assert np.allclose(drive.wheels.t, BOOT + np.array([0.1, 0.2, 0.3]))
    assert np.allclose(drive.wheels.distances[:, 0], [0.8, 1.6, 2.4])
    assert drive.wheels.pos_y_m == pytest.approx((0.2, -0.2))
    assert load_tlog(write_tlog(tmp_path / "none.tlog", d)).wheels is None
