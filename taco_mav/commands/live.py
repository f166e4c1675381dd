"""`taco-mav` commands that talk MAVLink: run (the daemon), sim (the autopilot simulator), demo (both on
loopback). Each checks its arguments and inputs (`taco_mav.checks`) before opening a socket or a thread."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from taco_mav import checks
from taco_mav.cli_support import EXIT_INTERRUPTED
from taco_mav.commands.offline import show_progress
from taco_mav.errors import UsageError

if TYPE_CHECKING:
    from taco_mav.config import Profile

log = logging.getLogger("taco_mav")

def check_camera_and_map(args: argparse.Namespace, matcher: str) -> None:
    """--camera and --map: what CVGL fixes need, unless --dead-reckoning says to run without them."""
    if args.dead_reckoning:
        if args.camera or args.map:
            raise UsageError("--dead-reckoning: runs without camera and map; drop --camera/--map or this flag")
        return
    if args.camera is None and matcher != "emulator":
        raise UsageError(f"--camera: required (matcher {matcher} matches camera frames against the map); "
                         "--dead-reckoning runs without fixes")
    world = args.camera.startswith("world:") if args.camera else False
    if args.camera and world:
        # its mosaic is the default map; `?faults=FILE` after the folder cues camera faults (simulation only)
        checks.world(args.camera[len("world:"):].partition("?")[0], f"--camera {args.camera}")
    elif args.camera and args.camera.startswith("folder:"):
        checks.input_dir(args.camera[len("folder:"):].partition("@")[0], "--camera")
    if args.map:
        checks.geotiff(args.map, "--map")
    elif not world and matcher != "emulator":
        raise UsageError(f"--map: required with --camera {args.camera} (a satellite GeoTIFF in UTM; only "
                         "--camera world:DIR brings its own)")


def world_profile_hint(world_dir: Path, profile: Profile) -> str | None:
    """The warning for a 3-D world (`taco-mav world`, its aerial map ~1 m off) run with a profile that takes
    the map as exact (map.georef_sigma_m 0); None when the pair fits."""
    from taco_mav.datasets.synthetic.world3d import world_is_3d

    if profile.map.georef_sigma_m > 0.0 or not world_is_3d(world_dir):
        return None
    return (f"--camera world:{world_dir} is a 3-D world whose aerial map is georeferenced about 1 m off; profile "
            f"{profile.name} takes the map as exact (map.georef_sigma_m 0): --profile synthetic_3d --estimator "
            "taco+ models the offset")


def check_connect(text: str, baud: int) -> None:
    """--connect: a network form with HOST:PORT, or a serial device path (an absent device is a runtime error,
    found when the daemon opens it); a word followed by ':' that is no known scheme is a typo."""
    from taco_mav.mavlink.connection import _NETWORK, parse_connection

    device, _ = parse_connection(text, baud)
    scheme = device.split(":", 1)[0] + ":" if ":" in device else ""
    if scheme and not text.startswith(_NETWORK) and not device.startswith(("/", "COM")):
        raise UsageError(f"--connect {text}: unknown link type {scheme!r} (known: {', '.join(_NETWORK)} or a "
                         "serial device such as /dev/ttyAMA0:921600)")


def cmd_run(args: argparse.Namespace) -> int:
    from taco_mav.config import Estimator, load_profile
    from taco_mav.mavlink.appendlog import session_dir
    from taco_mav.mavlink.signing import key_file

    origin = None
    if args.origin:
        vals = checks.coordinates(args.origin, "--origin", ("LAT", "LON", "ALT"), optional_last=True)
        origin = (vals[0], vals[1], vals[2] if len(vals) > 2 else 0.0)
    checks.number(args.matcher_latency, "--matcher-latency", 0.0, 60.0)
    profile = load_profile(args.profile)
    check_connect(args.connect, profile.link.baud)
    estimator = Estimator(args.estimator) if args.estimator else profile.estimator
    signing = key_file(args.signing_key) if args.signing_key else None
    check_camera_and_map(args, profile.matcher)
    if args.camera and args.camera.startswith("world:") and (hint := world_profile_hint(
            Path(args.camera[len("world:"):]), profile)):
        log.warning(hint)
    if args.log_dir:
        checks.output_dir(args.log_dir, "--log-dir", create=False)
    record = None
    if args.record:
        if not args.log_dir or not args.camera:
            raise UsageError("--record needs --log-dir (the session folder the frames go to) and --camera")
        checks.number(args.record_rate, "--record-rate", 0.0, 100.0, low_open=True)
        checks.number(args.record_width, "--record-width", 0, 10_000)
        checks.number(args.record_budget_mb, "--record-budget-mb", 0.0, low_open=True)
        from taco_mav.daemon.record import RecordOptions

        record = RecordOptions(rate_hz=args.record_rate, width=args.record_width, budget_mb=args.record_budget_mb)
    from taco_mav.daemon.daemon import DaemonOptions, run_daemon  # the heavy import, after every check
    from taco_mav.datasets.synthetic import register_world_camera

    register_world_camera()  # --camera world:DIR (camera.open_camera's registry; the daemon never imports datasets)

    log_dir = None
    if args.log_dir:
        log_dir = session_dir(checks.output_dir(args.log_dir, "--log-dir"))  # each session its own folder
        log.info("logging this session to %s", log_dir)
    opts = DaemonOptions(connect=args.connect, camera=args.camera, map_path=Path(args.map) if args.map else None,
                         log_dir=log_dir, origin=origin, estimator=estimator,
                         matcher_latency_s=args.matcher_latency, signing_key=signing, record=record,
                         shadow=args.shadow)
    return run_daemon(profile, opts)  # SIGTERM: a clean stop, 0; Ctrl-C: the same stop, 130


def cmd_sim(args: argparse.Namespace) -> int:
    from taco_mav.sim import simulate

    home = checks.coordinates(args.home, "--home", ("LAT", "LON", "ALT")) if args.home else None
    if args.spoof_drift is not None and args.spoof_after is None:
        raise UsageError("--spoof-drift needs --spoof-after")
    checks.number(args.speed, "--speed", 0.0, 1000.0, low_open=True)
    checks.number(args.duration, "--duration", 0.0, low_open=True)
    checks.number(args.deny_after, "--deny-after", 0.0)
    checks.number(args.gnss_noise, "--gnss-noise", 0.0, 1000.0)
    checks.number(args.spoof_after, "--spoof-after", 0.0)
    checks.number(args.spoof_drift, "--spoof-drift", 0.0, 1000.0)
    checks.number(args.wait, "--wait", 0.0, low_open=True)
    if bool(args.drive) == bool(args.tlog):
        raise UsageError("give either --drive DIR or --tlog SESSION/mav.tlog")
    if args.frames and not args.tlog:
        raise UsageError("--frames goes with --tlog")
    if args.tlog:
        drive = checks.input_file(args.tlog, "--tlog")
        if args.frames:
            from taco_mav.datasets.recording import load_recording

            load_recording(drive, checks.input_dir(args.frames, "--frames"))  # the frames are this session's
            log.info("serve the frames to the daemon with --camera folder:%s", args.frames)
    else:
        drive = checks.input_dir(args.drive, "--drive")
    out = checks.fresh_folder(checks.output_dir(args.out), "results.json", args.force)
    doc = simulate(drive, args.connect, out, args.speed, deny_after_s=args.deny_after,
                   lockstep=args.lockstep, duration_s=args.duration, gps1_type=args.gps1_type,
                   gps2_type=args.gps2_type, gnss_noise_m=args.gnss_noise, seed=args.seed,
                   spoof_after_s=args.spoof_after, spoof_drift_mps=args.spoof_drift or 0.0,
                   spoof_jump_m=args.spoof_jump, home=tuple(home) if home else None, send_home=not args.no_home,
                   wait_companion_s=args.wait, score_from_s=args.score_from)
    for name, seq in doc["sequences"].items():
        print(sim_table(name, seq))
    print(f"wrote {out / 'results.json'}")
    return 0


def fmt(value: object, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def sim_table(name: str, seq: dict, refusal: tuple[str, str] = ("EKF3 would refuse it", "the reported 1-sigma")
              ) -> str:
    """The simulator's figures for one drive as an aligned text table, ending with ArduPilot's acceptance checks
    and their figures (`ardupilot_rows`). refusal: the label of the row that says why EKF3 would not use the
    stream and the words for the accuracy it was sent (`ekf3_refusal`); that row is there only when it would not."""
    rows = [
        ("drive", name),
        ("ATE (first-pose aligned)", f"{fmt(seq.get('ate_m'), '.2f')} m"),
        ("ATE (UTM, unaligned)", f"{fmt(seq.get('ate_unaligned_m'), '.2f')} m"),
        ("length", f"{fmt(seq.get('length_km'), '.3f')} km"),
        ("ATE per km", f"{fmt(seq.get('ate_m_per_km'), '.2f')} m/km"),
        *([("ATE denied/spoofed / max", f"{fmt(seq.get('ate_denied_m'), '.2f')} / "
                                        f"{fmt(seq.get('max_error_denied_m'), '.2f')} m "
                                        f"(from {fmt(seq.get('denied_from_s'), '.0f')} s)")]
          if "ate_denied_m" in seq else []),
        ("GPS_INPUT received", f"{seq.get('gps_input_count', 0)} (fix types {seq.get('fix_type_counts', {})})"),
        ("GPS_INPUT rate", f"{fmt(seq.get('gps_input_rate_hz'), '.2f')} Hz"),
        ("interval p50 / p99 / max", f"{fmt(seq.get('gps_input_interval_p50_ms'), '.0f')} / "
                                     f"{fmt(seq.get('gps_input_interval_p99_ms'), '.0f')} / "
                                     f"{fmt(seq.get('gps_input_interval_max_ms'), '.0f')} ms"),
        *ardupilot_rows(seq),
    ]
    why = ekf3_refusal(seq, refusal[1])
    if why is not None:
        rows.append((refusal[0], why))
    return "\n".join(f"{k:28s} {v}" for k, v in rows)


def ardupilot_rows(seq: dict) -> list[tuple[str, str]]:
    """ArduPilot's acceptance checks of a GPS_INPUT stream (sim/gps_mav.py), each with the figures it is judged
    on: AP_GPS's timing (average interval, gaps over 245 ms in a row) and EKF3's GPS checks, which must hold for
    10 s in a row before EKF3 uses the position (3D fix, HDOP, horizontal accuracy, satellites; the speed
    accuracy is checked apart)."""
    from taco_mav.sim.gps_mav import (AVG_MAX_S, GAP_MAX_S, GATE_HACC_MAX_M, GATE_HDOP_MAX, GATE_SACC_MAX_MPS,
                                      GATE_SATS_MIN)

    timing_ok = seq.get("gps_unhealthy_updates") == 0 and not seq.get("gps_timeout", True)
    ready = seq.get("ekf_ready_after_s")
    ekf = (f"met, in use {ready:.1f} s after the first GPS_INPUT" if seq.get("ekf_gates_ok") and ready is not None
           else "NOT met")
    return [
        ("AP_GPS timing", f"{'met' if timing_ok else 'NOT met'} (average interval "
                          f"{fmt(seq.get('gps_input_interval_avg_ms'), '.0f')} ms < {AVG_MAX_S * 1e3:.0f}; two "
                          f"gaps > {GAP_MAX_S * 1e3:.0f} ms in a row {seq.get('consecutive_gaps_over_245ms')} "
                          f"times)"),
        ("EKF3 GPS checks (10 s)", f"{ekf} ({fmt(seq.get('ekf_gate_pass_fraction'), '.1%')} of GPS_INPUT pass)"),
        ("  HDOP p50 / max", f"{fmt(seq.get('hdop_p50'), '.2f')} / {fmt(seq.get('hdop_max'), '.2f')} "
                             f"(<= {GATE_HDOP_MAX:g})"),
        ("  accuracy p50 / max", f"{fmt(seq.get('horiz_accuracy_p50_m'), '.2f')} / "
                                 f"{fmt(seq.get('horiz_accuracy_max_m'), '.2f')} m (<= {GATE_HACC_MAX_M:g} m)"),
        ("  satellites (virtual) min", f"{fmt(seq.get('satellites_min'), 'd')} (>= {GATE_SATS_MIN})"),
        ("  speed accuracy max", f"{fmt(seq.get('speed_accuracy_max_mps'), '.2f')} m/s (<= {GATE_SACC_MAX_MPS:g} "
                                 f"m/s: {'met' if seq.get('ekf_speed_accuracy_ok') else 'NOT met'})"),
    ]


def ekf3_refusal(seq: dict, sigma: str = "the reported 1-sigma") -> str | None:
    """Why EKF3 would not use the stream, in one line with the figures (None when its checks were met). sigma
    names the accuracy that was sent (e.g. "its honest 1-sigma" for paper mode)."""
    from taco_mav.sim.gps_mav import GATE_HACC_MAX_M, GATE_HDOP_MAX, GATE_SATS_MIN

    if seq.get("ekf_gates_ok"):
        return None
    why: list[str] = []
    hacc, hdop, sats = seq.get("horiz_accuracy_p50_m"), seq.get("hdop_p50"), seq.get("satellites_min")
    hdop_over = hdop is not None and hdop > GATE_HDOP_MAX
    if hacc is not None and hacc > GATE_HACC_MAX_M:
        why.append(f"{sigma} (p50 {hacc:.2f} m) is over the {GATE_HACC_MAX_M:g} m EKF3 accepts"
                   + (f" (HDOP p50 {hdop:.2f} > {GATE_HDOP_MAX:g})" if hdop_over else ""))
    elif hdop_over:
        why.append(f"HDOP p50 {hdop:.2f} > {GATE_HDOP_MAX:g}")
    if sats is not None and sats < GATE_SATS_MIN:
        why.append(f"{sats} satellites < {GATE_SATS_MIN}")
    if seq.get("gps_unhealthy_updates") or seq.get("gps_timeout"):
        why.append("AP_GPS's timing checks fail")
    if not why:
        why.append(f"its checks never held 10 s in a row ({fmt(seq.get('ekf_gate_pass_fraction'), '.0%')} of "
                   "GPS_INPUT pass)")
    return "; ".join(why)


def cmd_demo(args: argparse.Namespace) -> int:
    from taco_mav.demo import DEMO_ESTIMATOR, run_demo

    res = run_demo(Path(args.out), progress=show_progress(args), speed=args.speed,
                   estimator=args.estimator or DEMO_ESTIMATOR, force=args.force)
    mode = "paper mode" if res.estimator == "paper" else res.estimator
    print(f"{'estimator / matcher':28s} {res.estimator} / {res.matcher} (profile {res.profile})")
    print(sim_table(res.drive, res.results, refusal=(f"EKF3 would refuse {mode}", "its honest 1-sigma")))
    fixes = res.daemon.get("fixes", {})
    print(f"{'CVGL fixes accepted':28s} {fixes.get('accepted', 0)} of {sum(fixes.values())} answered")
    print(f"{'wall time':28s} {res.wall_s:.0f} s{' (interrupted)' if res.interrupted else ''}")
    print(f"results:    {res.results_path}")
    print(f"trajectory: {res.plot_path}")
    if res.interrupted:
        print("taco-mav demo: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0
