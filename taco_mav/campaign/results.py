"""The per-run result files of a campaign (out/runs/*.json) as one table: a row per run, its kind,
configuration, status, attempts and wall seconds, the campaign's factors as columns (lists and mappings as
JSON text), then every figure the harness scored (a figure named like a factor gets the prefix `figure.`).
Written as Parquet when pyarrow is installed (the `campaign` extra), else as CSV."""

from __future__ import annotations

import csv
import json
import logging
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["load_results", "table_rows", "write_table"]

RUN_COLUMNS = ("run_id", "kind", "configuration", "status", "attempts", "wall_s", "node", "error")


def load_results(out: Path) -> list[dict[str, Any]]:
    """Every run result in out/runs, in the campaign's order (campaign.json) where it is known."""
    out = Path(out)
    docs = {p.stem: json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))}
    order: list[str] = []
    if (out / "campaign.json").is_file():
        order = [r["run_id"] for r in json.loads((out / "campaign.json").read_text())["runs"]]
    ranked = {run_id: i for i, run_id in enumerate(order)}
    return [docs[k] for k in sorted(docs, key=lambda k: (ranked.get(k, len(ranked)), k))]


def _cell(value: Any) -> Any:
    return json.dumps(value, sort_keys=True) if isinstance(value, (list, dict)) else value


def table_rows(docs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One flat row per run result (see the module docstring); every row has every column (None where absent)."""
    factor_names = list(dict.fromkeys(k for d in docs for k in d.get("factors", {})))
    rows = []
    for d in docs:
        row: dict[str, Any] = {c: d.get(c) for c in RUN_COLUMNS}
        row.update({k: _cell(d.get("factors", {}).get(k)) for k in factor_names})
        for key, value in (d.get("figures") or {}).items():
            row[f"figure.{key}" if key in row else key] = _cell(value)
        rows.append(row)
    columns = list(dict.fromkeys(c for r in rows for c in r))
    return [{c: r.get(c) for c in columns} for r in rows]


def _uniform(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each column one type for Parquet: numbers as float where a column mixes int and float; anything mixed
    with text as text."""
    out = [dict(r) for r in rows]
    for col in rows[0] if rows else []:
        kinds = {type(r[col]) for r in rows if r[col] is not None}
        if kinds <= {int, float} and float in kinds:
            for r in out:
                r[col] = None if r[col] is None else float(r[col])
        elif len(kinds) > 1:
            for r in out:
                r[col] = None if r[col] is None else str(r[col])
    return out


def write_table(rows: list[dict[str, Any]], out: Path, stem: str = "results") -> Path:
    """out/<stem>.parquet (pyarrow) or, without pyarrow, out/<stem>.csv; returns the path written."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        path = Path(out) / f"{stem}.csv"
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else list(RUN_COLUMNS))
            writer.writeheader()
            writer.writerows(rows)
        return path
    path = Path(out) / f"{stem}.parquet"
    pq.write_table(pa.Table.from_pylist(_uniform(rows)), path)
    return path
