"""The dense descriptors: what each is invariant to, measured on a real rendered frame's bird's-eye view."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from taco_mav.bench.classical import textured_mosaic
from taco_mav.cvgl.descriptors import DESCRIPTORS, describe, lcn, orientation


@pytest.fixture(scope="module")
def patch() -> np.ndarray:
    """A 160 x 160 grey patch of the bench's textured mosaic (roads, roofs, crowns, vegetation noise), 0.6 m/px."""
    rgb = textured_mosaic(2, 800, 0.2)[200:680, 200:680]
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, (160, 160), interpolation=cv2.INTER_AREA).astype(np.float32)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(axis=(1, 2), keepdims=True), b - b.mean(axis=(1, 2), keepdims=True)
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_orientation_is_blind_to_polarity_lcn_flips_sign(patch) -> None:
    """255 - x (every edge's polarity reversed): orientation channels unchanged, lcn negated (NCC -1), which
    is why grey-level correlation fails when camera and map disagree on which material is brighter."""
    inv = 255.0 - patch
    o, o_inv = orientation(patch, None, 3.3), orientation(inv, None, 3.3)
    np.testing.assert_allclose(o_inv, o, atol=1e-4)
    assert _ncc(lcn(patch, None, 3.3), lcn(inv, None, 3.3)) < -0.99


def test_orientation_survives_gain_gamma_and_blur(patch) -> None:
    """A different exposure (gain 0.7, gamma 1.5) and a coarser sensor (Gaussian blur 1 px) keep NCC > 0.7."""
    other = 255.0 * (0.7 * patch / 255.0) ** 1.5
    other = cv2.GaussianBlur(other, (0, 0), 1.0)
    assert _ncc(orientation(patch, None, 3.3), orientation(other, None, 3.3)) > 0.7


def test_masked_pixels_are_zero_and_the_mask_border_makes_no_edge() -> None:
    """A uniform image under a wedge mask describes to zero everywhere (no edge along the mask's border)."""
    img = np.full((60, 80), 120.0, np.float32)
    mask = np.zeros((60, 80), np.float32)
    cv2.fillConvexPoly(mask, np.array([[40, 59], [0, 0], [79, 0]], np.int32), 1.0)
    for name in DESCRIPTORS:
        ch = describe(name, img, mask, 3.3)
        assert ch.shape[1:] == img.shape
        assert np.abs(ch).max() < 1e-3, name


def test_unknown_descriptor_is_refused() -> None:
    with pytest.raises(ValueError, match="orientation"):
        describe("sift", np.zeros((8, 8), np.float32), None, 1.0)
