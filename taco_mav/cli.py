"""The `taco-mav` command: parse arguments, call one importable function, map TacoError to an exit code."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Sequence

from taco_mav.errors import TacoError

log = logging.getLogger("taco_mav")


def _cmd_bench(args: argparse.Namespace) -> int:
    from taco_mav.bench import run_bench

    only = args.only.split(",") if args.only else None
    results = run_bench(Path(args.out), only=only, progress=not args.quiet)
    for key in sorted(results):
        print(f"{key:45s} {results[key]}")
    print(f"wrote {args.out}")
    return 0


def _cmd_world(args: argparse.Namespace) -> int:
    from taco_mav.datasets.synthetic import build_world

    centre = None
    if args.centre:
        try:
            lat, lon = (float(v) for v in args.centre.split(","))
        except ValueError:
            raise TacoError(f"--centre: expected LAT,LON, got {args.centre!r}") from None
        centre = (lat, lon)
    path = build_world(Path(args.out), seed=args.seed, length_km=args.length_km, centre=centre,
                       along_drive=Path(args.along_drive) if args.along_drive else None,
                       imu_preset=args.imu, progress=not args.quiet)
    print(f"wrote world {path}")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from taco_mav.evaluation.evaluate import EvalRequest, evaluate

    ablations: tuple[str, ...] = ()
    if args.ablations:
        ablations = ("all",) if args.ablations == "all" else tuple(args.ablations.split(","))
    elif args.ablation:
        ablations = ("full", args.ablation)
    req = EvalRequest(
        out=Path(args.out), profile=args.profile, kitti_root=Path(args.kitti_root) if args.kitti_root else None,
        sequences=tuple(s.strip() for s in args.sequences.split(",") if s.strip()) if args.sequences else (),
        drives=tuple(Path(d) for d in args.drive), matcher=args.matcher, ablations=ablations, seed=args.seed,
        latency_s=args.matcher_latency, apply_on_arrival=args.apply_on_arrival, estimator=args.estimator,
        cross_area=args.cross_area, plots=not args.no_plots, progress=not args.quiet)
    results = evaluate(req)
    print((Path(args.out) / "table.md").read_text())
    s = results["summary"]
    print(f"median ATE {s['median_ate_m']} m (IMU only {s['median_ate_imu_only_m']} m) over {s['sequences_run']} "
          f"sequence(s); results in {Path(args.out) / 'results.json'}")
    return 0


def _cmd_drift(args: argparse.Namespace) -> int:
    import json

    from taco_mav.config import load_profile
    from taco_mav.datasets.tlog import load_tlog
    from taco_mav.evaluation.drift import measure_drift, report_text
    from taco_mav.evaluation.evaluate import EvalRequest, load_drives

    profile = load_profile(args.profile)
    drives = [load_tlog(Path(f), imu_message=args.imu_message) for f in args.tlog]
    if args.sequences or args.drive or not drives:
        drives += load_drives(EvalRequest(
            out=Path("."), kitti_root=Path(args.kitti_root) if args.kitti_root else None,
            sequences=tuple(s.strip() for s in args.sequences.split(",") if s.strip()) if args.sequences else (),
            drives=tuple(Path(d) for d in args.drive)))
    reports = [measure_drift(d, min_speed_mps=args.min_speed) for d in drives]
    name = Path(args.profile).stem
    print("\n\n".join(report_text(r, profile.plus, name) for r in reports))
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"profile": args.profile, "drives": [r.to_dict() for r in reports]}, indent=2) + "\n")
        print(f"wrote {out}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from taco_mav.config import Estimator, load_profile
    from taco_mav.link.daemon import DaemonOptions, run_daemon
    from taco_mav.link.signing import key_file

    origin = None
    if args.origin:
        try:
            parts = [float(v) for v in args.origin.split(",")]
            origin = (parts[0], parts[1], parts[2] if len(parts) > 2 else 0.0)
            if len(parts) not in (2, 3):
                raise ValueError
        except (ValueError, IndexError):
            raise TacoError(f"--origin: expected LAT,LON[,ALT], got {args.origin!r}") from None
    profile = load_profile(args.profile)
    estimator = Estimator(args.estimator) if args.estimator else profile.estimator
    opts = DaemonOptions(connect=args.connect, camera=args.camera, map_path=Path(args.map) if args.map else None,
                         log_dir=Path(args.log_dir) if args.log_dir else None, origin=origin, estimator=estimator,
                         matcher_latency_s=args.matcher_latency,
                         signing_key=key_file(args.signing_key) if args.signing_key else None)
    return run_daemon(profile, opts)


def _cmd_sim(args: argparse.Namespace) -> int:
    from taco_mav.sim import simulate

    home = None
    if args.home:
        try:
            lat, lon, alt = (float(v) for v in args.home.split(","))
        except ValueError:
            raise TacoError(f"--home: expected LAT,LON,ALT, got {args.home!r}") from None
        home = (lat, lon, alt)
    if args.spoof_drift is not None and args.spoof_after is None:
        raise TacoError("--spoof-drift needs --spoof-after")
    doc = simulate(Path(args.drive), args.connect, Path(args.out), args.speed, deny_after_s=args.deny_after,
                   lockstep=args.lockstep, duration_s=args.duration, gps1_type=args.gps1_type,
                   gps2_type=args.gps2_type, gnss_noise_m=args.gnss_noise, seed=args.seed,
                   spoof_after_s=args.spoof_after, spoof_drift_mps=args.spoof_drift or 0.0,
                   spoof_jump_m=args.spoof_jump, home=home, send_home=not args.no_home, wait_companion_s=args.wait)
    for name, seq in doc["sequences"].items():
        print(_sim_table(name, seq))
    print(f"wrote {Path(args.out) / 'results.json'}")
    return 0


def _fmt(value: object, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def _sim_table(name: str, seq: dict) -> str:
    """The simulator's figures for one drive as an aligned text table."""
    rows = [
        ("drive", name),
        ("ATE (first-pose aligned)", f"{_fmt(seq.get('ate_m'), '.2f')} m"),
        ("ATE (UTM, unaligned)", f"{_fmt(seq.get('ate_unaligned_m'), '.2f')} m"),
        ("length", f"{_fmt(seq.get('length_km'), '.3f')} km"),
        ("ATE per km", f"{_fmt(seq.get('ate_m_per_km'), '.2f')} m/km"),
        *([("ATE denied/spoofed / max", f"{_fmt(seq.get('ate_denied_m'), '.2f')} / "
                                        f"{_fmt(seq.get('max_error_denied_m'), '.2f')} m "
                                        f"(from {_fmt(seq.get('denied_from_s'), '.0f')} s)")]
          if "ate_denied_m" in seq else []),
        ("GPS_INPUT received", f"{seq.get('gps_input_count', 0)} (fix types {seq.get('fix_type_counts', {})})"),
        ("GPS_INPUT rate", f"{_fmt(seq.get('gps_input_rate_hz'), '.2f')} Hz"),
        ("interval p50 / p99 / max", f"{_fmt(seq.get('gps_input_interval_p50_ms'), '.0f')} / "
                                     f"{_fmt(seq.get('gps_input_interval_p99_ms'), '.0f')} / "
                                     f"{_fmt(seq.get('gps_input_interval_max_ms'), '.0f')} ms"),
        ("two gaps > 245 ms in a row", str(seq.get("consecutive_gaps_over_245ms"))),
        ("EKF3 gates (10 s)", f"{'ok' if seq.get('ekf_gates_ok') else 'NOT met'} "
                              f"(pass {_fmt(seq.get('ekf_gate_pass_fraction'), '.0%')}, HDOP p50 "
                              f"{_fmt(seq.get('hdop_p50'), '.2f')})"),
    ]
    return "\n".join(f"{k:28s} {v}" for k, v in rows)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from taco_mav.calibrate import calibrate, parse_board

    res = calibrate(Path(args.images), parse_board(args.board), args.square, Path(args.out), fisheye=args.fisheye)
    K, D = res.lens.K, res.lens.D
    print(f"board found in {len(res.used)} of {res.images} images")
    print(f"fx {K[0, 0]:.2f}  fy {K[1, 1]:.2f}  cx {K[0, 2]:.2f}  cy {K[1, 2]:.2f} px "
          f"({res.lens.width}x{res.lens.height})")
    print(f"{res.lens.model.value} distortion {' '.join(f'{d:+.5f}' for d in D)}")
    print(f"RMS reprojection error {res.rms_px:.3f} px")
    print(f"wrote {res.out}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from taco_mav.demo import run_demo

    res = run_demo(Path(args.out), progress=not args.quiet, speed=args.speed, estimator=args.estimator)
    print(_sim_table(res.drive, res.results))
    fixes = res.daemon.get("fixes", {})
    print(f"{'CVGL fixes accepted':28s} {fixes.get('accepted', 0)} of {sum(fixes.values())} answered")
    print(f"{'wall time':28s} {res.wall_s:.0f} s")
    print(f"results:    {res.results_path}")
    print(f"trajectory: {res.plot_path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    common.add_argument("-q", "--quiet", action="store_true", help="warnings only, no progress bars")
    parser = argparse.ArgumentParser(prog="taco-mav", description="GNSS substitute for ground robots (TACO over MAVLink)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("bench", parents=[common], help="speed/accuracy benchmarks to JSON")
    p.add_argument("--out", required=True, help="output JSON file")
    p.add_argument("--only", help="comma-separated section names (e.g. fusion)")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("world", parents=[common], help="generate a synthetic world + drive in KITTI raw layout")
    p.add_argument("--out", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--length-km", type=float, default=1.0)
    p.add_argument("--centre", help="LAT,LON of the world centre (default near Karlsruhe)")
    p.add_argument("--along-drive", help="a KITTI raw drive directory whose GPS track the roads follow")
    p.add_argument("--imu", default="automotive", help="IMU noise preset: automotive | rt3003 | none")
    p.set_defaults(func=_cmd_world)

    p = sub.add_parser("eval", parents=[common], help="offline evaluation on KITTI sequences or drives")
    p.add_argument("--kitti-root", help="KITTI raw root (with --sequences)")
    p.add_argument("--sequences", help="odometry sequence ids, e.g. 04,05")
    p.add_argument("--drive", action="append", default=[], help="a KITTI-layout drive dir (repeatable)")
    p.add_argument("--matcher", choices=("emulator", "classical", "fg2"), help="override the profile's matcher")
    p.add_argument("--out", required=True, help="run folder for results.json, table.md, trajectories, plots")
    p.add_argument("--profile", default="kitti", help="vehicle profile name or YAML path (default kitti)")
    p.add_argument("--ablation", help="one ablation beside the full pipeline (no_yaw_gate, single_crop, ...)")
    p.add_argument("--ablations", help="'all' or a comma-separated list")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (emulator)")
    p.add_argument("--matcher-latency", type=float, default=0.0, help="deliver each fix S seconds after capture")
    p.add_argument("--apply-on-arrival", action="store_true", help="apply late fixes naively, as if current")
    p.add_argument("--estimator", choices=("paper", "taco+"), help="estimator mode (default: the profile's)")
    p.add_argument("--cross-area", action="store_true",
                   help="emulator: FG2's cross-area error figures for every drive (default: the profile's list)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.set_defaults(func=_cmd_eval)

    p = sub.add_parser("drift", parents=[common], help="measure a vehicle's dead-reckoning drift against ground "
                       "truth and fit taco+'s process noise (plus: q_*) to it")
    p.add_argument("--tlog", action="append", default=[], help="a MAVLink tlog recorded with GNSS on (repeatable)")
    p.add_argument("--imu-message", help="tlog: which IMU message to use (default: the first present)")
    p.add_argument("--kitti-root", help="KITTI raw root (with --sequences)")
    p.add_argument("--sequences", help="odometry sequence ids, e.g. 04,05")
    p.add_argument("--drive", action="append", default=[], help="a KITTI-layout drive or synthetic world dir")
    p.add_argument("--profile", default="kitti", help="profile to compare with (name or YAML path; default kitti)")
    p.add_argument("--min-speed", type=float, default=2.0, help="use windows above this truth speed, m/s")
    p.add_argument("--out", help="JSON file for the measurements and the fit")
    p.set_defaults(func=_cmd_drift)

    p = sub.add_parser("run", parents=[common], help="the daemon: MAVLink IMU + camera in, GPS_INPUT out")
    p.add_argument("--profile", required=True, help="vehicle profile name or YAML path (e.g. ardupilot_rover)")
    p.add_argument("--connect", required=True, help="pymavlink connection: udpin:0.0.0.0:14550, tcp:HOST:PORT, "
                   "/dev/ttyAMA0:921600")
    p.add_argument("--camera", help="world:DIR | folder:DIR[@OFFSET_S] | device index | video file | RTSP/GStreamer")
    p.add_argument("--map", help="satellite GeoTIFF (UTM); default: the world's mosaic with --camera world:DIR")
    p.add_argument("--log-dir", help="folder for mav.tlog, events.jsonl and the resolved config")
    p.add_argument("--origin", help="LAT,LON[,ALT] start fix (default: the EKF origin, home, or a real GNSS's "
                   "3D fix, as the autopilot offers)")
    p.add_argument("--estimator", choices=("paper", "taco+"), help="estimator mode (default: the profile's)")
    p.add_argument("--matcher-latency", type=float, default=0.0,
                   help="hold each fix until the autopilot clock is S s past its capture (tests)")
    p.add_argument("--signing-key", help="MAVLink 2 signing key file (32 bytes raw or 64 hex digits): sign what we "
                   "send, ignore unsigned input")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("sim", parents=[common], help="autopilot simulator: play a drive as an ArduPilot rover over MAVLink")
    p.add_argument("--drive", required=True, help="KITTI raw drive folder (..._sync) or synthetic world folder")
    p.add_argument("--connect", required=True, help="pymavlink connection to the companion, e.g. udpout:127.0.0.1:14550")
    p.add_argument("--out", required=True, help="folder for results.json")
    p.add_argument("--speed", type=float, default=1.0, help="real-time factor (default 1)")
    p.add_argument("--deny-after", type=float, help="seconds of real GNSS before NO_FIX; 0: never a fix (default: "
                   "the start-up fix, 1 s; never denied with --spoof-after)")
    p.add_argument("--lockstep", action="store_true", help="never run more than 0.2 s (one 5 Hz period) ahead of the companion's GPS_INPUT")
    p.add_argument("--duration", type=float, help="play at most this many seconds of the drive")
    p.add_argument("--gps1-type", type=int, default=14, help="GPS1_TYPE (default 14: GPS1 = the companion's "
                   "GPS_INPUT, the real receiver is GPS2; 1: the receiver is GPS1, the companion GPS2)")
    p.add_argument("--gps2-type", type=int, help="GPS2_TYPE (default: 1 when GPS1_TYPE is 14, else 14; 0: no GPS2)")
    p.add_argument("--gnss-noise", type=float, default=1.0, metavar="SIGMA_M",
                   help="real receiver 1-sigma, m: white noise plus a wandering bias (default 1.0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the receiver's noise (default 0)")
    p.add_argument("--spoof-after", type=float, metavar="S", help="from S s the receiver is spoofed (keeps a "
                   "confident 3D fix while dragged away)")
    p.add_argument("--spoof-drift", type=float, metavar="MPS", help="spoofing drag speed, m/s (default 0)")
    p.add_argument("--spoof-jump", type=float, default=0.0, metavar="M", help="spoofing jump at its start, m")
    p.add_argument("--home", metavar="LAT,LON,ALT", help="home / EKF origin sent as HOME_POSITION and "
                   "GPS_GLOBAL_ORIGIN (default: the drive's start)")
    p.add_argument("--no-home", action="store_true", help="send neither HOME_POSITION nor GPS_GLOBAL_ORIGIN")
    p.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the companion's HEARTBEAT")
    p.set_defaults(func=_cmd_sim)

    p = sub.add_parser("calibrate", parents=[common], help="camera intrinsics and lens distortion from chessboard "
                       "photos, written as OpenCV FileStorage YAML (the profile's camera.calibration)")
    p.add_argument("--images", required=True, help="folder of chessboard photos (.png, .jpg, ...) of one size")
    p.add_argument("--board", default="9x6", help="inner corners COLSxROWS (default 9x6: a board of 10x7 squares)")
    p.add_argument("--square", type=float, default=0.025, help="side of one square, m (default 0.025)")
    p.add_argument("--out", required=True, help="calibration file to write, e.g. camera.yaml")
    p.add_argument("--fisheye", action="store_true", help="fisheye (equidistant) lens model instead of plumb_bob")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("demo", parents=[common], help="synthetic world + simulator + daemon on loopback, one command")
    p.add_argument("--out", default="taco_demo", help="output folder (default ./taco_demo; the world is reused)")
    p.add_argument("--estimator", choices=("paper", "taco+"), default="paper", help="estimator mode (default paper)")
    p.add_argument("--speed", type=float, default=8.0, help="real-time factor (default 8)")
    p.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except TacoError as exc:
        print(f"taco-mav {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
