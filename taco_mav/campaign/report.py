"""What a campaign's out folder says, written beside its runs: results.parquet (or .csv), summary.json and
summary.png, from whatever runs are done so far (a campaign cut short reports what it has)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from taco_mav.campaign.plot import plot_campaign
from taco_mav.campaign.results import load_results, table_rows, write_table
from taco_mav.campaign.summary import ConfigSummary, summarise

__all__ = ["CampaignReport", "report_campaign"]


@dataclass(frozen=True)
class CampaignReport:
    """The files written and the summaries they hold."""

    table: Path
    summary_json: Path
    plot: Path | None
    summaries: list[ConfigSummary]


def report_campaign(out: Path, title: str) -> CampaignReport:
    """Table, summary and plot of the runs in `out` (see the module docstring)."""
    out = Path(out)
    docs = load_results(out)
    summaries = summarise(docs)
    table = write_table(table_rows(docs), out)
    summary_json = out / "summary.json"
    summary_json.write_text(json.dumps([s.to_dict() for s in summaries], indent=1) + "\n")
    plot = plot_campaign(docs, out / "summary.png", title)
    return CampaignReport(table, summary_json, plot, summaries)
