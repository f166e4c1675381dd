"""The `taco-mav` command: parse arguments, check them, call one importable function, map errors to exit codes.

Every command keeps one contract (`taco_mav.cli_support`): a usage or input problem is found before the first
expensive step and reported as one line `taco-mav CMD: error: ...` naming the option, file, key or value;
exit code 2 for usage and configuration, 1 for data and runtime errors, 130 on Ctrl-C; a traceback only with
--debug. -q/-v/--debug go before or after the subcommand.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from taco_mav import checks
from taco_mav.bench import SECTION_NAMES
from taco_mav.cli_support import TacoArgumentParser, add_global_flags, configure_logging, package_version, run_command
from taco_mav.commands import campaign, live, mission, offline
from taco_mav.config.fields import Estimator
from taco_mav.config.profile import MATCHERS

ESTIMATORS = tuple(e.value for e in Estimator)
# taco_mav.datasets.synthetic.imu_model.PRESETS, written out so that parsing does not import scipy.signal
# (tests/test_cli.py checks they agree)
IMU_PRESETS = ("automotive", "rt3003", "none")


def _force(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--force", action="store_true", help=f"overwrite {what} of an earlier run (default: refuse)")


def build_parser() -> argparse.ArgumentParser:
    common = TacoArgumentParser(add_help=False)
    add_global_flags(common, subcommand=True)
    parser = TacoArgumentParser(prog="taco-mav", description="GNSS substitute for ground robots (TACO over MAVLink)",
                                epilog="exit codes: 0 done, 1 data or runtime error, 2 usage or configuration "
                                       "error, 130 interrupted (Ctrl-C)")
    parser.add_argument("--version", action="version", version=f"taco-mav {package_version()}")
    add_global_flags(parser, subcommand=False)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("bench", parents=[common], help="speed/accuracy benchmarks to JSON")
    p.add_argument("--out", required=True, help="output JSON file")
    p.add_argument("--only", help=f"comma-separated section names: {', '.join(SECTION_NAMES)}")
    p.add_argument("--fg2-checkout", help="fg2 section: a vita-epfl/FG2 checkout (without it the fg2 keys are "
                   "absent)")
    p.add_argument("--fg2-checkpoint", help="fg2 section: FG2's KITTI checkpoint (default: random weights)")
    p.add_argument("--device", default="cuda", choices=("cuda", "cpu", "auto"), help="fg2 section: torch device "
                   "(default cuda)")
    p.add_argument("--fg2-triggers", type=int, help="fg2 section: timed triggers (default 20 on CUDA, 3 on a CPU)")
    p.add_argument("--fg2-warmup", type=int, help="fg2 section: untimed triggers first (default 3 on CUDA, 1 on a "
                   "CPU)")
    p.add_argument("--fg2-published", action="store_true", help="fg2 section: FG2's own forward (fg2.fast: false)")
    p.add_argument("--fg2-compile", action="store_true", help="fg2 section: torch.compile DINOv2 (fg2.compile)")
    p.add_argument("--fg2-device-crops", action="store_true", help="fg2 section: crops warped on the matcher's "
                   "device (fg2.device_crops)")
    p.add_argument("--real-pairs", metavar="DIR", help="real section: a folder of real ground/aerial pair sets "
                   "(pairs.json each; default ../shared/data/real_pairs beside the checkout, or TACO_REAL_PAIRS)")
    p.add_argument("--real-profile", default="ardupilot_rover", help="real section: the profile whose matcher and "
                   "answer check are scored (default ardupilot_rover)")
    p.set_defaults(func=offline.cmd_bench)

    p = sub.add_parser("world", parents=[common], help="generate a synthetic world + drive in KITTI raw layout")
    p.add_argument("--out", required=True, help="world folder (refused if it holds a world, unless --force)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--length-km", type=float, default=1.0, help="route length, 0.05 .. 50 km (default 1)")
    p.add_argument("--centre", metavar="LAT,LON", help="world centre, e.g. -35.363261,149.165230 (default near "
                   "Karlsruhe)")
    p.add_argument("--along-drive", help="a KITTI raw drive directory whose GPS track the roads follow")
    p.add_argument("--imu", default="automotive", choices=IMU_PRESETS, help="IMU noise preset (default automotive)")
    p.add_argument("--realism", choices=("flat", "3d"),
                   help="3d: buildings, trees, cars, poles rendered in perspective, the mosaic an aerial photo of "
                   "another day with a ~1 m georeferencing error (run it with --profile synthetic_3d); flat: the "
                   "mosaic is the ground (fast; --profile synthetic) (default 3d; flat with --along-drive)")
    p.add_argument("--keep-clear", action="append", default=[], metavar="E,N;E,N;...",
                   help="a path another vehicle drives, metres east,north of the centre (e.g. a SITL mission's "
                   "square \"0,0;0,60;60,60;60,0;0,0\"): nothing that stands up is placed within 4 m of it "
                   "(repeatable)")
    _force(p, "the world")
    p.set_defaults(func=offline.cmd_world)

    p = sub.add_parser("map", parents=[common], help="the satellite map (a UTM GeoTIFF) of an area from an XYZ, "
                       "WMTS or WMS imagery service, through GDAL, with a tile cache")
    p.add_argument("--bbox", required=True, metavar="LAT0,LON0,LAT1,LON1", help="two opposite corners, degrees")
    p.add_argument("--source", required=True, help="https://host/{z}/{x}/{y}.png ({-y}: TMS rows) | "
                   "WMTS:CAPABILITIES_URL[,layer=NAME][,tilematrixset=TMS] | WMS:URL?LAYERS=NAME[&CRS=EPSG:3857]")
    p.add_argument("--out", required=True, help="the GeoTIFF to write (refused if it exists, unless --force)")
    p.add_argument("--zoom", type=int, help="XYZ zoom (WMTS: zoom level) to read (default: the one --m-per-px needs)")
    p.add_argument("--m-per-px", type=float, help="output resolution, metres per pixel (default: the source's)")
    p.add_argument("--cache", help="tile cache folder, reused by a re-run (default ~/.cache/taco_mav/tiles)")
    p.add_argument("--connections", type=int, default=2, help="parallel requests at most (default 2)")
    p.add_argument("--user-agent", help="the HTTP User-Agent (default taco-mav/VERSION ...)")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds per request (default 30)")
    _force(p, "the map")
    p.set_defaults(func=offline.cmd_map)

    p = sub.add_parser("eval", parents=[common], help="offline evaluation on KITTI sequences or drives")
    p.add_argument("--kitti-root", help="KITTI raw root (with --sequences)")
    p.add_argument("--sequences", help="odometry sequence ids, e.g. 04,05")
    p.add_argument("--drive", action="append", default=[], help="a KITTI-layout drive dir (repeatable)")
    p.add_argument("--tlog", help="a recorded session's mav.tlog (`taco-mav run --record`): its IMU, attitude and "
                   "the real receiver's fixes, the ground truth (never fused); with --frames and --map")
    p.add_argument("--frames", help="the session's frames/ folder (with --tlog)")
    p.add_argument("--map", help="the satellite GeoTIFF the recording is matched against (with --tlog)")
    p.add_argument("--matcher", choices=MATCHERS, help="override the profile's matcher")
    p.add_argument("--out", required=True, help="run folder for results.json, table.md, trajectories, plots "
                   "(refused if it holds results, unless --force)")
    p.add_argument("--profile", default="kitti", help="vehicle profile name or YAML path (default kitti)")
    p.add_argument("--ablation", help="one ablation beside the full pipeline (no_yaw_gate, single_crop, ...)")
    p.add_argument("--ablations", help="'all' or a comma-separated list of ablations")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (emulator)")
    p.add_argument("--matcher-latency", type=float, default=0.0, help="deliver each fix S seconds after capture")
    p.add_argument("--apply-on-arrival", action="store_true", help="apply late fixes naively, as if current")
    p.add_argument("--estimator", choices=ESTIMATORS, help="estimator mode (default: the profile's)")
    p.add_argument("--cross-area", action="store_true",
                   help="emulator: FG2's cross-area error figures for every drive (default: the profile's list)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    _force(p, "the results")
    p.set_defaults(func=offline.cmd_eval)

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
    p.set_defaults(func=offline.cmd_drift)

    p = sub.add_parser("run", parents=[common], help="the daemon: MAVLink IMU + camera in, GPS_INPUT out")
    p.add_argument("--profile", required=True, help="vehicle profile name or YAML path (e.g. ardupilot_rover)")
    p.add_argument("--connect", required=True, help="pymavlink connection: udpin:0.0.0.0:14550, tcp:HOST:PORT, "
                   "/dev/ttyAMA0:921600")
    p.add_argument("--camera", help="world:DIR | folder:DIR[@OFFSET_S] | device index | video file | RTSP/GStreamer")
    p.add_argument("--map", help="satellite GeoTIFF (UTM); default: the world's mosaic with --camera world:DIR")
    p.add_argument("--log-dir", help="folder of log sessions: each run writes mav.tlog, events.jsonl and the "
                   "resolved config.yaml into its own DIR/<UTC start time>/")
    p.add_argument("--origin", help="LAT,LON[,ALT] start fix (default: the EKF origin, home, or a real GNSS's "
                   "3D fix, as the autopilot offers)")
    p.add_argument("--estimator", choices=ESTIMATORS, help="estimator mode (default: the profile's)")
    p.add_argument("--matcher-latency", type=float, default=0.0,
                   help="hold each fix until the autopilot clock is S s past its capture (tests)")
    p.add_argument("--signing-key", help="MAVLink 2 signing key file (32 bytes raw or 64 hex digits): sign what we "
                   "send, ignore unsigned input")
    p.add_argument("--dead-reckoning", action="store_true", help="run without camera and map: IMU dead "
                   "reckoning (and GNSS while it is honest) only, no CVGL fixes")
    p.add_argument("--shadow", action="store_true", help="run a GNSS-free twin of the estimator beside the fused "
                   "one and report, while a real receiver is honest, how far from it the twin is (NAMED_VALUE_FLOAT "
                   "taco_shad, 'shadow' events, a summary line at the end)")
    p.add_argument("--record", action="store_true", help="keep the camera's frames in the session folder "
                   "(<log-dir>/<UTC start>/frames: JPEGs + frames.csv with autopilot and companion times); "
                   "needs --log-dir; replay with --camera folder:SESSION/frames")
    p.add_argument("--record-rate", type=float, default=5.0, help="frames kept per second (default 5)")
    p.add_argument("--record-width", type=int, default=0, help="scale recorded frames to this width, px "
                   "(default 0: as captured)")
    p.add_argument("--record-budget-mb", type=float, default=2000.0, help="stop recording (with a warning) at "
                   "this many MB of frames (default 2000)")
    p.set_defaults(func=live.cmd_run)

    p = sub.add_parser("sim", parents=[common], help="autopilot simulator: play a drive as an ArduPilot rover over MAVLink")
    p.add_argument("--drive", help="KITTI raw drive folder (..._sync) or synthetic world folder")
    p.add_argument("--tlog", help="instead of --drive: a recorded session's mav.tlog (`taco-mav run --record`), "
                   "played on its recorded clock, the real receiver as GNSS and truth")
    p.add_argument("--frames", help="with --tlog: the session's frames/, which the daemon reads with --camera "
                   "folder:FRAMES (checked to overlap the tlog)")
    p.add_argument("--connect", required=True, help="pymavlink connection to the companion, e.g. udpout:127.0.0.1:14550")
    p.add_argument("--out", required=True, help="folder for results.json (refused if it holds one, unless --force)")
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
    p.add_argument("--score-from", type=float, default=0.0, metavar="S", help="score the GPS_INPUT stream's rate, "
                   "gaps and fix types from S s of drive time on (the companion's start-up; default 0)")
    _force(p, "the results")
    p.set_defaults(func=live.cmd_sim)

    p = sub.add_parser("mission", parents=[common], help="fly a square mission on ArduPilot Rover SITL or PX4 SITL "
                       "(SIH) with the daemon in the loop; its scored figures to JSON (docs/sitl.md, docs/px4.md)")
    p.add_argument("--autopilot", required=True, choices=mission.AUTOPILOTS, help="ardupilot: Rover SITL; px4: SIH")
    p.add_argument("--ardurover", help="ardupilot: the Rover SITL binary (default $ARDUROVER)")
    p.add_argument("--px4", help="px4: the PX4 SITL binary (default $PX4_SITL)")
    p.add_argument("--out", required=True, help="JSON file for the mission's scored figures")
    p.add_argument("--run-dir", help="folder for the run: the world, the simulator's and the daemon's logs, tlogs, "
                   "CSVs, result.json (default: --out without its suffix; refused if it holds a result, unless "
                   "--force)")
    p.add_argument("--setup", default="solo", choices=mission.SETUPS["px4"], help="solo: taco-mav the only GNSS; "
                   "handover: the simulated receiver steers until --gnss-off-after, then ours; gnss (px4): the "
                   "simulated receiver only, no daemon (default solo)")
    p.add_argument("--estimator", default="taco+", choices=ESTIMATORS, help="the daemon's estimator (default taco+)")
    p.add_argument("--profile", help="daemon profile (default ardupilot_rover / px4_rover; handover: ..._gps2)")
    p.add_argument("--laps", type=int, default=2, help="laps of the square (default 2)")
    p.add_argument("--side", type=float, default=60.0, help="the square's side, m (default 60)")
    p.add_argument("--speed", "--wp-speed", "--cruise-speed", dest="speed", type=float, default=3.0,
                   help="cruise, m/s: ArduPilot's WP_SPEED, PX4's RO_SPEED_LIM (default 3)")
    p.add_argument("--gnss-off-after", type=float, default=30.0, help="handover: seconds after AUTO the simulated "
                   "receiver goes off (default 30)")
    p.add_argument("--timeout", type=float, default=300.0, help="seconds allowed after AUTO (default 300)")
    p.add_argument("--realism", choices=("flat", "3d"), default="flat", help="the world the camera sees (default "
                   "flat)")
    p.add_argument("--world-seed", type=int, default=7, help="the world's seed (default 7)")
    p.add_argument("--through", action="store_true", help="3d: drive through the buildings and trees")
    p.add_argument("--daemon-arg", action="append", default=[], help="one more `taco-mav run` option (repeat: "
                   "--daemon-arg=--record --daemon-arg=--shadow)")
    p.add_argument("--restart-after", type=float, help="SIGTERM the daemon this many seconds after AUTO and start "
                   "it again")
    p.add_argument("--fault", choices=mission.FAULTS, help="ardupilot: a fault on cue (glitch, spoof: handover)")
    p.add_argument("--fault-after", type=float, help="ardupilot: seconds after AUTO the fault starts (default 60)")
    p.add_argument("--map-seed", type=int, help="ardupilot: the daemon gets another world's map (this seed)")
    p.add_argument("--daemon-origin", action="store_true", help="ardupilot: the daemon gets --origin (home)")
    p.add_argument("--gcs-origin", action=argparse.BooleanOptionalAction, help="px4: the ground station sets "
                   "EKF2's origin at home (default: solo only)")
    p.add_argument("--params-file", help="parameters set at boot: px4: a QGroundControl parameter file (default: the "
                   "shipped px4_rover_<setup>.params; '' for none); ardupilot: a .parm file (a path, or one shipped "
                   "beside the profiles: ardupilot_rover_wheels.parm), over the set-up's own")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="a parameter at boot, over "
                   "--params-file (repeatable; SITL's wheel encoders: --param WENC_TYPE=10 --param WENC2_TYPE=10)")
    _force(p, "the run folder")
    p.set_defaults(func=mission.cmd_mission)

    p = sub.add_parser("calibrate", parents=[common], help="camera intrinsics and lens distortion from chessboard "
                       "photos, written as OpenCV FileStorage YAML (the profile's camera.calibration)")
    p.add_argument("--images", required=True, help="folder of chessboard photos (.png, .jpg, ...) of one size")
    p.add_argument("--board", default="9x6", help="inner corners COLSxROWS (default 9x6: a board of 10x7 squares)")
    p.add_argument("--square", type=float, default=0.025, help="side of one square, m (default 0.025)")
    p.add_argument("--out", required=True, help="calibration file to write, e.g. camera.yaml")
    p.add_argument("--fisheye", action="store_true", help="fisheye (equidistant) lens model instead of plumb_bob")
    p.set_defaults(func=offline.cmd_calibrate)

    p = sub.add_parser("demo", parents=[common], help="synthetic world + simulator + daemon on loopback, one command")
    p.add_argument("--out", default="taco_demo", help="output folder (default ./taco_demo): the world in OUT/world "
                   "(reused), each run in OUT/<estimator>-<matcher>")
    p.add_argument("--estimator", choices=ESTIMATORS, help="estimator mode (default taco+ with the profile "
                   "synthetic_rover: what a rover runs; paper: the paper's method, profile synthetic)")
    p.add_argument("--speed", type=float, default=8.0, help="real-time factor, > 0 (default 8)")
    _force(p, "the run folder")
    p.set_defaults(func=live.cmd_demo)

    def machine(p: argparse.ArgumentParser) -> None:  # where the runs run, and what this machine brings them
        p.add_argument("--address", help="a Ray cluster to join, e.g. ray://head:10001 or auto (default: start a "
                       "local Ray here)")
        p.add_argument("--cpus", type=int, help="the local Ray's cores (default: this machine's)")
        p.add_argument("--retries", type=int, default=3, help="times a run whose worker died is started again "
                       "(default 3)")
        p.add_argument("--ardurover", help="ArduPilot Rover SITL binary for ardupilot runs (default $ARDUROVER)")
        p.add_argument("--px4", help="PX4 SITL binary for px4 runs (default $PX4_SITL)")
        p.add_argument("--kitti-root", help="KITTI raw root for eval runs of sequences (default: as taco-mav eval)")

    p = sub.add_parser("campaign", parents=[common], help="a grid of SITL missions, simulator runs and evaluations "
                       "on Ray: a result per run, a table, a summary per configuration (docs/campaign.md)")
    p.add_argument("spec", metavar="SPEC", help="the campaign file (YAML)")
    p.add_argument("--out", required=True, help="folder for runs/, the table, summary.json and summary.png; a "
                   "campaign started again there skips the runs it has done")
    machine(p)
    p.set_defaults(func=campaign.cmd_campaign)

    p = sub.add_parser("tune", parents=[common], help="search a profile's parameters with Optuna against a "
                       "campaign's median error, its coverage held in a band (docs/campaign.md)")
    p.add_argument("--campaign", required=True, help="the campaign file whose runs score each trial")
    p.add_argument("--space", required=True, help="the search space (YAML): profile, parameters, trials, seed, "
                   "coverage band")
    p.add_argument("--out", required=True, help="folder for the trials' runs, tune.json and best_profile.yaml")
    machine(p)
    p.set_defaults(func=campaign.cmd_tune)
    return parser


QUIET_BY_DEFAULT = ("demo",)  # commands whose default output is their summary only (-v: their log)


def main(argv: Sequence[str] | None = None) -> int:
    """`taco-mav`: returns the exit code (0 done, 1 data/runtime error, 2 usage/configuration, 130 Ctrl-C)."""
    args_in = checks.join_negative_values(list(sys.argv[1:] if argv is None else argv))
    args = build_parser().parse_args(args_in)
    configure_logging(args.quiet, args.verbose, args.debug, quiet_by_default=args.command in QUIET_BY_DEFAULT)
    return run_command(args.command, lambda: args.func(args), args.debug)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
