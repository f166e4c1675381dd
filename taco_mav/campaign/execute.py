"""One run of each kind, in the process `taco_mav.campaign.child` starts for it: the harness called with the
run's parameters, its files under the run's work folder, and its figures returned with the four every kind
names alike (`error_m`, `coverage`, `completed`, `failsafe`: taco_mav.campaign.kinds).

`context` carries what the machine, not the campaign, decides: `ardurover` and `px4_sitl` (the SITL binaries)
and `kitti_root`.
"""

from __future__ import annotations

import dataclasses
import logging
import typing
from pathlib import Path
from typing import Any

import yaml

from taco_mav.campaign.kinds import KINDS
from taco_mav.campaign.overrides import apply_overrides
from taco_mav.config import Profile, load_profile, profile_to_dict
from taco_mav.errors import ConfigError

log = logging.getLogger(__name__)

__all__ = ["execute_run", "run_profile"]


def run_profile(name: str, overrides: dict[str, Any], folder: Path) -> tuple[Profile, str]:
    """Profile `name` with the run's `overrides`; without overrides the name itself, with them the profile
    written as folder/profile.yaml (what a subprocess such as the SITL harness's daemon is given)."""
    profile = load_profile(name)
    if not overrides:
        return profile, name
    profile = apply_overrides(profile, overrides, f"{name} with set")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "profile.yaml"
    path.write_text(yaml.safe_dump(profile_to_dict(profile), sort_keys=False))
    return profile, str(path)


def _scalars(doc: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """The numbers, strings and booleans of a nested result (dotted names for nested mappings; lists left out:
    they stay in the run's JSON)."""
    out: dict[str, Any] = {}
    for key, value in doc.items():
        if isinstance(value, dict):
            out.update(_scalars(value, f"{prefix}{key}."))
        elif value is None or isinstance(value, (bool, int, float, str)):
            out[f"{prefix}{key}"] = value
    return out


def _spec(cls: type, params: dict[str, Any], profile: str) -> Any:
    """A harness mission spec from a run's parameters (`seed` is the world's; tuples where the spec has them)."""
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = "seed" if f.name == "world_seed" else f.name
        if name not in params:
            continue
        value = params[name]
        if typing.get_origin(hints[f.name]) is tuple and value is not None:
            value = tuple(value)
        kwargs[f.name] = value
    kwargs["profile"] = profile
    return cls(**kwargs)


def _binary(context: dict[str, Any], key: str, env: str) -> Path:
    path = context.get(key)
    if not path or not Path(path).is_file():
        option = "--" + key.replace("_", "-")
        raise ConfigError(f"{key}: the SITL binary is not on this machine ({path or f'give {option} or set {env}'})")
    return Path(path)


def _ardupilot(params: dict[str, Any], work: Path, context: dict[str, Any]) -> dict[str, Any]:
    from taco_mav.closedloop.ardupilot import MissionSpec, default_profile, run_mission

    _, profile = run_profile(params["profile"] or default_profile(params["setup"]), params["set"], work)
    figures = run_mission(_binary(context, "ardurover", "ARDUROVER"), work / "mission", _spec(MissionSpec, params, profile))
    figures.pop("spec", None)  # the run's parameters are beside the figures already
    texts = [t.lower() for t in figures.get("statustext", [])]
    return {**figures, "completed": figures.get("mission_completed") is True,
            "failsafe": figures.get("verdict") == "runaway_stopped" or any("failsafe" in t for t in texts)}


def _px4(params: dict[str, Any], work: Path, context: dict[str, Any]) -> dict[str, Any]:
    from taco_mav.closedloop.px4 import Px4MissionSpec, default_profile, run_px4_mission

    _, profile = run_profile(params["profile"] or default_profile(params["setup"]), params["set"], work)
    figures = run_px4_mission(_binary(context, "px4_sitl", "PX4_SITL"), work / "mission",
                              _spec(Px4MissionSpec, params, profile))
    figures.pop("spec", None)
    return {**figures, "completed": figures.get("mission_completed") is True,
            "failsafe": bool(figures.get("failsafe")) or figures.get("verdict") in ("runaway_stopped", "disarmed")}


def _sim(params: dict[str, Any], work: Path, context: dict[str, Any]) -> dict[str, Any]:
    from taco_mav.config import Estimator
    from taco_mav.datasets.synthetic import build_world, register_world_camera
    from taco_mav.demo import demo_profile, play_on_loopback

    profile, _ = run_profile(params["profile"] or demo_profile(params["estimator"]), params["set"], work)
    register_world_camera()
    world = build_world(work / "world", seed=params["seed"], length_km=params["length_km"], progress=False,
                        realism=params["realism"])
    played = play_on_loopback(world, profile, Estimator(params["estimator"]), work / "daemon", speed=params["speed"],
                              duration_s=params["duration_s"], progress=False, seed=params["seed"],
                              deny_after_s=params["deny_after_s"])
    seq = played.sim.results()["sequences"][played.sim.drive.name]
    return {**seq, "daemon": played.daemon, "completed": not played.interrupted and seq.get("ate_m") is not None,
            "failsafe": False}


def _eval(params: dict[str, Any], work: Path, context: dict[str, Any]) -> dict[str, Any]:
    from taco_mav.evaluation.evaluate import EvalRequest, evaluate

    if (params["sequence"] is None) == (params["drive"] is None):
        raise ConfigError("an eval run names one of sequence (a KITTI odometry id) or drive (a folder)")
    _, profile = run_profile(params["profile"], params["set"], work)
    root = params["kitti_root"] or context.get("kitti_root")
    if params["sequence"] is not None and root is None:
        raise ConfigError("eval run: sequence needs the KITTI raw root (kitti_root, --kitti-root or TACO_KITTI_ROOT)")
    req = EvalRequest(out=work / "eval", profile=profile, kitti_root=Path(root) if root else None,
                      sequences=(params["sequence"],) if params["sequence"] is not None else (),
                      drives=(Path(params["drive"]),) if params["drive"] is not None else (), matcher=params["matcher"],
                      seed=params["seed"], latency_s=params["latency_s"], estimator=params["estimator"],
                      cross_area=params["cross_area"], plots=False, progress=False)
    results = evaluate(req)
    (seq,) = results["sequences"].values()
    return {**seq, "completed": seq.get("ate_m") is not None, "failsafe": False}


EXECUTORS = {"ardupilot": _ardupilot, "px4": _px4, "sim": _sim, "eval": _eval}


def execute_run(kind: str, params: dict[str, Any], work: Path, context: dict[str, Any]) -> dict[str, Any]:
    """Run one `kind` run with `params` in folder `work`; returns its figures: the harness's scalars (nested
    mappings flattened to dotted names) with error_m, coverage, completed and failsafe."""
    work.mkdir(parents=True, exist_ok=True)
    figures = _scalars(EXECUTORS[kind](params, work, context))
    spec = KINDS[kind]
    figures["error_m"] = figures.get(spec.error_figure)
    figures["coverage"] = figures.get(spec.coverage_figure) if spec.coverage_figure else None
    return figures
