"""Dotted profile keys (`ukf.sigma_fwd_k`, `gate.yaw_residual_max_rad`): checked against the profile's sections
before any run starts, and applied to a loaded profile with the loader's own validation (types and ranges)."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from taco_mav.config import Profile, profile_from_dict, profile_to_dict, replace_in
from taco_mav.errors import ConfigError

__all__ = ["apply_overrides", "key_type"]


def key_type(dotted: str, where: str) -> Any:
    """The type annotation of a profile field named by a dotted key (e.g. `float` for `ukf.sigma_fwd_k`);
    ConfigError naming `where` and the key when a part of it is not a field, or the key ends at a section."""
    cls: Any = Profile
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        fields = {f.name for f in dataclasses.fields(cls)}
        if part not in fields:
            head = ".".join(parts[:i]) or "the profile"
            raise ConfigError(f"{where}: {dotted}: {part!r} is not a key of {head} (known: {', '.join(sorted(fields))})")
        cls = typing.get_type_hints(cls)[part]
        if i < len(parts) - 1 and not dataclasses.is_dataclass(cls):
            raise ConfigError(f"{where}: {dotted}: {'.'.join(parts[:i + 1])} is a value, not a section")
    if dataclasses.is_dataclass(cls):
        raise ConfigError(f"{where}: {dotted}: a section, not a value (name one of its keys, e.g. "
                          f"{dotted}.{dataclasses.fields(cls)[0].name})")
    return cls


def apply_overrides(profile: Profile, overrides: dict[str, Any], where: str) -> Profile:
    """`profile` with each dotted key set to its value, validated as a profile file is (type, range); errors
    name `where` and the key."""
    for key, value in overrides.items():
        key_type(key, where)
        profile = replace_in(profile, key, value)
    return profile_from_dict(profile_to_dict(profile), where)
