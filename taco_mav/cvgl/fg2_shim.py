"""Default `fg2.entry`: checks a published FG2 checkout (vita-epfl/FG2) and its checkpoint.

The published KITTI model lives in the checkout's `models/model_kitti.py` (class `CVM`, fed DINOv2 ViT-L/14
features; the pose comes from a weighted Procrustes over its matching scores). Wrapping it into the
`encode_ground` / `match_aerial` interface of `taco_mav.cvgl.fg2` also needs FG2's own dependencies (mmcv) and
local DINOv2 weights; that wrapper is not written yet, so after checking the layout this raises a MatcherError
that says so. Point `fg2.entry` at your own wrapper ("module:function") meanwhile.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from taco_mav.errors import MatcherError

EXPECTED_MODULE = Path("models") / "model_kitti.py"


def build_model(checkout: Path, checkpoint: Path, device: Any) -> Any:
    """Check the checkout layout; the real-model wrapper is not implemented (MatcherError)."""
    if not (checkout / EXPECTED_MODULE).is_file():
        raise MatcherError(f"fg2.checkout: {checkout} is not an FG2 checkout ({EXPECTED_MODULE} not found)")
    raise MatcherError(f"fg2: {checkout} looks like FG2, but the wrapper around its CVM model is not implemented "
                       "yet; set fg2.entry to a 'module:function' that returns a model with the interface in "
                       "taco_mav/cvgl/fg2.py")
