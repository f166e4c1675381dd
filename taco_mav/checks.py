"""Checks the command line runs before any expensive step: output folders writable, input paths present and
well-formed, names in their allowed sets, numbers in range. Each failure is one `UsageError` (exit code 2) or,
for an input file that exists but is broken, one `DataError` (exit code 1), naming the option and the value."""

from __future__ import annotations

import math
import os
import re
import tempfile
from pathlib import Path
from typing import Iterable, Sequence

from taco_mav.errors import DataError, UsageError

__all__ = ["output_dir", "output_file", "input_dir", "input_file", "geotiff", "world", "world_of", "number", "names",
           "coordinates", "fresh_folder", "join_negative_values"]


def _why(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def _probe_writable(folder: Path, option: str, shown: Path) -> None:
    try:
        fd, name = tempfile.mkstemp(prefix=".taco-mav-write-test-", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise UsageError(f"{option} {shown}: cannot write in {folder} ({_why(exc)})") from None


def output_dir(path: str | Path, option: str = "--out", create: bool = True) -> Path:
    """`path` as a folder this process can write into, created (with its parents) if absent; with create False
    only checked (it exists and is writable, or its nearest existing parent is a writable folder)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path}: exists and is not a folder")
    if not create:
        parent = next((p for p in (path, *path.parents) if p.exists()), Path("."))
        if not parent.is_dir():
            raise UsageError(f"{option} {path}: cannot create the folder ({parent} is not a folder)")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise UsageError(f"{option} {path}: cannot create the folder ({parent} is not writable)")
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot create the folder ({_why(exc)})") from None
    _probe_writable(path, option, path)
    return path


def output_file(path: str | Path, option: str = "--out") -> Path:
    """`path` as a file this process can write: not a folder, its folder created if absent and writable."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name")
    if path.exists() and not os.access(path, os.W_OK):
        raise UsageError(f"{option} {path}: exists and is not writable")
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"{option} {path}: {parent} is not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot create the folder {parent} ({_why(exc)})") from None
    _probe_writable(parent, option, path)
    return path


def input_dir(path: str | Path, option: str) -> Path:
    """`path` as an existing, readable folder."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{option} {path}: no such folder")
    if not path.is_dir():
        raise UsageError(f"{option} {path}: not a folder")
    if not os.access(path, os.R_OK | os.X_OK):
        raise UsageError(f"{option} {path}: folder not readable")
    return path


def input_file(path: str | Path, option: str) -> Path:
    """`path` as an existing, readable, non-empty file."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{option} {path}: no such file")
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file")
    try:
        with path.open("rb") as f:
            head = f.read(1)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot read ({_why(exc)})") from None
    if not head:
        raise DataError(f"{option} {path}: the file is empty")
    return path


def geotiff(path: str | Path, option: str = "--map") -> Path:
    """`path` as a GeoTIFF that opens and is complete: every block's bytes lie inside the file (a truncated
    download fails here, not in the middle of a run), and its last pixel reads."""
    path = input_file(path, option)
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.windows import Window

    try:
        with rasterio.open(path) as ds:
            size = path.stat().st_size
            for band in range(1, ds.count + 1):
                bh, bw = ds.block_shapes[band - 1]
                nx, ny = math.ceil(ds.width / bw), math.ceil(ds.height / bh)
                for y in range(ny) if nx * ny <= 200_000 else ():
                    for x in range(nx):
                        off = ds.get_tag_item(f"BLOCK_OFFSET_{x}_{y}", "TIFF", bidx=band)
                        cnt = ds.get_tag_item(f"BLOCK_SIZE_{x}_{y}", "TIFF", bidx=band)
                        if off is not None and cnt is not None and int(off) + int(cnt) > size:
                            raise DataError(f"{option} {path}: truncated GeoTIFF ({size} bytes, block {x},{y} of "
                                            f"band {band} needs {int(off) + int(cnt)})")
            ds.read(1, window=Window(ds.width - 1, ds.height - 1, 1, 1))
    except DataError:
        raise
    except (RasterioError, OSError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"{option} {path}: not a readable GeoTIFF ({first})") from None
    return path


