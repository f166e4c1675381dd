"""`taco-mav campaign` and `taco-mav tune`: many runs on Ray (taco_mav.campaign). Each checks the campaign file,
the search space and the options before Ray starts."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import Any

from taco_mav import checks

log = logging.getLogger("taco_mav")


def context(args: argparse.Namespace) -> dict[str, Any]:
    """What this machine brings to the runs: the SITL binaries (--ardurover / --px4, else ARDUROVER / PX4_SITL)
    and the KITTI raw root (--kitti-root, else the one `taco-mav eval` finds)."""
    from taco_mav.datasets.kitti import default_kitti_root

    ardurover = args.ardurover or os.environ.get("ARDUROVER")
    px4 = args.px4 or os.environ.get("PX4_SITL")
    for option, path in (("--ardurover", args.ardurover), ("--px4", args.px4)):
        if path:
            checks.input_file(path, option)
    root = checks.input_dir(args.kitti_root, "--kitti-root") if args.kitti_root else default_kitti_root()
    return {"ardurover": str(Path(ardurover).resolve()) if ardurover else None,
            "px4_sitl": str(Path(px4).resolve()) if px4 else None,
            "kitti_root": str(Path(root).resolve()) if root else None}


def ray_options(args: argparse.Namespace) -> Any:
    from taco_mav.campaign.executor import RayOptions

    if args.cpus is not None:
        checks.number(args.cpus, "--cpus", 1, 4096)
    checks.number(args.retries, "--retries", 0, 100)
    return RayOptions(address=args.address, num_cpus=args.cpus, max_retries=args.retries)


def _finished_line(n: int, total: int, doc: dict[str, Any]) -> str:
    from taco_mav.campaign.summary import ERROR_NAMES

    if doc["status"] != "done":
        return f"[{n}/{total}] FAILED {doc['run_id']}: {str(doc['error']).splitlines()[0]}"
    figures = doc["figures"]
    err = figures.get("error_m")
    text = f"{err:.2f} m" if isinstance(err, (int, float)) else "-"
    retry = f", attempt {doc['attempts']}" if doc.get("attempts", 1) > 1 else ""
    return (f"[{n}/{total}] done {doc['run_id']}: {ERROR_NAMES[doc['kind']]} {text}, "
            f"completed {figures.get('completed')}{retry}, {doc['wall_s']:.0f} s")


def _report(out: Path, title: str) -> None:
    from taco_mav.campaign.report import report_campaign
    from taco_mav.campaign.summary import summary_text

    rep = report_campaign(out, title)
    print(summary_text(rep.summaries))
    print(f"wrote {rep.table}, {rep.summary_json}" + (f", {rep.plot}" if rep.plot else ""))


def cmd_campaign(args: argparse.Namespace) -> int:
    from taco_mav.campaign.executor import done_runs, run_campaign
    from taco_mav.campaign.spec import load_campaign

    campaign = load_campaign(checks.input_file(args.spec, "SPEC"))
    ctx, options = context(args), ray_options(args)
    out = checks.output_dir(args.out)
    total = len(campaign.runs)
    seen = [len(done_runs(out) & {r.run_id for r in campaign.runs})]  # done before: counted from there

    def on_result(run: Any, doc: dict[str, Any]) -> None:
        seen[0] += 1
        print(_finished_line(seen[0], total, doc), flush=True)

    try:
        outcome = run_campaign(campaign, out, ctx, options, on_result=on_result)
    except KeyboardInterrupt:
        print(f"interrupted: the runs done so far are in {out / 'runs'}; the same command resumes")
        _report(out, campaign.name)
        raise
    print(f"campaign {campaign.name}: {len(outcome.finished)} run(s) now, {len(outcome.skipped)} done before, "
          f"{len(outcome.failed)} failed; {outcome.wall_s:.0f} s")
    _report(out, campaign.name)
    return 1 if outcome.failed else 0


def cmd_tune(args: argparse.Namespace) -> int:
    from taco_mav.campaign.spec import load_campaign
    from taco_mav.campaign.tune import load_space, tune

    campaign = load_campaign(checks.input_file(args.campaign, "--campaign"))
    space = load_space(checks.input_file(args.space, "--space"))
    ctx, options = context(args), ray_options(args)
    out = checks.output_dir(args.out)
    res = tune(campaign, space, out, ctx, options)
    for t in res.trials:
        print(f"trial {t.number:3d}: median error {t.median_error_m} m, coverage {t.median_coverage}"
              f"{'' if t.feasible else ' (infeasible)'}  {t.values}")
    b, best = res.baseline, res.best
    print(f"{space.profile} as it is: median error {b.median_error_m} m, coverage {b.median_coverage}")
    if res.profile_path is None:
        print("no trial was feasible (coverage outside the band, or a run failed): no profile written")
        return 1
    print(f"best: trial {best.number}: median error {best.median_error_m} m, coverage {best.median_coverage}; "
          f"wrote {res.profile_path}")
    return 0
