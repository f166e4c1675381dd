"""3-D synthetic worlds (`--realism 3d`): occlusion in the camera renderer, the aerial map's georeferencing
error, the appearance gap between a camera frame and an IPM of the map, and the world as every reader sees it."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio

from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.sources import FrameGuard, open_camera
from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic import build_world, load_world
from taco_mav.datasets.synthetic.layout import Building, Scene
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.datasets.synthetic.render3d import GlRenderer3D, Lighting
from taco_mav.datasets.synthetic.scene3d import Mat, build_scene3d, moving_cars_at
from taco_mav.datasets.synthetic.world3d import AERIAL_M_PER_PX, WorldRenderer3D, lightings, render_aerial

pytest.importorskip("moderngl")


@pytest.fixture(scope="module")
def world3d(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_world(tmp_path_factory.mktemp("w3d") / "w", seed=5, length_km=0.3, progress=False, realism="3d")


def _box_scene(with_front: bool) -> Scene:
    """A 10 m cube 20..30 m east of the origin (optional) in front of a 30 m tower 50..60 m east."""
    def rect(x0: float, x1: float, h: float, colour: tuple[int, int, int]) -> Building:
        return Building(corners=np.array([[x0, -5.0], [x1, -5.0], [x1, 5.0], [x0, 5.0]]), height_m=h,
                        colour=colour, gable=False)

    blds = [rect(50.0, 60.0, 30.0, (40, 40, 200))] + ([rect(20.0, 30.0, 10.0, (200, 40, 40))] if with_front else [])
    return Scene(extent=(-100.0, -100.0, 100.0, 100.0), roads=[], junctions=np.zeros((0, 2)),
                 junction_style=np.zeros(0, int), junction_radius=np.zeros(0), buildings=blds)


def _gl(scene: Scene) -> GlRenderer3D:
    ground = np.full((200, 200, 3), 120, np.uint8)
    return GlRenderer3D(build_scene3d(scene, np.random.default_rng(0)), ground, (-100.0, 100.0), 1.0, shadow_px=1024)


def test_facade_occludes_what_is_behind() -> None:
    """Looking east along y = 0 from 1.65 m: the optical-axis depth at the principal point is the front
    facade's 20 m with the cube, the tower's 50 m without it, and the pixel's colour changes with it."""
    cam = GroundCamera.from_config(CameraConfig(), scale=0.5)
    u, v = int(round(cam.K[0, 2])), int(round(cam.K[1, 2]))
    out = {}
    for front in (True, False):
        gl = _gl(_box_scene(front))
        try:
            out[front] = gl.render_camera(cam, (0.0, 0.0, 0.0), depth=True, light=Lighting(sun_az_deg=270.0))
        finally:
            gl.close()
    (rgb_f, d_f), (rgb_b, d_b) = out[True], out[False]
    assert d_f[v, u] == pytest.approx(20.0, abs=0.05)
    assert d_b[v, u] == pytest.approx(50.0, abs=0.1)
    assert np.abs(rgb_f[v, u].astype(int) - rgb_b[v, u].astype(int)).sum() > 30
    # the top rows see sky (infinite depth); the bottom row sees the ground plane at h / tan(angle below axis)
    assert np.isinf(d_b[0, :40]).all() and np.isfinite(d_b[0, u])  # the tower reaches the top row
    ground_fwd = cam.mount_height_m * cam.K[1, 1] / (cam.height - 1 - cam.K[1, 2])
    assert d_b[-1, 0] == pytest.approx(ground_fwd, rel=0.01)


def test_aerial_roofs_lean_but_the_ground_stays() -> None:
    """render_ortho's lean: the 10 m cube's red roof moves lean x 10 m (0.1 -> 1 m east), its centroid
    measured to a tenth of a metre; with no lean the roof sits on its footprint (x 20..30 m)."""
    gl = _gl(_box_scene(True))
    res, cx = 0.1, []
    try:
        for lean in ((0.0, 0.0), (0.1, 0.0)):
            img = gl.render_ortho(10.0, 10.0, 300, 200, res, epoch="camera", light=Lighting(sun_elev_deg=89.0),
                                  lean=lean).astype(int)
            roof = (img[:, :, 0] > img[:, :, 2] + 60) & (img[:, :, 0] > img[:, :, 1] + 60)
            cols = np.nonzero(roof)[1]
            cx.append(10.0 + (cols.mean() + 0.5) * res)
    finally:
        gl.close()
    assert cx[0] == pytest.approx(25.0, abs=0.1)
    assert cx[1] - cx[0] == pytest.approx(1.0, abs=0.1)


