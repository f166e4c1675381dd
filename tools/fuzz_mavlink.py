#!/usr/bin/env python3
"""Fuzz the `taco-mav run` daemon over real UDP on 127.0.0.1 and write the figures as JSON.

    python tools/fuzz_mavlink.py --frames 100000 --seed 0 --out fuzz.json
    python tools/fuzz_mavlink.py --frames 20000 --exclude time_back,time_forward,negative_dt,zero_dt --out f.json
    python tools/fuzz_mavlink.py --frames 30000 --imu-message auto --corrupt-imu-first 200 --out f.json

Feeds seeded random and mutated MAVLink frames (tests/fuzz_frames.py: bit flips, truncations, bad CRC,
unknown ids, out-of-range and NaN/inf fields, zero/negative dt, time jumps, duplicates, late frames, foreign
sources, ...) mixed with a valid autopilot stream into a Daemon, one episode per IMU message kind, and checks
every float field the daemon sends back. Prints the headline figures; exit code 1 when the daemon crashed, an
exception escaped or was caught by the loop (handler_error), or an output field was not finite.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Sequence

# The fuzz harness is test tooling and lives with the tests (tests/fuzz_harness.py, tests/fuzz_frames.py), not
# in the product package; this developer tool runs from a checkout and reaches it there.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzz_frames import MUTATIONS  # noqa: E402
from fuzz_harness import FuzzOptions, run_fuzz  # noqa: E402

HEADLINE = ("fuzz_frames", "datagrams_sent", "datagrams_read", "wall_s", "crashes", "escaped_exceptions",
            "handler_errors", "logged_exceptions", "nonfinite_output_fields",
            "out_of_range_output_fields", "all_anchored", "gps_input_during_fuzz", "gps_input_fix3_during_fuzz",
            "imu_sources", "reboots", "rejected_by_reason")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=100_000, help="fuzz frames in all (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="JSON file for the figures (per episode too)")
    p.add_argument("--imu", default="RAW_IMU,HIGHRES_IMU,SCALED_IMU", help="IMU kinds, one episode each")
    p.add_argument("--exclude", default="", help=f"mutations left out, comma-separated (of {', '.join(MUTATIONS)})")
    p.add_argument("--realtime-factor", type=float, default=10.0,
                   help="autopilot seconds per wall second at most; 0 = as fast as the daemon reads")
    p.add_argument("--imu-message", default=None,
                   help="the daemon's link.imu_message (default: pinned to each episode's kind; 'auto': chosen)")
    p.add_argument("--corrupt-imu-first", type=int, default=0,
                   help="corrupt IMU messages (every kind) sent before the first valid IMU sample")
    p.add_argument("-v", "--verbose", action="store_true")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    excluded = {s.strip() for s in args.exclude.split(",") if s.strip()}
    unknown = excluded - set(MUTATIONS)
    if unknown or args.frames < 1:
        print(f"fuzz_mavlink: error: {'--frames must be >= 1' if args.frames < 1 else f'unknown mutations {sorted(unknown)}'}",
              file=sys.stderr)
        return 2
    opts = FuzzOptions(frames=args.frames, seed=args.seed, imu_kinds=tuple(s.strip() for s in args.imu.split(",")),
                       realtime_factor=args.realtime_factor or None,
                       mutations=tuple(name for name in MUTATIONS if name not in excluded),
                       imu_message=args.imu_message, corrupt_imu_first=args.corrupt_imu_first)
    report = run_fuzz(opts, progress=args.verbose)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1, sort_keys=False))
    for key in HEADLINE:
        print(f"{key:28s} {report[key]}")
    print(f"wrote {out}")
    bad = report["crashes"] or report["escaped_exceptions"] or report["handler_errors"] or report["nonfinite_output_fields"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
