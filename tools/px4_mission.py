#!/usr/bin/env python3
"""Closed loop on PX4: SIH (PX4's built-in simulator, no Gazebo) Ackermann rover driven by taco-mav.

The command line of `taco_mav.closedloop.px4` (the harness: what it starts, drives and scores, and its set-ups
gnss, solo and handover, are in its docstring); `taco-mav mission --autopilot px4` is the same mission from the
package's own command.

    python tools/px4_mission.py --px4 $PX4_SITL --out /tmp/px4_1 [--setup solo|handover|gnss] [--estimator paper]

Writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv, gcs.tlog (all the ground
station heard), the daemon's tlog and events in OUT/daemon/<UTC start time>/, OUT/daemon.log, and OUT/px4/ (rootfs
with PX4's log and parameters, out.log: its console), and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from taco_mav.closedloop.px4 import Px4MissionSpec, default_profile, run_px4_mission


def _kv(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    if not name or not value:
        raise argparse.ArgumentTypeError(f"{text!r}: NAME=VALUE")
    return name, float(value)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--px4", default=os.environ.get("PX4_SITL"), help="PX4 SITL binary (default $PX4_SITL)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--setup", choices=("solo", "handover", "gnss"), default="solo")
    ap.add_argument("--estimator", choices=("paper", "taco+"), default="taco+")
    ap.add_argument("--profile", help="daemon profile (default px4_rover; handover: px4_rover_gps2)")
    ap.add_argument("--laps", type=int, default=2)
    ap.add_argument("--side", type=float, default=60.0)
    ap.add_argument("--cruise-speed", type=float, default=3.0, help="RO_SPEED_LIM, m/s")
    ap.add_argument("--gnss-off-after", type=float, default=30.0)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--gcs-origin", action=argparse.BooleanOptionalAction, default=None,
                    help="the ground station sets EKF2's origin at home (default: solo only)")
    ap.add_argument("--params-file", default="auto",
                    help="QGroundControl parameter file for PX4 (default: the shipped px4_rover_<setup>.params; "
                         "'' for none)")
    ap.add_argument("--param", type=_kv, action="append", default=[], metavar="NAME=VALUE",
                    help="PX4 parameter at boot (repeatable)")
    ap.add_argument("--daemon-arg", action="append", default=[], help="extra `taco-mav run` argument (repeatable)")
    ap.add_argument("--restart-after", type=float, help="SIGTERM the daemon this many seconds after AUTO.MISSION "
                                                          "and start it again with the same command")
    a = ap.parse_args()
    if not a.px4 or not Path(a.px4).exists():
        print("px4_mission: error: --px4 (or $PX4_SITL) must name the PX4 SITL binary", file=sys.stderr)
        return 2
    spec = Px4MissionSpec(side_m=a.side, laps=a.laps, cruise_speed=a.cruise_speed, setup=a.setup,
                          gnss_off_after_s=a.gnss_off_after, estimator=a.estimator,
                          profile=a.profile or default_profile(a.setup),
                          timeout_s=a.timeout, gcs_sets_origin=a.gcs_origin, extra_params=dict(a.param),
                          daemon_args=a.daemon_arg, params_file=a.params_file, restart_after_s=a.restart_after)
    res = run_px4_mission(Path(a.px4), Path(a.out), spec)
    hidden = ("spec", "statustext", "px4_statustext", "modes", "px4_params")
    print(json.dumps({k: v for k, v in res.items() if k not in hidden}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
