"""`taco-mav tune`: a profile's parameters searched with Optuna against a campaign's objective.

The search space (YAML):

    profile: kitti                   # the profile tuned: a name or a YAML path
    trials: 20                       # Optuna trials (default 20)
    seed: 0                          # the sampler's seed (default 0): the same space and campaign, the same trials
    coverage: [0.865, 1.0]           # the band the runs' median coverage must stay in (default: no band)
    parameters:                      # dotted keys of the profile, each a range or a list of choices
      ukf.fix_fwd_num: {low: 0.5, high: 50.0, log: true}
      gate.yaw_residual_max_rad: {low: 0.05, high: 1.0}
      gate.enabled: {choices: [true, false]}

Every trial runs all the campaign's runs (`taco_mav.campaign.executor`, one Ray for the whole search) with the
profile set to `profile` and the trial's values as `set` overrides, into out/trial-NNN/ (out/baseline/ first: the
profile as it is). Its objective is the median of the runs' error (the ATE of eval and sim runs, the EKF's RMS
of SITL missions), metres; a trial whose median coverage (share of reports within 2 reported sigma) leaves the
band is infeasible (Optuna's constraint), as is one with a failed run. The TPE sampler is seeded and the
trials run one after another, so the search is deterministic; a search started again finds its trials' runs
done and goes through the same trials without running them.

The best feasible trial's profile is written as out/best_profile.yaml (a complete profile, loadable with
--profile; its figures in the comment at the top) and every trial in out/tune.json.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from taco_mav.campaign.executor import RayOptions, ray_session, run_campaign
from taco_mav.campaign.overrides import apply_overrides, key_type
from taco_mav.campaign.results import load_results
from taco_mav.campaign.spec import Campaign, Run, make_run_id, read_yaml
from taco_mav.config import load_profile, profile_to_dict
from taco_mav.errors import ConfigError, UsageError

log = logging.getLogger(__name__)

__all__ = ["Parameter", "SearchSpace", "TrialFigures", "TuneResult", "load_space", "tune"]

SPACE_KEYS = ("profile", "trials", "seed", "coverage", "parameters")


@dataclass(frozen=True)
class Parameter:
    """One searched profile key: a range (low, high; log: sampled in log space; integer for int keys) or choices."""

    key: str
    kind: str  # "float" | "int" | "choice"
    low: float | None = None
    high: float | None = None
    log: bool = False
    choices: tuple[Any, ...] = ()


@dataclass(frozen=True)
class SearchSpace:
    profile: str
    parameters: tuple[Parameter, ...]
    trials: int = 20
    seed: int = 0
    coverage: tuple[float, float] | None = None


@dataclass(frozen=True)
class TrialFigures:
    """A trial's figures over the campaign's runs: median error (m), median coverage (share; None where no run
    scores it), runs done and failed, and whether it is feasible (coverage in the band, no failed run)."""

    number: int | None
    values: dict[str, Any]
    median_error_m: float | None
    median_coverage: float | None
    done: int
    failed: int
    feasible: bool

    def to_dict(self) -> dict[str, Any]:
        return {"trial": self.number, "values": self.values, "median_error_m": self.median_error_m,
                "median_coverage": self.median_coverage, "done": self.done, "failed": self.failed,
                "feasible": self.feasible}


@dataclass
class TuneResult:
    baseline: TrialFigures
    best: TrialFigures
    trials: list[TrialFigures] = field(default_factory=list)
    profile_path: Path | None = None


def _parameter(key: str, data: Any, where: str, base: Any) -> Parameter:
    tp = key_type(key, where)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected {{low, high[, log]}} or {{choices: [...]}}, got {data!r}")
    for k in data:
        if k not in ("low", "high", "log", "choices"):
            raise ConfigError(f"{where}.{k}: unknown key (known: choices, high, log, low)")
    if "choices" in data:
        if not isinstance(data["choices"], list) or not data["choices"] or set(data) != {"choices"}:
            raise ConfigError(f"{where}.choices: expected a non-empty list (and no low, high, log)")
        param = Parameter(key, "choice", choices=tuple(data["choices"]))
        ends = list(param.choices)
    else:
        if tp not in (int, float, int | None, float | None):
            raise ConfigError(f"{where}: {key} is not a number; give it choices: [...]")
        low, high, use_log = data.get("low"), data.get("high"), data.get("log", False)
        for name, v in (("low", low), ("high", high)):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(f"{where}.{name}: expected a number, got {v!r}")
        if not low < high:
            raise ConfigError(f"{where}: low {low} must be below high {high}")
        if not isinstance(use_log, bool) or (use_log and low <= 0):
            raise ConfigError(f"{where}.log: true or false; log needs low > 0")
        is_int = tp in (int, int | None)
        param = Parameter(key, "int" if is_int else "float", float(low), float(high), use_log)
        ends = [int(low), int(high)] if is_int else [float(low), float(high)]
    for value in ends:  # each end must be a value the profile takes (type, range)
        apply_overrides(base, {key: value}, where)
    return param


def load_space(path: str | Path) -> SearchSpace:
    """Read and validate a search space (see the module docstring); ConfigError naming the file and key."""
    path = Path(path)
    doc = read_yaml(path)
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: a search space is a mapping with profile and parameters")
    for key in doc:
        if key not in SPACE_KEYS:
            raise ConfigError(f"{path}: {key}: unknown key (known: {', '.join(sorted(SPACE_KEYS))})")
    if not isinstance(doc.get("profile"), str):
        raise ConfigError(f"{path}: profile: the profile to tune (a name or a YAML path)")
    base = load_profile(doc["profile"])
    trials, seed = doc.get("trials", 20), doc.get("seed", 0)
    for name, v, lo in (("trials", trials, 1), ("seed", seed, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ConfigError(f"{path}: {name}: expected an integer >= {lo}, got {v!r}")
    band = doc.get("coverage")
    if band is not None:
        ok = isinstance(band, list) and len(band) == 2 and all(isinstance(b, (int, float)) for b in band)
        if not ok or not 0.0 <= band[0] <= band[1] <= 1.0:
            raise ConfigError(f"{path}: coverage: expected [low, high] with 0 <= low <= high <= 1, got {band!r}")
        band = (float(band[0]), float(band[1]))
    params = doc.get("parameters")
    if not isinstance(params, dict) or not params:
        raise ConfigError(f"{path}: parameters: expected a mapping of dotted profile keys to ranges")
    parsed = tuple(_parameter(str(k), v, f"{path}: parameters.{k}", base) for k, v in params.items())
    return SearchSpace(doc["profile"], parsed, trials, seed, band)


def _with_profile(campaign: Campaign, profile: str, values: dict[str, Any]) -> Campaign:
    """The campaign's runs with `profile` and `values` as set overrides (over each run's own)."""
    runs = []
    for run in campaign.runs:
        params = {**run.params, "profile": profile, "set": {**(run.params.get("set") or {}), **values}}
        grid = {k: v for k, v in run.factors.items() if k == "seed"}
        runs.append(Run(make_run_id(run.kind, grid, params), run.kind, params, run.factors, run.num_cpus, run.resources))
    return replace(campaign, runs=tuple(runs))


def _figures(out: Path, number: int | None, values: dict[str, Any], band: tuple[float, float] | None) -> TrialFigures:
    docs = load_results(out)
    done = [d for d in docs if d.get("status") == "done"]
    err = [d["figures"]["error_m"] for d in done if isinstance(d["figures"].get("error_m"), (int, float))]
    cov = [d["figures"]["coverage"] for d in done if isinstance(d["figures"].get("coverage"), (int, float))]
    failed = sum(d.get("status") == "failed" for d in docs)
    median_cov = round(float(np.median(cov)), 4) if cov else None
    in_band = band is None or (median_cov is not None and band[0] <= median_cov <= band[1])
    return TrialFigures(number, values, round(float(np.median(err)), 4) if err else None, median_cov, len(done),
                        failed, bool(in_band and not failed and err))


def _violation(f: TrialFigures, band: tuple[float, float] | None) -> float:
    """How far a trial is from feasible (<= 0: feasible), for Optuna's constraint."""
    if f.failed or f.median_error_m is None:
        return 1.0 + f.failed
    if band is None:
        return 0.0
    if f.median_coverage is None:
        return 1.0
    return max(band[0] - f.median_coverage, f.median_coverage - band[1], 0.0) if not f.feasible else -1.0


