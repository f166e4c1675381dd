"""Packaging: a wheel built from this tree works from another folder without the source tree.

`pip wheel . --no-deps` builds the wheel, `pip install --no-deps --target SITE` installs it, and a fresh
interpreter with PYTHONPATH=SITE, run from an empty folder, checks that it imported the installed copy (not this
checkout, which the development venv may also map), that every shipped vehicle profile loads by name (package
data found through importlib.resources), and that a short live run (synthetic world -> simulated ArduPilot
rover -> daemon with profile `synthetic`, loopback UDP, lockstep) tracks the truth within 2 m ATE. The sdist
is checked to carry the profiles too, so a wheel built from it has them.

Build isolation is off (the venv's setuptools and wheel build it, which the `dev` extra brings), so the test needs
no network. The README's set-up is what CI installs, command for command, and brings everything the tests need.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHIPPED = ("ardupilot_rover", "ardupilot_rover_gps2", "kitti", "px4_rover", "px4_rover_gps2", "synthetic",
           "synthetic_3d", "synthetic_rover", "ardupilot_rover_wheels", "ardupilot_rover_gps2_wheels")
PX4_PARAMS = ("px4_rover_solo", "px4_rover_handover")
AP_PARMS = ("ardupilot_rover_wheels",)

pytestmark = pytest.mark.slow


def _installs(lines: list[str]) -> list[list[str]]:
    """The install commands among shell lines (comments and pip's --quiet/-q dropped), each split at `&&`."""
    out = []
    for line in lines:
        for cmd in line.split("#")[0].split("&&"):
            words = [w for w in shlex.split(cmd) if w not in ("--quiet", "-q")]
            if words[:2] == ["pip", "install"] or (words[:1] == ["python"] and "taco_mav" in " ".join(words)):
                out.append(words)
    return out


def test_dev_extra_brings_what_the_tests_build_with() -> None:
    """The wheel below is built without build isolation, with the venv's own setuptools and wheel: the dev extra
    brings both, at the versions [build-system] asks for (a fresh venv has neither wheel nor setuptools >= 68)."""
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    dev = meta["project"]["optional-dependencies"]["dev"]
    for need in meta["build-system"]["requires"]:  # setuptools>=68, wheel
        assert need in dev, (need, dev)
    assert "setuptools>=68" in dev and "wheel" in dev and any(d.startswith("pytest") for d in dev)


def test_ci_installs_what_the_readme_says_and_nothing_else() -> None:
    """.ci/run's install commands are the README's set-up commands, in order: a test that needs more than the
    README installs fails in CI too."""
    readme = (REPO / "README.md").read_text()
    block = re.search(r"## Set up[^\n]*\n+```bash\n(.*?)```", readme, re.S)
    assert block, "README.md: no bash block under '## Set up'"
    readme_cmds = _installs(block.group(1).splitlines())
    ci_cmds = _installs((REPO / ".ci" / "run").read_text().splitlines())
    assert readme_cmds == ci_cmds, (readme_cmds, ci_cmds)
    assert ["pip", "install", "-e", ".[dev]"] in readme_cmds and ["pip", "install", "-e", ".[fg2]"] in readme_cmds
    assert ["python", "-m", "taco_mav.core.ukf_aot"] in readme_cmds


def _pip(*args: str, cwd: Path) -> None:
    """Run pip in this interpreter quietly; the failure message carries pip's output."""
    cmd = [sys.executable, "-m", "pip", "--disable-pip-version-check", *args]
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"


def _installed_python(site: Path, code: str, cwd: Path, *args: str, timeout: float = 240.0
                      ) -> subprocess.CompletedProcess:
    """`python -c code args` seeing only the installed copy of taco_mav (PYTHONPATH=site, run from `cwd`)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSTARTUP")}
    env.update(PYTHONPATH=str(site), PYTHONNOUSERSITE="1", MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the source tree (what a clone holds), so building writes no build/ or egg-info here."""
    src = tmp_path_factory.mktemp("src") / "taco_mav_src"
    skip = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache",
                                  "taco_demo", "out", "runs")
    shutil.copytree(REPO, src, ignore=skip)
    return src


