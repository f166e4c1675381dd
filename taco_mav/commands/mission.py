"""`taco-mav mission`: one closed-loop mission on ArduPilot Rover SITL or PX4 SITL (SIH) with the daemon in the loop
(`taco_mav.closedloop`), its scored figures written as JSON. Every option is checked before the simulator starts:
the binary, the options that belong to the other autopilot, the fault's set-up, the profile, the output paths."""

from __future__ import annotations

import argparse
import json
import logging
import os
from pathlib import Path
from typing import Any

from taco_mav import checks
from taco_mav.errors import UsageError

log = logging.getLogger("taco_mav")

AUTOPILOTS = ("ardupilot", "px4")
SETUPS = {"ardupilot": ("solo", "handover"), "px4": ("solo", "handover", "gnss")}  # closedloop.ardupilot/px4.SETUPS
# taco_mav.closedloop.faults.KINDS, written out so that parsing does not import pymavlink (tests/test_mission.py
# checks they agree)
FAULTS = ("camera", "stall", "link", "glitch", "spoof")
BINARY = {"ardupilot": ("ardurover", "ARDUROVER"), "px4": ("px4", "PX4_SITL")}  # the binary's option, its default
# options of one autopilot only: dest -> (the option, its autopilot, its value when not given)
ONLY = {"fault": ("--fault", "ardupilot", None), "fault_after": ("--fault-after", "ardupilot", None),
        "map_seed": ("--map-seed", "ardupilot", None), "daemon_origin": ("--daemon-origin", "ardupilot", False),
        "ardurover": ("--ardurover", "ardupilot", None), "px4": ("--px4", "px4", None),
        "gcs_origin": ("--[no-]gcs-origin", "px4", None)}
# the figures printed (result.json and --out hold them all)
NOT_PRINTED = ("spec", "statustext", "px4_statustext", "modes", "px4_params")


def run_dir_for(out: Path) -> Path:
    """The run folder beside --out: its name without the suffix (runs/solo.json -> runs/solo), or NAME.run."""
    return out.with_suffix("") if out.suffix else out.with_name(out.name + ".run")


def _binary(args: argparse.Namespace) -> Path:
    dest, env = BINARY[args.autopilot]
    given = getattr(args, dest)
    text = given or os.environ.get(env)
    if not text:
        raise UsageError(f"--{dest}: required (or set ${env}): the {args.autopilot} SITL binary "
                         f"({'docs/sitl.md' if args.autopilot == 'ardupilot' else 'docs/px4.md'} builds it)")
    return checks.input_file(text, f"--{dest}" if given else f"${env}")


