"""The kinds of run a campaign is made of: what parameters each takes (with their defaults), what it needs of a
machine (cores, a SITL binary), whether it needs a network namespace of its own, and which figure scores it.

- `ardupilot`: an ArduPilot Rover SITL mission (`taco_mav.closedloop.ardupilot.run_mission`); parameters: the
  fields of its `MissionSpec` (setup, laps, side_m, realism, fault, ...), `seed` (the world's) for world_seed;
- `px4`: a PX4 SITL (SIH) mission (`taco_mav.closedloop.px4.run_px4_mission`); parameters: the fields of
  `Px4MissionSpec`, `seed` for world_seed;
- `sim`: the in-process simulator and the daemon on loopback, as `taco-mav demo` runs them, on a synthetic
  world of its own (`SimRun`);
- `eval`: `taco-mav eval` of one KITTI odometry sequence or one drive folder (`EvalRun`).

Every kind also takes `set`: profile overrides by dotted key (`{ukf.sigma_fwd_k: 1.5}`), checked against the
profile before anything runs. A run's figures are the harness's own, plus four every kind gives the same name:
`error_m` (SITL missions: the EKF's RMS error against the truth, ekf_rms_m; sim and eval: the ATE, ate_m),
`coverage` (the share of our reports whose error is within 2 reported sigma: SITL ours_sent_within_2_hacc, eval
coverage_2sigma; None for sim, whose simulator does not score it), `completed` and `failsafe`.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["KINDS", "EvalRun", "RunKind", "SimRun", "kind_fields"]

ESTIMATORS = ("taco+", "paper")
REALISMS = ("flat", "3d")


@dataclass(frozen=True)
class SimRun:
    """An in-process simulator run. estimator: taco+ | paper; profile: name or YAML path (default the demo's for
    the estimator: synthetic_rover, synthetic); seed: the world's and the simulated receiver's; length_km: the
    world's route; realism: flat | 3d; speed: real-time factor; duration_s: drive seconds played (None: all);
    deny_after_s: drive seconds of real GNSS before it is denied."""

    estimator: str = "taco+"
    profile: str | None = None
    seed: int = 0
    length_km: float = 0.3
    realism: str = "flat"
    speed: float = 8.0
    duration_s: float | None = None
    deny_after_s: float = 1.0
    set: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class EvalRun:
    """An offline evaluation of one drive. sequence: a KITTI odometry id (with kitti_root: the KITTI raw root,
    default the one `taco-mav eval` finds, TACO_KITTI_ROOT or ../shared/data/kitti_raw) or drive: a KITTI-layout
    or synthetic world folder; profile: name or YAML path; matcher, estimator: overrides (None: the profile's);
    seed: the emulator's draws; latency_s: each fix delivered this late, s; cross_area: the emulator's FG2
    cross-area figures for the drive, as `taco-mav eval --cross-area` (False: per the profile's
    emulator.cross_area_sequences)."""

    sequence: str | None = None
    drive: str | None = None
    kitti_root: str | None = None
    profile: str = "kitti"
    matcher: str | None = None
    estimator: str | None = None
    seed: int = 0
    latency_s: float = 0.0
    cross_area: bool = False
    set: dict[str, Any] = field(default_factory=dict)


def _sitl_fields(module: str, cls_name: str) -> Callable[[], dict[str, tuple[Any, Any]]]:
    """The parameters of a SITL kind: its mission spec's fields, world_seed given as `seed`, profile None (the
    harness's default for the set-up), and `set`. Imported when asked (the harness loads pymavlink)."""

    def fields() -> dict[str, tuple[Any, Any]]:
        import importlib

        cls = getattr(importlib.import_module(module), cls_name)
        hints = typing.get_type_hints(cls)
        out: dict[str, tuple[Any, Any]] = {}
        for f in dataclasses.fields(cls):
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
            if f.name == "world_seed":
                out["seed"] = (int, default)
            elif f.name == "profile":
                out["profile"] = (str | None, None)
            else:
                out[f.name] = (hints[f.name], default)
        out["set"] = (dict[str, Any], {})
        return out

    return fields


def _dataclass_fields(cls: type) -> Callable[[], dict[str, tuple[Any, Any]]]:
    def fields() -> dict[str, tuple[Any, Any]]:
        hints = typing.get_type_hints(cls)
        return {f.name: (hints[f.name], f.default_factory() if f.default_factory is not dataclasses.MISSING
                         else f.default) for f in dataclasses.fields(cls)}

    return fields


@dataclass(frozen=True)
class RunKind:
    """One kind of run. fields: its parameters {name: (type, default)}; choices: the allowed values of some;
    num_cpus: cores a run takes by default; resources: Ray custom resources it needs (a node offering
    `ardurover` has the ArduPilot SITL binary, `px4_sitl` PX4's); isolated: run in a network namespace and /tmp
    of its own (SITL's fixed ports and lock files); error_figure, coverage_figure: the harness figures taken as
    `error_m` and `coverage`."""

    name: str
    fields: Callable[[], dict[str, tuple[Any, Any]]]
    choices: dict[str, tuple[Any, ...]]
    num_cpus: float
    resources: dict[str, float]
    isolated: bool
    error_figure: str
    coverage_figure: str | None


KINDS: dict[str, RunKind] = {
    "ardupilot": RunKind("ardupilot", _sitl_fields("taco_mav.closedloop.ardupilot", "MissionSpec"),
                         {"setup": ("solo", "handover"), "estimator": ESTIMATORS, "realism": REALISMS},
                         1.0, {"ardurover": 1.0}, True, "ekf_rms_m", "ours_sent_within_2_hacc"),
    "px4": RunKind("px4", _sitl_fields("taco_mav.closedloop.px4", "Px4MissionSpec"),
                   {"setup": ("solo", "handover", "gnss"), "estimator": ESTIMATORS, "realism": REALISMS},
                   1.0, {"px4_sitl": 1.0}, True, "ekf_rms_m", "ours_sent_within_2_hacc"),
    "sim": RunKind("sim", _dataclass_fields(SimRun), {"estimator": ESTIMATORS, "realism": REALISMS},
                   1.0, {}, False, "ate_m", None),
    "eval": RunKind("eval", _dataclass_fields(EvalRun), {"estimator": (None, *ESTIMATORS)},
                    1.0, {}, False, "ate_m", "coverage_2sigma"),
}


def kind_fields(kind: str) -> dict[str, tuple[Any, Any]]:
    """The parameters of run kind `kind`, {name: (type, default)}."""
    return KINDS[kind].fields()