@pytest.fixture(scope="module")
def wheel(source: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel built from this tree."""
    dist = tmp_path_factory.mktemp("dist")
    _pip("wheel", ".", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist), cwd=source)
    (whl,) = dist.glob("taco_mav-*.whl")
    return whl


@pytest.fixture(scope="module")
def site(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel installed (no dependencies: the venv's are used) into a folder of its own."""
    target = tmp_path_factory.mktemp("site")
    _pip("install", "--no-deps", "-q", "--target", str(target), str(wheel), cwd=target)
    return target


def test_wheel_ships_profiles_and_no_test_tooling(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    for name in SHIPPED:
        assert f"taco_mav/vehicle_profiles/{name}.yaml" in names
    for name in PX4_PARAMS:  # the PX4 parameter files a user loads in QGroundControl, beside the profiles
        assert f"taco_mav/vehicle_profiles/{name}.params" in names
    for name in AP_PARMS:  # the ArduPilot parameter files a user loads in a ground station
        assert f"taco_mav/vehicle_profiles/{name}.parm" in names
    assert not [n for n in names if n.startswith(("tests/", "tools/")) or "/fuzz" in n], "test tooling in the wheel"
    # the closed-loop harness (`taco-mav mission`) and the appearance-gap maker are package modules, tools/ their
    # command lines
    assert "taco_mav/closedloop/ardupilot.py" in names and "taco_mav/datasets/synthetic/gap.py" in names


def test_installed_wheel_loads_profiles_by_name_from_another_folder(site: Path, tmp_path: Path) -> None:
    code = f"""
import json, taco_mav
from taco_mav.config import PROFILE_DIR, load_profile, shipped_profiles
p = load_profile("ardupilot_rover")
print(json.dumps({{"file": taco_mav.__file__, "dir": str(PROFILE_DIR), "shipped": shipped_profiles(),
                  "name": p.name, "estimator": p.estimator.value,
                  "all": [load_profile(n).name for n in {list(SHIPPED)!r}]}}))
"""
    proc = _installed_python(site, code, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert Path(got["file"]).resolve().is_relative_to(site.resolve()), got["file"]  # not the checkout
    assert Path(got["dir"]).resolve().is_relative_to(site.resolve())
    assert set(SHIPPED) <= set(got["shipped"])
    assert got["name"] == "ardupilot_rover" and got["estimator"] == "taco+"
    # a user's own YAML path still works beside the shipped names
    (tmp_path / "mine.yaml").write_text("name: mine\nmatcher: emulator\n")
    proc = _installed_python(site, "from taco_mav.config import load_profile; print(load_profile('mine.yaml').name)",
                             tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == "mine", proc.stderr[-3000:]
    proc = _installed_python(site, "from taco_mav.config import load_profile; load_profile('no_such_vehicle')",
                             tmp_path)
    assert proc.returncode != 0 and "no such profile" in proc.stderr and "ardupilot_rover" in proc.stderr


LIVE = """
import json, logging, socket, sys
from pathlib import Path

import taco_mav
from taco_mav.config import load_profile
from taco_mav.datasets.synthetic import build_world
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.sim import Simulator

logging.basicConfig(level=logging.WARNING)  # stderr: shown when the run fails
assert Path(taco_mav.__file__).resolve().is_relative_to(Path(sys.argv[1]).resolve()), taco_mav.__file__
world = build_world(Path("world"), seed=3, length_km=0.3, progress=False)
with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True, duration_s=30.0, wait_companion_s=120.0,
                drain_s=0.3)
daemon = Daemon(load_profile("synthetic"), DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}"),
                clock=sim.clock, wall_clock=sim.utc_now)
daemon.start()
try:
    sim.start()
    assert sim.join(timeout=300.0), "simulator did not finish"
finally:
    daemon.stop()
    daemon.join(10.0)
seq = sim.results()["sequences"][sim.drive.name]
print(json.dumps({"ate_m": seq["ate_m"], "length_km": seq["length_km"], "gps_input_count": seq["gps_input_count"],
                  "fixes": daemon.summary()["fixes"]}))
"""


def test_installed_wheel_runs_a_short_live_demo(site: Path, tmp_path: Path) -> None:
    """World, simulator and daemon from the installed copy only, profile `synthetic` by name: ATE <= 2 m. The
    simulator waits up to 120 s for the daemon's first heartbeat: a fresh install compiles its kernels first."""
    proc = _installed_python(site, LIVE, tmp_path, str(site), timeout=480.0)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["length_km"] > 0.1 and got["gps_input_count"] > 50, (got, proc.stderr[-3000:])
    assert got["ate_m"] <= 2.0, got
    assert got["fixes"].get("accepted", 0) >= 3, got


def test_sdist_ships_profiles(source: Path, tmp_path: Path) -> None:
    """The sdist (what `pip install taco_mav-*.tar.gz` builds from) carries the profiles as package data."""
    proc = subprocess.run([sys.executable, "-c", "from setuptools import build_meta as b; import sys; "
                           "print(b.build_sdist(sys.argv[1]))", str(tmp_path)], cwd=source, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    sdist = tmp_path / proc.stdout.strip().splitlines()[-1]
    names = tarfile.open(sdist).getnames()
    for name in SHIPPED:
        assert any(n.endswith(f"/taco_mav/vehicle_profiles/{name}.yaml") for n in names), name
    for name in PX4_PARAMS:
        assert any(n.endswith(f"/taco_mav/vehicle_profiles/{name}.params") for n in names), name
    for name in AP_PARMS:
        assert any(n.endswith(f"/taco_mav/vehicle_profiles/{name}.parm") for n in names), name


def test_own_profiles_folder_is_looked_up_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bare name is looked for in ./vehicle_profiles (the user's own) before the shipped profiles."""
    from taco_mav.config import PROFILE_DIR, load_profile, resolve_profile_path

    monkeypatch.chdir(tmp_path)
    assert resolve_profile_path("ardupilot_rover") == PROFILE_DIR / "ardupilot_rover.yaml"
    (tmp_path / "vehicle_profiles").mkdir()
    (tmp_path / "vehicle_profiles" / "ardupilot_rover.yaml").write_text("name: my_rover\n")
    (tmp_path / "vehicle_profiles" / "other.yaml").write_text("name: other\n")
    assert load_profile("ardupilot_rover").name == "my_rover"
    assert load_profile("other").name == "other"
