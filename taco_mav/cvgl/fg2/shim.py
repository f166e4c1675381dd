"""Default `fg2.entry`: build the published FG2 KITTI model (vita-epfl/FG2) from a local checkout.

What it assumes of the checkout (see docs/matchers.md for the commit): `config.ini` with the [KITTI], [Model]
and [RandomSeed] keys that `kitti_train_test.py` reads; `models/model_kitti.py` defining
`CVM(device, grd_bev_res, grd_height_res, sat_bev_res, grid_size_h, grid_size_v)` whose forward(grd_feature,
sat_feature, camera_k) returns (matching_score, matching_score_original); `models/modules.py` defining
`DinoExtractor(dinov2_weights)`. FG2's modules read "./config.ini" at import and import `models`, `utils`,
`att_layers`, `DINO_modules` as top-level packages, so the import runs with the checkout as working directory and
first on sys.path, and both are restored afterwards (as are the RNG states and torch's determinism flags, which
FG2's imports set globally). FG2's bare top-level names leave sys.modules again, but its modules stay registered
as `taco_mav_fg2_<n>.<name>` so that torch.compile, which re-imports a traced function's module by name for its
guards, finds them. mmcv: its CUDA kernel on CUDA when installed, else (and on every non-CUDA device)
`taco_mav.cvgl.fg2.mmcv`, a PyTorch stand-in with mmcv's parameters and the CUDA kernel's semantics.

The model is built the way `kitti_train_test.py` builds it: seed, DinoExtractor, then CVM. A checkpoint saved
from a model built on CUDA lacks `grd_grid_queries` (FG2 creates it with `.to(device)`, which unregisters it), so
those queries are FG2's seeded random values, reproduced by the same construction order. DINOv2 weights are
never downloaded: `dinov2_vitl14_pretrain.pth` must be in one of `dinov2_candidates(...)`.
"""

from __future__ import annotations

import configparser
import contextlib
import importlib
import itertools
import logging
import os
import random
import sys
import types
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch

from taco_mav.cvgl.fg2.mmcv import mmcv_installed, stand_in_modules
from taco_mav.cvgl.fg2.published import Fg2Settings, PublishedFg2, dinov2_precision_for
from taco_mav.errors import MatcherError

log = logging.getLogger(__name__)

EXPECTED_MODULE = Path("models") / "model_kitti.py"
CONFIG_FILE = "config.ini"
DINOV2_FILE = "dinov2_vitl14_pretrain.pth"
DINOV2_URL = "https://dl.fbaipublicfiles.com/dinov2/dinov2_vitl14/dinov2_vitl14_pretrain.pth"
# FG2's top-level packages (imported from the checkout; removed from sys.modules again after the import).
FG2_PACKAGES = ("models", "utils", "att_layers", "DINO_modules", "dataloaders")
# Keys the KITTI checkpoint may lack (unregistered on CUDA, see the module docstring).
SEEDED_KEYS = ("grd_grid_queries",)
INSTALL_HINTS = {
    "mmcv": "mmcv 2.x with its CUDA ops (not mmcv-lite) is optional (taco_mav.cvgl.fg2.mmcv stands in): pip "
            "install -U openmim && mim install 'mmcv>=2.0.0' (matching your torch and CUDA versions)",
    "mmengine": "pip install mmengine (mmcv 2.x depends on it)",
    "matplotlib": "pip install matplotlib (FG2's models/modules.py imports it)",
    "einops": "pip install einops (FG2's att_layers/transformer.py imports it)",
}


