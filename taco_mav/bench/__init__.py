"""`taco-mav bench`: speed, memory and accuracy figures written as one flat JSON object (keys in DESIGN.md).

Each section is a module with `run(progress: bool) -> dict[str, float]`; a section whose part is not built
yet is simply absent from SECTIONS, so its keys are absent (never zero).
"""

from __future__ import annotations

import importlib
import json
import logging
import time
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

SECTIONS: tuple[str, ...] = (
    "taco_mav.bench.fusion",
    "taco_mav.bench.evaluation",
    "taco_mav.bench.cvgl_map",
    "taco_mav.bench.emulator",
    "taco_mav.bench.kitti_load",
    "taco_mav.bench.classical",
    "taco_mav.bench.daemon",
)


def run_bench(out: Path, only: list[str] | None = None, progress: bool = True) -> dict[str, Any]:
    """Run every bench section (or those whose short name is in `only`) and write the merged JSON to `out`."""
    results: dict[str, Any] = {}
    for name in SECTIONS:
        short = name.rsplit(".", 1)[-1]
        if only and short not in only:
            continue
        module = importlib.import_module(name)
        start = time.perf_counter()
        log.info("bench section %s ...", short)
        results.update(module.run(progress=progress))
        log.info("bench section %s done in %.1f s", short, time.perf_counter() - start)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    return results
