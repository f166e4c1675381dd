"""`taco-mav bench`: speed, memory and accuracy figures written as one flat JSON object (keys in DESIGN.md).

Each section is a module with `run(progress: bool) -> dict[str, float]`; a section whose part is not built
yet is simply absent from SECTIONS, so its keys are absent (never zero). `only` names sections by their short
name (SECTION_NAMES); an unknown name is a UsageError before any section runs. A section that fails stops the
bench, but the keys measured before it are still written to `out`.
"""

from __future__ import annotations

import importlib
import json
import logging
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from taco_mav.errors import TacoError, UsageError

log = logging.getLogger(__name__)

SECTIONS: tuple[str, ...] = (
    "taco_mav.bench.fusion",
    "taco_mav.bench.evaluation",
    "taco_mav.bench.cvgl_map",
    "taco_mav.bench.emulator",
    "taco_mav.bench.kitti_load",
    "taco_mav.bench.classical",
    "taco_mav.bench.real",
    "taco_mav.bench.real_signal",
    "taco_mav.bench.daemon",
    "taco_mav.bench.world3d",
    "taco_mav.bench.fg2",
)
SECTION_NAMES: tuple[str, ...] = tuple(name.rsplit(".", 1)[-1] for name in SECTIONS)


def check_sections(only: Sequence[str] | None) -> tuple[str, ...]:
    """The section short names to run: all for None; UsageError naming any unknown name."""
    if only is None:
        return SECTION_NAMES
    names = tuple(s.strip() for s in only if s.strip())
    unknown = [n for n in names if n not in SECTION_NAMES]
    if unknown or not names:
        raise UsageError(f"--only {','.join(unknown) or repr(','.join(only))}: unknown section "
                         f"(known: {', '.join(SECTION_NAMES)})")
    return names


def _write(out: Path, results: dict[str, Any]) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")


def run_bench(out: Path, only: Sequence[str] | None = None, progress: bool = True,
              options: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """Run every bench section (or those whose short name is in `only`) and write the merged JSON to `out`;
    on a failing section (or Ctrl-C) the keys measured so far are written before the error propagates.
    options: keyword arguments for a section's run(), by short name (e.g. {"fg2": {"checkout": ...}})."""
    wanted = check_sections(only)
    out = Path(out)
    results: dict[str, Any] = {}
    done: list[str] = []
    try:
        for name in SECTIONS:
            short = name.rsplit(".", 1)[-1]
            if short not in wanted:
                continue
            start = time.perf_counter()
            log.info("bench section %s ...", short)
            try:
                results.update(importlib.import_module(name).run(progress=progress, **(options or {}).get(short, {})))
            except (TacoError, KeyboardInterrupt):
                raise
            except Exception as exc:
                raise TacoError(f"bench section {short}: {type(exc).__name__}: {exc}") from exc
            done.append(short)
            log.info("bench section %s done in %.1f s", short, time.perf_counter() - start)
    except BaseException:
        if results:
            _write(out, results)
            log.warning("wrote the %d key(s) of section(s) %s to %s before the error", len(results),
                        ", ".join(done), out)
        raise
    _write(out, results)
    return results
