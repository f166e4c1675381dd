"""Fix-budget bound: the along-track error an optimal filter would reach with fixes of a given quality at a given
spacing, when the IMU's speed error drifts as `taco-mav drift` measures. It answers "can any estimator meet this
accuracy with these fixes at this budget?" before one tunes the real filter.

    python tools/fix_budget_bound.py --q-speed 0.035 --fix-sigma 0.80 --spacings 40 --speed-mps 8.2 --latencies 1
    python tools/fix_budget_bound.py --q-speed 0.035 --fix-mix 0.19:1.38,0.26:0.79,0.42:0.42,0.13:0.24 \\
        --spacings 20,25,33,40 --latencies 0,1

A command line over `taco_mav.evaluation.fix_budget`, whose docstring states the model (along track, a Riccati
recursion of the optimal Kalman filter; metres, seconds). --fix-sigma is every fix's along-track 1-sigma (e.g.
eval's `fix_error_along_rms_m`); --fix-mix draws each fix's sigma from SHARE:SIGMA pairs with --seed.
"""

from __future__ import annotations

import argparse
import sys

from taco_mav.errors import TacoError
from taco_mav.evaluation.fix_budget import Drift, budget_table, parse_mix


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--q-speed", type=float, required=True, help="speed-error random walk, (m/s)/sqrt(s)")
    ap.add_argument("--q-bias", type=float, default=0.0, help="accelerometer-bias random walk, (m/s^2)/sqrt(s)")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--fix-sigma", type=float, help="every fix's along-track 1-sigma, m")
    src.add_argument("--fix-mix", help="SHARE:SIGMA,...: fix sigmas (m) drawn per fix in these shares")
    ap.add_argument("--spacings", default="40", help="distances between fixes, m, e.g. 25,33,40 (default 40)")
    ap.add_argument("--speed-mps", type=float, default=8.2, help="mean speed, m/s (default 8.2, KITTI's)")
    ap.add_argument("--latencies", default="0", help="matcher latencies, s, e.g. 0,1 (default 0)")
    ap.add_argument("--fixes", type=int, default=2000, help="fixes averaged over (default 2000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the --fix-mix draws (default 0)")
    a = ap.parse_args(argv)
    try:
        mix = parse_mix(a.fix_mix) if a.fix_mix else [(1.0, a.fix_sigma)]
        spacings = [float(s) for s in a.spacings.split(",")]
        latencies = [float(x) for x in a.latencies.split(",")]
        table = budget_table(Drift(a.q_speed, a.q_bias), mix, spacings, a.speed_mps, latencies, a.fixes, a.seed)
    except (TacoError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"along-track RMS error of the optimal filter, m (q_speed {a.q_speed}, q_bias {a.q_bias}, "
          f"{a.speed_mps} m/s, fix sigmas {', '.join(f'{s:g}:{v:g} m' for s, v in mix)})")
    print("spacing m  fixes/km  " + "  ".join(f"latency {lat:g} s" for lat in latencies))
    for spacing, cells in zip(spacings, table):
        print(f"{spacing:9.1f}  {1000.0 / spacing:8.1f}  " + "  ".join(f"{c:11.3f}" for c in cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
