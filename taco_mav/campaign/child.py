"""The process a run lives in, and the Ray task that starts it.

`run_in_child` (the body of every campaign task, in a Ray worker) counts the attempt, clears what an earlier
attempt left in the run's work folder, and starts `python -m taco_mav.campaign.child RUN.json`, which runs the
run (`execute.execute_run`) and writes result.json. The child dies with the worker that started it (the kernel's
parent-death signal), so a worker killed mid-run leaves no autopilot or daemon behind and Ray's retry starts
from a clean folder.

A run of an isolated kind (SITL missions) starts in namespaces of its own (`unshare`, unprivileged): a network
namespace (its own loopback: two missions at a time never compete for SITL's fixed ports, whatever instance
number each harness picks), a PID namespace (everything it started ends with it) and a mount namespace with
its own /tmp (PX4's lock and socket files; the run's work folder stays at its path). Where the kernel refuses
unprivileged namespaces, the run starts without them and says so in its figures (`isolated: false`).
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from taco_mav.errors import TacoError

log = logging.getLogger(__name__)

__all__ = ["RunFailed", "namespaces_available", "run_in_child"]

ATTEMPTS = "attempts"
UNSHARE = ("unshare", "--user", "--map-root-user", "--net", "--mount", "--pid", "--fork", "--kill-child")
PR_SET_PDEATHSIG = 1


class RunFailed(TacoError):
    """A run's process ended without figures: its last log lines say why."""


def namespaces_available() -> bool:
    """Whether this machine lets an unprivileged process make its own user, network, mount and PID namespaces."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    try:
        return subprocess.run([*UNSHARE, "true"], capture_output=True, timeout=20, check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _die_with_parent() -> None:  # pragma: no cover - runs in the forked child
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _attempt(work: Path) -> int:
    """Count this attempt in work/attempts and clear everything else an earlier attempt left there."""
    work.mkdir(parents=True, exist_ok=True)
    counter = work / ATTEMPTS
    n = int(counter.read_text()) + 1 if counter.is_file() else 1
    for entry in work.iterdir():
        if entry.name != ATTEMPTS:
            shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
    counter.write_text(str(n))
    return n


def run_in_child(run: dict[str, Any], work_dir: str, context: dict[str, Any]) -> dict[str, Any]:
    """Run `run` (a `spec.Run` as a dict) in a child process in `work_dir`; returns {"figures", "attempts",
    "wall_s", "node", "isolated"}. RunFailed when the child ends without figures."""
    from taco_mav.campaign.kinds import KINDS

    work = Path(work_dir)
    attempts = _attempt(work)
    isolated = KINDS[run["kind"]].isolated and bool(context.get("namespaces"))
    (work / "run.json").write_text(json.dumps({"run": run, "context": context, "isolated": isolated}, indent=1))
    cmd = [sys.executable, "-m", "taco_mav.campaign.child", str(work / "run.json")]
    if isolated:
        cmd = [*UNSHARE, *cmd]
    start = time.monotonic()
    with open(work / "child.log", "w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                preexec_fn=_die_with_parent)
        try:
            rc = proc.wait()
        except BaseException:  # the task cancelled (Ctrl-C of the campaign): its run goes with it
            proc.kill()
            proc.wait()
            raise
    result = work / "result.json"
    if rc != 0 or not result.is_file():
        tail = (work / "child.log").read_text(errors="replace").splitlines()[-15:]
        raise RunFailed(f"run {run['run_id']} ended with exit code {rc} (log {work / 'child.log'}):\n" + "\n".join(tail))
    return {"figures": json.loads(result.read_text()), "attempts": attempts, "wall_s": time.monotonic() - start,
            "node": socket.gethostname(), "isolated": isolated}


def _own_tmp(work: Path) -> None:
    """A fresh /tmp for this mount namespace, with the work folder (and the package, when they live under /tmp)
    still at their paths: bound back in from file descriptors opened before."""
    keep = [p for p in (work, Path(__file__).resolve().parents[2], Path(sys.prefix)) if p.is_relative_to("/tmp")]
    fds = [(p, os.open(p, os.O_RDONLY | os.O_DIRECTORY)) for p in keep]
    subprocess.run(["mount", "-t", "tmpfs", "tmpfs", "/tmp"], check=True)
    for path, fd in fds:
        path.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", "--no-canonicalize", "--bind", f"/proc/self/fd/{fd}", str(path)], check=True,
                       pass_fds=(fd,))
        os.close(fd)


def main(argv: list[str] | None = None) -> int:
    """`python -m taco_mav.campaign.child RUN.json`: run it, write result.json beside it; exit 1 on an error."""
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0])
    doc = json.loads(path.read_text())
    run, work = doc["run"], path.parent
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if doc["isolated"]:
        subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
        _own_tmp(work)
    from taco_mav.campaign.execute import execute_run

    try:
        figures = execute_run(run["kind"], run["params"], work / "run", doc["context"])
    except TacoError as exc:
        log.error("%s", exc)
        return 1
    figures["isolated"] = doc["isolated"]
    tmp = work / "result.json.part"
    tmp.write_text(json.dumps(figures, indent=1, default=str))
    tmp.replace(work / "result.json")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
