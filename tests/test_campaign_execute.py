"""taco_mav.campaign.execute, an eval run without Ray: a cell of tools/campaigns/kitti_seeds.yaml gives
`taco-mav eval`'s numbers; cross_area, the seed and a profile override reach the run."""

from __future__ import annotations

from pathlib import Path

import pytest

from taco_mav.campaign.execute import execute_run
from taco_mav.campaign.spec import load_campaign
from taco_mav.evaluation.evaluate import EvalRequest, evaluate

REPO = Path(__file__).resolve().parents[1]
KEYS = ("ate_m", "fixes_per_km", "accepted", "attempts", "coverage_2sigma", "max_error_m", "ate_along_m")


def _cell(**factors: object) -> dict:
    """The parameters of the kitti_seeds run with these factors."""
    (run,) = [r for r in load_campaign(REPO / "tools/campaigns/kitti_seeds.yaml").runs
              if all(r.params[k] == v for k, v in factors.items())]
    return dict(run.params)


def test_the_seed_campaign_is_a_grid_of_taco_plus_evaluations() -> None:
    runs = load_campaign(REPO / "tools/campaigns/kitti_seeds.yaml").runs
    assert len(runs) == 80 and {r.kind for r in runs} == {"eval"}
    assert {r.params["estimator"] for r in runs} == {"taco+"}
    assert {(r.params["sequence"], r.params["cross_area"], r.params["latency_s"]) for r in runs} == {
        (q, a, lat) for q in ("04", "05", "07", "09") for a in (False, True) for lat in (0, 1)}
    assert sorted({r.params["seed"] for r in runs}) == [0, 1, 2, 3, 4]
    assert runs[-1].configuration() == "eval: cross_area=True, estimator=taco+, latency_s=1, sequence=09"


def test_an_eval_cell_is_taco_mav_eval_and_its_parameters_reach_the_run(tmp_path: Path, kitti_root: Path) -> None:
    context = {"kitti_root": str(kitti_root)}
    cross = execute_run("eval", _cell(sequence="04", seed=0, cross_area=True, latency_s=1), tmp_path / "c", context)
    ref = evaluate(EvalRequest(out=tmp_path / "ref", kitti_root=kitti_root, sequences=("04",), estimator="taco+",
                               seed=0, latency_s=1.0, cross_area=True, plots=False))["sequences"]
    (only,) = ref.values()
    for key in KEYS:
        assert cross[key] == only[key], key
    assert cross["error_m"] == cross["ate_m"] and cross["coverage"] == cross["coverage_2sigma"]
    same = execute_run("eval", _cell(sequence="04", seed=0, cross_area=False, latency_s=1), tmp_path / "s", context)
    assert same["ate_m"] < cross["ate_m"]  # FG2's same-area errors are the smaller (median 4.15 m cross-area)
    other_seed = execute_run("eval", _cell(sequence="04", seed=1, cross_area=True, latency_s=1), tmp_path / "o",
                             context)
    assert other_seed["ate_m"] != cross["ate_m"]  # the seed reaches the emulator
    tenfold = {**_cell(sequence="04", seed=0, cross_area=True, latency_s=1), "set": {"plus.q_pos_mps": 0.2}}
    assert execute_run("eval", tenfold, tmp_path / "t", context)["ate_m"] != cross["ate_m"]
    with pytest.raises(Exception, match="q_pos_mps_typo"):
        execute_run("eval", {**tenfold, "set": {"plus.q_pos_mps_typo": 0.2}}, tmp_path / "x", context)
