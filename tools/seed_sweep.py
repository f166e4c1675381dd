"""Seed sweep: `taco-mav eval`'s per-sequence metrics over several emulator seeds, both FG2 areas and several
matcher latencies, in parallel, with profile overrides. The emulator is random, so one seed says little about a
bar such as "no sequence above 1.0 m"; this prints every seed's ATE and the worst case per sequence.

    python tools/seed_sweep.py --kitti-root ../shared/data/kitti_raw --sequences 04,05,07,09 \
        --seeds 0-4 --areas same,cross --latencies 0,1 [--set plus.q_speed_mps=0.05 ...] [--out sweep.json]

Each cell runs the same code as `taco-mav eval --estimator taco+ --seed S --matcher-latency L [--cross-area]`
(resolve_profile, run_drive, metrics) and gives the same numbers, except that area 'same' runs same-area even a
sequence the profile lists as cross-area (emulator.cross_area_sequences: 00, 06), which eval runs cross-area. Profile keys for --set are dotted as in
vehicle_profiles/*.yaml; values are parsed as YAML (0.05, true, [1, 2]).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from taco_mav.config import parse_overrides, replace_in
from taco_mav.errors import UsageError
from taco_mav.evaluation.evaluate import EvalRequest, load_drives, resolve_profile
from taco_mav.evaluation.runner import run_drive
from taco_mav.evaluation.summary import metrics


@dataclass(frozen=True)
class Cell:
    """One run: a sequence under a seed, an area ('same' or 'cross') and a matcher latency (s)."""

    sequence: str
    seed: int
    area: str
    latency_s: float


def seeds(text: str) -> list[int]:
    """'0-4' or '0,2,7' -> the seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        out += list(range(int(lo), int(hi) + 1)) if hi else [int(lo)]
    return out


def run_cell(cell: Cell, kitti_root: Path, estimator: str, profile: str, sets: dict[str, Any]) -> dict[str, Any]:
    """The results.json metrics of one cell (the same code path as `taco-mav eval`)."""
    req = EvalRequest(out=Path("."), profile=profile, kitti_root=kitti_root, sequences=(cell.sequence,),
                      estimator=estimator, seed=cell.seed, latency_s=cell.latency_s, cross_area=cell.area == "cross")
    prof = resolve_profile(req)
    for key, value in sets.items():
        prof = replace_in(prof, key, value)
    run = run_drive(load_drives(req)[0], prof, latency_s=cell.latency_s, cross_area=cell.area == "cross")
    return {"sequence": cell.sequence, "seed": cell.seed, "area": cell.area, "latency_s": cell.latency_s,
            **metrics(run)}


def _pair(group: list[dict[str, Any]], along: str, cross: str) -> str:
    """'a/c': the RMS over the runs of two per-run RMS figures, metres ('-' where no run has them)."""
    def pooled(key: str) -> str:
        vals = [r[key] for r in group if r.get(key) is not None]
        return f"{math.sqrt(statistics.mean(v * v for v in vals)):.2f}" if vals else "-"
    return f"{pooled(along)}/{pooled(cross)} m"


def table(rows: list[dict[str, Any]]) -> str:
    """One line per (area, latency): every seed's ATE per sequence, the worst fixes/km, and the pooled figures."""
    lines = []
    for area in dict.fromkeys(r["area"] for r in rows):
        for lat in dict.fromkeys(r["latency_s"] for r in rows):
            group = [r for r in rows if r["area"] == area and r["latency_s"] == lat]
            if not group:
                continue
            parts = []
            for seq in dict.fromkeys(r["sequence"] for r in group):
                mine = [r for r in group if r["sequence"] == seq]
                ates = ",".join(f"{r['ate_m']:.2f}" for r in mine)
                parts.append(f"{seq}: {ates} (fixes/km <= {max(r['fixes_per_km'] for r in mine):.0f})")
            ates = [r["ate_m"] for r in group]
            cov2 = [r["coverage_2sigma"] for r in group if r.get("coverage_2sigma") is not None]
            cov = f" 2-sigma coverage {min(cov2):.2f}-{max(cov2):.2f}" if cov2 else ""
            split = ("; along/cross track (RMS over the runs): error " + _pair(group, "ate_along_m", "ate_cross_m")
                     + ", fixes " + _pair(group, "fix_error_along_rms_m", "fix_error_cross_rms_m"))
            lines.append(f"{area:5s} L{lat:g}: " + "  ".join(parts)
                         + f" | median {statistics.median(ates):.3f} mean {statistics.mean(ates):.3f} "
                           f"max {max(ates):.2f} above 1 m: {sum(a > 1.0 for a in ates)}/{len(ates)}{cov}{split}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kitti-root", type=Path, required=True, help="KITTI raw root")
    ap.add_argument("--sequences", default="04,05,07,09", help="odometry ids (default 04,05,07,09)")
    ap.add_argument("--seeds", default="0-4", help="emulator seeds, e.g. 0-4 or 0,3 (default 0-4)")
    ap.add_argument("--areas", default="same,cross", help="FG2 error figures: same, cross or both (default both)")
    ap.add_argument("--latencies", default="0,1", help="matcher latencies, s (default 0,1)")
    ap.add_argument("--estimator", default="taco+", choices=("paper", "taco+"), help="default taco+")
    ap.add_argument("--profile", default="kitti", help="vehicle profile name or YAML path (default kitti)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="profile override (repeatable)")
    ap.add_argument("--jobs", type=int, default=2, help="parallel processes (default 2)")
    ap.add_argument("--out", type=Path, help="write every cell's metrics here (JSON)")
    args = ap.parse_args(argv)
    areas = [a.strip() for a in args.areas.split(",") if a.strip()]
    if not areas or any(a not in ("same", "cross") for a in areas):
        raise SystemExit(f"--areas {args.areas!r}: expected same, cross or same,cross")
    try:
        sets = parse_overrides(args.set)
    except UsageError as e:
        raise SystemExit(str(e)) from None
    cells = [Cell(q.strip().zfill(2), s, a, float(lat)) for a in areas for lat in args.latencies.split(",")
             for s in seeds(args.seeds) for q in args.sequences.split(",") if q.strip()]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(partial(run_cell, kitti_root=args.kitti_root, estimator=args.estimator,
                                     profile=args.profile, sets=sets), cells))
    print(table(rows))
    if args.out:
        args.out.write_text(json.dumps({"overrides": sets, "estimator": args.estimator, "profile": args.profile,
                                        "cells": rows}, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
