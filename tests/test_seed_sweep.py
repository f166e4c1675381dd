"""tools/seed_sweep.py: every cell gives `taco-mav eval`'s numbers; overrides reach the run; bad input is named."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from taco_mav.config import parse_overrides
from taco_mav.evaluation.evaluate import EvalRequest, evaluate

spec = importlib.util.spec_from_file_location("seed_sweep", Path(__file__).parents[1] / "tools" / "seed_sweep.py")
seed_sweep = importlib.util.module_from_spec(spec)
sys.modules["seed_sweep"] = seed_sweep  # the worker processes find run_cell by this name
spec.loader.exec_module(seed_sweep)


def test_seed_ranges_and_overrides_parse():
    assert seed_sweep.seeds("0-3") == [0, 1, 2, 3]
    assert seed_sweep.seeds("2,5-6") == [2, 5, 6]
    assert parse_overrides(["plus.q_speed_mps=0.05", "plus.guard=false"]) == {
        "plus.q_speed_mps": 0.05, "plus.guard": False}
    with pytest.raises(SystemExit, match="expected key=value"):
        seed_sweep.main(["--kitti-root", ".", "--set", "plus.q_speed_mps"])
    with pytest.raises(SystemExit, match="--areas"):
        seed_sweep.main(["--kitti-root", ".", "--areas", "elsewhere"])


def test_each_cell_equals_taco_mav_eval_and_overrides_change_the_run(tmp_path, kitti_root):
    out = tmp_path / "sweep.json"
    assert seed_sweep.main(["--kitti-root", str(kitti_root), "--sequences", "04", "--seeds", "0-1",
                            "--areas", "cross", "--latencies", "1", "--out", str(out)]) == 0
    cells = json.loads(out.read_text())["cells"]
    assert [(c["seed"], c["area"], c["latency_s"]) for c in cells] == [(0, "cross", 1.0), (1, "cross", 1.0)]
    for cell in cells:
        ref = evaluate(EvalRequest(out=tmp_path / f"eval{cell['seed']}", kitti_root=kitti_root, sequences=("04",),
                                   estimator="taco+", seed=cell["seed"], latency_s=1.0, cross_area=True,
                                   plots=False))["sequences"]
        (only,) = ref.values()
        for key in ("ate_m", "fixes_per_km", "accepted", "attempts", "coverage_2sigma", "max_error_m"):
            assert cell[key] == only[key], key
    assert cells[0]["ate_m"] != cells[1]["ate_m"]  # the seed reaches the emulator
    # an override reaches the filter: a tenfold position random walk changes the track
    changed = seed_sweep.run_cell(seed_sweep.Cell("04", 0, "cross", 1.0), kitti_root, "taco+", "kitti",
                                  {"plus.q_pos_mps": 0.2})
    assert changed["ate_m"] != cells[0]["ate_m"]
    with pytest.raises(Exception, match="q_pos_mps_typo"):
        seed_sweep.run_cell(seed_sweep.Cell("04", 0, "cross", 1.0), kitti_root, "taco+", "kitti",
                            {"plus.q_pos_mps_typo": 0.2})
