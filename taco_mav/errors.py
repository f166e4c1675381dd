"""One error hierarchy for everything a user can get wrong; the CLI maps it to exit codes.

Exit codes (every `taco-mav` command): 2 for usage and configuration errors (a bad argument, a missing input
path, an unwritable output, an invalid profile), 1 for data and runtime errors (a malformed input file, a
failure while working), 130 on Ctrl-C."""

from __future__ import annotations


class TacoError(Exception):
    """Base of every error taco_mav raises on bad input; the message names file, key, field or message.
    A plain TacoError is a runtime error (exit code 1)."""

    exit_code: int = 1


class UsageError(TacoError):
    """A command-line argument is wrong: malformed, out of range, not in its allowed set, a missing input path
    or an output that cannot be written (the message names the option and the value)."""

    exit_code = 2


class ConfigError(TacoError):
    """A vehicle profile or option is invalid (unknown key, wrong type, out of range, missing file)."""

    exit_code = 2


class DataError(TacoError):
    """A dataset file is malformed or incomplete (names the file and, where known, the line): a data error,
    exit code 1. A path the command line names that does not exist is a UsageError, checked before work."""

    exit_code = 1


class MapError(TacoError):
    """A satellite map cannot serve a request (unreadable GeoTIFF, unsupported CRS): exit code 1."""

    exit_code = 1


class OffMapError(MapError):
    """A crop lies wholly or partly outside the satellite mosaic."""

    def __init__(self, message: str, valid_fraction: float = 0.0) -> None:
        super().__init__(message)
        self.valid_fraction = valid_fraction


class MapSourceError(MapError):
    """A map service (XYZ tiles, WMTS, WMS) cannot be read: unreachable, refusing (HTTP 401/403), failing, or with
    no imagery in the area; `url` names the tile or the service, `status` the HTTP status (0: no answer, None:
    unknown). Exit code 1."""

    def __init__(self, message: str, url: str = "", status: int | None = None) -> None:
        super().__init__(message)
        self.url = url
        self.status = status


class MatcherError(TacoError):
    """A matcher cannot run (missing checkpoint, missing images, wrong input shape)."""

    exit_code = 2
