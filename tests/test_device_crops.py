"""Crops warped on the matcher's device (fg2.device_crops): the same crops as SatelliteMap.crop within
interpolation tolerance, the same off-map rules, and the same FG2 answers through FixService. All on a CPU device
(the CUDA path is the same code with device="cuda": `FG2_DEVICE=cuda pytest tests/test_device_crops.py`)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import rasterio

torch = pytest.importorskip("torch", reason="the fg2 extra (torch) is not installed")

from taco_mav.camera.geometry import GroundCamera  # noqa: E402
from taco_mav.config import CameraConfig, Fg2Config  # noqa: E402
from taco_mav.core.types import FixQuery  # noqa: E402
from taco_mav.cvgl.base import Crop, GroundFrame  # noqa: E402
from taco_mav.cvgl.fg2.adapter import Fg2Matcher  # noqa: E402
from taco_mav.cvgl.fg2.device_crops import DeviceCropper, GeometryMatcher  # noqa: E402
from taco_mav.cvgl.fg2.shim import build_random_model  # noqa: E402
from taco_mav.cvgl.fg2.tiny import TinyFg2  # noqa: E402
from taco_mav.cvgl.satellite import SatelliteMap  # noqa: E402
from taco_mav.cvgl.service import (
    FixService,  # noqa: E402
    uses_device_crops,  # noqa: E402
)
from taco_mav.errors import OffMapError  # noqa: E402

DEVICE = os.environ.get("FG2_DEVICE", "cpu")
E_LEFT, N_TOP, RES, SIZE = 456_000.0, 5_430_000.0, 0.25, 1200  # 300 m square in UTM 32N
CENTRE = np.array([E_LEFT + 150.0, N_TOP - 150.0])
HEADINGS = (0.0, 0.3, 1.0, math.pi / 2, 2.5, -2.0)
# Asserted bounds, grey levels (measured on a CPU, this mosaic: worst mean 0.018, worst max 1, from cv2's 1/32 px
# position and 15-bit weight quantisation against grid_sample's fp32 arithmetic).
MEAN_TOL, MAX_TOL = 0.5, 3.0
VALID_TOL = 2e-3  # valid fraction: mean of the rounded uint8 alpha (crop) vs of the rounded fp32 alpha (device)
CAMERA = GroundCamera.from_config(CameraConfig(), scale=0.25)
FAKE = Path(__file__).parent / "fake_fg2"


def write_textured(path: Path, nodata: bool = False) -> Path:
    """A 300 m RGB mosaic of 1 m random blocks plus per-pixel noise (sharp edges everywhere); with nodata, a
    60 m nodata square (value 0) north-east of the centre."""
    rng = np.random.default_rng(0)
    img = np.repeat(np.repeat(rng.integers(0, 256, (3, SIZE // 4, SIZE // 4)), 4, 1), 4, 2)
    img = np.clip(img + rng.integers(-30, 30, img.shape), 1, 255).astype(np.uint8)
    if nodata:
        img[:, 200:440, 700:940] = 0
    with rasterio.open(path, "w", driver="GTiff", width=SIZE, height=SIZE, count=3, dtype="uint8",
                       crs="EPSG:32632", transform=rasterio.Affine(RES, 0.0, E_LEFT, 0.0, -RES, N_TOP),
                       nodata=0 if nodata else None) as dst:
        dst.write(img)
    return path


@pytest.fixture(scope="module")
def mosaic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_textured(tmp_path_factory.mktemp("dc") / "textured.tif")


def cpu_or_error(sat: SatelliteMap, c: np.ndarray, heading: float, size: int, m_per_px: float) -> Crop | OffMapError:
    try:
        return sat.crop(c, heading, size, m_per_px)
    except OffMapError as exc:
        return exc


def compare(sat: SatelliteMap, cropper: DeviceCropper, centres: list[np.ndarray], heading: float, size: int,
            m_per_px: float) -> tuple[float, float, int]:
    """Device batch vs crop() for each centre: same presence, valid fraction, pixels within the bounds.
    Returns the worst mean and max abs differences and how many crops were off the map."""
    dc = cropper.cut(sat, centres, heading, size, m_per_px)
    assert dc.images.device.type == torch.device(DEVICE).type and dc.images.dtype == torch.float32
    images = (dc.images.permute(0, 2, 3, 1).cpu().numpy() * 255.0).round()
    worst_mean = worst_max = 0.0
    off, j = 0, 0
    for i, c in enumerate(centres):
        ref = cpu_or_error(sat, c, heading, size, m_per_px)
        if isinstance(ref, OffMapError):
            off += 1
            assert not dc.present[i] and isinstance(dc.errors[i], OffMapError)
            assert dc.errors[i].valid_fraction == pytest.approx(ref.valid_fraction, abs=VALID_TOL)
            assert str(dc.errors[i]).split(" is ")[0] == str(ref).split(" is ")[0]
            continue
        assert dc.present[i] and dc.errors[i] is None
        assert dc.valid_fraction[i] == pytest.approx(ref.valid_fraction, abs=VALID_TOL)
        diff = np.abs(images[j] - ref.image.astype(float))
        j += 1
        worst_mean, worst_max = max(worst_mean, float(diff.mean())), max(worst_max, float(diff.max()))
    assert j == dc.images.shape[0] == sum(dc.present)
    assert worst_mean < MEAN_TOL and worst_max <= MAX_TOL, (heading, m_per_px, worst_mean, worst_max)
    return worst_mean, worst_max, off


@pytest.mark.parametrize("in_memory_mb", [1024.0, 0.0], ids=["in_memory", "block_cache"])
def test_device_crops_equal_cv2_crops_inside_the_map(mosaic: Path, in_memory_mb: float) -> None:
    centres = [CENTRE, CENTRE + [30.0, -20.0], CENTRE + [-17.3, 8.1], CENTRE + [0.0, 41.0], CENTRE + [-44.0, -3.0]]
    worst = [0.0, 0.0]
    with SatelliteMap(mosaic, in_memory_max_mb=in_memory_mb) as sat:
        cropper = DeviceCropper(DEVICE)
        # 0.25: the mosaic's own resolution; 0.3: resampled at level 0; 0.6: from the 2x shrunk level
        for m_per_px in (0.25, 0.3, 0.6):
            for heading in HEADINGS:
                mean, mx, off = compare(sat, cropper, centres, heading, 128, m_per_px)
                assert off == 0
                worst = [max(worst[0], mean), max(worst[1], mx)]
        # the in-memory level is uploaded once per level and reused; block-cache maps upload a window per trigger
        assert cropper.uploads == (2 if in_memory_mb else 3 * len(HEADINGS))
    print(f"device vs cv2 crops, {'in memory' if in_memory_mb else 'block cache'}: worst mean |diff| "
          f"{worst[0]:.3f}, worst max {worst[1]:.0f} grey levels")


def test_device_crops_near_the_edge_zero_fill_and_valid_fraction(mosaic: Path) -> None:
    e0, n0, e1, n1 = SatelliteMap(mosaic).bounds_utm
    # centres 5..40 m inside the edges (part off the map), one wholly outside; 128 px at 0.3 m/px = 38 m
    centres = [np.array([e0 + 5.0, CENTRE[1]]), np.array([e1 - 12.0, n1 - 9.0]), np.array([CENTRE[0], n0 + 16.0]),
               np.array([e0 + 19.0, n0 + 40.0]), np.array([e1 + 80.0, CENTRE[1]]), CENTRE]
    with SatelliteMap(mosaic, min_valid=0.0) as sat:
        cropper = DeviceCropper(DEVICE)
        partial = 0
        for heading in HEADINGS:
            compare(sat, cropper, centres, heading, 128, 0.3)
            dc = cropper.cut(sat, centres, heading, 128, 0.3)
            assert not dc.present[4] and dc.valid_fraction[4] == 0.0 and "wholly outside" in str(dc.errors[4])
            partial += sum(0.0 < v < 1.0 for v in dc.valid_fraction)
            # the zero fill: off-map pixels of an edge crop are exactly 0 in every channel
            edge = dc.images[0].cpu().numpy()
            assert (edge.max(0) == 0).mean() == pytest.approx(1 - dc.valid_fraction[0], abs=0.02)
        assert partial >= 3 * len(HEADINGS)
    with SatelliteMap(mosaic) as sat:  # min_valid 0.9: the edge crops are OffMapError as crop() raises them
        _, _, off = compare(sat, DeviceCropper(DEVICE), centres, 0.7, 128, 0.3)
        assert off >= 3  # the wholly outside one and two below 90 % on the map


def test_nodata_mask_per_crop_windows_and_pyramid(tmp_path: Path) -> None:
    path = write_textured(tmp_path / "nodata.tif", nodata=True)
    # partly on the nodata square, wholly on it (on-map share 0: OffMapError, as crop() says), clear of it
    centres = [CENTRE + [30.0, 45.0], CENTRE + [60.0, 60.0], CENTRE - 30.0]
    with SatelliteMap(path, min_valid=0.0) as sat:
        for heading in (0.0, 1.1):
            compare(sat, DeviceCropper(DEVICE), centres, heading, 96, 0.3)
            # one window per crop (the union is over window_max_px): the same crops
            compare(sat, DeviceCropper(DEVICE, window_max_px=1000), centres, heading, 96, 0.3)
            # the whole level too large for the device budget: a window upload per trigger instead
            small = DeviceCropper(DEVICE, max_mosaic_mb=0.1)
            compare(sat, small, centres, heading, 96, 0.7)
            assert small.uploads == 1
        dc = DeviceCropper(DEVICE).cut(sat, centres, 0.0, 96, 0.3)
        assert 0.0 < dc.valid_fraction[0] < 1.0 and dc.valid_fraction[1] == 0.0 and dc.valid_fraction[2] == 1.0
        assert dc.present == [True, False, True] and "100.0 % off" in str(dc.errors[1])


# ---------------------------------------------------------------------------------------------- FG2 end to end
class Spy:
    """Counts which path a FixService took."""

    def __init__(self, matcher: Fg2Matcher) -> None:
        self.m, self.calls = matcher, {"match": 0, "cut_crops": 0}

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        attr = getattr(self.m, name)
        if name not in self.calls:
            return attr

        def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
            self.calls[name] += 1
            return attr(*args, **kwargs)

        return counted


def answers(matcher: Fg2Matcher, sat: SatelliteMap, frame: GroundFrame, heading: float,
            offsets: np.ndarray, size: int, decoys: int = 0) -> tuple[list, Spy, FixService]:
    spy = Spy(matcher)
    # decoys: every decoy answer counts (no yaw gate; apart by any distance), so the chance level is their best w
    service = FixService(spy, sat, CENTRE, crop_size_px=size, m_per_px=0.8, decoys=decoys,  # type: ignore[arg-type]
                         yaw_gate_rad=None, decoy_apart_m=1e-6)
    query = FixQuery(1, 1.0, np.zeros(2), heading, offsets, offsets, 5.0)
    return service.answer(query, frame), spy, service


def same_results(a: list, b: list, tol: float) -> float:
    worst = 0.0
    assert [r is None for r in a] == [r is None for r in b]
    for ra, rb in zip(a, b):
        if ra is not None:
            for x, y in ((ra.t, rb.t), (ra.R, rb.R), (np.array([ra.w]), np.array([rb.w]))):
                worst = max(worst, float(np.abs(x - y).max()))
    assert worst <= tol, worst
    return worst


@pytest.mark.parametrize("model_name", ["tiny", "fake_fg2"])
def test_fg2_answers_from_device_crops_equal_cpu_crops(mosaic: Path, model_name: str) -> None:
    rng = np.random.default_rng(4)
    frame = GroundFrame(rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8), 1.0, CAMERA)
    torch.manual_seed(0)
    model = (TinyFg2() if model_name == "tiny" else build_random_model(FAKE, DEVICE, seed=3)).to(DEVICE).eval()
    # back, centre, forward, left and a crop off the map (relative to CENTRE, ENU metres)
    offsets = np.array([[-6.0, 1.0], [0.0, 0.0], [6.0, -1.0], [2.0, 7.0], [400.0, 0.0]])
    size = 128  # 102 m at 0.8 m/px (the fake checkout needs 99 m), cut from the 2x shrunk level
    worst = 0.0
    with SatelliteMap(mosaic) as sat:
        for heading in (0.4, 2.2):
            out = {}
            for on in (False, True):
                cfg = Fg2Config(checkout="x", checkpoint="x", device=DEVICE, device_crops=on)
                matcher = Fg2Matcher(cfg, CAMERA, model=model)
                assert uses_device_crops(matcher) is on and isinstance(matcher, GeometryMatcher)
                out[on], spy, service = answers(matcher, sat, frame, heading, offsets, size)
                assert spy.calls == {"match": int(not on), "cut_crops": int(on)}
                assert service.stats.crops_off_map == 1 and out[on][4] is None
                if on:  # match_geometry: the same answers in one call
                    same_results(out[on], matcher.match_geometry(frame, sat, CENTRE + offsets, heading, size, 0.8),
                                 1e-6)
                    # the device pixels through the uint8 path give the very same answers: the only difference
                    # between the paths is the warp
                    dc = matcher.cut_crops(sat, CENTRE + offsets, heading, size, 0.8)
                    u8 = (dc.images.permute(0, 2, 3, 1).cpu().numpy() * 255).round().astype(np.uint8)
                    crops = [Crop(im, CENTRE, heading, 0.8) for im in u8]
                    same_results([r for r in out[on] if r is not None], matcher.match(frame, crops), 1e-5)
            worst = max(worst, same_results(out[False], out[True], 0.05))
    print(f"{model_name}: max |t, R, w| difference, device vs CPU crops: {worst:.3g}")


def test_decoys_on_the_device_give_the_cpu_crops_chance_level(mosaic: Path) -> None:
    """FixService's decoys (the centre crop turned by 90, 270, 180 deg) cut on the device, one batch per turn,
    give each answer the chance level the CPU crops give."""
    rng = np.random.default_rng(5)
    frame = GroundFrame(rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8), 1.0, CAMERA)
    torch.manual_seed(0)
    model = TinyFg2().to(DEVICE).eval()
    offsets = np.array([[-6.0, 1.0], [0.0, 0.0], [6.0, -1.0], [2.0, 7.0], [0.0, -7.0]])
    with SatelliteMap(mosaic) as sat:
        out = {}
        for on in (False, True):
            cfg = Fg2Config(checkout="x", checkpoint="x", device=DEVICE, device_crops=on)
            out[on], spy, _ = answers(Fg2Matcher(cfg, CAMERA, model=model), sat, frame, 0.4, offsets, 128, decoys=3)
            assert spy.calls == ({"match": 0, "cut_crops": 4} if on else {"match": 1, "cut_crops": 0})
        assert all(r is not None and r.null_w is not None and r.null_w > 0.0 for r in out[False] + out[True])
        same_results(out[False], out[True], 0.05)
        assert max(abs(a.null_w - b.null_w) for a, b in zip(out[False], out[True])) <= 0.05
