"""Bench: wall time of `taco-mav eval` on KITTI odometry 05 with the emulator (no plots)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from taco_mav.datasets.kitti import default_kitti_root
from taco_mav.evaluation.evaluate import EvalRequest, evaluate


def run(progress: bool = False) -> dict[str, float]:
    """eval_seq05_emulator_s (absent when the KITTI data is not beside the checkout or in $TACO_KITTI_ROOT)."""
    root = default_kitti_root()
    if root is None or not (root / "2011_09_30" / "2011_09_30_drive_0018_sync").is_dir():
        return {}
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        res = evaluate(EvalRequest(out=Path(tmp), kitti_root=root, sequences=("05",), matcher="emulator",
                                   plots=False, progress=False))
        elapsed = time.perf_counter() - start
    return {"eval_seq05_emulator_s": round(elapsed, 3), "eval_seq05_emulator_ate_m": res["sequences"]["05"]["ate_m"]}
