"""Dense descriptors that the classical matcher correlates: grey-level LCN and gradient orientation (the default),
and the one channel of a colour image they describe (`grey_channel`).

Both take a float32 grey image (H, W) at the matcher's resolution and an optional float32 0/1 validity mask
(H, W), and return channels (C, H, W) float32 that are zero where the mask is 0. The matcher correlates all
channels at once (a zero-normalised cross-correlation of the stacked channels), so a descriptor is only its
channels.

- "lcn" (C = 1): local contrast normalisation, (x - local mean) / local std, Gaussian windows of `sigma_px`.
  Undoes gain and offset, not gamma, colour mixing or shadows; a season that inverts the grey-level order of
  grass and asphalt turns a match into an anti-correlation.
- "orientation" (C = 2): the orientation of the image gradient in doubled-angle form, weighted by gradient
  magnitude and normalised by the local mean magnitude:
      (|g| cos 2 phi, |g| sin 2 phi) of the image smoothed over `smooth_px` (0.7 px), optionally pooled over
      `pool_px` (cell pooling, as HOG does; off by default: pooling over 1 px cost accuracy and robustness on
      the bench mosaic, 0.35 m against 0.21 m median error on clean frames), then divided by the
      Gaussian(`sigma_px`) local mean of |g| plus a floor (5 % of the image's mean |g|, and 0.25 grey
      levels per pixel).
  Doubling the angle makes it blind to the polarity of an edge (a dark road on bright grass and a bright road
  on dark soil give the same vector), the local normalisation to gain, gamma and soft shadows' brightness; the
  vectors are weighted by gradient strength, so uniform areas and weak noise
  give short vectors and long straight edges (kerbs, lane lines, roof and field boundaries) dominate (pooled, the
  vectors would be the normalised structure tensor's orientation part). The
  correlation of two such fields is the cosine similarity of the edge orientations, weighted by their strength.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from taco_mav.errors import MatcherError

__all__ = ["DESCRIPTORS", "GREYS", "check_grey", "describe", "grey_channel", "lcn", "orientation"]

DESCRIPTORS = ("lcn", "orientation")
GREYS = ("luma", "unsaturated", "achromatic")
# "achromatic": 255 / (1 + exp((chroma - ACHROMATIC_CHROMA) / ACHROMATIC_SCALE)), chroma = |(a*, b*)| of OpenCV's
# 8-bit Lab (128 = grey). Asphalt's chroma is under 8: its 90th percentile is 5.1 and 7.3 in the bottom-centre
# patches of two of the three real KITTI frames (shared/data/kitti_images; the third's patch holds a car).
ACHROMATIC_CHROMA = 8.0
ACHROMATIC_SCALE = 2.0
_EPS = 1e-6
_MIN_GRADIENT = 0.25  # grey levels per pixel: below uint8 quantisation, so a flat image describes to ~0


def grey_channel(rgb: np.ndarray, mode: str) -> np.ndarray:
    """The one channel the matcher describes, uint8 (H, W), of an RGB image (H, W, 3): "luma" (brightness),
    "unsaturated" (255 - HSV saturation: asphalt, concrete and kerbs bright, grass, foliage, soil and red roofs
    dark; a material's colourfulness, which changes less between days than its brightness) or "achromatic" (how
    grey a pixel is, from its Lab chroma: ACHROMATIC_CHROMA; a road-or-not layer, steadier than saturation in dark
    pixels, where saturation is noise). MatcherError for another mode."""
    check_grey(mode)
    if mode == "luma":
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    if mode == "unsaturated":
        return 255 - cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)[..., 1]
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)  # achromatic
    chroma = np.hypot(lab[..., 1].astype(np.float32) - 128.0, lab[..., 2].astype(np.float32) - 128.0)
    z = np.minimum((chroma - ACHROMATIC_CHROMA) / ACHROMATIC_SCALE, 80.0)
    return np.rint(255.0 / (1.0 + np.exp(z))).astype(np.uint8)


def check_grey(mode: str) -> None:
    """MatcherError naming the profile key when `mode` is not one of GREYS."""
    if mode not in GREYS:
        raise MatcherError(f"classical matcher: grey {mode!r} is not one of {', '.join(GREYS)} (profile key "
                           "classical.grey)")


def _ksize(sigma_px: float) -> int:
    return int(2 * math.ceil(3 * sigma_px) + 1)


def lcn(img: np.ndarray, mask: np.ndarray | None, sigma_px: float) -> np.ndarray:
    """Local contrast normalisation, channels (1, H, W): (x - local mean) / local std with Gaussian windows;
    normalised convolution over `mask` (float32 0/1) so that masked-out pixels neither contribute nor get
    values (they return 0)."""
    k = _ksize(sigma_px)
    if mask is None:
        mean = cv2.GaussianBlur(img, (k, k), sigma_px)
        d = img - mean
        var = cv2.GaussianBlur(d * d, (k, k), sigma_px)
        return (d / np.sqrt(var + 1.0))[None]
    wsum = cv2.GaussianBlur(mask, (k, k), sigma_px) + _EPS
    mean = cv2.GaussianBlur(img * mask, (k, k), sigma_px) / wsum
    d = (img - mean) * mask
    var = cv2.GaussianBlur(d * d, (k, k), sigma_px) / wsum
    return (d / np.sqrt(var + 1.0))[None]


def orientation(img: np.ndarray, mask: np.ndarray | None, sigma_px: float, pool_px: float = 0.0,
                smooth_px: float = 0.7, floor: float = 0.05) -> np.ndarray:
    """Gradient-orientation channels (2, H, W) in doubled-angle form (module docstring). Outside `mask` the
    image is first filled with its local mean (so the mask's border makes no edge), and the output is zero
    within one pixel of the border."""
    img = img.astype(np.float32, copy=False)
    if mask is not None:
        k = _ksize(2.0)
        wsum = cv2.GaussianBlur(mask, (k, k), 2.0)
        fill = cv2.GaussianBlur(img * mask, (k, k), 2.0) / (wsum + _EPS)
        far = wsum < 1e-3
        if far.any():
            fill[far] = float((img * mask).sum() / max(float(mask.sum()), 1.0))
        img = img * mask + fill * (1.0 - mask)
    if smooth_px > 0:
        img = cv2.GaussianBlur(img, (_ksize(smooth_px), _ksize(smooth_px)), smooth_px)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    mag2 = gx * gx + gy * gy
    mag = np.sqrt(mag2)
    inv = 1.0 / (mag + _EPS)
    c2 = (gx * gx - gy * gy) * inv  # |g| cos 2 phi
    s2 = (2.0 * gx * gy) * inv  # |g| sin 2 phi
    if mask is not None:
        inner = cv2.erode(mask, np.ones((3, 3), np.uint8))
        c2 *= inner
        s2 *= inner
        mag *= inner
    if pool_px > 0:
        kp = _ksize(pool_px)
        c2 = cv2.GaussianBlur(c2, (kp, kp), pool_px)
        s2 = cv2.GaussianBlur(s2, (kp, kp), pool_px)
    kn = _ksize(sigma_px)
    if mask is not None:
        wsum = cv2.GaussianBlur(inner, (kn, kn), sigma_px) + _EPS
        local = cv2.GaussianBlur(mag, (kn, kn), sigma_px) / wsum
        mean_mag = float(mag.sum() / max(float(inner.sum()), 1.0))
    else:
        local = cv2.GaussianBlur(mag, (kn, kn), sigma_px)
        mean_mag = float(mag.mean())
    denom = local + floor * mean_mag + _MIN_GRADIENT
    out = np.stack([c2 / denom, s2 / denom])
    if mask is not None:
        out *= mask[None]
    return out


def describe(name: str, img: np.ndarray, mask: np.ndarray | None, sigma_px: float) -> np.ndarray:
    """Channels (C, H, W) of descriptor `name` (one of DESCRIPTORS)."""
    if name == "lcn":
        return lcn(img, mask, sigma_px)
    if name == "orientation":
        return orientation(img, mask, sigma_px)
    raise ValueError(f"descriptor {name!r} is not one of {', '.join(DESCRIPTORS)}")
