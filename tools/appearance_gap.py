"""Measure the classical matcher across an appearance gap (docs/matchers.md has the figures this prints).

Two measurements on a world made by `taco-mav world` (flat or 3d):

  crops  single crops at poses along the world's drive, the vehicle 0-`--max-offset` m from the crop centre, the
         query heading within +-3 deg of the truth; per descriptor and condition: median fix error, share within
         2 / 5 m, PSR and w, and the (w, error) pairs that calibrate w (--dump FILE.npz).
  eval   offline runs (`taco_mav.evaluation.runner.run_drive`) of paper and taco+ with the classical matcher;
         per run: ATE, fixes, median fix error, share within 2 / 5 m, mean NIS of accepted fixes and the mean
         normalised fix error squared under the fix noise that w implies (paper Sec. III-F).

Conditions: `clean` (frames rendered from the map itself), `map` (the map re-photographed: `MapGap()`: gain,
gamma, autumn tint, moved shadows, 0.4 m/px), `fold` (the same and a change of the materials' brightness order,
`MapGap(fold=0.45)`), `+occ` after either (vertical occluders in every camera frame: `FrameGap()`); on a 3d
world the gap is the world's own (use `clean`). Examples:

  python tools/appearance_gap.py crops --world W --conditions clean,map,fold,fold+occ --descriptors lcn,orientation
  python tools/appearance_gap.py eval --world W --conditions clean,fold+occ --descriptors lcn,orientation \
      --estimators paper,taco+
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from taco_mav.config import Estimator, Profile, load_profile, parse_overrides, replace_in
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.classical import ClassicalMatcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.datasets.synthetic.drive import SyntheticDrive, load_world
from taco_mav.datasets.synthetic.gap import FrameGap, MapGap, alter_mosaic, occlude_frame

log = logging.getLogger("appearance_gap")

SEED = 11


CONDITIONS = {"map": MapGap(), "fold": MapGap(fold=0.45)}


def gap_map(world: SyntheticDrive, out_dir: Path, seed: int = SEED, gap: MapGap = MapGap(), name: str = "map") -> Path:
    """Write the world's mosaic re-photographed under `gap` as a GeoTIFF in out_dir; returns its path."""
    with rasterio.open(world.mosaic) as src:
        rgb = src.read().transpose(1, 2, 0)
        profile = src.profile
        m = 0.5 * (src.transform.a - src.transform.e)
    altered = alter_mosaic(np.ascontiguousarray(rgb[:, :, :3]), m, seed, gap)
    path = Path(out_dir) / f"gap_{name}.tif"
    profile.update(count=3)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(altered.transpose(2, 0, 1))
    return path


class OccludedDrive:
    """A drive whose camera frames carry vertical occluders (`occlude_frame`, seeded per frame index)."""

    def __init__(self, drive: SyntheticDrive, seed: int = SEED, gap: FrameGap = FrameGap()) -> None:
        self._drive, self._seed, self._gap = drive, seed, gap

    def __getattr__(self, name: str) -> Any:
        return getattr(self._drive, name)

    def frame(self, index: int) -> np.ndarray:
        rgb = self._drive.frame(index)
        return occlude_frame(rgb, self._drive.camera, self._seed * 1_000_003 + index, self._gap)[0]


def _fix_error(crop_centre: np.ndarray, heading: float, res: MatchResult, true_en: np.ndarray) -> tuple[float, float]:
    """Fix error in the vehicle's (forward, left) frame at the query heading, metres."""
    c, s = math.cos(heading), math.sin(heading)
    fix = crop_centre + res.t[0] * np.array([c, s]) + res.t[1] * np.array([-s, c])
    d = fix - true_en
    return float(d @ [c, s]), float(d @ [-s, c])


def crop_samples(drive: SyntheticDrive, smap: SatelliteMap, matcher: ClassicalMatcher, *, occlude: bool,
                 n: int = 60, max_offset_m: float = 15.0, seed: int = SEED, crop_px: int = 512,
                 crop_m_per_px: float = 0.2) -> dict[str, np.ndarray]:
    """Single-crop matches at n poses spread along the drive: error (fwd, left) m, PSR, w, offset m."""
    rng = np.random.default_rng(seed)
    idx = np.linspace(20, len(drive.frame_times) - 20, n).astype(int)
    rows = []
    for i in idx:
        t = float(drive.frame_times[i])
        E, N, th = drive.camera_pose(t)
        rgb = drive.frame(int(i))
        if occlude:
            rgb = occlude_frame(rgb, drive.camera, seed * 1_000_003 + int(i))[0]
        r = rng.uniform(0, max_offset_m)
        a = rng.uniform(-math.pi, math.pi)
        dpsi = math.radians(rng.uniform(-3, 3))
        q = th - dpsi
        centre = np.array([E, N]) + r * np.array([math.cos(a), math.sin(a)])
        crop = smap.crop(centre, q, crop_px, crop_m_per_px, min_valid=0.5)
        (res,) = matcher.match(GroundFrame(rgb, t, drive.camera), [crop])
        ef, el = _fix_error(centre, q, res, np.array([E, N]))
        rows.append((ef, el, matcher.last_psr[0], res.w, r))
    a = np.array(rows)
    return {"err_fwd": a[:, 0], "err_lat": a[:, 1], "psr": a[:, 2], "w": a[:, 3], "offset": a[:, 4]}


