"""The house rules of docs/architecture.md, read from the source with `ast` (nothing is imported).

Every `import` in every module of the package counts: at module level and inside functions (a lazy import is
still a dependency). Imports under `if TYPE_CHECKING:` (annotations only) count for the cycle rule, not for the
layers. The rules:

- layers: a module imports only modules of its own layer or below (`LAYERS`, bottom first);
- core imports nothing of taco_mav but core and errors, and no I/O library (sockets, files, YAML, MAVLink,
  images, plots, progress bars);
- mavlink (the protocol) sits below daemon (the application), and neither imports anything of
  datasets/sim/evaluation, directly or through the modules it uses (camera, config, ...); exceptions would be
  listed in `KNOWN_UPWARD` (there are none);
- no import cycle between modules;
- nothing imports the CLI; no test tooling in the product package; the split modules stay small.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from dataclasses import dataclass
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "taco_mav"

# Bottom first. A top-level module or subpackage of taco_mav is named by its first component after "taco_mav".
LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"", "errors", "geo", "timestamps", "progress"}),  # "" = taco_mav/__init__.py
    frozenset({"core"}),
    frozenset({"config", "camera"}),
    frozenset({"cvgl"}),
    frozenset({"mavlink"}),
    frozenset({"daemon"}),
    frozenset({"datasets"}),
    frozenset({"evaluation"}),
    frozenset({"sim"}),
    frozenset({"bench", "reliability", "closedloop", "demo", "calibrate", "checks"}),
    frozenset({"campaign"}),  # runs of the use cases (SITL missions, the simulator, evaluations) on Ray
    frozenset({"cli", "cli_support", "commands"}),
)
CORE_MAY_IMPORT = ("taco_mav.core", "taco_mav.errors")
IO_LIBRARIES = frozenset({"pymavlink", "rasterio", "cv2", "serial", "yaml", "socket", "matplotlib", "tqdm", "PIL",
                          "torch", "pyproj", "requests", "urllib", "http", "subprocess", "sqlite3"})
LIVE_MUST_NOT_REACH = ("taco_mav.datasets", "taco_mav.sim", "taco_mav.evaluation", "taco_mav.bench",
                       "taco_mav.reliability", "taco_mav.closedloop", "taco_mav.demo", "taco_mav.cli")
# Tolerated upward imports, each (importer, imported prefix, the class the import must sit in; "" outside
# classes). Empty: the last one (camera.WorldSource building datasets/synthetic's renderers) went when WorldSource
# moved to datasets/synthetic/world_camera.py and `open_camera` took the `world:` scheme from a registry.
KNOWN_UPWARD: tuple[tuple[str, str, str], ...] = ()
SPLIT_MODULES_MAX_LINES = 350  # config/ and daemon/ hold one idea a module, ~300 lines at most


@dataclass(frozen=True)
class Import:
    """One import statement's target in a module: `target` is a module of the package or an external top-level
    name; `cls` the class it sits in ("" outside classes); `lazy` whether it sits inside a function."""

    source: str
    target: str
    line: int
    cls: str
    lazy: bool


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES: dict[str, Path] = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _resolve(source: str, node: ast.ImportFrom | ast.Import) -> list[str]:
    """The modules (of the package, else external top-level names) an import statement loads."""
    if isinstance(node, ast.Import):
        return [a.name if a.name.split(".")[0] == "taco_mav" else a.name.split(".")[0] for a in node.names]
    if node.level:  # relative: from the importing module's package
        base = source.split(".")
        base = base[: len(base) - node.level + (1 if MODULES[source].name == "__init__.py" else 0)]
        module = ".".join(base + ([node.module] if node.module else []))
    else:
        module = node.module or ""
    if module.split(".")[0] != "taco_mav":
        return [module.split(".")[0]]
    # `from pkg import sub` loads the submodule pkg.sub when there is one
    return [f"{module}.{a.name}" if f"{module}.{a.name}" in MODULES else module for a in node.names]


def _imports(name: str, type_checking: bool = False) -> list[Import]:
    """The imports of module `name`; with type_checking, those under `if TYPE_CHECKING:` too."""
    out: list[Import] = []

    def visit(node: ast.AST, cls: str, lazy: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test) and not type_checking:
            for child in node.orelse:
                visit(child, cls, lazy)
            return
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.extend(Import(name, t, node.lineno, cls, lazy) for t in _resolve(name, node))
            return
        if isinstance(node, ast.ClassDef):
            cls = node.name
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            lazy = True
        for child in ast.iter_child_nodes(node):
            visit(child, cls, lazy)

    visit(ast.parse(MODULES[name].read_text(), str(MODULES[name])), "", False)
    return out


IMPORTS: dict[str, list[Import]] = {name: _imports(name) for name in MODULES}
EVERY_IMPORT: dict[str, list[Import]] = {name: _imports(name, type_checking=True) for name in MODULES}


def _component(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _layer(module: str) -> int:
    comp = _component(module)
    for i, layer in enumerate(LAYERS):
        if comp in layer:
            return i
    raise AssertionError(f"{module}: {comp!r} is in no layer of tests/test_architecture.py (add it there and to "
                         f"docs/architecture.md)")


def _internal(imp: Import) -> bool:
    return imp.target in MODULES


def _known(imp: Import) -> bool:
    return any(imp.source == src and imp.target.startswith(prefix) and imp.cls == cls
               for src, prefix, cls in KNOWN_UPWARD)


def _where(imp: Import) -> str:
    return f"{MODULES[imp.source].relative_to(PACKAGE.parent)}:{imp.line} imports {imp.target}"


def test_every_module_parses_and_has_a_layer() -> None:
    assert "taco_mav.core.localiser" in MODULES and "taco_mav.config" in MODULES
    for name in MODULES:
        _layer(name)


def test_imports_go_down_the_layers() -> None:
    bad = [_where(i) + f" (layer {_layer(i.source)} -> {_layer(i.target)})"
           for imps in IMPORTS.values() for i in imps
           if _internal(i) and _layer(i.target) > _layer(i.source) and not _known(i)]
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_known_upward_exceptions_are_still_needed() -> None:
    """Every tolerated upward import still exists (a fixed one is removed from `KNOWN_UPWARD`)."""
    stale = [e for e in KNOWN_UPWARD if not any(_known(i) and (i.source, i.cls) == (e[0], e[2]) and
                                                i.target.startswith(e[1]) for imps in IMPORTS.values() for i in imps)]
    assert not stale, f"KNOWN_UPWARD lists imports that are gone: {stale}"


def test_core_imports_no_io_and_nothing_above_it() -> None:
    core = [i for name, imps in IMPORTS.items() if _component(name) == "core" for i in imps]
    assert core, "no imports found in taco_mav/core"
    upward = [_where(i) for i in core if _internal(i) and not i.target.startswith(CORE_MAY_IMPORT)]
    io = [_where(i) for i in core if not _internal(i) and i.target in IO_LIBRARIES]
    assert not upward, "core imports outside core:\n" + "\n".join(upward)
    assert not io, "core imports an I/O library:\n" + "\n".join(io)


def test_mavlink_and_daemon_do_not_reach_datasets_sim_or_evaluation() -> None:
    """Directly, or through any module they import (transitively), save the known exceptions."""
    bad: list[str] = []
    for start in (n for n in MODULES if _component(n) in ("mavlink", "daemon")):
        seen, stack = {start}, [start]
        while stack:
            for imp in IMPORTS[stack.pop()]:
                if not _internal(imp) or imp.target in seen or _known(imp):
                    continue
                if imp.target.startswith(LIVE_MUST_NOT_REACH):
                    bad.append(f"{start}: {_where(imp)}")
                    continue
                seen.add(imp.target)
                stack.append(imp.target)
    assert not bad, "mavlink / daemon reach a layer above them:\n" + "\n".join(sorted(set(bad)))


def test_no_import_cycles() -> None:
    """Counting every import, annotation-only ones too: a module that names another's type depends on it."""
    graph: dict[str, set[str]] = defaultdict(set)
    for name, imps in EVERY_IMPORT.items():
        graph[name] |= {i.target for i in imps if _internal(i) and i.target != name}
    try:
        list(TopologicalSorter(graph).static_order())
    except CycleError as exc:
        pytest.fail(f"import cycle: {' -> '.join(exc.args[1])}")


