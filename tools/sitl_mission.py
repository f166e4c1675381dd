#!/usr/bin/env python3
"""Closed loop on a real autopilot: ArduPilot Rover SITL driven by taco-mav (docs/sitl.md).

The command line of `taco_mav.closedloop.ardupilot` (the harness: what it starts, drives and scores is in its
docstring); `taco-mav mission --autopilot ardupilot` is the same mission from the package's own command.

    python tools/sitl_mission.py --ardurover $ARDUROVER --out /tmp/sitl1 [--setup handover] [--estimator paper]

Writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv, gcs.tlog (all the ground station
heard), the daemon's tlog and events in OUT/daemon/<UTC start time>/, and OUT/sitl/ (SITL's own files), and prints
the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from taco_mav.closedloop.ardupilot import MissionSpec, default_profile, run_mission
from taco_mav.closedloop.faults import KINDS as FAULT_KINDS


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ardurover", default=os.environ.get("ARDUROVER"), help="SITL binary (default $ARDUROVER)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--setup", choices=("solo", "handover"), default="solo")
    ap.add_argument("--estimator", choices=("paper", "taco+"), default="taco+")
    ap.add_argument("--laps", type=int, default=2)
    ap.add_argument("--side", type=float, default=60.0)
    ap.add_argument("--wp-speed", type=float, default=3.0)
    ap.add_argument("--gnss-off-after", type=float, default=30.0)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--profile", help="daemon profile (default ardupilot_rover; handover: ardupilot_rover_gps2)")
    ap.add_argument("--daemon-origin", action="store_true", help="start the daemon with --origin (SITL's home)")
    ap.add_argument("--daemon-arg", action="append", default=[], help="one more `taco-mav run` option (repeat: "
                    "--daemon-arg=--record --daemon-arg=--shadow)")
    ap.add_argument("--realism", choices=("flat", "3d"), default="flat",
                    help="the synthetic world (`taco-mav world --realism`): flat (default) or 3d")
    ap.add_argument("--restart-after", type=float, help="SIGTERM the daemon this many seconds after AUTO and start "
                                                          "it again with the same command")
    ap.add_argument("--fault", choices=FAULT_KINDS, help="a fault on cue (taco_mav/closedloop/faults.py; glitch and "
                                                         "spoof need --setup handover)")
    ap.add_argument("--fault-after", type=float, default=60.0, help="seconds after AUTO the fault starts")
    ap.add_argument("--world-seed", type=int, default=7, help="the world's seed (default 7)")
    ap.add_argument("--through", action="store_true", help="3d: drive the square through the buildings and trees "
                    "(no --keep-clear)")
    ap.add_argument("--map-seed", type=int, help="give the daemon another world's map (this seed) over the same "
                    "ground: a camera that cannot read the map it has")
    a = ap.parse_args()
    if not a.ardurover or not Path(a.ardurover).exists():
        print("sitl_mission: error: --ardurover (or $ARDUROVER) must name the SITL binary", file=sys.stderr)
        return 2
    spec = MissionSpec(side_m=a.side, laps=a.laps, wp_speed=a.wp_speed, setup=a.setup,
                       gnss_off_after_s=a.gnss_off_after, estimator=a.estimator, timeout_s=a.timeout,
                       daemon_origin=a.daemon_origin, restart_after_s=a.restart_after,
                       daemon_args=tuple(a.daemon_arg), fault=a.fault, fault_after_s=a.fault_after,
                       realism=a.realism, world_seed=a.world_seed, map_seed=a.map_seed, keep_clear=not a.through,
                       profile=a.profile or default_profile(a.setup))
    res = run_mission(Path(a.ardurover), Path(a.out), spec)
    print(json.dumps({k: v for k, v in res.items() if k not in ("spec", "statustext")}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