def crop_figures(s: dict[str, np.ndarray]) -> dict[str, float]:
    e = np.hypot(s["err_fwd"], s["err_lat"])
    return {"n": int(len(e)), "median_error_m": float(np.median(e)), "within_2m": float(np.mean(e < 2.0)),
            "within_5m": float(np.mean(e < 5.0)), "median_psr": float(np.median(s["psr"])),
            "median_w": float(np.median(s["w"]))}


def matcher_profile(prof: Profile, variant: str) -> Profile:
    """The profile with the classical matcher as `variant`: "lcn" (grey-level LCN, no masks) or
    "orientation" (gradient orientation with the vertical-structure mask)."""
    prof = replace_in(prof, "matcher", "classical")
    prof = replace_in(prof, "classical.descriptor", variant)
    return replace_in(prof, "classical.mask_vertical", variant != "lcn")


def run_eval(drive: Any, profile_name: str, estimator: str, descriptor: str, smap: SatelliteMap | None,
             overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """One offline run; ATE, fix statistics, NIS. overrides: dotted profile keys -> values (e.g. ukf.fix_fwd_num)."""
    from taco_mav.evaluation.runner import run_drive
    from taco_mav.evaluation.summary import metrics

    prof = matcher_profile(load_profile(profile_name), descriptor)
    prof = replace_in(prof, "estimator", Estimator(estimator))
    for key, value in (overrides or {}).items():
        prof = replace_in(prof, key, value)
    run = run_drive(drive, prof, sat_map=smap)
    m = metrics(run)
    acc = [o for o in run.outcomes if o.accepted and o.xy is not None]
    errs, nees, nis = [], [], []
    for o in acc:
        x, y, th = drive.truth.pose_at(o.capture_t)
        d = np.asarray(o.xy) - [x, y]
        c, s_ = math.cos(th), math.sin(th)
        ef, el = d @ [c, s_], d @ [-s_, c]
        errs.append(math.hypot(ef, el))
        nees.append((ef / o.sigma_fwd) ** 2 + (el / o.sigma_lat) ** 2)
        nis.append(o.nis)
    e = np.array(errs) if errs else np.array([np.nan])
    return {"ate_m": m["ate_m"], "attempts": m["attempts"], "accepted": m["accepted"],
            "median_fix_error_m": float(np.median(e)), "fix_within_2m": float(np.mean(e < 2.0)),
            "fix_within_5m": float(np.mean(e < 5.0)), "nis_mean": float(np.mean(nis)) if nis else float("nan"),
            "fix_nees_mean": float(np.mean(nees)) if nees else float("nan"), "max_error_m": m.get("max_error_m")}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=("crops", "eval"))
    p.add_argument("--world", required=True, type=Path)
    p.add_argument("--conditions", default="clean,map,map+occ,fold,fold+occ")
    p.add_argument("--descriptors", default="lcn,orientation")
    p.add_argument("--estimators", default="paper,taco+")
    p.add_argument("--profile", default="synthetic")
    p.add_argument("--n", type=int, default=60)
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--dump", type=Path, help="crops: write every sample to this .npz")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="eval: a profile override, e.g. ukf.fix_fwd_num=0.5 (repeatable; values parsed as YAML)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    overrides = parse_overrides(args.set)
    drive = load_world(args.world)
    prof = load_profile(args.profile)
    out: dict[str, Any] = {}
    dump: dict[str, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp:
        maps = {"clean": SatelliteMap(drive.mosaic)}
        for cond in args.conditions.split(","):
            key = cond.split("+")[0]
            if key not in maps:
                maps[key] = SatelliteMap(gap_map(drive, Path(tmp), args.seed, CONDITIONS[key], key))
            smap = maps[key]
            occ = cond.endswith("+occ")
            for desc in args.descriptors.split(","):
                if args.what == "crops":
                    matcher = ClassicalMatcher(matcher_profile(prof, desc).classical, drive.camera)
                    s = crop_samples(drive, smap, matcher, occlude=occ, n=args.n, seed=args.seed)
                    out[f"{cond}/{desc}"] = crop_figures(s)
                    for k, v in s.items():
                        dump[f"{cond}/{desc}/{k}"] = v
                else:
                    d = OccludedDrive(drive, args.seed) if occ else drive
                    for est in args.estimators.split(","):
                        out[f"{cond}/{desc}/{est}"] = run_eval(d, args.profile, est, desc, smap, overrides)
                print(json.dumps({k: v for k, v in out.items() if k.startswith(f"{cond}/{desc}")}), flush=True)
        for m in maps.values():
            m.close()
    if args.dump:
        np.savez(args.dump, **dump)
    return 0


if __name__ == "__main__":
    sys.exit(main())