def test_scene3d_deterministic_and_epochs_differ(world3d: Path) -> None:
    """Same seed, same meshes; the aerial day's parked cars are partly the camera day's (STAY), not all."""
    a, b = (build_scene3d(_box_scene(True), np.random.default_rng(7)).static for _ in range(2))
    assert np.array_equal(a.interleaved(), b.interleaved())
    with np.load(world3d / "scene3d.npz") as z:
        static = z["static"]
        cars = {k: z[f"parked_{k}"] for k in ("camera", "aerial")}
    assert len(static) > 3000
    assert set(np.unique(static[:, 9]).astype(int)) >= {Mat.WALL, Mat.ROOF, Mat.FOLIAGE, Mat.TRUNK, Mat.METAL}

    def centres(m: np.ndarray) -> set[tuple[float, float]]:
        shadow = m[m[:, 9] == Mat.CONTACT_SHADOW, :2].reshape(-1, 6, 2).mean(axis=1)  # one quad per car
        return {(round(float(x), 1), round(float(y), 1)) for x, y in shadow}

    c_cam, c_aer = centres(cars["camera"]), centres(cars["aerial"])
    assert len(c_cam) >= 3 and c_cam != c_aer and len(c_cam & c_aer) >= 1


def test_objects_keep_clear_of_the_ego_path_and_cars_move(world3d: Path) -> None:
    """Nothing below crown height (2 m) stands within 1 m of the driven path; moving cars advance at their
    speed and never come within 3 m of the ego vehicle at a frame time."""
    drive = load_world(world3d)
    path = drive.truth.xy
    from scipy.spatial import cKDTree

    with np.load(world3d / "scene3d.npz") as z:
        from taco_mav.datasets.synthetic.scene3d import Scene3D

        s3 = Scene3D.from_npz(z)
    low = np.vstack([m.pos[(m.pos[:, 2] < 2.0) & (m.mat != Mat.CONTACT_SHADOW)] for m in (s3.static, s3.parked["camera"])])
    origin_local = drive.origin_utm - np.asarray(drive.meta["centre_utm"])
    dist, _ = cKDTree(path + origin_local).query(low[:, :2])
    assert dist.min() > 1.0
    mc = s3.moving
    if len(mc):
        p0, p1 = moving_cars_at(mc, 10.0), moving_cars_at(mc, 10.5)
        step = np.hypot(*(p1[:, :2] - p0[:, :2]).T)
        ok = step < 0.6 * mc.speed  # not wrapping at a road's end
        assert np.allclose(step[ok], 0.5 * mc.speed[ok], rtol=0.05)
        t = drive.frame_times
        poses = moving_cars_at(mc, t)
        ego = np.array([drive.truth.pose_at(float(x))[:2] for x in t]) + origin_local
        assert np.min(np.linalg.norm(poses[:, :, :2] - ego[None], axis=2)) > 2.9


def test_world3d_loads_through_the_existing_readers(world3d: Path) -> None:
    """world.json, the GeoTIFF (rasterio: RGB uint8, 0.3 m/px, UTM), the drive (KITTI reader), frames."""
    meta = json.loads((world3d / "world.json").read_text())
    assert meta["realism"] == "3d" and meta["m_per_px"] == AERIAL_M_PER_PX
    with rasterio.open(world3d / meta["mosaic"]) as src:
        assert src.count == 3 and src.dtypes[0] == "uint8" and src.crs.to_epsg() == meta["crs_epsg"]
        assert src.res == pytest.approx((0.3, 0.3))
    drive = load_world(world3d)
    assert len(drive.imu) == len(drive.truth.t) and len(drive.frame_times) > 100
    img = drive.frame(50)
    assert img.shape == (375, 1242, 3) and img.dtype == np.uint8
    sky = img[:10].reshape(-1, 3).mean(axis=0)
    assert sky[2] > sky[0] + 20  # blue sky at the top
    assert img[200:].std() > 10  # textured ground and objects below the horizon
    # the live daemon's camera source renders the same frame at the same pose
    src = open_camera(f"world:{world3d}", drive.camera)
    try:
        t = float(drive.frame_times[50])
        lat, lon = (float(v) for v in drive.kitti.oxts[int(round(t * 100)), :2])
        yaw_ned = math.pi / 2 - drive.truth.pose_at(t)[2] + float(src.projector.grid_convergence(lat, lon))
        src.feed_pose(t, lat, lon, yaw_ned)
        got = FrameGuard(drive.camera.width, drive.camera.height, 0.2, check_frozen=False).check(src.frame_near(t, 0.1), t)
        assert got[1].shape == img.shape
        assert np.abs(got[1].astype(float) - img.astype(float)).mean() < 8.0
    finally:
        src.close()


