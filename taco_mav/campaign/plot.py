"""A campaign's errors as a box per configuration (matplotlib, PNG): each box the finished runs' error (SITL
missions: the EKF's RMS error; sim and eval runs: the ATE), metres, its points drawn over it."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["plot_campaign"]


def plot_campaign(docs: list[dict[str, Any]], path: Path, title: str) -> Path | None:
    """Boxes of `error_m` per configuration of the run results `docs` into `path`; None when no run has one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from taco_mav.campaign.summary import ERROR_NAMES

    groups: dict[str, list[float]] = {}
    names: dict[str, str] = {}
    for d in docs:
        value = (d.get("figures") or {}).get("error_m") if d.get("status") == "done" else None
        groups.setdefault(d["configuration"], [])
        names[d["configuration"]] = ERROR_NAMES.get(d["kind"], "error")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            groups[d["configuration"]].append(float(value))
    groups = {k: v for k, v in groups.items() if v}
    if not groups:
        return None
    labels = list(groups)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(labels) + 2.0), 5.0))
    ax.boxplot([groups[k] for k in labels], whis=(5, 95), showfliers=False)  # every run is drawn as a point
    for i, k in enumerate(labels, start=1):
        ax.plot([i] * len(groups[k]), groups[k], "k.", alpha=0.6)
    ax.set_xticks(range(1, len(labels) + 1), [f"{k}\n({names[k]}, n={len(groups[k])})" for k in labels],
                  rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("error, m")
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