def _params(items: list[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for text in items:
        name, _, value = text.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise UsageError(f"--param {text}: expected NAME=VALUE, VALUE a number") from None
        if not name.strip():
            raise UsageError(f"--param {text}: expected NAME=VALUE")
    return out


def _parm_file(text: str) -> Path:
    """--params-file for ArduPilot: the path, or a file of that name shipped beside the profiles
    (ardupilot_rover_wheels.parm)."""
    from taco_mav.config import PROFILE_DIR

    path = Path(text)
    if not path.exists() and path.name == text and (PROFILE_DIR / text).is_file():
        return PROFILE_DIR / text
    return checks.input_file(path, "--params-file")


def check_options(args: argparse.Namespace) -> None:
    """Usage errors before any work: options of the other autopilot, a set-up it has not, numbers out of range,
    a fault without the set-up it needs."""
    for dest, (option, owner, unset) in ONLY.items():
        if owner != args.autopilot and getattr(args, dest) != unset:
            raise UsageError(f"{option}: {owner} only (this is --autopilot {args.autopilot})")
    if args.setup not in SETUPS[args.autopilot]:
        raise UsageError(f"--setup {args.setup}: --autopilot {args.autopilot} flies "
                         f"{', '.join(SETUPS[args.autopilot])}")
    checks.number(args.laps, "--laps", 1, 100)
    checks.number(args.side, "--side", 0.0, 1000.0, low_open=True)
    checks.number(args.speed, "--speed", 0.0, 20.0, low_open=True)
    checks.number(args.gnss_off_after, "--gnss-off-after", 0.0)
    checks.number(args.timeout, "--timeout", 0.0, low_open=True)
    checks.number(args.restart_after, "--restart-after", 0.0)
    checks.number(args.fault_after, "--fault-after", 0.0)
    if args.fault in ("glitch", "spoof") and args.setup != "handover":
        raise UsageError(f"--fault {args.fault}: needs --setup handover (SITL's GNSS steering the rover)")
    if args.fault_after is not None and args.fault is None:
        raise UsageError("--fault-after: goes with --fault KIND")
    if args.through and args.realism != "3d":
        raise UsageError("--through: goes with --realism 3d (a flat world has nothing to drive through)")


def mission_spec(args: argparse.Namespace) -> Any:
    """The `ardupilot.MissionSpec` or `px4.Px4MissionSpec` the options ask for (checked: `check_options`)."""
    common = {"side_m": args.side, "laps": args.laps, "setup": args.setup, "gnss_off_after_s": args.gnss_off_after,
              "estimator": args.estimator, "timeout_s": args.timeout, "restart_after_s": args.restart_after,
              "realism": args.realism, "world_seed": args.world_seed, "keep_clear": not args.through}
    if args.autopilot == "ardupilot":
        from taco_mav.closedloop.ardupilot import MissionSpec, default_profile, read_parm_file

        extra = read_parm_file(_parm_file(args.params_file)) if args.params_file else {}
        extra.update(_params(args.param))  # --param after the file: it wins
        return MissionSpec(**common, wp_speed=args.speed, profile=args.profile or default_profile(args.setup),
                           daemon_origin=args.daemon_origin, daemon_args=tuple(args.daemon_arg), fault=args.fault,
                           fault_after_s=60.0 if args.fault_after is None else args.fault_after,
                           map_seed=args.map_seed, extra_params=extra)
    from taco_mav.closedloop.px4 import Px4MissionSpec, default_profile

    return Px4MissionSpec(**common, cruise_speed=args.speed, profile=args.profile or default_profile(args.setup),
                          gcs_sets_origin=args.gcs_origin, extra_params=_params(args.param),
                          daemon_args=list(args.daemon_arg),
                          params_file="auto" if args.params_file is None else args.params_file)


def cmd_mission(args: argparse.Namespace) -> int:
    check_options(args)
    binary = _binary(args)
    spec = mission_spec(args)
    if spec.setup != "gnss":
        from taco_mav.config import load_profile

        load_profile(spec.profile)  # an unknown or invalid profile: refused here, not by the daemon mid-run
    if args.autopilot == "px4" and spec.params_file not in ("auto", ""):
        checks.input_file(spec.params_file, "--params-file")
    out = checks.output_file(args.out)
    run_dir = Path(args.run_dir) if args.run_dir else run_dir_for(out)
    checks.fresh_folder(checks.output_dir(run_dir, "--run-dir", create=False), "result.json", args.force,
                        "--run-dir")
    log.info("mission: %s, %s set-up, %d lap(s) of %g m at %g m/s; the run in %s (a few minutes)",
             args.autopilot, spec.setup, spec.laps, spec.side_m, args.speed, run_dir)
    if args.autopilot == "ardupilot":
        from taco_mav.closedloop.ardupilot import run_mission

        res = run_mission(binary, run_dir, spec)
    else:
        from taco_mav.closedloop.px4 import run_px4_mission

        res = run_px4_mission(binary, run_dir, spec)
    out.write_text(json.dumps(res, indent=2, default=float))
    print(json.dumps({k: v for k, v in res.items() if k not in NOT_PRINTED}, indent=1, default=float))
    print(f"wrote {out} (the run: {run_dir})")
    return 0
