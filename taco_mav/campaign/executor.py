"""A campaign's runs as Ray tasks: resources per run, lost workers retried, each result written as it comes,
and a campaign started again skipping what is done.

The out folder holds:

- `campaign.json`: the runs (ids, kinds, parameters, factors);
- `runs/<run id>.json`: one per finished run, written atomically the moment it finishes: status `done` (with its
  figures, attempts, wall seconds, node) or `failed` (with the error). A run with a `done` file is skipped by
  the next start; a failed one is run again;
- `work/<run id>/`: what the run itself wrote (the harness's files, the child's log), on the node that ran it.

Ray: by default a local Ray started here (`num_cpus` cores; custom resources `ardurover` / `px4_sitl`, one per
core, when this machine has the binary), with a 200 MB object store, no dashboard and its logs kept out of the
terminal; `address` joins a running cluster instead, whose nodes declare those resources themselves (`ray start
--resources='{"ardurover": 4}'`). A task whose worker process dies (killed, out of memory, its node lost) is
retried up to `max_retries` times by Ray; an error inside a run is not retried (it would fail again) and is
recorded. Ctrl-C cancels what is in flight (the runs' processes end with their workers) and leaves every
result already written.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from taco_mav.campaign.child import namespaces_available, run_in_child
from taco_mav.campaign.kinds import KINDS
from taco_mav.campaign.spec import Campaign, Run
from taco_mav.errors import ConfigError, UsageError

log = logging.getLogger(__name__)

__all__ = ["CampaignOutcome", "RayOptions", "done_runs", "ray_session", "run_campaign"]

Runner = Callable[[dict[str, Any], str, dict[str, Any]], dict[str, Any]]
OBJECT_STORE_BYTES = 200 * 1024 * 1024
SITL_RESOURCES = {"ardurover": "ardurover", "px4_sitl": "px4_sitl"}  # resource name -> context key of its binary


@dataclass(frozen=True)
class RayOptions:
    """address: a Ray cluster to join (None: start a local Ray); num_cpus: the local Ray's cores (None: this
    machine's); max_retries: how often a run whose worker died is started again."""

    address: str | None = None
    num_cpus: int | None = None
    max_retries: int = 3


@dataclass
class CampaignOutcome:
    """What a start of the campaign did: runs skipped (done before), run now, failed now (ids), and its wall
    seconds."""

    skipped: list[str] = field(default_factory=list)
    finished: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    wall_s: float = 0.0


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(doc, indent=1, default=str))
    tmp.replace(path)


def done_runs(out: Path) -> set[str]:
    """The ids of the runs whose result in out/runs says done."""
    done = set()
    for path in sorted((Path(out) / "runs").glob("*.json")):
        try:
            if json.loads(path.read_text()).get("status") == "done":
                done.add(path.stem)
        except (OSError, ValueError):
            log.warning("%s: unreadable, the run is done again", path)
    return done


class ray_session:
    """`with ray_session(options, context):` a Ray to submit to: the local one started here (stopped at the end)
    or the cluster at options.address (left running). A local Ray offers the SITL resources only for the
    binaries in `context` that exist."""

    def __init__(self, options: RayOptions, context: dict[str, Any]) -> None:
        self.options = options
        self.context = context
        self.started = False

    def __enter__(self) -> ray_session:
        try:
            import ray
        except ImportError:
            raise UsageError("campaigns run on Ray: pip install -e '.[campaign]'") from None
        if ray.is_initialized():
            return self
        common = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.WARNING,
                  "configure_logging": True}
        if self.options.address:
            ray.init(address=self.options.address, **common)
        else:
            cpus = self.options.num_cpus or os.cpu_count() or 1
            custom = {name: float(cpus) for name, key in SITL_RESOURCES.items()
                      if self.context.get(key) and Path(self.context[key]).is_file()}
            ray.init(num_cpus=cpus, resources=custom, object_store_memory=OBJECT_STORE_BYTES, **common)
        self.started = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self.started:
            import ray

            ray.shutdown()


