"""`simulate(...)`: the `taco-mav sim` use case: play a drive to a companion, score it, write results.json."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

from taco_mav.sim.simulator import SimOptions, Simulator

log = logging.getLogger(__name__)

__all__ = ["simulate", "write_results"]


def _clean(obj: Any) -> Any:
    """JSON-ready copy: non-finite floats become None (results.json never holds NaN)."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalars
        return _clean(obj.item())
    return obj


def write_results(doc: dict[str, Any], out: Path) -> Path:
    """Write `doc` to `out/results.json` (creating `out`); returns the file path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.json"
    path.write_text(json.dumps(_clean(doc), indent=2, sort_keys=True) + "\n")
    return path


def simulate(drive: Path, connect: str, out: Path, speed: float = 1.0, *, deny_after_s: float | None = None,
             lockstep: bool = False, duration_s: float | None = None, gps1_type: int = 14,
             gps2_type: int | None = None, gnss_noise_m: float = 1.0, seed: int = 0,
             spoof_after_s: float | None = None, spoof_drift_mps: float = 0.0, spoof_jump_m: float = 0.0,
             home: tuple[float, float, float] | None = None, send_home: bool = True,
             wait_companion_s: float = 30.0, score_from_s: float = 0.0) -> dict[str, Any]:
    """Play `drive` (KITTI raw drive folder or synthetic world folder) to the companion on `connect` until the
    drive (or `duration_s`) ends, then score the GPS_INPUT received and write `out/results.json`.

    deny_after_s: drive seconds of real GNSS before NO_FIX (0: never a fix; None: only the start-up fix, first
    second, or never denied when spoofing). gps1_type / gps2_type, gnss_noise_m, seed, spoof_*, home,
    send_home, score_from_s: see `SimOptions`. Returns the results document. Ctrl-C stops playback early; what
    was played is still scored and written, then KeyboardInterrupt propagates (the command exits 130).
    """
    if deny_after_s is None:
        deny_after_s = math.inf if spoof_after_s is not None else 1.0
    opts = SimOptions(speed=speed, deny_after_s=deny_after_s, lockstep=lockstep, duration_s=duration_s,
                      gps1_type=gps1_type, gps2_type=gps2_type, gnss_noise_m=gnss_noise_m, seed=seed,
                      spoof_after_s=spoof_after_s, spoof_drift_mps=spoof_drift_mps, spoof_jump_m=spoof_jump_m,
                      home=home, send_home=send_home, wait_companion_s=wait_companion_s, score_from_s=score_from_s)
    sim = Simulator(drive, connect, speed, options=opts)
    sim.start()
    interrupted = False
    try:
        while not sim.join(timeout=0.5):
            pass
    except KeyboardInterrupt:
        interrupted = True
        log.warning("interrupted: scoring what was played")
        sim.stop()
        sim.join(timeout=5.0)
    doc = sim.results()
    path = write_results(doc, out)
    log.info("wrote %s", path)
    if interrupted:
        raise KeyboardInterrupt
    return doc