def world(folder: str | Path, option: str) -> Path:
    """A synthetic world folder (`taco-mav world`): world.json readable and naming a complete GeoTIFF mosaic.
    Returns the mosaic's path."""
    import json

    folder = Path(folder)
    meta_path = folder / "world.json"
    if not meta_path.is_file():
        raise UsageError(f"{option}: {folder} is not a world folder (no world.json; `taco-mav world` makes one)")
    try:
        meta = json.loads(meta_path.read_text())
        mosaic = folder / meta["mosaic"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{option}: {meta_path}: not a world description ({type(exc).__name__}: {exc})") from None
    if not mosaic.is_file():
        raise DataError(f"{option}: {meta_path}: its mosaic {mosaic} is missing")
    return geotiff(mosaic, option)


def world_of(drive: str | Path) -> Path | None:
    """The world folder a drive path belongs to (the folder itself or one of 3 parents holds world.json)."""
    drive = Path(drive)
    for folder in (drive, *drive.parents[:3]):
        if (folder / "world.json").is_file():
            return folder
    return None


def number(value: float | None, option: str, low: float | None = None, high: float | None = None,
           low_open: bool = False) -> float | None:
    """`value` checked to lie in [low, high] ((low, high] with low_open); None passes (option not given)."""
    if value is None:
        return None
    ok = math.isfinite(value) and (low is None or (value > low if low_open else value >= low)) and \
        (high is None or value <= high)
    if not ok:
        lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
        hi = "" if high is None else f"<= {high:g}"
        raise UsageError(f"{option} {value:g}: must be {' and '.join(s for s in (lo, hi) if s) or 'finite'}")
    return value


def names(text: str | Sequence[str], option: str, allowed: Iterable[str]) -> tuple[str, ...]:
    """A comma-separated list (or a sequence) of names, each in `allowed`; at least one."""
    allowed = tuple(allowed)
    items = tuple(s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip())
    if not items:
        raise UsageError(f"{option}: empty list (known: {', '.join(allowed)})")
    unknown = [s for s in items if s not in allowed]
    if unknown:
        raise UsageError(f"{option} {','.join(unknown)}: unknown (known: {', '.join(allowed)})")
    return items


def coordinates(text: str, option: str, names_: Sequence[str] = ("LAT", "LON"),
                optional_last: bool = False) -> tuple[float, ...]:
    """"LAT,LON[,ALT]" -> floats; latitude within +-90, longitude within +-180 (first two fields)."""
    fields = [s.strip() for s in text.split(",")]
    want = len(names_)
    spec = ",".join(names_[:-1]) + (f"[,{names_[-1]}]" if optional_last else f",{names_[-1]}")
    if len(fields) not in ((want - 1, want) if optional_last else (want,)):
        raise UsageError(f"{option} {text}: expected {spec}")
    try:
        vals = tuple(float(v) for v in fields)
    except ValueError:
        raise UsageError(f"{option} {text}: expected {spec} as numbers") from None
    if not all(math.isfinite(v) for v in vals) or abs(vals[0]) > 90.0 or abs(vals[1]) > 180.0:
        raise UsageError(f"{option} {text}: latitude must lie within +-90 and longitude within +-180 degrees")
    return vals


def fresh_folder(folder: Path, marker: str, force: bool, option: str = "--out") -> Path:
    """Refuse a results folder that already holds `marker` (a finished run) unless `force`."""
    if (Path(folder) / marker).exists() and not force:
        raise UsageError(f"{option} {folder}: already holds {marker} from an earlier run; add --force to "
                         "overwrite it or choose another folder")
    return Path(folder)


_NEGATIVE_VALUE = re.compile(r"^-\.?\d[\d.eE+-]*(,[-+]?[\d.eE+-]*)*$")


def join_negative_values(argv: Sequence[str]) -> list[str]:
    """`--centre -35.36,149.16` -> `--centre=-35.36,149.16`: argparse takes a value that starts with '-' and
    is not a plain number for an option; a long option followed by a negative number (list) gets it joined."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        takes_value = tok.startswith("--") and tok != "--" and "=" not in tok
        if takes_value and i + 1 < len(argv) and _NEGATIVE_VALUE.match(argv[i + 1]):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out