def _check_feasible(runs: list[Run]) -> None:
    """Every run's resources offered by some node of the Ray (else its task would wait for ever)."""
    import ray

    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    for run in runs:
        need = {"CPU": run.num_cpus, **run.resources}
        if not any(all(node.get(k, 0.0) >= v for k, v in need.items()) for node in nodes):
            offered = sorted({k for node in nodes for k in node if not k.startswith("node:")})
            raise ConfigError(f"run {run.run_id}: no node of this Ray offers {need} (offered: {', '.join(offered)}; "
                              "a SITL kind needs its binary: --ardurover / --px4 or ARDUROVER / PX4_SITL)")


def _results(refs: dict[Any, Run], cancel_on_exit: bool) -> Iterator[tuple[Run, dict[str, Any] | None, str | None]]:
    """(run, result, error) as each task ends, in the order they end; cancels the rest when interrupted."""
    import ray
    from ray.exceptions import RayError, RayTaskError

    pending = list(refs)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=1.0)
            for ref in ready:
                try:
                    yield refs[ref], ray.get(ref), None
                except RayTaskError as exc:  # an error inside the run: recorded, not retried
                    cause = exc.cause if exc.cause is not None else exc
                    yield refs[ref], None, f"{type(cause).__name__}: {cause}"
                except RayError as exc:  # the worker lost more often than max_retries
                    yield refs[ref], None, f"{type(exc).__name__}: {exc}"
    finally:
        if cancel_on_exit and pending:
            log.warning("cancelling %d run(s) in flight", len(pending))
            for ref in pending:
                ray.cancel(ref, force=True)


def run_campaign(campaign: Campaign, out: Path, context: dict[str, Any], options: RayOptions = RayOptions(),
                 runner: Runner = run_in_child, on_result: Callable[[Run, dict[str, Any]], None] | None = None
                 ) -> CampaignOutcome:
    """Run the campaign's runs not done yet in `out` (see the module docstring); `on_result(run, doc)` is called
    with each run's JSON as it is written. `runner(run dict, work dir, context)` runs one run in a Ray worker
    (default: in a child process, `child.run_in_child`)."""
    out = Path(out)
    start = time.monotonic()
    outcome = CampaignOutcome()
    _write_json(out / "campaign.json", {"name": campaign.name, "source": campaign.source,
                                        "runs": [r.to_dict() for r in campaign.runs]})
    done = done_runs(out)
    todo = [r for r in campaign.runs if r.run_id not in done]
    outcome.skipped = [r.run_id for r in campaign.runs if r.run_id in done]
    if outcome.skipped:
        log.info("%d of %d runs done before: skipped", len(outcome.skipped), len(campaign.runs))
    if not todo:
        return outcome
    context = {**context, "namespaces": any(KINDS[r.kind].isolated for r in todo) and namespaces_available()}
    with ray_session(options, context):
        import ray

        _check_feasible(todo)
        task = ray.remote(runner)
        refs = {task.options(num_cpus=r.num_cpus, resources=r.resources or None, max_retries=options.max_retries,
                             retry_exceptions=False, name=f"run {r.run_id}")
                .remote(r.to_dict(), str((out / "work" / r.run_id).resolve()), context): r for r in todo}
        for run, result, error in _results(refs, cancel_on_exit=True):
            doc = {**run.to_dict(), "status": "done" if error is None else "failed", "error": error,
                   "configuration": run.configuration(), **(result or {})}
            _write_json(out / "runs" / f"{run.run_id}.json", doc)
            (outcome.finished if error is None else outcome.failed).append(run.run_id)
            if error is not None:
                log.error("run %s failed: %s", run.run_id, error)
            if on_result is not None:
                on_result(run, doc)
    outcome.wall_s = time.monotonic() - start
    return outcome
