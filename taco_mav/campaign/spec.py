"""A campaign file (YAML) -> the runs it names, every one validated before any starts.

    name: smoke                    # optional; default the file's name
    seed: 0                        # the seed of runs that name none (default 0)
    runs:                          # blocks; each is one run, or a grid of them
      - kind: sim                  # ardupilot | px4 | sim | eval (taco_mav.campaign.kinds)
        grid:                      # factors: each a list; every combination is a run
          estimator: [taco+, paper]
          seed: [1, 2, 3]
        with: {duration_s: 30}     # parameters every run of the block takes
        resources: {num_cpus: 1}   # optional: cores and Ray custom resources per run (default: the kind's)

Errors (`ConfigError`) name the file and the key (`smoke.yaml: runs[0].grid.laps: ...`). A run's id names its kind
and grid values and ends in a hash of all its parameters, so a campaign started again finds the runs it has done,
and a changed parameter makes a new run.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from taco_mav.campaign.kinds import KINDS, kind_fields
from taco_mav.campaign.overrides import key_type
from taco_mav.errors import ConfigError

__all__ = ["Campaign", "Run", "load_campaign", "make_run_id", "parse_campaign", "read_yaml"]

BLOCK_KEYS = ("kind", "grid", "with", "resources")


@dataclass(frozen=True)
class Run:
    """One run. params: every parameter of its kind (defaults filled in; JSON values); factors: the ones the
    campaign named (grid and with), the results table's columns; num_cpus and resources: what Ray reserves."""

    run_id: str
    kind: str
    params: dict[str, Any]
    factors: dict[str, Any]
    num_cpus: float
    resources: dict[str, float]

    def configuration(self) -> str:
        """The configuration this run is one seed of: its kind and factors but the seed, as text."""
        rest = ", ".join(f"{k}={_text(v)}" for k, v in sorted(self.factors.items()) if k != "seed")
        return f"{self.kind}: {rest}" if rest else self.kind

    def to_dict(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "kind": self.kind, "params": self.params, "factors": self.factors,
                "num_cpus": self.num_cpus, "resources": self.resources}


@dataclass(frozen=True)
class Campaign:
    """A campaign: its name, the file it came from, and its runs in the file's order."""

    name: str
    source: str
    runs: tuple[Run, ...]


def _text(value: Any) -> str:
    return json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else str(value)


