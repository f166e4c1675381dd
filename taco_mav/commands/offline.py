"""`taco-mav` commands that work on files: bench, world, map, eval, drift, calibrate. Each checks its arguments and
inputs (`taco_mav.checks`) before the first expensive step, then calls one importable function."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from taco_mav import checks
from taco_mav.errors import UsageError

log = logging.getLogger("taco_mav")


def show_progress(args: argparse.Namespace) -> bool:
    return not args.quiet


def sequences(text: str | None) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip()) if text else ()


def check_sources(args: argparse.Namespace) -> None:
    """--kitti-root/--sequences/--drive (eval and drift): present, known, readable."""
    from taco_mav.datasets.kitti import ODOMETRY_SEQUENCES

    if args.kitti_root:
        checks.input_dir(args.kitti_root, "--kitti-root")
    seqs = sequences(args.sequences)
    if args.sequences is not None:
        checks.names([s.zfill(2) for s in seqs] or [args.sequences], "--sequences", sorted(ODOMETRY_SEQUENCES))
        if not args.kitti_root:
            raise UsageError("--sequences needs --kitti-root DIR (the KITTI raw root)")
    for d in args.drive:
        checks.input_dir(d, "--drive")
        folder = checks.world_of(d)
        if folder is not None:  # a synthetic world: its mosaic must be complete before any work
            checks.world(folder, f"--drive {d}")


def cmd_bench(args: argparse.Namespace) -> int:
    from taco_mav.bench import SECTION_NAMES, run_bench

    only = list(checks.names(args.only, "--only", SECTION_NAMES)) if args.only is not None else None
    out = checks.output_file(args.out)
    fg2 = {"checkout": args.fg2_checkout, "checkpoint": args.fg2_checkpoint, "device": args.device,
           "triggers": args.fg2_triggers, "warmup": args.fg2_warmup, "fast": not args.fg2_published,
           "compile": args.fg2_compile, "device_crops": args.fg2_device_crops}
    real = {"real_pairs": args.real_pairs, "profile": args.real_profile}
    options = {"fg2": fg2, "real": real, "real_signal": {"real_pairs": args.real_pairs}}
    results = run_bench(out, only=only, progress=show_progress(args), options=options)
    for key in sorted(results):
        print(f"{key:45s} {results[key]}")
    print(f"wrote {out}")
    return 0


def _polyline(text: str, option: str) -> list[tuple[float, float]]:
    """"E,N;E,N;..." (metres) -> [(E, N), ...], at least two points, each within 10 km."""
    points = []
    for part in text.split(";"):
        e, n = checks.coordinates(part, option, ("E", "N"))
        if abs(e) > 1e4 or abs(n) > 1e4:
            raise UsageError(f"{option} {text}: {part} is more than 10 km from the centre")
        points.append((e, n))
    if len(points) < 2:
        raise UsageError(f"{option} {text}: give at least two points E,N;E,N")
    return points


def cmd_world(args: argparse.Namespace) -> int:
    centre = checks.coordinates(args.centre, "--centre") if args.centre else None
    keep_clear = [_polyline(text, "--keep-clear") for text in args.keep_clear]
    checks.number(args.length_km, "--length-km", 0.05, 50.0)
    along = checks.input_dir(args.along_drive, "--along-drive") if args.along_drive else None
    out = checks.fresh_folder(checks.output_dir(args.out), "world.json", args.force)
    realism = args.realism or ("flat" if along else "3d")  # 3-D along a real drive is not built yet
    from taco_mav.datasets.synthetic import build_world

    path = build_world(out, seed=args.seed, length_km=args.length_km,
                       centre=(centre[0], centre[1]) if centre else None, along_drive=along,
                       imu_preset=args.imu, progress=show_progress(args), realism=realism, keep_clear=keep_clear)
    profile = "synthetic_3d --estimator taco+" if realism == "3d" else "synthetic"
    print(f"wrote world {path} ({realism}; run it with --profile {profile})")
    return 0


def cmd_map(args: argparse.Namespace) -> int:
    from taco_mav.datasets.map_sources import DEFAULT_USER_AGENT, BBox, parse_source
    from taco_mav.datasets.map_tiles import build_map, check_request

    bbox = BBox.parse(args.bbox)
    source = parse_source(args.source)
    check_request(source, args.m_per_px, args.zoom, args.connections)
    checks.number(args.timeout, "--timeout", 1.0, 600.0)
    out = checks.output_file(args.out)
    if out.exists() and not args.force:
        raise UsageError(f"--out {out}: exists; add --force to overwrite it or choose another file")
    cache = checks.output_dir(args.cache, "--cache") if args.cache else None
    res = build_map(bbox, source, out, m_per_px=args.m_per_px, zoom=args.zoom, cache_dir=cache,
                    connections=args.connections, user_agent=args.user_agent or DEFAULT_USER_AGENT,
                    timeout_s=args.timeout, progress=show_progress(args))
    zone = f"UTM {res.epsg % 100}{'N' if res.epsg < 32700 else 'S'}"
    zoom = f", zoom {res.zoom}" if res.zoom is not None else ""
    print(f"wrote {res.path}: {res.width} x {res.height} px at {res.m_per_px:g} m/px, EPSG:{res.epsg} ({zone}){zoom}, "
          f"imagery on {100 * res.imagery_fraction:.1f} % (tiles cached in {res.cache_dir})")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from taco_mav.config import load_profile

    load_profile(args.profile)  # the profile's own errors first: they name the file and key
    checks.number(args.matcher_latency, "--matcher-latency", 0.0, 60.0)
    check_sources(args)
    recording = None
    if args.tlog or args.frames:
        if not (args.tlog and args.frames and args.map) or args.drive or args.sequences:
            raise UsageError("a recording is --tlog SESSION/mav.tlog --frames SESSION/frames --map MAP.tif, "
                             "without --drive or --sequences")
        recording = (checks.input_file(args.tlog, "--tlog"), checks.input_dir(args.frames, "--frames"),
                     checks.input_file(args.map, "--map"))
    elif args.map:
        raise UsageError("--map goes with --tlog and --frames (a KITTI or synthetic drive brings its own map)")
    elif not args.drive and not args.sequences:
        raise UsageError("nothing to evaluate: give --kitti-root DIR --sequences LIST, --drive DIR, or a recording "
                         "(--tlog, --frames, --map)")
    if args.drive and args.sequences:
        raise UsageError("give either --sequences (with --kitti-root) or --drive, not both")
    checks.fresh_folder(checks.output_dir(args.out, create=False), "results.json", args.force)
    from taco_mav.evaluation.evaluate import ABLATIONS, EvalRequest, evaluate, resolve_profile

    ablations: tuple[str, ...] = ()
    if args.ablations:
        ablations = ("all",) if args.ablations == "all" else checks.names(args.ablations, "--ablations", ABLATIONS)
    elif args.ablation:
        ablations = ("full", *checks.names(args.ablation, "--ablation", ABLATIONS))
    req = EvalRequest(
        out=Path(args.out), profile=args.profile, kitti_root=Path(args.kitti_root) if args.kitti_root else None,
        sequences=sequences(args.sequences), drives=tuple(Path(d) for d in args.drive), matcher=args.matcher,
        ablations=ablations, seed=args.seed, latency_s=args.matcher_latency, apply_on_arrival=args.apply_on_arrival,
        estimator=args.estimator, cross_area=args.cross_area, plots=not args.no_plots, progress=show_progress(args),
        recording=recording)
    profile = resolve_profile(req)  # with the command line's overrides (--matcher, --estimator, --cross-area)
    checks.fresh_folder(checks.output_dir(args.out), "results.json", args.force)
    log.info("evaluating with estimator %s, matcher %s into %s", profile.estimator.value, profile.matcher, args.out)
    results = evaluate(req)
    print((Path(args.out) / "table.md").read_text())
    s = results["summary"]
    print(f"median ATE {s['median_ate_m']} m (IMU only {s['median_ate_imu_only_m']} m) over {s['sequences_run']} "
          f"sequence(s), estimator {profile.estimator.value}, matcher {profile.matcher}; results in "
          f"{Path(args.out) / 'results.json'}")
    if recording is not None:  # a GNSS-on drive: the survey's verdict against its receiver
        for name, seq in results["sequences"].items():
            print(survey_text(name, seq.get("survey")))
    return 0


def survey_text(name: str, survey: dict | None) -> str:
    """The survey verdict of one evaluated drive as lines: the whole drive, then the stretches."""
    if not survey:
        return f"{name}: no survey"
    d = survey["drive"]
    lines = [f"{name}: camera fixes {d['verdict'].replace('usable', 'usable here')}: {d['accepted']} of "
             f"{d['answers']} answers accepted, precision {d['precision']}, median error {d['median_error_m']} m "
             "against the receiver"]
    for st in survey["stretches"]:
        lines.append(f"  {st['start_m']:7.0f}-{st['end_m']:<7.0f} m  {st['verdict']:16s} {st['accepted']:3d} of "
                     f"{st['answers']:3d} accepted, precision {st['precision']}")
    return "\n".join(lines)


def cmd_drift(args: argparse.Namespace) -> int:
    import json

    from taco_mav.config import load_profile

    profile = load_profile(args.profile)
    checks.number(args.min_speed, "--min-speed", 0.0, 100.0)
    tlogs = [checks.input_file(f, "--tlog") for f in args.tlog]
    check_sources(args)
    out = checks.output_file(args.out) if args.out else None
    from taco_mav.datasets.tlog import load_tlog
    from taco_mav.evaluation.drift import measure_drift, report_text
    from taco_mav.evaluation.evaluate import EvalRequest, load_drives

    name = Path(args.profile).stem
    reports: list[Any] = []

    def write() -> None:
        if out is not None:
            doc = {"profile": args.profile, "drives": [r.to_dict() for r in reports]}
            out.write_text(json.dumps(doc, indent=2) + "\n")
            print(f"wrote {out}")

    drives = [load_tlog(f, imu_message=args.imu_message) for f in tlogs]  # every input read before measuring
    if args.sequences or args.drive or not tlogs:
        drives += load_drives(EvalRequest(out=Path("."), kitti_root=Path(args.kitti_root) if args.kitti_root else None,
                                          sequences=sequences(args.sequences),
                                          drives=tuple(Path(d) for d in args.drive)))
    try:
        for drive in drives:
            reports.append(measure_drift(drive, min_speed_mps=args.min_speed))
    except BaseException:
        if reports:  # work done is never lost to a later drive's error
            print("\n\n".join(report_text(r, profile.plus, name) for r in reports))
            write()
        raise
    print("\n\n".join(report_text(r, profile.plus, name) for r in reports))
    write()
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from taco_mav.calibrate import calibrate, parse_board

    board = parse_board(args.board)
    checks.number(args.square, "--square", 0.0, 10.0, low_open=True)
    images = checks.input_dir(args.images, "--images")
    out = checks.output_file(args.out)
    res = calibrate(images, board, args.square, out, fisheye=args.fisheye)
    K, D = res.lens.K, res.lens.D
    print(f"board found in {len(res.used)} of {res.images} images")
    print(f"fx {K[0, 0]:.2f}  fy {K[1, 1]:.2f}  cx {K[0, 2]:.2f}  cy {K[1, 2]:.2f} px "
          f"({res.lens.width}x{res.lens.height})")
    print(f"{res.lens.model.value} distortion {' '.join(f'{d:+.5f}' for d in D)}")
    print(f"RMS reprojection error {res.rms_px:.3f} px")
    print(f"wrote {res.out}")
    return 0
