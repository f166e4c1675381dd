"""A campaign's results per configuration (its runs' kind and factors but the seed): the error's median, 95th
percentile and worst (SITL missions: the EKF's RMS error against the truth; sim and eval runs: the ATE), metres;
the reported-accuracy coverage (median and lowest share of reports within 2 reported sigma); how many runs
finished, completed their mission or drive, failed safe, and needed a retry."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["ERROR_NAMES", "ConfigSummary", "summarise", "summary_text"]

ERROR_NAMES = {"ardupilot": "EKF RMS", "px4": "EKF RMS", "sim": "ATE", "eval": "ATE"}


@dataclass(frozen=True)
class ConfigSummary:
    """One configuration's figures. error_*: metres over its finished runs (np.percentile, linear; None without
    any); coverage_*: shares 0..1 (None where the kind does not score it); runs: in the results, done: finished
    with figures, failed: ended in an error, completed / failsafes: among the done, retried: done after more than
    one attempt (a worker lost)."""

    configuration: str
    kind: str
    error_name: str
    runs: int
    done: int
    failed: int
    completed: int
    failsafes: int
    retried: int
    error_p50_m: float | None
    error_p95_m: float | None
    error_worst_m: float | None
    coverage_p50: float | None
    coverage_min: float | None
    wall_s_total: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _numbers(docs: list[dict[str, Any]], key: str) -> np.ndarray:
    vals = [d["figures"].get(key) for d in docs]
    return np.array([v for v in vals if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)],
                    dtype=float)


def _r(value: float) -> float:
    return round(float(value), 4)


def summarise(docs: list[dict[str, Any]]) -> list[ConfigSummary]:
    """The summaries of the run results `docs` (out/runs/*.json), one per configuration, in order of first
    appearance."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for d in docs:
        groups.setdefault(d["configuration"], []).append(d)
    out = []
    for name, group in groups.items():
        done = [d for d in group if d.get("status") == "done"]
        err, cov = _numbers(done, "error_m"), _numbers(done, "coverage")
        out.append(ConfigSummary(
            configuration=name, kind=group[0]["kind"], error_name=ERROR_NAMES.get(group[0]["kind"], "error"),
            runs=len(group), done=len(done), failed=sum(d.get("status") == "failed" for d in group),
            completed=sum(d["figures"].get("completed") is True for d in done),
            failsafes=sum(d["figures"].get("failsafe") is True for d in done),
            retried=sum((d.get("attempts") or 1) > 1 for d in done),
            error_p50_m=_r(np.percentile(err, 50)) if err.size else None,
            error_p95_m=_r(np.percentile(err, 95)) if err.size else None,
            error_worst_m=_r(err.max()) if err.size else None,
            coverage_p50=_r(np.percentile(cov, 50)) if cov.size else None,
            coverage_min=_r(cov.min()) if cov.size else None,
            wall_s_total=round(sum(float(d.get("wall_s") or 0.0) for d in done), 1)))
    return out


def _f(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def summary_text(summaries: list[ConfigSummary]) -> str:
    """The summaries as a fixed-width table for the terminal (error in metres, coverage as a share); the
    configuration column is as wide as the longest configuration (at least 48 characters), none cut short."""
    width = max([48, *(len(s.configuration) for s in summaries)])
    head = (f"{'configuration':{width}s} {'error':7s} {'p50':>6s} {'p95':>6s} {'worst':>6s} {'cov p50':>7s} "
            f"{'cov min':>7s} {'done':>5s} {'compl':>5s} {'fsafe':>5s} {'retry':>5s} {'fail':>4s}")
    lines = [head, "-" * len(head)]
    for s in summaries:
        lines.append(f"{s.configuration:{width}s} {s.error_name:7s} {_f(s.error_p50_m):>6s} {_f(s.error_p95_m):>6s} "
                     f"{_f(s.error_worst_m):>6s} {_f(s.coverage_p50, 3):>7s} {_f(s.coverage_min, 3):>7s} "
                     f"{s.done:>2d}/{s.runs:<2d} {s.completed:>5d} {s.failsafes:>5d} {s.retried:>5d} {s.failed:>4d}")
    return "\n".join(lines)
