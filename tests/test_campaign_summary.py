"""taco_mav.campaign.summary, results and plot: the per-configuration figures against a hand computation, the
table (Parquet or CSV) with the factors as columns, and a box per configuration."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

from taco_mav.campaign.plot import plot_campaign
from taco_mav.campaign.results import table_rows, write_table
from taco_mav.campaign.summary import summarise, summary_text


def _doc(run_id: str, kind: str, config: str, factors: dict[str, Any], status: str = "done", attempts: int = 1,
         **figures: Any) -> dict[str, Any]:
    return {"run_id": run_id, "kind": kind, "configuration": config, "factors": factors, "status": status,
            "attempts": attempts, "wall_s": 100.0, "node": "n", "error": None if status == "done" else "boom",
            "figures": figures if status == "done" else None}


DOCS = [
    _doc("a1", "ardupilot", "ardupilot: setup=solo", {"setup": "solo", "seed": 1}, error_m=0.5, coverage=0.9,
         completed=True, failsafe=False, ekf_rms_m=0.5),
    _doc("a2", "ardupilot", "ardupilot: setup=solo", {"setup": "solo", "seed": 2}, attempts=2, error_m=1.5,
         coverage=0.7, completed=True, failsafe=True, ekf_rms_m=1.5),
    _doc("a3", "ardupilot", "ardupilot: setup=solo", {"setup": "solo", "seed": 3}, error_m=1.0, coverage=0.8,
         completed=False, failsafe=False, ekf_rms_m=1.0),
    _doc("a4", "ardupilot", "ardupilot: setup=solo", {"setup": "solo", "seed": 4}, error_m=3.0, coverage=1.0,
         completed=True, failsafe=False, ekf_rms_m=3.0),
    _doc("a5", "ardupilot", "ardupilot: setup=solo", {"setup": "solo", "seed": 5}, status="failed"),
    _doc("e1", "eval", "eval: sequence=04", {"sequence": "04", "seed": 0}, error_m=0.27, coverage=None,
         completed=True, failsafe=False, ate_m=0.27, setup="not a factor here"),
]


def test_the_summary_per_configuration_is_the_hand_computed_one() -> None:
    """Errors 0.5, 1.5, 1.0, 3.0 m (sorted 0.5, 1.0, 1.5, 3.0): median 1.25; 95th percentile at position
    0.95 * 3 = 2.85, between 1.5 and 3.0: 1.5 + 0.85 * 1.5 = 2.775; worst 3.0. Coverage 0.9, 0.7, 0.8, 1.0:
    median 0.85, lowest 0.7. 4 of 5 done, 3 completed, 1 failsafe, 1 retried, 1 failed."""
    solo, ev = summarise(DOCS)
    assert solo.configuration == "ardupilot: setup=solo" and solo.error_name == "EKF RMS"
    assert (solo.runs, solo.done, solo.failed, solo.completed, solo.failsafes, solo.retried) == (5, 4, 1, 3, 1, 1)
    assert solo.error_p50_m == pytest.approx(1.25) and solo.error_p95_m == pytest.approx(2.775)
    assert solo.error_worst_m == 3.0
    assert solo.coverage_p50 == pytest.approx(0.85) and solo.coverage_min == 0.7
    assert solo.wall_s_total == 400.0
    assert (ev.error_name, ev.error_p50_m, ev.error_p95_m, ev.error_worst_m, ev.coverage_p50) == ("ATE", 0.27, 0.27,
                                                                                               0.27, None)
    text = summary_text([solo, ev])
    assert "ardupilot: setup=solo" in text and " 1.25   2.77   3.00   0.850   0.700  4/5" in text
    # a configuration longer than the column's 48 characters widens it rather than being cut short
    long = dataclasses.replace(ev, configuration="eval: cross_area=True, estimator=taco+, latency_s=1, sequence=09")
    head, _, solo_row, long_row = summary_text([solo, long]).splitlines()
    assert long_row.startswith(long.configuration + " ATE       0.27   0.27   0.27")
    assert head.index("error") == solo_row.index("EKF RMS") == long_row.index("ATE") == len(long.configuration) + 1


def test_the_table_has_a_row_per_run_and_the_factors_as_columns(tmp_path: Path) -> None:
    rows = table_rows(DOCS)
    assert len(rows) == 6 and len({tuple(r) for r in rows}) == 1  # every row has every column
    assert rows[0]["setup"] == "solo" and rows[0]["seed"] == 1 and rows[0]["ekf_rms_m"] == 0.5
    assert rows[5]["sequence"] == "04" and rows[5]["setup"] is None
    assert rows[5]["figure.setup"] == "not a factor here"  # a figure named like a factor is kept apart
    assert rows[4]["status"] == "failed" and rows[4]["error_m"] is None
    path = write_table(rows, tmp_path)
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        back = pq.read_table(path).to_pylist()
    else:
        import csv

        back = list(csv.DictReader(path.open()))
    assert len(back) == 6 and back[1]["run_id"] == "a2" and float(back[1]["error_m"]) == 1.5


def test_a_box_per_configuration(tmp_path: Path) -> None:
    path = plot_campaign(DOCS, tmp_path / "s.png", "test")
    assert path is not None and path.stat().st_size > 10_000
    assert plot_campaign([DOCS[4]], tmp_path / "none.png", "test") is None  # nothing finished: no plot