def build_model(checkout: Path, checkpoint: Path, device: Any) -> PublishedFg2:
    """`fg2.entry` function: the published FG2 model from `checkout` with `checkpoint` on `device`, eval mode."""
    checkout, checkpoint = Path(checkout), Path(checkpoint)
    if not (checkout / EXPECTED_MODULE).is_file():
        raise MatcherError(f"fg2.checkout: {checkout} is not an FG2 checkout ({EXPECTED_MODULE} not found)")
    settings = read_settings(checkout / CONFIG_FILE)
    dino_state = _load_state(find_dinov2(checkout, checkpoint), "DINOv2 weights")
    state = _load_state(checkpoint, "fg2.checkpoint")
    device = torch.device(device)
    with fg2_import_scope(checkout, device):
        model_kitti = _import_fg2(checkout, "models.model_kitti")
        modules = _import_fg2(checkout, "models.modules")
        torch.manual_seed(settings.seed)  # as kitti_train_test.py: seed, DinoExtractor, then CVM
        try:
            extractor = modules.DinoExtractor(dinov2_weights=dino_state)
        except Exception as exc:
            raise MatcherError(f"fg2: DINOv2 weights do not fit FG2's ViT-L/14 ({type(exc).__name__}: {exc})") from None
        cvm = model_kitti.CVM(device, grd_bev_res=settings.grd_bev_res, grd_height_res=settings.grd_height_res,
                              sat_bev_res=settings.sat_bev_res, grid_size_h=settings.grid_size_h,
                              grid_size_v=settings.grid_size_v)
    _load_cvm(cvm, state, checkpoint)
    model = PublishedFg2(extractor, cvm, settings).to(device).eval()
    dinov2_precision_for(model.extractor, device)
    log.info("fg2: published FG2 from %s, checkpoint %s, on %s", checkout, checkpoint, device)
    return model


def build_random_model(checkout: Path, device: Any, seed: int = 0) -> PublishedFg2:
    """The published FG2 model from `checkout` with random weights (no checkpoint, no DINOv2 file): DINOv2 from
    the checkout's own `DINO_modules.dinov2.vit_large` initialised after torch.manual_seed(seed), then the CVM
    built as `build_model` does (FG2's seed, DinoExtractor, CVM). For benchmarks and equality tests only."""
    checkout = Path(checkout)
    if not (checkout / EXPECTED_MODULE).is_file():
        raise MatcherError(f"fg2.checkout: {checkout} is not an FG2 checkout ({EXPECTED_MODULE} not found)")
    settings = read_settings(checkout / CONFIG_FILE)
    device = torch.device(device)
    with fg2_import_scope(checkout, device):
        model_kitti = _import_fg2(checkout, "models.model_kitti")
        modules = _import_fg2(checkout, "models.modules")
        dinov2 = _import_fg2(checkout, "DINO_modules.dinov2")
        torch.manual_seed(seed)
        vit = dinov2.vit_large(img_size=518, patch_size=14, init_values=1.0, ffn_layer="mlp", block_chunks=0)
        dino_state = vit.state_dict()
        del vit
        torch.manual_seed(settings.seed)
        extractor = modules.DinoExtractor(dinov2_weights=dino_state)
        cvm = model_kitti.CVM(device, grd_bev_res=settings.grd_bev_res, grd_height_res=settings.grd_height_res,
                              sat_bev_res=settings.sat_bev_res, grid_size_h=settings.grid_size_h,
                              grid_size_v=settings.grid_size_v)
    model = PublishedFg2(extractor, cvm, settings).to(device).eval()
    dinov2_precision_for(model.extractor, device)
    log.info("fg2: published FG2 from %s with RANDOM weights (seed %d) on %s", checkout, seed, device)
    return model


