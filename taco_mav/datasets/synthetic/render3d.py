"""Perspective and orthographic rendering of a `Scene3D` with OpenGL 3.3 (moderngl) on a headless EGL context.

On a machine without a GPU, EGL is Mesa's llvmpipe (a multi-threaded LLVM-compiled software rasteriser), so
the same code runs in CI, on a laptop and on a GPU machine. Each frame is two passes: a depth-only pass from
the sun into a shadow map (orthographic, around the view), then the colour pass: a sky gradient, the textured
ground plane, the static meshes, the parked cars of the chosen epoch and the moving cars at time t, lit by
sun (Lambert, 2x2-PCF shadow-map test) and sky, with procedural facade windows and leaf/plaster noise, and
distance haze (GLSL in `shaders3d.py`). Frames are read back as uint8 RGB (row 0 at the top).

Frames: meshes and poses are local ENU metres relative to the world centre (float32 on the GPU; UTM metres
would lose centimetres). Camera: OpenCV pinhole (x right, y down, z forward; pixel centres at integer
coordinates) mounted `mount_height_m` above the ground, pitched down by `pitch_rad`, at pose (x, y, theta)
with theta the heading (0 = east, CCW). All GL calls run on one private thread (an EGL context is current in
one thread at a time), so a renderer may be used from any thread.
"""

from __future__ import annotations

import logging
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.datasets.synthetic.scene3d import CAR_RGB, Scene3D, car_mesh, moving_cars_at
from taco_mav.datasets.synthetic.shaders3d import DEPTH_FS, DEPTH_VS, FS, SKY_FS, SKY_VS, VS
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["Lighting", "GlRenderer3D", "camera_matrices", "gl_info"]

CELL_M = 40.0  # culling cell size, metres
SHADOW_SNAP_M = 20.0  # a camera's shadow map is redrawn when its view centre moves to another 20 m cell

@dataclass(frozen=True)
class Lighting:
    """One day's light. sun_az_deg: azimuth clockwise from north; sun_elev_deg: elevation; season: 0 summer
    (green) .. 1 late autumn (dry grass, brown leaves); exposure: overall gain; haze_m: e-folding distance of
    the camera's distance haze (metres); haze_mix: constant haze share (aerial: atmosphere below the aircraft);
    haze_rgb, sky_rgb: colours in [0, 1]."""

    sun_az_deg: float = 150.0
    sun_elev_deg: float = 50.0
    season: float = 0.0
    exposure: float = 1.0
    haze_m: float = 300.0
    haze_mix: float = 0.0
    haze_rgb: tuple[float, float, float] = (0.78, 0.82, 0.86)
    sky_rgb: tuple[float, float, float] = (0.43, 0.59, 0.82)

    def sun_dir(self) -> np.ndarray:
        """Unit vector towards the sun, local ENU."""
        az, el = math.radians(self.sun_az_deg), math.radians(self.sun_elev_deg)
        return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def camera_matrices(camera: GroundCamera, pose: tuple[float, float, float], near: float = 0.3,
                    far: float = 400.0) -> tuple[np.ndarray, np.ndarray]:
    """(clip-from-local 4x4, eye position (3,)) of the camera at local pose (x, y, theta) metres / ENU rad."""
    x, y, th = (float(v) for v in pose)
    c, s = math.cos(th), math.sin(th)
    sp, cp, h = math.sin(camera.pitch_rad), math.cos(camera.pitch_rad), camera.mount_height_m
    # vehicle (f, l, dz) from local: f = c dx + s dy, l = -s dx + c dy, dz = z - h
    V = np.array([[c, s, 0, -(c * x + s * y)], [-s, c, 0, s * x - c * y], [0, 0, 1, -h], [0, 0, 0, 1]])
    C = np.array([[0, -1, 0, 0], [-sp, 0, -cp, 0], [cp, 0, -sp, 0], [0, 0, 0, 1]])  # OpenCV camera from vehicle
    K, W, H = camera.K, camera.width, camera.height
    P = np.array([[2 * K[0, 0] / W, 2 * K[0, 1] / W, 2 * (K[0, 2] + 0.5) / W - 1, 0],
                  [0, -2 * K[1, 1] / H, 1 - 2 * (K[1, 2] + 0.5) / H, 0],
                  [0, 0, (far + near) / (far - near), -2 * far * near / (far - near)], [0, 0, 1, 0]])
    return P @ C @ V, np.array([x, y, h])