def _suggest(trial: Any, p: Parameter) -> Any:
    if p.kind == "choice":
        return trial.suggest_categorical(p.key, list(p.choices))
    if p.kind == "int":
        return trial.suggest_int(p.key, int(p.low), int(p.high), log=p.log)
    return trial.suggest_float(p.key, p.low, p.high, log=p.log)


def _write_profile(space: SearchSpace, best: TrialFigures, baseline: TrialFigures, path: Path, campaign: Campaign) -> None:
    base = load_profile(space.profile)
    profile = apply_overrides(base, {**best.values, "name": f"{base.name}_tuned"}, str(path))
    lines = [f"# {base.name} tuned by `taco-mav tune` on campaign {campaign.name} ({len(campaign.runs)} run(s)), "
             f"Optuna TPE seed {space.seed}, {space.trials} trials",
             f"# best: trial {best.number}: median error {best.median_error_m} m, median coverage "
             f"{best.median_coverage} (band {list(space.coverage) if space.coverage else 'none'}), "
             f"{best.done} run(s) done",
             f"# the profile as it was: median error {baseline.median_error_m} m, median coverage "
             f"{baseline.median_coverage}",
             *(f"#   {k}: {v!r}" for k, v in best.values.items())]
    path.write_text("\n".join(lines) + "\n" + yaml.safe_dump(profile_to_dict(profile), sort_keys=False))


