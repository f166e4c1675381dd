"""One error hierarchy for everything a user can get wrong; the CLI maps it to exit codes."""

from __future__ import annotations


class TacoError(Exception):
    """Base of every error taco_mav raises on bad input; the message names file, key, field or message."""

    exit_code: int = 1


class ConfigError(TacoError):
    """A vehicle profile or option is invalid (unknown key, wrong type, out of range, missing file)."""

    exit_code = 2


class DataError(TacoError):
    """A dataset file is missing or malformed (names the file and, where known, the line)."""

    exit_code = 2


class MapError(TacoError):
    """A satellite map cannot serve a request (missing GeoTIFF, unsupported CRS)."""

    exit_code = 2


class OffMapError(MapError):
    """A crop lies wholly or partly outside the satellite mosaic."""

    def __init__(self, message: str, valid_fraction: float = 0.0) -> None:
        super().__init__(message)
        self.valid_fraction = valid_fraction


class MatcherError(TacoError):
    """A matcher cannot run (missing checkpoint, missing images, wrong input shape)."""

    exit_code = 2
