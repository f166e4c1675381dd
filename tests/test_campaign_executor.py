"""taco_mav.campaign.executor and child, on a real local Ray with real runs (offline evaluations of KITTI
sequence 04, a few seconds each): results written per run, a second start skipping what is done, a worker
killed mid-run retried with nothing lost, and a run's error recorded without a retry."""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")

from taco_mav.campaign.child import run_in_child
from taco_mav.campaign.executor import RayOptions, done_runs, ray_session, run_campaign
from taco_mav.campaign.spec import parse_campaign

CAMPAIGN = {"name": "t", "runs": [{"kind": "eval", "grid": {"seed": [0, 1]}, "with": {"sequence": "04"}}]}


@pytest.fixture(scope="module")
def ray_local(kitti_root: Path) -> Iterator[dict[str, Any]]:
    """One local Ray of 2 cores for the module's campaigns (each campaign uses it and leaves it running)."""
    import ray

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the test's runners, in the workers
    context = {"kitti_root": str(kitti_root)}
    with ray_session(RayOptions(num_cpus=2), context):
        yield context


def _figures(out: Path, run_id: str) -> dict[str, Any]:
    doc = json.loads((out / "runs" / f"{run_id}.json").read_text())
    assert doc["status"] == "done", doc.get("error")
    return doc


def test_results_per_run_and_a_second_start_skips_what_is_done(tmp_path: Path, ray_local: dict) -> None:
    campaign = parse_campaign(CAMPAIGN, "t.yaml")
    first = run_campaign(campaign, tmp_path, ray_local)
    ids = [r.run_id for r in campaign.runs]
    assert sorted(first.finished) == sorted(ids) and not first.failed and not first.skipped
    assert done_runs(tmp_path) == set(ids)
    a, b = (_figures(tmp_path, i) for i in ids)
    assert a["figures"]["error_m"] == a["figures"]["ate_m"] < 1.0 and a["attempts"] == 1
    assert a["factors"] == {"sequence": "04", "seed": 0} and a["configuration"] == "eval: sequence=04"
    assert (tmp_path / "work" / ids[0] / "run" / "eval" / "results.json").is_file()
    # one result lost (as if the campaign had been stopped before it finished): only that run is run again
    (tmp_path / "runs" / f"{ids[1]}.json").unlink()
    again = run_campaign(campaign, tmp_path, ray_local)
    assert again.skipped == [ids[0]] and again.finished == [ids[1]]
    assert _figures(tmp_path, ids[1])["figures"]["ate_m"] == b["figures"]["ate_m"]  # deterministic
    third = run_campaign(campaign, tmp_path, ray_local)
    assert third.skipped == ids and not third.finished


def _killed_once(marks: Path) -> Any:
    """A runner whose first attempt at each run dies mid-run: the run's child process started, then the Ray
    worker process ends (os._exit), as a worker killed by the kernel or a lost node does."""

    def runner(run: dict[str, Any], work_dir: str, context: dict[str, Any]) -> dict[str, Any]:
        mark = marks / run["run_id"]
        if mark.exists():
            return run_in_child(run, work_dir, context)
        mark.write_text(str(os.getpid()))
        threading.Thread(target=run_in_child, args=(run, work_dir, context), daemon=True).start()
        deadline = time.monotonic() + 60
        while not (Path(work_dir) / "child.log").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # the child is running
        os._exit(1)

    return runner


def test_a_worker_killed_mid_run_is_retried_and_nothing_is_lost(tmp_path: Path, ray_local: dict) -> None:
    campaign = parse_campaign({"runs": [{"kind": "eval", "with": {"sequence": "04", "seed": 0}}]}, "k.yaml")
    marks = tmp_path / "marks"
    marks.mkdir()
    out = tmp_path / "out"
    outcome = run_campaign(campaign, out, ray_local, RayOptions(max_retries=2), runner=_killed_once(marks))
    assert sorted(outcome.finished) == sorted(r.run_id for r in campaign.runs) and not outcome.failed
    for run in campaign.runs:
        doc = _figures(out, run.run_id)
        assert doc["attempts"] == 2  # the killed attempt counted, the second one finished
        assert int((marks / run.run_id).read_text()) != os.getpid()  # it was a worker that died, not us
    # nothing lost: the same figures as runs never interrupted
    clean = tmp_path / "clean"
    run_campaign(campaign, clean, ray_local)
    for run in campaign.runs:
        assert _figures(out, run.run_id)["figures"]["ate_m"] == _figures(clean, run.run_id)["figures"]["ate_m"]


def test_an_error_inside_a_run_is_recorded_and_not_retried(tmp_path: Path, ray_local: dict) -> None:
    campaign = parse_campaign({"runs": [{"kind": "eval", "with": {"drive": str(tmp_path / "no_such_drive")}}]},
                              "e.yaml")
    outcome = run_campaign(campaign, tmp_path / "out", ray_local)
    (run_id,) = outcome.failed
    doc = json.loads((tmp_path / "out" / "runs" / f"{run_id}.json").read_text())
    assert doc["status"] == "failed" and "no_such_drive" in doc["error"] and "exit code 1" in doc["error"]
    assert (tmp_path / "out" / "work" / run_id / "attempts").read_text() == "1"
    assert done_runs(tmp_path / "out") == set()  # a failed run is run again by the next start
