"""Bad configuration through the real command line: `taco-mav run` and `taco-mav eval` as subprocesses with each
kind of invalid profile (and a bad --signing-key file) exit with code 2 and one stderr line that names the file
and the dotted key."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from mav_autopilot import free_udp_port

from taco_mav.config import PROFILE_DIR

PROFILES = {  # case -> (YAML text or None for a missing file, what the error line must contain besides the file)
    "unknown_key": ("link:\n  bogus: 1\n", ["link.bogus", "unknown key"]),
    "wrong_type": ("gate:\n  enabled: 3\n", ["gate.enabled", "expected true/false"]),
    "out_of_range": ("output:\n  rate_hz: 500\n", ["output.rate_hz", "out of range"]),
    "missing_file": (None, ["not found"]),
    "yaml_syntax": ("link: [1, 2\n  x: :\n", ["not valid YAML", "line"]),
}


@dataclass
class Result:
    rc: int
    stderr: str
    stdout: str


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], tuple[Result, Path]]:
    """Every (command, case) run at once as subprocesses; their exit codes and output."""
    root = tmp_path_factory.mktemp("faults")
    procs = {}
    for case, (text, _) in PROFILES.items():
        path = root / f"{case}.yaml"
        if text is not None:
            path.write_text(text)
        for cmd in ("run", "eval"):
            extra = (["--connect", f"udpin:127.0.0.1:{free_udp_port()}"] if cmd == "run"
                     else ["--out", str(root / f"out_{case}"), "--drive", str(root / "no_drive")])
            procs[(cmd, case)] = (_start([cmd, "--profile", str(path), *extra]), path)
    for name, content in (("short.key", b"abc"),):  # the other key faults: test_signing.py, in-process
        key = root / name
        key.write_bytes(content)
        good = PROFILE_DIR / "ardupilot_rover.yaml"
        procs[("run", name)] = (_start(["run", "--profile", str(good), "--connect",
                                        f"udpin:127.0.0.1:{free_udp_port()}", "--signing-key", str(key)]), key)
    out = {}
    for k, (proc, path) in procs.items():
        try:
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
        out[k] = (Result(proc.returncode, stderr.decode(), stdout.decode()), path)
    return out


def _start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "taco_mav.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def _check(res: Result, path: Path, cmd: str, needles: list[str]) -> None:
    lines = res.stderr.strip().splitlines()
    assert res.rc == 2, res.stderr
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith(f"taco-mav {cmd}: error: ") and str(path) in lines[0], lines[0]
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.mark.parametrize("cmd", ["run", "eval"])
@pytest.mark.parametrize("case", list(PROFILES))
def test_invalid_profile(results, cmd: str, case: str) -> None:
    res, path = results[(cmd, case)]
    _check(res, path, cmd, PROFILES[case][1])


@pytest.mark.parametrize("name, needle", [("short.key", "got 3 bytes")])
def test_bad_signing_key(results, name: str, needle: str) -> None:
    res, path = results[("run", name)]
    _check(res, path, "run", ["--signing-key", needle])