def _check(value: Any, tp: Any, where: str) -> Any:
    """`value` checked against annotation `tp` (int, float, str, bool, X | None, tuple/list/dict of them);
    returns it as JSON (tuples as lists, ints where floats are asked stay numbers)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _check(value, inner[0], where)
    if tp is Any:
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = [a for a in typing.get_args(tp) if a is not Ellipsis] or [Any]
        if origin is tuple and len(typing.get_args(tp)) > 1 and Ellipsis not in typing.get_args(tp) \
                and len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} values, got {len(value)}")
        return [_check(v, args[min(i, len(args) - 1)], f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        vt = typing.get_args(tp)[1] if typing.get_args(tp) else Any
        return {str(k): _check(v, vt, f"{where}.{k}") for k, v in value.items()}
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (tp is int and not isinstance(value, int)):
            raise ConfigError(f"{where}: expected {'an integer' if tp is int else 'a number'}, got {value!r}")
        return value
    if tp is str:
        if isinstance(value, bool) or not isinstance(value, (str, int)):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return str(value)
    raise ConfigError(f"{where}: unsupported parameter type {tp!r}")  # pragma: no cover - a kind's own bug


def _params(kind: str, given: dict[str, Any], where: dict[str, str]) -> dict[str, Any]:
    """Every parameter of `kind`: `given` checked (unknown keys, types, choices, profile keys of `set`) over
    the defaults. where: the file-and-key text of each given name."""
    fields = kind_fields(kind)
    params = {name: _check(default, Any, name) for name, (_, default) in fields.items()}
    params = json.loads(json.dumps(params, default=list))  # tuples as lists, as JSON has them
    for name, value in given.items():
        if name not in fields:
            raise ConfigError(f"{where[name]}: unknown parameter of a {kind} run (known: {', '.join(sorted(fields))})")
        params[name] = _check(value, fields[name][0], where[name])
        allowed = KINDS[kind].choices.get(name)
        if allowed is not None and params[name] not in allowed:
            raise ConfigError(f"{where[name]}: {value!r} is not one of {', '.join(str(a) for a in allowed)}")
    for key in params.get("set") or {}:
        key_type(key, where.get("set", "set"))
    return params


def make_run_id(kind: str, grid: dict[str, Any], params: dict[str, Any]) -> str:
    digest = hashlib.sha1(json.dumps({"kind": kind, **params}, sort_keys=True).encode()).hexdigest()[:8]
    named = "-".join(f"{k}={_text(v)}" for k, v in grid.items())
    slug = re.sub(r"[^A-Za-z0-9=.+_-]", "_", f"{kind}-{named}" if named else kind)[:80]
    return f"{slug}-{digest}"


def _resources(kind: str, data: Any, where: str) -> tuple[float, dict[str, float]]:
    cpus, custom = KINDS[kind].num_cpus, dict(KINDS[kind].resources)
    if data is None:
        return cpus, custom
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of resource names to amounts, got {data!r}")
    for name, amount in data.items():
        if isinstance(amount, bool) or not isinstance(amount, (int, float)) or amount < 0:
            raise ConfigError(f"{where}.{name}: expected an amount >= 0, got {amount!r}")
        if name == "num_cpus":
            cpus = float(amount)
        else:
            custom[str(name)] = float(amount)
    return cpus, custom


def _block(doc_where: str, i: int, block: Any, default_seed: int) -> list[Run]:
    at = f"{doc_where} runs[{i}]"
    if not isinstance(block, dict):
        raise ConfigError(f"{at}: expected a mapping with kind, grid, with, resources")
    for key in block:
        if key not in BLOCK_KEYS:
            raise ConfigError(f"{at}.{key}: unknown key (known: {', '.join(BLOCK_KEYS)})")
    kind = block.get("kind")
    if kind not in KINDS:
        raise ConfigError(f"{at}.kind: {kind!r} is not one of {', '.join(KINDS)}")
    grid, fixed = block.get("grid") or {}, block.get("with") or {}
    for name, part in (("grid", grid), ("with", fixed)):
        if not isinstance(part, dict):
            raise ConfigError(f"{at}.{name}: expected a mapping of parameter names to values")
    for name, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{at}.grid.{name}: expected a non-empty list of values")
        if name in fixed:
            raise ConfigError(f"{at}.grid.{name}: also under with (give a factor in one place)")
    cpus, custom = _resources(kind, block.get("resources"), f"{at}.resources")
    runs = []
    for combo in itertools.product(*grid.values()) if grid else [()]:
        named = dict(zip(grid, combo))
        given = {**fixed, **named}
        where = {k: f"{at}.with.{k}" for k in fixed} | {k: f"{at}.grid.{k}" for k in named}
        if "seed" not in given:
            given["seed"], where["seed"] = default_seed, f"{doc_where} seed"
        params = _params(kind, given, where)
        factors = {k: params[k] for k in given}
        runs.append(Run(make_run_id(kind, named, params), kind, params, factors, cpus, custom))
    return runs


def parse_campaign(doc: Any, source: str) -> Campaign:
    """A campaign from its parsed YAML `doc`; `source` names the file in errors."""
    where = f"{source}:"
    if not isinstance(doc, dict):
        raise ConfigError(f"{where} a campaign must be a mapping with runs")
    for key in doc:
        if key not in ("name", "seed", "runs"):
            raise ConfigError(f"{where} {key}: unknown key (known: name, runs, seed)")
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"{where} seed: expected an integer, got {seed!r}")
    blocks = doc.get("runs")
    if not isinstance(blocks, list) or not blocks:
        raise ConfigError(f"{where} runs: expected a non-empty list of run blocks")
    runs: list[Run] = []
    seen: dict[str, int] = {}
    for i, block in enumerate(blocks):
        for run in _block(where, i, block, seed):
            if run.run_id in seen:
                raise ConfigError(f"{where} runs[{i}]: a run with the same parameters as one of runs[{seen[run.run_id]}] "
                                  f"({run.run_id})")
            seen[run.run_id] = i
            runs.append(run)
    return Campaign(str(doc.get("name") or Path(source).stem), source, tuple(runs))


def read_yaml(path: Path) -> Any:
    """A YAML file's document; ConfigError naming the file when it cannot be read or is not YAML."""
    try:
        return yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign file; ConfigError naming the file (and the key) when it is not one."""
    return parse_campaign(read_yaml(Path(path)), str(path))
