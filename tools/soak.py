"""Soak the daemon: `python tools/soak.py --hours 1 --speed 20 --out soak.json` (see taco_mav/reliability/soak.py)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from taco_mav.reliability.soak import soak
from taco_mav.sim.run import _clean


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--hours", type=float, default=1.0, help="simulated driving, hours (default 1)")
    ap.add_argument("--speed", type=float, default=20.0, help="at most this many times real time (default 20)")
    ap.add_argument("--out", type=Path, default=Path("soak.json"), help="results JSON (default soak.json)")
    ap.add_argument("--log-dir", type=Path, default=None, help="keep the daemon's logs here (default: temporary)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    doc = soak(args.hours, args.speed, args.log_dir, progress=True)
    args.out.write_text(json.dumps(_clean(doc), indent=2) + "\n")
    print(json.dumps({k: doc[k] for k in ("data_s", "wall_s", "speed_achieved", "rss_mb", "rss_growth_pct",
                                          "gps_input_per_min_range", "sizes_max")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