def read_settings(path: Path) -> Fg2Settings:
    """The keys kitti_train_test.py reads from config.ini (MatcherError naming the file, section and key)."""
    if not path.is_file():
        raise MatcherError(f"fg2.checkout: {path} not found (FG2's settings file)")
    cfg = configparser.ConfigParser()
    try:
        cfg.read(path)

        def get(section: str, key: str, kind: type) -> Any:
            try:
                raw = cfg.get(section, key)
                if kind is tuple:
                    value = tuple(int(v) for v in raw.strip(" ()").split(","))
                    if len(value) != 2:
                        raise ValueError("expected (height, width)")
                    return value
                return kind(raw)
            except (configparser.Error, ValueError) as exc:
                raise MatcherError(f"{path}: [{section}] {key}: {exc}") from None

        return Fg2Settings(
            grid_size_h=get("KITTI", "grid_size_h", float), grid_size_v=get("KITTI", "grid_size_v", float),
            ground_size=get("KITTI", "ground_image_size", tuple),
            aerial_size=get("KITTI", "satellite_image_size", tuple)[0],
            grd_bev_res=get("Model", "grd_bev_res", int), grd_height_res=get("Model", "grd_height_res", int),
            sat_bev_res=get("Model", "sat_bev_res", int), num_samples=get("Model", "num_samples_matches", int),
            seed=get("RandomSeed", "seed", int))
    except configparser.Error as exc:
        raise MatcherError(f"{path}: cannot parse ({exc})") from None


def dinov2_candidates(checkout: Path, checkpoint: Path) -> list[Path]:
    """Where the DINOv2 ViT-L/14 weights are looked for, in order: next to fg2.checkpoint, the checkout root,
    its checkpoints/ folder, and torch's hub cache (where FG2's own download would have put them)."""
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    return [checkpoint.parent / DINOV2_FILE, checkout / DINOV2_FILE, checkout / "checkpoints" / DINOV2_FILE,
            hub / DINOV2_FILE]


def find_dinov2(checkout: Path, checkpoint: Path) -> Path:
    """The first existing DINOv2 weights file (MatcherError listing the places looked in)."""
    candidates = dinov2_candidates(checkout, checkpoint)
    for path in candidates:
        if path.is_file():
            return path
    raise MatcherError(f"fg2: DINOv2 ViT-L/14 weights {DINOV2_FILE} not found (nothing is downloaded at run time); "
                       f"fetch {DINOV2_URL} once and put it next to fg2.checkpoint. Looked in: "
                       + ", ".join(str(p) for p in candidates))


