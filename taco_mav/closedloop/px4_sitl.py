"""PX4 SITL (SIH, PX4's built-in simulator: no Gazebo) as a closed-loop mission runs it: a free instance, a private
command folder and a fresh rootfs (`prepare_px4`), the process started with its parameters (`start_px4`), the
ground station on its UDP link (`Px4Gcs`), its flight modes (`set_mode`, `modes`) and its STATUSTEXTs joined from
their chunks (`statustexts`)."""

from __future__ import annotations

import fcntl
import os
import shutil
import socket
import subprocess
import time
from pathlib import Path
from typing import Any

from taco_mav.closedloop.gcs import Gcs, M, mavutil

# PX4 custom modes (px4_custom_mode.h): main mode AUTO 4; its sub modes LOITER 3 (a rover holds), MISSION 4.
# MAV_CMD_DO_SET_MODE param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, param2 = main, param3 = sub.
PX4_MAIN_AUTO, PX4_AUTO_LOITER, PX4_AUTO_MISSION = 4, 3, 4
MODE_MISSION = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN_AUTO, PX4_AUTO_MISSION)
MODE_HOLD = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN_AUTO, PX4_AUTO_LOITER)
MISSION_STATE_ACTIVE, MISSION_STATE_COMPLETE = 3, 5
TRUTH = "HIL_STATE_QUATERNION"  # SIH's ground truth; lat/lon degE7, time_usec 0 (stamped by arrival)


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _lock_free(inst: int) -> bool:
    """/tmp/px4_lock-I absent, or present and not held (PX4 holds it with lockf while it runs)."""
    path = f"/tmp/px4_lock-{inst}"
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        return True
    except OSError:
        return False  # another user's lock file
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def instance_usable(inst: int) -> bool:
    """Whether PX4 instance I's lock is free and its UDP ports are: GCS 18570+I, onboard 14580+I and its remote
    14540+I (the daemon binds it), and the other links rcS starts (14280+I, 13030+I, 19450+I)."""
    return _lock_free(inst) and all(_udp_free(p + inst) for p in (18570, 14580, 14540, 14280, 13030, 19450))


FIRST_INSTANCE = 3  # instances below are left to a PX4 a user runs by hand (its default is 0)


def prepare_px4(px4: Path, folder: Path) -> tuple[Path, Path]:
    """A private command folder and a fresh rootfs under `folder`; returns (the px4 link to run, rootfs).

    The shared build's bin/px4-* command links are plain files, so rcS's `px4-param ...` fails: the private
    folder holds px4 -> the binary and px4-<name> -> px4 for each of them (px4-alias.sh copied). The rootfs
    holds etc -> the build's ROMFS."""
    real = px4.resolve()
    shutil.rmtree(folder, ignore_errors=True)
    bindir, rootfs = folder / "bin", folder / "rootfs"
    bindir.mkdir(parents=True)
    rootfs.mkdir()
    (bindir / "px4").symlink_to(real)
    for f in sorted(real.parent.glob("px4-*")):
        if f.name == "px4-alias.sh":
            shutil.copy(f, bindir / f.name)
        else:
            (bindir / f.name).symlink_to("px4")
    (rootfs / "etc").symlink_to(real.parents[1] / "etc")
    return bindir / "px4", rootfs


