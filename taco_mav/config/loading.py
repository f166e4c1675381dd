"""Loading and validating profiles: YAML -> frozen dataclasses, by path or by the name of a shipped profile.

Unknown keys, wrong types and out-of-range values raise `ConfigError` naming the file and the dotted key.
Shipped profiles live at the repository top (`vehicle_profiles/*.yaml`) and are package data through the link
`taco_mav/vehicle_profiles`, read through `importlib.resources`, so a name such as "ardupilot_rover" resolves
from any folder and in any install (editable, wheel, sdist).
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
import types
import typing
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from taco_mav.config.profile import MATCHERS, Profile
from taco_mav.errors import ConfigError, UsageError

log = logging.getLogger(__name__)

__all__ = ["LOCAL_PROFILE_DIR", "PROFILE_DIR", "load_profile", "profile_from_dict", "resolve_profile_path",
           "shipped_profiles"]

# A folder of the user's own profiles, looked up (relative to the working directory) before the shipped ones.
LOCAL_PROFILE_DIR = Path("vehicle_profiles")


def _shipped_dir() -> Path:
    """The folder of the profiles shipped with the package. setuptools installs packages unzipped, so the
    resource is a plain folder; a zipped install is refused with a message rather than half-working."""
    folder = resources.files("taco_mav").joinpath("vehicle_profiles")
    if not isinstance(folder, Path):  # pragma: no cover - only a zipimport install gets here
        raise ConfigError(f"{folder}: shipped profiles are not a folder on disk (install taco_mav unzipped)")
    return folder


PROFILE_DIR: Path = _shipped_dir()


def shipped_profiles() -> list[str]:
    """Names of the profiles shipped with the package, sorted (e.g. "ardupilot_rover", "synthetic")."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Check and convert one YAML value against a type annotation; `where` names file and key."""
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return _build(tp, value, where)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], where)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(value)
        except ValueError:
            allowed = ", ".join(repr(m.value) for m in tp)
            raise ConfigError(f"{where}: {value!r} is not one of {allowed}") from None
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:  # tuple[X, ...]: any length
            return tuple(_convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):  # tuple[X, Y, Z]: exactly that many
            raise ConfigError(f"{where}: expected a list of {len(args)} values, got {len(value)}")
        return tuple(_convert(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, (str, int)) or isinstance(value, bool):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return str(value)
    raise ConfigError(f"{where}: unsupported type {tp!r}")  # pragma: no cover - a bug in this module


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    """One dataclass from a mapping: unknown keys, wrong types and out-of-range numbers are ConfigErrors."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        key_where = f"{where}.{key}" if not where.endswith(":") else f"{where} {key}"
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"{key_where}: unknown key (known: {known})")
        converted = _convert(value, hints[key], key_where)
        lo, hi, open_lo = fields[key].metadata.get("range", (None, None, False))
        items = enumerate(converted) if isinstance(converted, tuple) else [(None, converted)]
        for i, number in items:  # a range applies to a number, or to each number of a tuple
            if isinstance(number, (int, float)) and not isinstance(number, bool):
                at = key_where if i is None else f"{key_where}[{i}]"
                if lo is not None and (number < lo or (open_lo and number == lo)):
                    raise ConfigError(f"{at}: {number} is out of range (must be {'>' if open_lo else '>='} {lo})")
                if hi is not None and number > hi:
                    raise ConfigError(f"{at}: {number} is out of range (must be <= {hi})")
        kwargs[key] = converted
    return cls(**kwargs)


def profile_from_dict(data: dict[str, Any], source: str = "<dict>", base_dir: Path | None = None) -> Profile:
    """Build a Profile from a nested mapping; `source` names the file in error messages; base_dir: the folder
    relative paths in it are taken from (the profile's; default the working directory)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a profile must be a mapping at the top level")
    profile = _build(Profile, data, f"{source}:")
    if profile.matcher not in MATCHERS:
        raise ConfigError(f"{source}: matcher: {profile.matcher!r} is not one of {', '.join(MATCHERS)}")
    if profile.camera.calibration:
        from taco_mav.camera.calibration import resolve_calibration

        camera = resolve_calibration(profile.camera, data.get("camera") or {}, base_dir, f"{source}:")
        profile = dataclasses.replace(profile, camera=camera)
    return profile


def resolve_profile_path(name_or_path: str | Path) -> Path:
    """A path as given (anything ending in .yaml/.yml or naming an existing file), or a bare name looked up in
    ./vehicle_profiles (the user's own) and then among the shipped profiles."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ConfigError(f"{path}: profile file not found")
        return path
    for folder in (LOCAL_PROFILE_DIR, PROFILE_DIR):
        candidate = folder / f"{name_or_path}.yaml"
        if candidate.is_file():
            log.debug("profile %s: %s", name_or_path, candidate)
            return candidate
    raise ConfigError(f"{name_or_path}: no such profile (shipped: {', '.join(shipped_profiles())}; "
                      f"or give a path to a .yaml file)")


def load_profile(name_or_path: str | Path) -> Profile:
    """Load a vehicle profile by path or by name; errors name the file and the key. Relative paths inside a
    profile (camera.calibration) are taken from the profile's own folder."""
    path = resolve_profile_path(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}: not valid YAML ({where}{problem})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    return profile_from_dict(data, str(path), base_dir=path.resolve().parent)


def parse_overrides(items: typing.Iterable[str], option: str = "--set") -> dict[str, Any]:
    """Profile overrides given as KEY=VALUE text (a tool's repeatable `option`): {dotted key: value}, each value
    parsed as YAML as a profile's are (0.05, true, [1, 2]); apply them with `replace_in`. UsageError names an item
    without '=' or without a key."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} {item!r}: expected key=value, e.g. plus.q_speed_mps=0.05")
        out[key.strip()] = yaml.safe_load(value)
    return out