def _light_matrix(sun: np.ndarray, centre: np.ndarray, radius: float, depth: float = 400.0) -> np.ndarray:
    """Orthographic clip-from-local matrix looking down the sun direction at a square of `radius` metres."""
    w = sun / np.linalg.norm(sun)
    u = np.cross([0.0, 0.0, 1.0], w)
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([1.0, 0.0, 0.0])
    v = np.cross(w, u)
    R = np.eye(4)
    R[0, :3], R[1, :3], R[2, :3] = u / radius, v / radius, -w / depth
    T = np.eye(4)
    T[:3, 3] = -np.asarray(centre, np.float64)
    return R @ T


def gl_info() -> dict[str, str]:
    """Renderer and version strings of the headless context (for docs and bench)."""
    import moderngl

    ctx = moderngl.create_standalone_context(backend="egl")
    try:
        return {"renderer": ctx.info["GL_RENDERER"], "version": ctx.info["GL_VERSION"]}
    finally:
        ctx.release()


class GlRenderer3D:
    """A `Scene3D` and its ground texture on a headless OpenGL context.

    ground_rgb: (H, W, 3) uint8, north-up, covering local x0 .. x0 + W r, y1 - H r .. y1 with r metres per
    pixel (`ground_origin` = (x0, y1)); ground_mat: (H, W) uint8 material labels (`mosaic.Material`; grass
    takes the season's tint, yards 40 % of it) or None. shadow_px: shadow-map size; samples: MSAA samples.
    """

    def __init__(self, scene: Scene3D, ground_rgb: np.ndarray, ground_origin: tuple[float, float],
                 ground_m_per_px: float, ground_mat: np.ndarray | None = None, shadow_px: int = 4096,
                 samples: int = 0) -> None:
        if ground_rgb.ndim != 3 or ground_rgb.shape[2] != 3 or ground_rgb.dtype != np.uint8:
            raise DataError(f"ground texture must be uint8 RGB (H, W, 3), got {ground_rgb.dtype} {ground_rgb.shape}")
        self.scene = scene
        self.ground_xf = (float(ground_origin[0]), float(ground_origin[1]),
                          ground_rgb.shape[1] * ground_m_per_px, ground_rgb.shape[0] * ground_m_per_px)
        self._fill = ground_rgb[::16, ::16].reshape(-1, 3).mean(axis=0) / 255.0
        self.shadow_px, self.samples = int(shadow_px), int(samples)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="taco-gl")
        self._lock = threading.Lock()
        self._fbos: dict[tuple[int, int], tuple] = {}
        self._shadow_key: tuple | None = None
        self._call(self._init_gl, ground_rgb, ground_mat)

    # --- GL thread ---------------------------------------------------------------------------------------
    def _call(self, fn, *args):
        with self._lock:
            return self._pool.submit(fn, *args).result()

    def _init_gl(self, ground_rgb: np.ndarray, ground_mat: np.ndarray | None) -> None:
        try:
            import moderngl

            self.ctx = moderngl.create_standalone_context(backend="egl")
        except Exception as exc:  # no libEGL / no Mesa driver
            raise DataError(f"3-D rendering needs a headless OpenGL 3.3 context (EGL; on Debian: apt-get install "
                            f"libegl1 libgl1-mesa-dri): {exc}") from None
        ctx = self.ctx
        log.debug("GL: %s, %s", ctx.info["GL_RENDERER"], ctx.info["GL_VERSION"])
        # Two variants of one shader (a software rasteriser runs every branch for every fragment): the
        # ground plane's (texture, material tint) and the objects' (facades, foliage, roofs, cars).
        self.prog = ctx.program(vertex_shader=VS, fragment_shader=FS)
        self.ground_prog = ctx.program(vertex_shader=VS, fragment_shader=FS.replace("#version 330", "#version 330\n#define GROUND 1", 1))
        self.depth_prog = ctx.program(vertex_shader=DEPTH_VS, fragment_shader=DEPTH_FS)
        self.sky_prog = ctx.program(vertex_shader=SKY_VS, fragment_shader=SKY_FS)
        self.sky_vao = ctx.vertex_array(self.sky_prog, [(ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], "f4")), "2f", "in_xy")])
        h, w = ground_rgb.shape[:2]
        self.tex = ctx.texture((w, h), 3, np.ascontiguousarray(ground_rgb).tobytes(), alignment=1)
        self.tex.build_mipmaps()
        self.tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.tex.anisotropy = 1.0  # llvmpipe's anisotropic filtering costs ~10x the frame time
        self.tex.repeat_x = self.tex.repeat_y = False
        mat = np.zeros((h, w), np.uint8) + 4 if ground_mat is None else np.ascontiguousarray(ground_mat, np.uint8)
        self.mat_tex = ctx.texture((w, h), 1, mat.tobytes(), alignment=1)
        self.mat_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.shadow_tex = ctx.depth_texture((self.shadow_px, self.shadow_px))
        self.shadow_tex.compare_func = "<="
        self.shadow_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.shadow_fbo = ctx.framebuffer(depth_attachment=self.shadow_tex)
        x0, y1, gw, gh = self.ground_xf
        m = 2000.0
        g = np.array([[x0 - m, y1 - gh - m], [x0 + gw + m, y1 - gh - m], [x0 + gw + m, y1 + m], [x0 - m, y1 + m]])
        ground = np.zeros((6, 12), np.float32)
        ground[:, 0:2] = g[[0, 1, 2, 0, 2, 3]]
        ground[:, 5] = 1.0
        self._vaos: dict[str, tuple] = {}
        self._add("ground", ground, chunked=False)
        self._add("static", self.scene.static.interleaved())
        for k, mesh in self.scene.parked.items():
            self._add(f"parked_{k}", mesh.interleaved())
        self._car = car_mesh((1.0, 1.0, 1.0))
        n_moving = max(1, len(self.scene.moving)) * len(self._car)
        self._moving_buf = ctx.buffer(reserve=n_moving * 12 * 4)
        self._vaos["moving"] = self._make_vaos(self._moving_buf, 0) + (None,)

    def _make_vaos(self, buf, n: int, ground: bool = False) -> tuple:
        prog = self.ground_prog if ground else self.prog
        attrs = [(a, k) for a, k in (("in_pos", 3), ("in_nrm", 3), ("in_col", 3), ("in_mat", 1), ("in_uv", 2))]
        fmt = " ".join(f"{k}f" if a in prog else f"{4 * k}x" for a, k in attrs)  # skip what a variant leaves out
        return (self.ctx.vertex_array(prog, [(buf, fmt, *[a for a, _ in attrs if a in prog])]),
                self.ctx.vertex_array(self.depth_prog, [(buf, "3f 36x", "in_pos")]), n)

    def _add(self, name: str, data: np.ndarray, chunked: bool = True) -> None:
        """Upload a triangle list; with `chunked`, sorted by CELL_M x CELL_M cells of the triangles'
        centroids so that a view draws only the cells within its reach (`_runs`)."""
        if len(data) == 0:
            return
        data = np.ascontiguousarray(data, np.float32)
        cells = None
        if chunked:
            cen = data[:, :2].reshape(-1, 3, 2).mean(axis=1)
            key = np.floor(cen / CELL_M).astype(np.int64)
            order = np.lexsort((key[:, 1], key[:, 0]))
            data = np.ascontiguousarray(data.reshape(-1, 3, 12)[order].reshape(-1, 12))
            key = key[order]
            uniq, first, count = np.unique(key, axis=0, return_index=True, return_counts=True)
            cells = ((uniq + 0.5) * CELL_M, first * 3, count * 3)
        self._vaos[name] = self._make_vaos(self.ctx.buffer(data.tobytes()), len(data), name == "ground") + (cells,)

    def _runs(self, name: str, centre: np.ndarray, reach: float, ahead: np.ndarray | None) -> list[tuple[int, int]]:
        """(first vertex, count) runs of `name` to draw for a view of `reach` metres around `centre`; with
        `ahead` (unit (2,)), cells more than one cell behind `centre` are skipped."""
        _, _, n, cells = self._vaos[name]
        if cells is None:
            return [(0, n)]
        c, first, count = cells
        d = c - centre
        keep = np.hypot(d[:, 0], d[:, 1]) < reach + CELL_M
        if ahead is not None:
            keep &= d @ ahead > -1.5 * CELL_M
        runs: list[tuple[int, int]] = []
        for f, k in zip(first[keep], count[keep]):
            if runs and runs[-1][0] + runs[-1][1] == f:
                runs[-1] = (runs[-1][0], runs[-1][1] + int(k))
            else:
                runs.append((int(f), int(k)))
        return runs

    def _fbo(self, w: int, h: int):
        if (w, h) not in self._fbos:
            ctx = self.ctx
            color = ctx.renderbuffer((w, h), 3, samples=self.samples)
            depth = ctx.depth_renderbuffer((w, h), samples=self.samples)
            fbo = ctx.framebuffer(color, depth)
            resolve = None
            if self.samples:
                resolve = ctx.framebuffer(ctx.renderbuffer((w, h), 3), ctx.depth_renderbuffer((w, h)))
            self._fbos[(w, h)] = (fbo, resolve)
        return self._fbos[(w, h)]

    def _update_moving(self, t: float | None, centre: np.ndarray, reach: float) -> int:
        mc = self.scene.moving
        if len(mc) == 0 or t is None:
            return 0
        poses = moving_cars_at(mc, float(t))
        keep = np.flatnonzero(np.hypot(poses[:, 0] - centre[0], poses[:, 1] - centre[1]) < reach)
        if len(keep) == 0:
            return 0
        car = self._car
        c, s = np.cos(poses[keep, 2])[:, None], np.sin(poses[keep, 2])[:, None]
        px, py = car.pos[None, :, 0], car.pos[None, :, 1]
        nx, ny = car.nrm[None, :, 0], car.nrm[None, :, 1]
        k = len(keep) * len(car)
        data = np.zeros((len(keep), len(car), 12), np.float32)
        data[..., 0] = c * px - s * py + poses[keep, 0:1]
        data[..., 1] = s * px + c * py + poses[keep, 1:2]
        data[..., 2] = car.pos[None, :, 2]
        data[..., 3] = c * nx - s * ny
        data[..., 4] = s * nx + c * ny
        data[..., 5] = car.nrm[None, :, 2]
        rgb = CAR_RGB[mc.colour[keep] % len(CAR_RGB)]
        glass = car.col[:, 0] < 0.5  # the template's cabin glass stays dark
        data[..., 6:9] = np.where(glass[None, :, None], car.col[None], rgb[:, None, :])
        data[..., 9] = car.mat[None]
        self._moving_buf.write(data.reshape(k, 12).tobytes())
        return k

    def _draw(self, mvp: np.ndarray, eye: np.ndarray, ortho: bool, light: Lighting, epoch: str,
              t: float | None, view_centre: np.ndarray, reach: float, fbo, horizon_ndc: float | None,
              ahead: np.ndarray | None = None, ortho_view: np.ndarray | None = None) -> None:
        import moderngl

        ctx = self.ctx
        n_moving = self._update_moving(t, view_centre, reach)
        names = ["ground", "static", f"parked_{epoch}"]
        sun = light.sun_dir()
        runs = {name: ([(0, n_moving)] if name == "moving" else self._runs(name, view_centre, reach, ahead))
                for name in names + ["moving"] if name in self._vaos}
        # Shadow pass (static objects and parked cars; moving cars carry a contact shadow): a camera reuses
        # the map while its view centre stays within SHADOW_SNAP_M of the map's, which covers the margin.
        snap = np.round(view_centre / SHADOW_SNAP_M) * SHADOW_SNAP_M if not ortho else view_centre
        key = (tuple(snap), reach, tuple(sun), epoch, ortho)
        radius = reach + 30.0 + (SHADOW_SNAP_M if not ortho else 0.0)
        L = _light_matrix(sun, np.r_[snap, 0.0], radius)
        if key != self._shadow_key:
            self.shadow_fbo.use()
            self.shadow_fbo.clear(depth=1.0)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.disable(moderngl.CULL_FACE)
            self.depth_prog["mvp"].write(L.T.astype("f4").tobytes())
            for name in names[1:]:
                if name in self._vaos:
                    for f, n in self._runs(name, snap, radius - 30.0, None):
                        self._vaos[name][1].render(moderngl.TRIANGLES, vertices=n, first=f)
            self._shadow_key = key
        # colour pass
        fbo.use()
        fbo.clear(*light.haze_rgb, 1.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        p: dict = {}
        p["mvp"] = mvp.T.astype("f4").tobytes()
        p["light_mvp"] = L.T.astype("f4").tobytes()
        p["ground_xf"] = self.ground_xf
        p["ground_fill"] = tuple(float(v) for v in self._fill)
        sin_el = max(sun[2], 0.05)
        ambient = 0.42
        p["sun_dir"] = tuple(sun)
        p["sun_rgb"] = tuple(np.array([1.0, 0.97, 0.9]) * (1.05 - ambient) / sin_el * min(1.0, sin_el / 0.5 + 0.3))
        p["sky_rgb"] = (ambient * 0.95, ambient, ambient * 1.08)
        p["eye"] = tuple(eye)
        p["ortho"] = int(ortho)
        p["ortho_view"] = tuple(ortho_view) if ortho_view is not None else (0.0, 0.0, 1.0)
        p["haze_m"] = float(light.haze_m)
        p["haze_rgb"] = tuple(light.haze_rgb)
        p["haze_mix"] = float(light.haze_mix)
        s = float(np.clip(light.season, 0.0, 1.0))
        p["grass_tint"] = tuple(np.array([1.0, 1.0, 1.0]) * (1 - s) + np.array([1.22, 1.02, 0.82]) * s)
        p["foliage_tint"] = tuple(np.array([1.0, 1.0, 1.0]) * (1 - s) + np.array([3.2, 1.6, 1.1]) * s)
        p["exposure"] = float(light.exposure)
        self.tex.use(0)
        self.mat_tex.use(1)
        self.shadow_tex.use(2)
        p["ground_rgb"], p["ground_mat"], p["shadow_map"] = 0, 1, 2
        for prog in (self.prog, self.ground_prog):
            for key, value in p.items():
                if key in prog:  # uniforms a variant does not use are compiled away
                    if isinstance(value, bytes):
                        prog[key].write(value)
                    else:
                        prog[key].value = value
        # Near objects first and the ground last, so that early depth tests skip hidden ground fragments;
        # the sky last, behind everything.
        for name in ["moving", f"parked_{epoch}", "static", "ground"]:
            for f, n in runs.get(name, []):
                if n:
                    self._vaos[name][0].render(moderngl.TRIANGLES, vertices=n, first=f)
        if horizon_ndc is not None:
            self.sky_prog["horizon_ndc"].value = float(horizon_ndc)
            self.sky_prog["zenith"].value = tuple(light.sky_rgb)
            self.sky_prog["horizon"].value = tuple(light.haze_rgb)
            fbo.depth_mask = False  # the sky keeps the far depth (reads back as inf)
            self.sky_vao.render(moderngl.TRIANGLES)
            fbo.depth_mask = True

    def _read(self, fbo, resolve, w: int, h: int, depth: bool) -> tuple[np.ndarray, np.ndarray | None]:
        src = fbo
        if resolve is not None:
            self.ctx.copy_framebuffer(resolve, fbo)
            src = resolve
        rgb = np.frombuffer(src.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)[::-1].copy()
        d = None
        if depth:
            d = np.frombuffer(src.read(components=1, attachment=-1, dtype="f4", alignment=1), np.float32).reshape(h, w)[::-1].copy()
        return rgb, d

    def _camera_job(self, camera: GroundCamera, pose, t, epoch, light, depth: bool, far: float):
        near = 0.3
        mvp, eye = camera_matrices(camera, pose, near, far)
        fbo, resolve = self._fbo(camera.width, camera.height)
        K = camera.K
        v_h = K[1, 2] - K[1, 1] * math.tan(camera.pitch_rad)
        horizon_ndc = 1 - 2 * (v_h + 0.5) / camera.height
        ahead = np.array([pose[0] + 60.0 * math.cos(pose[2]), pose[1] + 60.0 * math.sin(pose[2])])
        heading = np.array([math.cos(pose[2]), math.sin(pose[2])])
        self._draw(mvp, eye, False, light, epoch, t, ahead, 140.0, fbo, horizon_ndc, heading)
        rgb, d = self._read(fbo, resolve, camera.width, camera.height, depth)
        if d is not None:
            z = d * 2.0 - 1.0
            d = (2.0 * far * near / ((far + near) - z * (far - near))).astype(np.float32)
            d[z >= 1.0 - 1e-7] = np.inf
        return rgb, d

    def render_camera(self, camera: GroundCamera, pose: tuple[float, float, float], t: float | None = None,
                      epoch: str = "camera", light: Lighting = Lighting(), depth: bool = False,
                      far: float = 400.0) -> tuple[np.ndarray, np.ndarray | None]:
        """The camera view from local pose (x, y, theta): uint8 RGB (H, W, 3) and, with depth=True, the depth
        along the optical axis (H, W) float32 metres (inf where only sky is seen). t: seconds for the moving
        cars (None: no moving cars); epoch: which day's parked cars."""
        return self._call(self._camera_job, camera, tuple(float(v) for v in pose), t, epoch, light, depth, far)

    def _ortho_job(self, x0, y1, w, h, res, epoch, t, light, lean):
        xa, xb, yb = x0, x0 + w * res, y1
        ya = y1 - h * res
        zmin, zmax = -1.0, 120.0
        P = np.array([[2 / (xb - xa), 0, 0, -(xb + xa) / (xb - xa)], [0, 2 / (yb - ya), 0, -(yb + ya) / (yb - ya)],
                      [0, 0, -2 / (zmax - zmin), (zmax + zmin) / (zmax - zmin)], [0, 0, 0, 1]])
        S = np.eye(4)
        S[0, 2], S[1, 2] = lean  # a point z metres up is drawn lean * z metres away (relief displacement)
        view = np.array([-lean[0], -lean[1], 1.0]) / math.hypot(lean[0], lean[1], 1.0)
        fbo, resolve = self._fbo(w, h)
        centre = np.array([(xa + xb) / 2, (ya + yb) / 2])
        reach = 0.5 * math.hypot(xb - xa, yb - ya) + 40.0
        self._draw(P @ S, np.r_[centre, 1e4], True, light, epoch, t, centre, reach, fbo, None, ortho_view=view)
        return self._read(fbo, resolve, w, h, False)[0]

    def render_ortho(self, x0: float, y1: float, width: int, height: int, m_per_px: float, epoch: str = "aerial",
                     t: float | None = None, light: Lighting = Lighting(),
                     lean: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """A north-up parallel view from above: uint8 RGB (height, width, 3) whose top-left pixel corner is at
        local (x0, y1), `m_per_px` metres per pixel. lean: (east, north) metres per metre of height by which
        raised points are displaced, as in an orthophoto that is not a true ortho (0: straight down); the
        ground (z = 0) stays where it is."""
        return self._call(self._ortho_job, float(x0), float(y1), int(width), int(height), float(m_per_px), epoch, t,
                          light, (float(lean[0]), float(lean[1])))

    def close(self) -> None:
        """Release the GL context and its thread."""
        def _release():
            if hasattr(self, "ctx"):
                self.ctx.release()
        try:
            self._call(_release)
        finally:
            self._pool.shutdown(wait=True)