def _param_text(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def read_params_file(path: Path) -> dict[str, float]:
    """NAME -> value from a QGroundControl parameter file (tab-separated vehicle, component, name, value, type;
    # comments)."""
    out: dict[str, float] = {}
    for line in path.read_text().splitlines():
        cols = line.split("\t")
        if line.startswith("#") or len(cols) < 4:
            continue
        out[cols[2].strip()] = float(cols[3])
    return out


def start_px4(px4: Path, folder: Path, inst: int, model: str, params: dict[str, float]) -> subprocess.Popen:
    """PX4 SITL (SIH, PX4_SIM_MODEL `model`) instance `inst` in its own process group, `params` set at boot
    (PX4_PARAM_<NAME>); console to folder/out.log."""
    exe, rootfs = prepare_px4(px4, folder)
    env = dict(os.environ, PX4_SIMULATOR="sihsim", PX4_SIM_MODEL=model)
    env.update({f"PX4_PARAM_{k}": _param_text(v) for k, v in params.items()})
    return subprocess.Popen([str(exe), "-d", "-i", str(inst), "-w", str(rootfs)], cwd=rootfs, env=env,
                            stdin=subprocess.DEVNULL, stdout=open(folder / "out.log", "w"),
                            stderr=subprocess.STDOUT, start_new_session=True)


class Px4Gcs(Gcs):
    """The harness's ground station on PX4's GCS link (UDP 18570+I; PX4 answers whoever sends to it, so it
    sends a HEARTBEAT every second)."""

    heartbeat_s = 1.0

    def __init__(self, inst: int, limit_s: float = 60.0) -> None:
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{18570 + inst}", source_system=250, source_component=190)
        deadline = time.time() + limit_s
        while True:
            try:
                m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            except OSError:
                pass  # PX4 not listening yet
            hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=1)
            if hb is not None and hb.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1:
                break
            if time.time() > deadline:
                raise RuntimeError(f"no PX4 heartbeat on UDP {18570 + inst}")
        m.target_system = hb.get_srcSystem()
        self._attach(m)


def px4_mode(custom_mode: int) -> tuple[int, int]:
    """(main mode, sub mode) of a PX4 HEARTBEAT custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def set_mode(gcs: Gcs, mode: tuple[float, float, float], limit_s: float = 10.0) -> bool:
    """MAV_CMD_DO_SET_MODE `mode` (MODE_MISSION, MODE_HOLD) once a second until PX4's HEARTBEAT shows its main
    and sub mode; False after limit_s (PX4 refuses a mode it cannot fly, e.g. Mission without a position)."""
    want = (int(mode[1]), int(mode[2]))
    end = time.time() + limit_s
    while time.time() < end:
        gcs.send_cmd(M.MAV_CMD_DO_SET_MODE, *mode)
        for msg in gcs.pump(1.0):
            if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == gcs.target[0] and \
                    msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 and px4_mode(msg.custom_mode) == want:
                return True
    return False


def modes(gcs: Gcs, t_ref: float) -> list[dict[str, Any]]:
    """Each change of PX4's (armed, main mode, sub mode) in the autopilot's HEARTBEATs, wall s after t_ref."""
    seen: list[dict[str, Any]] = []
    last = None
    for t, msg in gcs.log:
        if msg.get_type() != "HEARTBEAT" or msg.get_srcSystem() != gcs.target[0] or \
                msg.get_srcComponent() != M.MAV_COMP_ID_AUTOPILOT1:
            continue
        main, sub = px4_mode(msg.custom_mode)
        now = (bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED), main, sub)
        if now != last:
            seen.append({"t_s": round(t - t_ref, 2), "armed": now[0], "main": main, "sub": sub})
            last = now
    return seen


def statustexts(gcs: Gcs) -> list[tuple[float, int, int, str]]:
    """(wall time, sender's component id, severity, text) of each STATUSTEXT in the GCS log, PX4's chunks
    joined: a text longer than 50 characters comes as several messages with the same non-zero id and chunk_seq
    0, 1, ... The daemon's texts (component 191) reach the ground station through PX4 too."""
    out: list[tuple[float, int, int, str]] = []
    last = None
    for t, msg in gcs.log:
        if msg.get_type() != "STATUSTEXT":
            continue
        key = (msg.get_srcComponent(), getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0))
        if key[1] and last is not None and key[:2] == last[:2] and key[2] == last[2] + 1 and out:
            out[-1] = out[-1][:3] + (out[-1][3] + msg.text,)
        else:
            out.append((t, key[0], msg.severity, msg.text))
        last = key
    return [(t, comp, sev, txt.strip()) for t, comp, sev, txt in out]  # PX4 ends some with a tab

