"""Tests of taco_mav.datasets.kitti: exact conversions on tiny drives written here, strict refusal of broken
files, and the sign conventions proven on the real KITTI OXTS drives."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from scipy.spatial.transform import Rotation

from taco_mav.config import load_profile
from taco_mav.datasets.kitti import (ODOMETRY_SEQUENCES, OXTS, OXTS_FIELDS, KittiDrive, default_kitti_root, load_drive,
                                     load_sequence)
from taco_mav.datasets.kitti_io import camera_position_frd_m
from taco_mav.errors import DataError
from taco_mav.geo import UtmProjector, enu_from_ned_yaw, grid_convergence, wrap_angle

DATE = "2011_09_30"
T0_UNIX = 1317383679.239671138
CALIB = (
    "calib_time: 09-Jan-2012 13:57:47\n"
    "S_rect_02: 1.200000e+01 8.000000e+00\n"
    "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 "
    "1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03\n"
)
# A drive heading along ENU 30 deg at 10 m/s, starting 1 km east of KITTI 0018's frame 0.
E0, N0, HEADING, SPEED = 456909.0, 5433136.0, math.radians(30.0), 10.0


def stamp(i: int, dt_ms: int = 100) -> str:
    ns = 239671138 + i * dt_ms * 1_000_000
    return f"2011-09-30 11:54:{39 + ns // 1_000_000_000:02d}.{ns % 1_000_000_000:09d}"


def oxts_rows(n: int) -> np.ndarray:
    """(n, 30) OXTS packets for the straight drive; attitude and IMU fields hold recognisable constants."""
    proj = UtmProjector(32632)
    s = SPEED * 0.1 * np.arange(n)
    lat, lon = proj.to_latlon(E0 + s * math.cos(HEADING), N0 + s * math.sin(HEADING))
    rows = np.zeros((n, len(OXTS_FIELDS)))
    rows[:, OXTS["lat"]], rows[:, OXTS["lon"]], rows[:, OXTS["alt"]] = lat, lon, 113.0
    rows[:, OXTS["roll"]], rows[:, OXTS["pitch"]], rows[:, OXTS["yaw"]] = 0.01, 0.02, HEADING
    rows[:, OXTS["vn"]], rows[:, OXTS["ve"]] = SPEED * math.sin(HEADING), SPEED * math.cos(HEADING)
    rows[:, [OXTS["ax"], OXTS["ay"], OXTS["az"]]] = [0.1, 0.2, 9.8]
    rows[:, [OXTS["wx"], OXTS["wy"], OXTS["wz"]]] = [0.01, 0.02, 0.03]
    rows[:, OXTS["navstat"]:] = [4, 9, 5, 5, 6]
    return rows


def write_drive(root: Path, n: int = 6, drive: int = 18, images: bool = False, calib: bool = False,
                image_size: tuple[int, int] = (12, 8)) -> Path:
    """A KITTI-layout drive under root; returns the drive folder."""
    drive_dir = root / DATE / f"{DATE}_drive_{drive:04d}_sync"
    (drive_dir / "oxts" / "data").mkdir(parents=True)
    (drive_dir / "oxts" / "timestamps.txt").write_text("".join(stamp(i) + "\n" for i in range(n)))
    for i, row in enumerate(oxts_rows(n)):
        (drive_dir / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(repr(float(v)) for v in row) + "\n")
    if images:
        (drive_dir / "image_02" / "data").mkdir(parents=True)
        (drive_dir / "image_02" / "timestamps.txt").write_text("".join(stamp(i, 100) + "\n" for i in range(n)))
        w, h = image_size
        for i in range(n):
            rgb = np.zeros((h, w, 3), np.uint8)
            rgb[..., 0] = 200  # red
            rgb[..., 2] = i  # frame index in blue
            cv2.imwrite(str(drive_dir / "image_02" / "data" / f"{i:010d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if calib:
        (root / DATE / "calib_cam_to_cam.txt").write_text(CALIB)
    return drive_dir


# ------------------------------------------------------------------------------ conversions, tiny drives

def test_tiny_drive_exact_conversions(tmp_path: Path) -> None:
    d = load_drive(write_drive(tmp_path, n=6))
    assert isinstance(d, KittiDrive) and d.name == "2011_09_30_drive_0018" and d.sequence is None and len(d) == 6
    assert np.allclose(d.imu.t, np.arange(6) * 0.1, atol=1e-9) and d.imu.t[0] == 0.0
    assert d.t0_unix == pytest.approx(T0_UNIX, abs=1e-6)
    assert np.allclose(d.imu.accel_frd, [0.1, -0.2, -9.8])  # FLU -> FRD: y, z negated
    assert np.allclose(d.imu.gyro_frd, [0.01, -0.02, -0.03])
    assert np.allclose(d.imu.rpy_ned, [0.01, -0.02, math.pi / 2 - HEADING])  # roll same, pitch negated
    assert d.utm_epsg == 32632
    assert np.allclose(d.origin_utm, [E0, N0], atol=1e-3)
    s = SPEED * 0.1 * np.arange(6)
    assert np.allclose(d.truth.xy, np.c_[s * math.cos(HEADING), s * math.sin(HEADING)], atol=1e-3)
    gamma = grid_convergence(d.start.lat, d.start.lon)
    assert d.convergence_rad == pytest.approx(gamma) and -0.01 < gamma < 0.0
    assert np.allclose(d.truth.heading, HEADING + gamma)  # true yaw turned onto the UTM grid
    assert d.start.t == 0.0 and d.start.alt == 113.0
    assert d.start.speed == pytest.approx(SPEED) and d.start.course == pytest.approx(HEADING)
    assert d.frame_times.shape == (0,) and d.camera is None and d.mosaic is None
    assert d.oxts.shape == (6, 30) and np.allclose(d.t_unix - d.t0_unix, d.imu.t, atol=1e-6)
    with pytest.raises(DataError, match="no camera images"):
        d.frame(0)


def test_frame_slice_resets_origin_and_time(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=8)
    d = load_drive(drive_dir, slice(2, 5))
    assert len(d) == 3 and d.first_index == 2 and d.imu.t[0] == 0.0
    assert d.t0_unix == pytest.approx(T0_UNIX + 0.2, abs=1e-6)
    assert np.allclose(d.origin_utm, [E0 + 2 * math.cos(HEADING), N0 + 2 * math.sin(HEADING)], atol=1e-3)
    assert np.allclose(d.truth.xy[0], 0.0) and d.truth.length_m() == pytest.approx(2.0, abs=1e-3)
    for bad in (slice(5, 9), slice(4, 4), slice(0, 6, 2)):
        with pytest.raises(DataError):
            load_drive(drive_dir, bad)


def test_images_and_calib(tmp_path: Path) -> None:
    d = load_drive(write_drive(tmp_path, n=4, images=True, calib=True), slice(1, 4))
    assert np.allclose(d.frame_times, [0.0, 0.1, 0.2], atol=1e-9)
    cam = d.camera
    assert cam is not None and (cam.width, cam.height) == (12, 8) and cam.mount_height_m == 1.65
    assert np.allclose(cam.K, [[721.5377, 0, 609.5593], [0, 721.5377, 172.854], [0, 0, 1]])
    img = d.frame(1)  # raw frame 2
    assert img.dtype == np.uint8 and img.shape == (8, 12, 3)
    assert tuple(img[0, 0]) == (200, 0, 2)  # RGB order, the right file
    with pytest.raises(DataError, match="out of range"):
        d.frame(3)
    assert load_drive(d.path, camera_height_m=2.0).camera.mount_height_m == 2.0


def test_image_size_must_match_calib(tmp_path: Path) -> None:
    d = load_drive(write_drive(tmp_path, n=2, images=True, calib=True, image_size=(10, 8)))
    with pytest.raises(DataError, match="10x8 px, calibration says 12x8"):
        d.frame(0)


def test_world_json_names_the_mosaic(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=3)
    tif = tmp_path / "map.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=4, height=4, count=3, dtype="uint8", crs="EPSG:32632",
                       transform=Affine(1.0, 0.0, E0 - 2.0, 0.0, -1.0, N0 + 2.0)) as dst:
        dst.write(np.zeros((3, 4, 4), np.uint8))
    # In the dataset root (the synthetic world's layout), with the drive named.
    (tmp_path / "world.json").write_text(json.dumps({"mosaic": "map.tif", "drive": "2011_09_30_drive_0018_sync",
                                                     "seed": 3}))
    assert load_drive(drive_dir).mosaic == tif.resolve()
    # A world.json for another drive is ignored.
    (tmp_path / "world.json").write_text(json.dumps({"mosaic": "map.tif", "drive": "2011_09_30_drive_0099"}))
    assert load_drive(drive_dir).mosaic is None
    # The nearest world.json wins; a broken one is refused, naming the file.
    (tmp_path / DATE / "world.json").write_text(json.dumps({"mosaic": "../map.tif"}))
    assert load_drive(drive_dir).mosaic == tif.resolve()
    (drive_dir / "world.json").write_text(json.dumps({"mosaic": "missing.tif"}))
    with pytest.raises(DataError, match=r"world.json: mosaic 'missing.tif' not found"):
        load_drive(drive_dir)
    (drive_dir / "world.json").write_text("{not json")
    with pytest.raises(DataError, match="world.json: not readable JSON"):
        load_drive(drive_dir)
    (drive_dir / "world.json").write_text(json.dumps({"drive": "2011_09_30_drive_0018"}))
    with pytest.raises(DataError, match='key "mosaic"'):
        load_drive(drive_dir)


# ---------------------------------------------------------------------------------------- refusals

def test_missing_and_mismatched_files(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="drive folder not found"):
        load_drive(tmp_path / "nope")
    drive_dir = write_drive(tmp_path, n=4)
    stamps = drive_dir / "oxts" / "timestamps.txt"
    stamps.write_text("".join(stamp(i) + "\n" for i in range(3)))
    with pytest.raises(DataError, match="holds 4 OXTS files but timestamps.txt has 3 lines"):
        load_drive(drive_dir)
    stamps.write_text("".join(stamp(i) + "\n" for i in range(5)))
    with pytest.raises(DataError, match="holds 4 OXTS files but timestamps.txt has 5 lines"):
        load_drive(drive_dir)
    stamps.unlink()
    with pytest.raises(DataError, match=r"timestamps.txt: timestamps file not found"):
        load_drive(drive_dir)


def test_renamed_packet_is_missing(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=4)
    data = drive_dir / "oxts" / "data"
    (data / "0000000002.txt").rename(data / "0000000007.txt")
    with pytest.raises(DataError, match=r"0000000002.txt: OXTS packet file not found"):
        load_drive(drive_dir)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("1 2 3\n", r"0000000001.txt, line 1: expected 30 OXTS fields, found 3"),
        ("", r"0000000001.txt, line 1: empty OXTS packet"),
        (" ".join(["1"] * 30) + "\n" + " ".join(["1"] * 30) + "\n", r"0000000001.txt, line 2: expected one OXTS line"),
        (" ".join(["1"] * 5 + ["abc"] + ["1"] * 24), r"0000000001.txt, line 1: field 6 \(yaw\) is not a number: 'abc'"),
        (" ".join(["1"] * 3 + ["nan"] + ["1"] * 26), r"0000000001.txt, line 1: non-finite navigation value"),
    ],
)
def test_malformed_oxts_line(tmp_path: Path, content: str, message: str) -> None:
    drive_dir = write_drive(tmp_path, n=3)
    (drive_dir / "oxts" / "data" / "0000000001.txt").write_text(content)
    with pytest.raises(DataError, match=message):
        load_drive(drive_dir)


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        ([stamp(0), stamp(1), "2011-09-30 xx:54:39.4"], r"timestamps.txt, line 3: not a KITTI timestamp"),
        ([stamp(0), "", stamp(2)], r"timestamps.txt, line 2: not a KITTI timestamp"),
        ([stamp(0), stamp(2), stamp(1)], r"timestamps.txt, line 3: time goes backwards"),
    ],
)
def test_malformed_timestamps(tmp_path: Path, lines: list[str], message: str) -> None:
    drive_dir = write_drive(tmp_path, n=3)
    (drive_dir / "oxts" / "timestamps.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=message):
        load_drive(drive_dir)


def test_images_without_oxts_are_refused(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=2, images=True)
    for f in (drive_dir / "oxts" / "data").iterdir():
        f.unlink()
    (drive_dir / "oxts" / "data").rmdir()
    (drive_dir / "oxts" / "timestamps.txt").unlink()
    (drive_dir / "oxts").rmdir()
    with pytest.raises(DataError, match="OXTS folder not found .image_02 is present"):
        load_drive(drive_dir)


def test_image_counts_must_match(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=3, images=True)
    (drive_dir / "image_02" / "timestamps.txt").write_text(stamp(0) + "\n" + stamp(1) + "\n")
    with pytest.raises(DataError, match="2 image timestamps but 3 OXTS packets"):
        load_drive(drive_dir)
    (drive_dir / "image_02" / "timestamps.txt").write_text("".join(stamp(i) + "\n" for i in range(3)))
    (drive_dir / "image_02" / "data" / "0000000002.png").unlink()
    with pytest.raises(DataError, match="2 PNG files but 3 frames"):
        load_drive(drive_dir)


def test_calib_without_p_rect_02_is_refused(tmp_path: Path) -> None:
    drive_dir = write_drive(tmp_path, n=2)
    (tmp_path / DATE / "calib_cam_to_cam.txt").write_text("S_rect_02: 1242 375\nP_rect_00: 1 2 3\n")
    with pytest.raises(DataError, match="calib_cam_to_cam.txt: key P_rect_02 missing"):
        load_drive(drive_dir)
    (tmp_path / DATE / "calib_cam_to_cam.txt").write_text(CALIB.replace("1.200000e+01 8", "1.2e+01 x"))
    with pytest.raises(DataError, match="key S_rect_02: not all values are numbers"):
        load_drive(drive_dir)


def test_sequence_table_and_lookup_errors(tmp_path: Path) -> None:
    assert len(ODOMETRY_SEQUENCES) == 11
    assert ODOMETRY_SEQUENCES["08"].frames == slice(1100, 5171)
    assert ODOMETRY_SEQUENCES["05"].drive_name == "2011_09_30_drive_0018"
    with pytest.raises(DataError, match="unknown KITTI odometry sequence '11' .known: 00, 01, 02"):
        load_sequence(tmp_path, "11")
    with pytest.raises(DataError, match=r"2011_10_03/2011_10_03_drive_0027_sync: drive folder for KITTI odometry "
                                        r"sequence 00 not found"):
        load_sequence(tmp_path, "0")
    write_drive(tmp_path, n=5, drive=16)  # odometry 04 wants frames 0..270
    with pytest.raises(DataError, match=r"frames 0..270 asked for, the drive has frames 0..4"):
        load_sequence(tmp_path, "04")


# ------------------------------------------------------------------------------------- real KITTI OXTS

def test_sequence_05_from_real_data(kitti_root: Path) -> None:
    d = load_sequence(kitti_root, "5")
    assert d.sequence == "05" and d.name == "2011_09_30_drive_0018" and len(d) == 2761
    assert 286.0 < d.imu.t[-1] < 289.0 and 2100.0 < d.truth.length_m() < 2300.0
    assert d.utm_epsg == 32632 and np.allclose(d.origin_utm, [455909.404, 5433136.019], atol=1e-3)
    assert d.t0_unix == pytest.approx(T0_UNIX, abs=1e-6)
    assert d.start.speed == pytest.approx(math.hypot(5.3746291625744, -0.90447053873548))
    assert d.start.course == pytest.approx(math.atan2(5.3746291625744, -0.90447053873548))
    assert len(load_drive(d.path)) == 2762  # the raw drive has one frame more than the sequence


REAL_DRIVES = ["2011_09_26/2011_09_26_drive_0005", "2011_09_26/2011_09_26_drive_0009",
               "2011_09_30/2011_09_30_drive_0016", "2011_09_30/2011_09_30_drive_0018",
               "2011_09_30/2011_09_30_drive_0027", "2011_09_30/2011_09_30_drive_0033"]


def _gravity_residual(d: KittiDrive, rpy_ned: np.ndarray) -> np.ndarray:
    """|measured FRD specific force - R(rpy)^T (a_ned - g)| per sample, m/s^2, with a_ned from OXTS velocity."""
    v_ned = d.oxts[:, [OXTS["vn"], OXTS["ve"], OXTS["vu"]]] * [1.0, 1.0, -1.0]
    a_ned = np.gradient(v_ned, d.imu.t, axis=0)
    body_from_ned = Rotation.from_euler("ZYX", rpy_ned[:, ::-1]).inv()
    return np.linalg.norm(d.imu.accel_frd - body_from_ned.apply(a_ned - [0.0, 0.0, 9.81]), axis=1)


@pytest.mark.parametrize("drive", REAL_DRIVES)
def test_attitude_signs_explain_the_measured_specific_force(kitti_root: Path, drive: str) -> None:
    d = load_drive(kitti_root / f"{drive}_sync")
    rpy = d.imu.rpy_ned
    residual = _gravity_residual(d, rpy).mean()
    assert residual < 0.25
    # Each wrong sign convention explains the data clearly worse.
    assert _gravity_residual(d, rpy * [1, -1, 1]).mean() > residual + 0.08  # pitch not negated
    assert _gravity_residual(d, rpy * [-1, 1, 1]).mean() > residual + 0.15  # roll negated
    assert _gravity_residual(d, np.c_[rpy[:, :2], d.oxts[:, OXTS["yaw"]]]).mean() > residual + 0.2  # ENU yaw
    # Theta_ENU round-trips through the NED yaw; the NED yaw rate is the FRD z rate.
    assert np.allclose(wrap_angle(enu_from_ned_yaw(rpy[:, 2]) - d.oxts[:, OXTS["yaw"]]), 0.0, atol=1e-12)
    yaw_rate = np.gradient(np.unwrap(rpy[:, 2]), d.imu.t)
    assert np.corrcoef(yaw_rate, d.imu.gyro_frd[:, 2])[0, 1] > 0.9


@pytest.mark.parametrize("drive", REAL_DRIVES)
def test_truth_heading_and_velocity_agree_with_the_utm_track(kitti_root: Path, drive: str) -> None:
    d = load_drive(kitti_root / f"{drive}_sync")
    step = np.diff(d.truth.xy, axis=0)
    moving = np.linalg.norm(step, axis=1) > 0.5
    track = np.arctan2(step[:, 1], step[:, 0])
    mid = np.angle(np.exp(1j * d.truth.heading[:-1]) + np.exp(1j * d.truth.heading[1:]))
    off = wrap_angle(track - mid)[moving]
    assert abs(np.degrees(np.median(off))) < 0.4 and np.degrees(np.median(np.abs(off))) < 1.2
    vel_grid = Rotation.from_euler("z", d.convergence_rad).apply(
        np.c_[d.oxts[:, OXTS["ve"]], d.oxts[:, OXTS["vn"]], np.zeros(len(d))])[:, :2]
    assert np.median(np.abs(np.gradient(d.truth.xy, d.imu.t, axis=0) - vel_grid)) < 0.1


def test_vehicle_at_rest_reads_minus_g_on_frd_z(kitti_root: Path) -> None:
    rest = []
    for drive in REAL_DRIVES:
        d = load_drive(kitti_root / f"{drive}_sync")
        still = np.hypot(d.oxts[:, OXTS["vn"]], d.oxts[:, OXTS["ve"]]) < 0.05
        rest.append((d.imu.accel_frd[still], d.imu.gyro_frd[still]))
    accel = np.concatenate([a for a, _ in rest])
    gyro = np.concatenate([g for _, g in rest])
    assert len(accel) > 100  # 0009, 0018, 0027 stop at traffic lights
    assert np.mean(accel[:, 2]) == pytest.approx(-9.81, abs=0.1)
    assert np.all(accel[:, 2] < -9.5)
    assert np.percentile(np.abs(accel[:, :2]), 95) < 0.5  # a few samples still brake to the stop
    assert np.mean(np.linalg.norm(accel, axis=1)) == pytest.approx(9.81, abs=0.05)
    assert np.percentile(np.abs(gyro), 95) < 0.01 and np.max(np.abs(gyro)) < 0.06  # rocking after braking


@pytest.mark.parametrize("drive", REAL_DRIVES[:2])
def test_2011_09_26_drives_have_the_calibrated_camera(kitti_root: Path, drive: str) -> None:
    d = load_drive(kitti_root / f"{drive}_sync")
    assert d.camera is not None and (d.camera.width, d.camera.height) == (1242, 375)
    assert d.camera.K[0, 0] == pytest.approx(721.5377) and d.camera.K[1, 1] == pytest.approx(721.5377)
    assert d.camera.K[0, 2] == pytest.approx(609.5593) and d.camera.K[1, 2] == pytest.approx(172.854)
    assert d.frame_times.shape == (0,)  # OXTS only in the shared copy


def test_default_kitti_root_honours_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACO_KITTI_ROOT", str(tmp_path))
    assert default_kitti_root() == tmp_path
    monkeypatch.setenv("TACO_KITTI_ROOT", str(tmp_path / "absent"))
    assert default_kitti_root() is None


def test_kitti_profile_lever_arm_is_the_calibrations(kitti_root: Path) -> None:
    """vehicle_profiles/kitti.yaml camera.position_frd_m = image_02's optical centre in the OXTS frame computed from
    2011_09_26's imu_to_velo, velo_to_cam, R_rect_00 and P_rect_02 (within 2 cm): about 1.08 m ahead, 0.25 m
    right and 0.73 m above the OXTS unit."""
    computed = camera_position_frd_m(kitti_root / "2011_09_26")
    assert computed == pytest.approx([1.0805, 0.2500, -0.7293], abs=1e-3)
    profile = load_profile("kitti").camera.position_frd_m
    assert np.max(np.abs(np.array(profile) - computed)) < 0.02
    assert np.max(np.abs(np.array(profile) - computed)) < 0.001  # in fact to the millimetre


def test_camera_position_refuses_a_broken_calibration(tmp_path: Path) -> None:
    for name in ("calib_imu_to_velo.txt", "calib_velo_to_cam.txt"):
        (tmp_path / name).write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    (tmp_path / "calib_cam_to_cam.txt").write_text("R_rect_00: 1 0 0 0 1 0 0 0 1\nP_rect_02: 0 0 0 0 0 0 0 0 0 0 0 0\n")
    with pytest.raises(DataError, match="P_rect_02 is singular"):
        camera_position_frd_m(tmp_path)
    (tmp_path / "calib_imu_to_velo.txt").write_text("R: 1 0 0\nT: 0 0 0\n")
    with pytest.raises(DataError, match="calib_imu_to_velo.txt: key R: expected 9 finite numbers"):
        camera_position_frd_m(tmp_path)