def test_nothing_imports_the_cli() -> None:
    bad = [_where(i) for imps in IMPORTS.values() for i in imps
           if i.target == "taco_mav.cli" and i.source != "taco_mav.cli"]
    assert not bad


def test_no_test_tooling_in_the_package() -> None:
    assert not [n for n in MODULES if n.rsplit(".", 1)[-1].startswith(("fuzz", "test_", "conftest"))]


@pytest.mark.parametrize("pattern", ["config/*.py", "daemon/*.py"])
def test_split_modules_stay_small(pattern: str) -> None:
    sizes = {p.name: len(p.read_text().splitlines()) for p in PACKAGE.glob(pattern)}
    assert sizes and max(sizes.values()) <= SPLIT_MODULES_MAX_LINES, sizes


def test_config_reexports_every_public_name_of_its_modules() -> None:
    """`from taco_mav.config import X` works for every X that a config module exports."""
    import taco_mav.config as config

    for name in (n for n in MODULES if n.startswith("taco_mav.config.")):
        module = __import__(name, fromlist=["__all__"])
        missing = [x for x in getattr(module, "__all__", ()) if getattr(config, x, None) is not getattr(module, x)]
        assert not missing, f"{name}: not re-exported by taco_mav.config: {missing}"


def _dataclass_fields() -> dict[str, frozenset[str]]:
    """Every @dataclass of the package: 'module.Class' -> its annotated field names."""
    out: dict[str, frozenset[str]] = {}
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and any(
                    "dataclass" in ast.unparse(d) for d in node.decorator_list):
                fields = {s.target.id for s in node.body
                          if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
                out[f"{name}.{node.name}"] = frozenset(fields)
    return out


def test_no_two_parameter_classes_mirror_each_other() -> None:
    """Every parameter is defined once: no two parameter dataclasses (named *Params or *Config) of 4 or more
    fields share 80 % of them (a config-side mirror of PlusParams, all 77 fields with five defaults apart, is what
    it catches)."""
    classes = sorted((k, v) for k, v in _dataclass_fields().items() if k.endswith(("Params", "Config")))
    twins = [(a, b) for i, (a, fa) in enumerate(classes) for b, fb in classes[i + 1:]
             if min(len(fa), len(fb)) >= 4 and len(fa & fb) >= 0.8 * min(len(fa), len(fb))]
    assert not twins, twins