def test_aerial_georeferencing_offset_matches_metadata(world3d: Path) -> None:
    """The mosaic shows the scene displaced by world.json's georef_offset_m (within one 0.3 m pixel): phase
    correlation of a 512 px window against the same window rendered without the offset."""
    meta = json.loads((world3d / "world.json").read_text())
    aer = meta["aerial"]
    offset = np.asarray(aer["georef_offset_m"])
    assert 0.7 < np.linalg.norm(offset) < 1.3
    drive = load_world(world3d)
    r = WorldRenderer3D(world3d, drive.camera, meta)
    with rasterio.open(world3d / meta["mosaic"]) as src:
        mosaic = src.read().transpose(1, 2, 0)
        tr = src.transform
    c0, r0, n = mosaic.shape[1] // 2 - 256, mosaic.shape[0] // 2 - 256, 512
    x0 = tr.c + c0 * tr.a - meta["centre_utm"][0]
    y1 = tr.f + r0 * tr.e - meta["centre_utm"][1]
    light = Lighting(**{k: tuple(v) if isinstance(v, list) else v for k, v in aer["light"].items()})
    try:
        true = render_aerial(r.gl, x0, y1, n, n, AERIAL_M_PER_PX, np.zeros(2), light, aer["moving_cars_t_s"],
                             np.random.default_rng(0), tuple(aer["lean_m_per_m"]))
    finally:
        r.close()
    grey = lambda a: cv2.cvtColor(a, cv2.COLOR_RGB2GRAY).astype(np.float64)  # noqa: E731
    win = cv2.createHanningWindow((n, n), cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(grey(true), grey(mosaic[r0:r0 + n, c0:c0 + n]), win)
    expect = offset[0] / AERIAL_M_PER_PX, -offset[1] / AERIAL_M_PER_PX  # north-up: +y is up the rows
    assert abs(dx - expect[0]) < 1.0 and abs(dy - expect[1]) < 1.0, ((dx, dy), expect)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def test_camera_frame_differs_from_an_ipm_of_the_mosaic(world3d: Path) -> None:
    """The appearance gap: below the horizon, a 3d world's frame and the flat IPM of its own mosaic at the
    same pose correlate weakly (a flat world's frame IS that IPM, correlation 1), and a measurable share of
    the ground-plane pixels is hidden by objects standing on it."""
    drive = load_world(world3d)
    with rasterio.open(drive.mosaic) as src:
        ipm = GroundRenderer(np.ascontiguousarray(src.read().transpose(1, 2, 0)), src.transform, drive.camera)
    r = WorldRenderer3D(world3d, drive.camera, drive.meta)
    cam = drive.camera
    rows = slice(int(cam.K[1, 2]) + 20, cam.height)
    fwd, _, ground = cam.pixel_ground_points(80.0)
    nccs, hidden = [], []
    try:
        for i in range(40, len(drive.frame_times), max(1, len(drive.frame_times) // 12)):
            t = float(drive.frame_times[i])
            pose = drive.camera_pose(t)
            rgb, depth = r.render_depth(pose, t)
            flat = ipm.render(pose)
            g3, gf = (cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)[rows].astype(np.float64) for x in (rgb, flat))
            nccs.append(_ncc(g3, gf))
            m = ground & (fwd < 60.0)
            hidden.append(float(np.mean(depth[m] < 0.95 * fwd[m])))
            valid = r.ipm_valid(pose, t, 60.0)
            assert not valid[: int(cam.K[1, 2])].any()  # nothing above the horizon is ground
            assert np.mean(~valid[m]) == pytest.approx(hidden[-1], abs=0.02)
    finally:
        r.close()
    assert 0.0 < np.median(nccs) < 0.8, nccs
    assert np.mean(hidden) > 0.02, hidden
    assert max(hidden) > 0.08, hidden


def test_lightings_are_different_days() -> None:
    """The aerial day's sun is at least 20 degrees of azimuth and 5 of elevation away from the camera's."""
    for seed in range(20):
        cam, aer = lightings(np.random.default_rng(seed))
        assert aer.sun_az_deg - cam.sun_az_deg >= 20.0 and cam.sun_elev_deg - aer.sun_elev_deg >= 5.0
        assert aer.season >= 0.5 > cam.season


@pytest.mark.slow
def test_live_taco_plus_on_a_3d_world(world3d: Path) -> None:
    """End to end: the simulator plays the 3d world, the daemon renders its frames through `world:DIR`
    (perspective, occlusion) for the classical matcher, taco+ with profile synthetic_3d (the map's offset as
    states), 30 s at 5x (lockstep). Checked: the autopilot's rate rules, frames reach the matcher and fixes are
    accepted, the track stays within 2 m. (ATE and EKF3 gate passes over whole 1 km drives are measured in
    docs/taco_plus.md, "3-D synthetic worlds, live".)"""
    from tests.test_live import assert_autopilot_accepts_rate, run_live

    seq, summary = run_live(world3d, "synthetic_3d", speed=5.0, camera=f"world:{world3d}", duration_s=30.0,
                            lockstep=True, estimator="taco+")
    assert_autopilot_accepts_rate(seq)
    assert seq["ate_m"] < 2.0 and seq["max_error_m"] < 4.0, seq
    assert summary["fixes"].get("accepted", 0) + summary["fixes"].get("weak", 0) >= 1, summary["fixes"]


def test_realism_is_checked(tmp_path: Path) -> None:
    """An unknown realism and 3d along a real drive are refused before anything is written."""
    from taco_mav.errors import ConfigError

    with pytest.raises(ConfigError, match="realism"):
        build_world(tmp_path / "a", realism="photo", progress=False)
    with pytest.raises(ConfigError, match="along-drive"):
        build_world(tmp_path / "b", along_drive=tmp_path, realism="3d", progress=False)
    assert not (tmp_path / "a" / "world.json").exists() and not (tmp_path / "b").exists()


def test_nothing_stands_on_a_keep_clear_path(tmp_path: Path) -> None:
    """`keep_clear` (a SITL mission's square, metres east/north of the centre): no building footprint within
    KEEP_CLEAR_M of it (wall points), nothing below crown height (2 m: trunks, poles, parked cars) within 1.5 m,
    and world.json records the path."""
    from scipy.spatial import cKDTree

    from taco_mav.datasets.synthetic.layout import KEEP_CLEAR_M
    from taco_mav.datasets.synthetic.scene3d import Scene3D

    square = [(0.0, 0.0), (0.0, 60.0), (60.0, 60.0), (60.0, 0.0), (0.0, 0.0)]
    w = build_world(tmp_path / "w", seed=7, length_km=0.3, centre=(-35.363261, 149.165230), progress=False,
                    realism="3d", keep_clear=[square])
    meta = json.loads((w / "world.json").read_text())
    assert meta["keep_clear_en_m"] == [[list(p) for p in square]]
    # the square in the world's local grid metres (UTM minus the centre's): turned by the meridian convergence
    from taco_mav.geo import UtmProjector

    proj = UtmProjector(meta["crs_epsg"])
    lat0, lon0 = -35.363261, 149.165230
    e0, n0 = meta["centre_utm"]
    r = 6378137.0
    ll = [(lat0 + math.degrees(n / r), lon0 + math.degrees(e / (r * math.cos(math.radians(lat0))))) for e, n in square]
    corners = np.array([np.subtract(proj.to_utm(lat, lon), (e0, n0)) for lat, lon in ll])
    path = np.vstack([a + (b - a) * np.linspace(0, 1, 121)[:, None] for a, b in itertools.pairwise(corners)])
    with np.load(w / "scene3d.npz") as z:
        s3 = Scene3D.from_npz(z)
    meshes = (s3.static, s3.parked["camera"])
    low = np.vstack([m.pos[(m.pos[:, 2] < 2.0) & (m.mat != Mat.CONTACT_SHADOW)] for m in meshes])
    tree = cKDTree(path)
    assert tree.query(low[:, :2])[0].min() > 1.5
    # walls: points spread over each wall triangle (pos holds 3 vertices per triangle), not only its corners
    tri = s3.static.pos[:, :2].reshape(-1, 3, 2)[s3.static.mat[::3] == Mat.WALL]
    assert len(tri)
    ab = np.array([(a, b) for a in np.linspace(0, 1, 7) for b in np.linspace(0, 1, 7) if a + b <= 1.0])
    pts = (tri[:, None, 0] * (1 - ab.sum(1))[None, :, None] + tri[:, None, 1] * ab[None, :, :1]
           + tri[:, None, 2] * ab[None, :, 1:]).reshape(-1, 2)
    assert tree.query(pts)[0].min() > KEEP_CLEAR_M
