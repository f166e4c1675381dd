"""What every `taco-mav` command shares: the argument parser that reports a usage error in one line, the global
flags (-q/-v/--debug, before or after the subcommand), logging through the progress bars, and the error
contract (one line `taco-mav CMD: error: ...`; exit 2 usage/configuration, 1 data/runtime, 130 Ctrl-C; a
traceback only with --debug)."""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import traceback
from typing import Any, Callable, NoReturn, Sequence

from taco_mav.errors import TacoError
from taco_mav.progress import TqdmHandler

__all__ = ["EXIT_DATA", "EXIT_INTERRUPTED", "EXIT_USAGE", "TacoArgumentParser", "add_global_flags",
           "configure_logging", "package_version", "run_command"]

EXIT_DATA = 1  # a data or runtime error
EXIT_USAGE = 2  # a usage or configuration error (argparse's own code)
EXIT_INTERRUPTED = 130  # Ctrl-C, as a shell reports SIGINT
MAX_MESSAGE = 600  # characters of one error line
_NUMBER = re.compile(r"^-\.?\d")  # a negative number (list) as a value, not an option


def package_version() -> str:
    """The installed distribution's version (importlib.metadata), else the package's own."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("taco_mav")
    except PackageNotFoundError:
        from taco_mav import __version__

        return __version__


class TacoArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line `PROG: error: MESSAGE` plus a hint, exit code 2
    (argparse prints the whole usage block, which for `eval` or `sim` is a dozen lines)."""

    argv: Sequence[str] = ()  # the arguments being parsed (set by parse_args), to name an unknown option
    global_options: frozenset[str] = frozenset()  # options of the main parser, valid in any position

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: Any = None) -> argparse.Namespace:
        TacoArgumentParser.argv = tuple(sys.argv[1:] if args is None else args)
        TacoArgumentParser.global_options = frozenset(self._option_string_actions)
        return super().parse_args(args, namespace)

    def _prog_for_error(self) -> str:
        """`taco-mav CMD` for an error the main parser reports about a subcommand's arguments."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                for tok in self.argv:
                    if tok in action.choices:
                        return action.choices[tok].prog
        return self.prog

    def _unknown_option(self) -> str | None:
        """The first option in argv neither this parser nor the main parser knows (argparse reports a missing
        required option before an unknown one, which hides a typo such as --ouput)."""
        known = set(self._option_string_actions) | self.global_options
        for tok in self.argv:
            if tok.startswith("-") and tok != "--" and not _NUMBER.match(tok) and tok.split("=", 1)[0] not in known:
                return tok.split("=", 1)[0]
        return None

    def error(self, message: str) -> NoReturn:
        if message.startswith("the following arguments are required"):
            unknown = self._unknown_option()
            if unknown is not None:
                message = f"unrecognized arguments: {unknown}"
        prog = self._prog_for_error()
        sys.stderr.write(f"{prog}: error: {message}\n(see {prog} --help)\n")
        sys.exit(EXIT_USAGE)


def add_global_flags(parser: argparse.ArgumentParser, subcommand: bool) -> None:
    """-q/-v/--debug on the main parser (defaults) and on each subcommand (SUPPRESS: a flag given before the
    subcommand is not reset by the subcommand's default)."""
    keep = argparse.SUPPRESS
    parser.add_argument("-q", "--quiet", action="store_true", default=keep if subcommand else False,
                        help="warnings and errors only (the demo: errors), no progress bars")
    parser.add_argument("-v", "--verbose", action="count", default=keep if subcommand else 0,
                        help="more log output: -v debug (the demo, quiet by default: -v info, -vv debug)")
    parser.add_argument("--debug", action="store_true", default=keep if subcommand else False,
                        help="debug logging and a traceback with any error")


class _Shown(logging.Filter):
    """Which records the console shows besides the level: taco_mav's at the handler's level; other libraries'
    (rasterio, numba, ...) warnings and errors only, and Python warnings only with -v, unless --debug."""

    def __init__(self, verbose: int, debug: bool) -> None:
        super().__init__()
        self.verbose, self.debug = verbose, debug

    def filter(self, record: logging.LogRecord) -> bool:
        if self.debug or record.name == "taco_mav" or record.name.startswith("taco_mav."):
            return True
        if record.name == "py.warnings":
            return self.verbose > 0
        return record.levelno >= logging.WARNING


def configure_logging(quiet: bool, verbose: int, debug: bool, quiet_by_default: bool = False) -> TqdmHandler:
    """The one place handlers are set: records go through tqdm.write (above the progress bars) on stderr.
    Levels: -q WARNING; default INFO; -v DEBUG; --debug DEBUG. Where quiet_by_default (the demo, whose summary
    is its output): errors only by default and with -q, -v INFO, -vv DEBUG. Returns the handler (an earlier one
    of ours is replaced; other handlers are left alone)."""
    if quiet_by_default:
        steps, quiet_level = [logging.ERROR, logging.INFO, logging.DEBUG], logging.ERROR
    else:
        steps, quiet_level = [logging.INFO, logging.DEBUG], logging.WARNING
    level = logging.DEBUG if debug else quiet_level if quiet else steps[min(verbose, len(steps) - 1)]
    handler = TqdmHandler(level)
    handler.addFilter(_Shown(verbose, debug))
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
    root = logging.getLogger()
    for old in [h for h in root.handlers if isinstance(h, TqdmHandler)]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level)
    logging.captureWarnings(True)  # warnings.warn from libraries goes through the same handler (shown with -v)
    if not (debug or verbose):  # OpenCV prints its own warnings to stderr (e.g. a camera index it cannot open)
        os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    return handler


def _one_line(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


def _describe(exc: BaseException) -> tuple[str, int]:
    """The error line's text and the exit code for an exception escaping a command."""
    if isinstance(exc, TacoError):
        return str(exc), exc.exit_code
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        return f"{where}{exc.strerror or exc}", EXIT_DATA
    if isinstance(exc, MemoryError):
        return "out of memory", EXIT_DATA
    return f"internal error ({type(exc).__name__}: {exc}); run with --debug for the traceback", EXIT_DATA


def run_command(command: str, func: Callable[[], int], debug: bool) -> int:
    """Run one command's function under the error contract; returns the exit code."""
    try:
        return int(func() or 0)
    except KeyboardInterrupt:
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"taco-mav {command}: interrupted\n")
        return EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - the contract: one line, an exit code, a traceback only with --debug
        text, code = _describe(exc)
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"taco-mav {command}: error: {_one_line(text)}\n")
        return code
