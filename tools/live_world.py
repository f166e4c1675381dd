"""Live figures on a synthetic world: the simulator (a scripted ArduPilot rover) plays WORLD to the real daemon in
this process over loopback UDP, lockstep, and the simulator's scoring is printed (ATE, EKF3 gate pass, ...) with
the daemon's summary; the same path as tests/test_live.py's run_live.

    python tools/live_world.py W [--profile synthetic_3d] [--estimator taco+] [--speed 5] [--deny-after 1]
                                 [--gnss-noise 1] [--set plus.trigger_distance_m=40 ...] [--out results.json]

World: `taco-mav world --out W --seed S` (3-D by default: profile synthetic_3d; a flat world, `--realism flat`:
--profile synthetic). ATE is metres over the whole drive (DESIGN.md), with GNSS (the simulator's receiver) for
the first --deny-after seconds only.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

KEYS = ("ate_m", "ate_unaligned_m", "ate_denied_m", "max_error_m", "ekf_gate_pass_fraction", "horiz_accuracy_p50_m",
        "fix_type_counts", "gps_input_rate_hz", "length_km")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("world", type=Path)
    ap.add_argument("--profile", default="synthetic_3d")
    ap.add_argument("--estimator", default="taco+", choices=("paper", "taco+"))
    ap.add_argument("--speed", type=float, default=5.0, help="real-time factor (lockstep)")
    ap.add_argument("--deny-after", type=float, default=1.0, help="drive seconds of real GNSS")
    ap.add_argument("--gnss-noise", type=float, default=1.0, help="the receiver's 1-sigma, m")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=JSON", help="profile override")
    ap.add_argument("--out", type=Path, help="write the figures here as JSON")
    args = ap.parse_args(argv)

    from taco_mav.config import Estimator, load_profile, replace_in
    from taco_mav.daemon.daemon import Daemon, DaemonOptions
    from taco_mav.mavlink.connection import free_udp_port
    from taco_mav.sim import Simulator

    prof = load_profile(args.profile)
    for item in args.set:
        key, _, value = item.partition("=")
        prof = replace_in(prof, key, json.loads(value))
    port = free_udp_port()
    sim = Simulator(args.world, f"udpout:127.0.0.1:{port}", speed=args.speed, lockstep=True, wait_companion_s=10.0,
                    drain_s=0.3, deny_after_s=args.deny_after, gnss_noise_m=args.gnss_noise)
    daemon = Daemon(prof, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{args.world}",
                                        estimator=Estimator(args.estimator)),
                    clock=sim.clock, wall_clock=sim.utc_now)
    start = time.time()
    daemon.start()
    try:
        sim.start()
        if not sim.join(timeout=3600.0):
            print("simulator did not finish", file=sys.stderr)
            return 1
    finally:
        daemon.stop()
        daemon.join(5.0)
    seq = sim.results()["sequences"][sim.drive.name]
    summary = daemon.summary()
    out = {k: seq.get(k) for k in KEYS}
    out.update(fixes=summary.get("fixes"), map_offset=(summary.get("estimator") or {}).get("map_offset"),
               wall_s=round(time.time() - start, 1))
    print(json.dumps(out))
    if args.out:
        args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
