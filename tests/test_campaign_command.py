"""`taco-mav campaign` (taco_mav/commands/campaign.py) end to end on the campaign CI runs,
tools/campaigns/smoke.yaml: in-process simulator runs on a local Ray of 2 cores, the table, the summary and the
plot; and the one-line errors of a bad campaign file before Ray starts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from taco_mav import cli

REPO = Path(__file__).resolve().parents[1]


def test_the_smoke_campaign(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Four in-process runs (taco+ and paper, two worlds each) to the end: each a finished drive with an ATE
    under 3 m, one row each in the table, two configurations in the summary; a second start runs nothing."""
    pytest.importorskip("ray")
    out = tmp_path / "smoke"
    assert cli.main(["-q", "campaign", str(REPO / "tools/campaigns/smoke.yaml"), "--out", str(out), "--cpus", "2"]) == 0
    text = capsys.readouterr().out
    assert text.count("] done sim-") == 4 and "[4/4] done sim-" in text and "4 run(s) now, 0 done before, 0 failed" in text
    summaries = json.loads((out / "summary.json").read_text())
    assert [s["configuration"] for s in summaries] == ["sim: duration_s=30, estimator=taco+, length_km=0.3",
                                                       "sim: duration_s=30, estimator=paper, length_km=0.3"]
    for s in summaries:
        assert (s["runs"], s["done"], s["completed"], s["failed"], s["failsafes"]) == (2, 2, 2, 0, 0)
        assert s["error_name"] == "ATE" and 0.0 < s["error_p50_m"] <= s["error_worst_m"] < 3.0
        assert s["configuration"][:40] in text  # the terminal summary
    assert (out / "summary.png").stat().st_size > 10_000
    import pyarrow.parquet as pq

    rows = pq.read_table(out / "results.parquet").to_pylist()
    assert len(rows) == 4 and {r["estimator"] for r in rows} == {"taco+", "paper"} and {r["seed"] for r in rows} == {1, 2}
    assert all(r["status"] == "done" and r["ate_m"] == r["error_m"] and r["gps_input_count"] > 0 for r in rows)
    assert cli.main(["-q", "campaign", str(REPO / "tools/campaigns/smoke.yaml"), "--out", str(out), "--cpus", "2"]) == 0
    assert "0 run(s) now, 4 done before" in capsys.readouterr().out


def test_a_bad_campaign_file_is_one_line_naming_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    spec = tmp_path / "bad.yaml"
    spec.write_text("runs:\n  - kind: ardupilot\n    grid: {setup: [solo, handoff]}\n")
    assert cli.main(["campaign", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"taco-mav campaign: error: {spec}: runs[0].grid.setup: 'handoff' is not one of solo, handover" in err
    assert not (tmp_path / "o" / "runs").exists()