def _load_state(path: Path, what: str) -> dict[str, torch.Tensor]:
    """A state_dict from a torch file: plain, or under "state_dict" / "model"; a DataParallel "module." prefix
    is dropped."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt or foreign files
        raise MatcherError(f"{path}: cannot load {what} ({type(exc).__name__}: {exc})") from None
    for key in ("state_dict", "model"):
        if isinstance(blob, dict) and isinstance(blob.get(key), dict):
            blob = blob[key]
    if not isinstance(blob, dict) or not blob or not all(torch.is_tensor(v) for v in blob.values()):
        raise MatcherError(f"{path}: {what} is not a state_dict of tensors")
    return {k.removeprefix("module."): v for k, v in blob.items()}


def _load_cvm(cvm: torch.nn.Module, state: dict[str, torch.Tensor], checkpoint: Path) -> None:
    """Load the CVM weights; SEEDED_KEYS may be absent (kept at FG2's seeded values) or be unregistered tensors."""
    own = cvm.state_dict()
    for key in SEEDED_KEYS:  # built on CUDA, FG2's model holds these as plain tensors: copy by hand
        if key in state and key not in own and torch.is_tensor(getattr(cvm, key, None)):
            getattr(cvm, key).data.copy_(state.pop(key))
    try:
        missing, unexpected = cvm.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # shape mismatches
        raise MatcherError(f"{checkpoint}: does not fit FG2's CVM ({str(exc).splitlines()[-1].strip()})") from None
    missing = [k for k in missing if k not in SEEDED_KEYS]
    if missing or unexpected:
        raise MatcherError(f"{checkpoint}: does not fit FG2's CVM (missing keys {missing[:5]}, unexpected keys "
                           f"{list(unexpected)[:5]}); is it FG2's KITTI checkpoint?")
    if any(k not in state for k in SEEDED_KEYS if k in own):
        log.info("fg2: %s has no %s; using FG2's seeded values", checkpoint, ", ".join(SEEDED_KEYS))


def _import_fg2(checkout: Path, name: str) -> Any:
    """Import one of FG2's modules (inside fg2_import_scope), turning failures into MatcherErrors that say what
    is missing and how to install it."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        missing = exc.name or str(exc)
        top = missing.split(".")[0]
        if top in FG2_PACKAGES:
            raise MatcherError(f"fg2.checkout: {checkout} is incomplete: importing {name} needs {missing} "
                               f"({checkout / missing.replace('.', '/')} not found)") from None
        hint = INSTALL_HINTS.get(top, f"pip install {top}")
        raise MatcherError(f"fg2: importing FG2's {name} from {checkout} needs the module {missing!r}, which is "
                           f"not installed: {hint}") from None
    except Exception as exc:  # FG2 runs code at import (config.ini reads, seeding)
        raise MatcherError(f"fg2: importing FG2's {name} from {checkout} failed ({type(exc).__name__}: {exc})") \
            from None


_scopes = itertools.count(1)


def _keep_private(name: str, module: types.ModuleType, prefix: str) -> None:
    """Re-register an FG2 module imported in a scope as `prefix.name` (its __name__ and the __module__ of what it
    defines follow), so tools that look modules up by name (torch.compile's guards, pickle) still find it
    while FG2's bare top-level names (`models`, `utils`, ...) are given back."""
    new = f"{prefix}.{name}"
    for obj in list(vars(module).values()):
        if isinstance(obj, (type, types.FunctionType)) and getattr(obj, "__module__", None) == name:
            try:
                obj.__module__ = new
            except (AttributeError, TypeError):  # extension types
                pass
    module.__name__ = new
    sys.modules[new] = module


@contextlib.contextmanager
def fg2_import_scope(checkout: Path, device: torch.device) -> Iterator[None]:
    """Run with the checkout as working directory and first on sys.path, FG2's package names free in
    sys.modules; afterwards restore the directory, sys.path, sys.modules, the RNG states (torch, numpy,
    random) and torch's determinism flags. The FG2 modules imported inside stay registered under a private
    name, `taco_mav_fg2_<n>.<name>` (see `_keep_private`); the bare names are removed again."""
    checkout = Path(checkout).resolve()  # it becomes the working directory: a relative path would break
    cwd, path = os.getcwd(), list(sys.path)
    stand_in = {} if device.type == "cuda" and mmcv_installed() else stand_in_modules()
    if stand_in:
        log.info("fg2: FG2's deformable attention and FFN run on taco_mav's PyTorch stand-in for mmcv "
                 "(taco_mav.cvgl.fg2.mmcv; %s)", "mmcv is not installed" if not mmcv_installed()
                 else f"mmcv's own {device.type} path returns NaN for FG2's KITTI grid")
    owned = FG2_PACKAGES + (("mmcv",) if stand_in else ())
    shadowed = {k: sys.modules.pop(k) for k in list(sys.modules) if k.split(".")[0] in owned}
    sys.modules.update(stand_in)
    flags = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled(),
             torch.backends.cudnn.benchmark, torch.backends.cudnn.deterministic)
    np_state, py_state = np.random.get_state(), random.getstate()
    devices = [device.index or 0] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        try:
            os.chdir(checkout)
            sys.path.insert(0, str(checkout))
            yield
        finally:
            os.chdir(cwd)
            sys.path[:] = path
            prefix = f"taco_mav_fg2_{next(_scopes)}"
            package = types.ModuleType(prefix, f"FG2 modules imported from {checkout}")
            package.__path__ = []
            sys.modules[prefix] = package
            for k in [k for k in sys.modules if k.split(".")[0] in owned]:
                module = sys.modules.pop(k)
                if k.split(".")[0] in FG2_PACKAGES and isinstance(module, types.ModuleType):
                    _keep_private(k, module, prefix)
            sys.modules.update(shadowed)
            torch.use_deterministic_algorithms(flags[0], warn_only=flags[1])
            torch.backends.cudnn.benchmark, torch.backends.cudnn.deterministic = flags[2], flags[3]
            np.random.set_state(np_state)
            random.setstate(py_state)
