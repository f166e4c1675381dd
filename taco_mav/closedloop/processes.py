"""The processes a closed-loop mission starts and stops: the daemon, started exactly as a user starts it
(`taco-mav run`, a subprocess in its own process group, its console in a log file), and the end of a process
group (the daemon, the autopilot) with the signal each wants first."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Sequence


def daemon_command(profile: str, connect: str, camera: str, log_dir: Path, estimator: str,
                   more: Sequence[str] = ()) -> list[str]:
    """`taco-mav run` (this interpreter's taco_mav) with the profile, the link to the autopilot, the camera, the
    log folder, the estimator and `more` options."""
    return [sys.executable, "-m", "taco_mav.cli", "run", "--profile", profile, "--connect", connect, "--camera",
            camera, "--log-dir", str(log_dir), "--estimator", estimator, *more]


def start(cmd: Sequence[str], log: Path) -> subprocess.Popen:
    """`cmd` in a process group of its own (`stop_group` ends it and its children), stdout and stderr to `log`."""
    with open(log, "w") as console:
        return subprocess.Popen(list(cmd), stdout=console, stderr=subprocess.STDOUT, start_new_session=True)


def stop_group(proc: subprocess.Popen | None, first: int, wait_s: float = 15.0) -> None:
    """End a process started with start_new_session=True and everything in its group: `first` (SIGINT for the
    daemon, which then closes its logs; SIGTERM for an autopilot), SIGKILL after wait_s."""
    if proc is not None and proc.poll() is None:
        os.killpg(proc.pid, first)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def log_tail(path: Path, lines: int = 25) -> list[str]:
    """The last `lines` lines of a log file ([] when it is missing): for a result that explains a failed start."""
    try:
        return path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return []