def tune(campaign: Campaign, space: SearchSpace, out: Path, context: dict[str, Any],
         options: RayOptions = RayOptions()) -> TuneResult:
    """Search `space` against `campaign` into `out` (see the module docstring); returns the baseline, the best
    trial and every trial's figures."""
    try:
        import optuna
    except ImportError:
        raise UsageError("taco-mav tune needs Optuna: pip install -e '.[campaign]'") from None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    trials: list[TrialFigures] = []
    with ray_session(options, context):
        run_campaign(_with_profile(campaign, space.profile, {}), out / "baseline", context, options)
        baseline = _figures(out / "baseline", None, {}, space.coverage)
        log.info("baseline: median error %s m, coverage %s", baseline.median_error_m, baseline.median_coverage)

        def objective(trial: Any) -> float:
            values = {p.key: _suggest(trial, p) for p in space.parameters}
            folder = out / f"trial-{trial.number:03d}"
            run_campaign(_with_profile(campaign, space.profile, values), folder, context, options)
            figures = _figures(folder, trial.number, values, space.coverage)
            trials.append(figures)
            trial.set_constraint("coverage_band", _violation(figures, space.coverage))
            log.info("trial %d %s: median error %s m, coverage %s%s", trial.number, values, figures.median_error_m,
                     figures.median_coverage, "" if figures.feasible else " (infeasible)")
            return figures.median_error_m if figures.median_error_m is not None else math.inf

        sampler = optuna.samplers.TPESampler(seed=space.seed, n_startup_trials=min(10, max(2, space.trials // 2)))
        study = optuna.create_study(direction="minimize", sampler=sampler)
        study.optimize(objective, n_trials=space.trials, n_jobs=1)
    feasible = [t for t in trials if t.feasible]
    best = min(feasible, key=lambda t: t.median_error_m) if feasible else baseline
    result = TuneResult(baseline, best, trials)
    (out / "tune.json").write_text(json.dumps({"space": {"profile": space.profile, "trials": space.trials,
                                                         "seed": space.seed, "coverage": space.coverage},
                                               "baseline": baseline.to_dict(), "best": best.to_dict(),
                                               "trials": [t.to_dict() for t in trials]}, indent=1) + "\n")
    if best is not baseline:
        result.profile_path = out / "best_profile.yaml"
        _write_profile(space, best, baseline, result.profile_path, campaign)
    return result
