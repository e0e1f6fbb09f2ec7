"""Architecture rules of the package, checked on the source itself.

1. Imports go one way. Every import statement in ``src/ncflow`` is read from the syntax tree — at module
   level, inside functions and classes, under ``if TYPE_CHECKING:`` and in ``try`` blocks — relative
   imports are resolved, and each import of another ncflow package must respect the layers

       geometry (0) <- io (1) <- jit (2) <- {measures, skeleton, flow, tissue, losses, optim, config} (3)
                    <- {matcher, synthetic} (4) <- evaluate (5) <- {view, retarget, runs} (6) <- cli (7)

   A package imports only packages of lower layers; packages of one layer do not import each other except
   the few edges of ``SAME_LAYER_ALLOWED`` (each with its reason). ``synthetic`` imports only geometry, io,
   skeleton and errors. ``errors`` is a leaf: everybody imports it, it imports nothing of ncflow.
   ``ncflow/__init__.py`` and ``ncflow/__main__.py`` may import anything; the other modules take nothing
   from the root package but ``__version__``. The package-level import graph has no cycle.
   A "package" here is the second component of a dotted module name: ``ncflow.geometry.mesh`` belongs to
   ``geometry``, ``ncflow.tissue`` to ``tissue``.
2. ``geometry`` is pure NumPy: it imports neither JAX, Equinox nor Optax.
3. A module has at most ``MAX_LINES`` lines unless its docstring says why, on a line of its own that starts
   with the marker ``Over 500 lines:`` followed by the reason.
4. ``import ncflow`` does not import the optional heavy dependencies (plotting, tetrahedralisation,
   geodesics, marching cubes); they are imported inside the functions that use them.
"""

import ast
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "ncflow"

LAYERS = {
    "geometry": 0,
    "io": 1,
    "jit": 2,
    "measures": 3,
    "skeleton": 3,
    "flow": 3,
    "tissue": 3,
    "losses": 3,
    "optim": 3,
    "config": 3,
    "matcher": 4,
    "synthetic": 4,
    "evaluate": 5,
    "view": 6,
    "retarget": 6,
    "runs": 6,
    "track": 6,
    "cli": 7,
}
ROOT = "ncflow"  # the root package, ncflow/__init__.py
UNRESTRICTED = {ROOT, "__main__"}  # the public surface and `python -m ncflow` may import anything
LEAF = "errors"  # importable from everywhere, imports nothing of ncflow
SYNTHETIC_MAY_IMPORT = {"geometry", "io", "skeleton", LEAF}
# names other modules may take from the root package: __version__ is bound at the top of ncflow/__init__.py,
# before it imports any submodule, and Python initialises the root package before any submodule anyway, so
# reading it adds no import edge
ROOT_NAMES_ALLOWED = {"__version__"}

# imports between packages of one layer that exist for a reason; keep this list short and every entry used
SAME_LAYER_ALLOWED = {
    ("flow", "skeleton"): "the skeleton-driven flow field (flow/skinning.py) is a function of a Skeleton and its "
    "dual-quaternion kinematics",
    ("losses", "flow"): "the trajectory bone constraint is evaluated on the integrator's time grid "
    "(flow.integrate.time_grid), one definition of the grid",
    ("track", "retarget"): "a tracked sequence's animation recovers joint rotations and skin weights as the rig "
    "does (retarget.rig.joint_motion, retarget.weights), one definition of each",
    ("losses", "measures"): "the distortion terms use the guarded normalisation of the measures "
    "(measures.normal_cycles.safe_normalize), one definition of the guard",
}

MAX_LINES = 500
LONG_MODULE_MARKER = re.compile(r"^\s*Over 500 lines:\s*\S", re.MULTILINE)

HEAVY_OPTIONAL = ("matplotlib", "pytetwild", "pyvista", "potpourri3d", "skimage")
GEOMETRY_FORBIDDEN = ("jax", "jaxlib", "equinox", "optax")


@dataclass(frozen=True)
class Import:
    """One imported module (or name of the root package) at one place of the source."""

    path: Path  # the importing file
    line: int
    source: str  # dotted name of the importing module
    target: str  # dotted name of the imported module
    name: str | None  # for `from ncflow import name` where name is not a submodule: the name

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(SRC.parent)}:{self.line}"


def _module_name(path: Path) -> tuple[str, bool]:
    """Dotted module name of a source file and whether it is a package's ``__init__``."""
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), True
    return ".".join(parts), False


def _is_module(dotted: str) -> bool:
    """Whether a dotted ncflow name is a module or package of the source tree."""
    base = SRC.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _resolve(module: str, is_package: bool, level: int, name: str | None) -> str:
    """Absolute module named by a (possibly relative) ``from`` import."""
    if level == 0:
        return name or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def collect_imports() -> list[Import]:
    """Every import of an ncflow module in the source tree, wherever it stands in the file."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module, is_package = _module_name(path)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    found.append(Import(path, node.lineno, module, alias.name, None))
            elif isinstance(node, ast.ImportFrom):
                target = _resolve(module, is_package, node.level, node.module)
                for alias in node.names:
                    child = f"{target}.{alias.name}"
                    if alias.name != "*" and _is_module(child):
                        found.append(Import(path, node.lineno, module, child, None))
                    elif target == ROOT:
                        found.append(Import(path, node.lineno, module, target, alias.name))
                    else:
                        found.append(Import(path, node.lineno, module, target, None))
    return [imp for imp in found if imp.target == ROOT or imp.target.startswith(ROOT + ".")]


def package_of(dotted: str) -> str:
    """The layer unit of a dotted module name: its second component, or the root package itself."""
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 else ROOT


def rule_violation(imp: Import) -> str | None:
    """Why an import breaks the import rule, or None when it respects it."""
    src, dst = package_of(imp.source), package_of(imp.target)
    if src == dst or src in UNRESTRICTED:
        return None
    if src == LEAF:
        return f"`{LEAF}` is a leaf and imports nothing of ncflow (imports {imp.target})"
    if dst == LEAF:
        return None
    if dst == ROOT:
        if imp.name in ROOT_NAMES_ALLOWED:
            return None
        return (
            f"takes `{imp.name}` from the root package `ncflow`, which imports everything; "
            f"import it from the module that defines it"
        )
    if dst == "__main__":
        return "imports ncflow.__main__"
    for package in (src, dst):
        if package not in LAYERS:
            return f"package `{package}` has no layer: add it to LAYERS in tests/test_architecture.py"
    if src == "synthetic":
        if dst in SYNTHETIC_MAY_IMPORT:
            return None
        return f"`synthetic` may import only {sorted(SYNTHETIC_MAY_IMPORT)} (imports {imp.target})"
    if LAYERS[dst] < LAYERS[src]:
        return None
    if LAYERS[dst] == LAYERS[src]:
        if (src, dst) in SAME_LAYER_ALLOWED:
            return None
        return (
            f"`{src}` and `{dst}` are both layer {LAYERS[src]} and may not import each other "
            f"(imports {imp.target}; see SAME_LAYER_ALLOWED)"
        )
    return f"`{src}` (layer {LAYERS[src]}) imports `{dst}` (layer {LAYERS[dst]}): imports go one way ({imp.target})"


@pytest.fixture(scope="module")
def imports() -> list[Import]:
    found = collect_imports()
    assert len(found) > 50, "the import scan found almost nothing: is SRC right?"
    return found


def test_resolver_on_known_cases():
    # relative imports: from a module and from a package __init__
    assert _resolve("ncflow.io.gltf.skins", False, 1, "document") == "ncflow.io.gltf.document"
    assert _resolve("ncflow.io.gltf.skins", False, 2, "meshes") == "ncflow.io.meshes"
    assert _resolve("ncflow.io.gltf", True, 1, "skins") == "ncflow.io.gltf.skins"
    assert _resolve("ncflow.io.gltf", True, 2, None) == "ncflow.io"
    assert _resolve("ncflow.tissue", False, 1, "errors") == "ncflow.errors"
    assert package_of("ncflow.geometry.skeleton") == "geometry"
    assert package_of("ncflow.tissue") == "tissue"
    assert package_of("ncflow") == ROOT
    assert _is_module("ncflow.io.gltf") and _is_module("ncflow.losses") and not _is_module("ncflow.Mesh")


def test_scan_sees_function_local_and_type_checking_imports(tmp_path, monkeypatch):
    fake = tmp_path / "ncflow"
    (fake / "geometry").mkdir(parents=True)
    (fake / "__init__.py").write_text("__version__ = '0'\n")
    (fake / "errors.py").write_text("")
    (fake / "geometry" / "__init__.py").write_text("")
    (fake / "geometry" / "mesh.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    from ncflow.matcher import steps\n"
        "def f():\n"
        "    from ..cli import main\n"
        "    from ncflow import errors, __version__, Mesh\n"
        "class A:\n"
        "    import ncflow.io.meshes\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "SRC", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    got = {(imp.line, imp.target, imp.name) for imp in collect_imports()}
    assert got == {
        (3, "ncflow.matcher", None),  # `steps` is no file of the fake tree, so the package is the target
        (5, "ncflow.cli", None),
        (6, "ncflow.errors", None),
        (6, "ncflow", "__version__"),
        (6, "ncflow", "Mesh"),
        (8, "ncflow.io.meshes", None),
    }
    verdicts = {(imp.line, imp.name): rule_violation(imp) for imp in collect_imports()}
    assert verdicts[6, None] is None and verdicts[6, "__version__"] is None  # errors, and the version
    assert "root package" in verdicts[6, "Mesh"]
    assert "`geometry` (layer 0) imports `matcher` (layer 4)" in verdicts[3, None]
    assert "`geometry` (layer 0) imports `cli` (layer 7)" in verdicts[5, None]
    assert "`geometry` (layer 0) imports `io` (layer 1)" in verdicts[8, None]


def test_imports_go_one_way(imports):
    broken = sorted(
        {(str(imp.path), imp.line, f"{imp.where}: {why}") for imp in imports if (why := rule_violation(imp))}
    )
    assert not broken, "import rule broken:\n" + "\n".join(message for _, _, message in broken)


def test_same_layer_allow_list_is_used_and_same_layer(imports):
    used = {(package_of(imp.source), package_of(imp.target)) for imp in imports}
    for src, dst in SAME_LAYER_ALLOWED:
        assert LAYERS[src] == LAYERS[dst], f"{src} -> {dst} in SAME_LAYER_ALLOWED is not a same-layer edge"
    stale = sorted(edge for edge in SAME_LAYER_ALLOWED if edge not in used)
    assert not stale, f"SAME_LAYER_ALLOWED entries no import uses any more, remove them: {stale}"


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of a directed graph as a closed list of nodes, or None when the graph is acyclic."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_find_cycle_on_small_graphs():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set(), "d": {"d"}}) == ["d", "d"]


def test_package_graph_is_acyclic(imports):
    graph: dict[str, set[str]] = {}
    where: dict[tuple[str, str], str] = {}
    for imp in imports:
        src, dst = package_of(imp.source), package_of(imp.target)
        if src == dst or src in UNRESTRICTED or dst in UNRESTRICTED:
            continue
        graph.setdefault(src, set()).add(dst)
        where.setdefault((src, dst), imp.where)
    cycle = _find_cycle(graph)
    assert cycle is None, "package import cycle: " + ", ".join(
        f"{a} -> {b} ({where[a, b]})" for a, b in zip(cycle, cycle[1:])
    )


def test_geometry_is_pure_numpy():
    offenders = []
    for path in sorted((PACKAGE / "geometry").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            offenders += [
                f"{path.relative_to(SRC.parent)}:{node.lineno}: imports {name}"
                for name in names
                if name.split(".")[0] in GEOMETRY_FORBIDDEN
            ]
    assert not offenders, "geometry/ is pure NumPy:\n" + "\n".join(offenders)


def test_modules_are_short_or_say_why():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        lines = len(text.splitlines())
        if lines <= MAX_LINES:
            continue
        docstring = ast.get_docstring(ast.parse(text)) or ""
        if not LONG_MODULE_MARKER.search(docstring):
            offenders.append(f"{path.relative_to(SRC.parent)}: {lines} lines")
    assert not offenders, (
        f"modules over {MAX_LINES} lines without a line 'Over 500 lines: <reason>' in their docstring "
        "(split them, or give the reason):\n" + "\n".join(offenders)
    )


def test_long_module_marker():
    assert LONG_MODULE_MARKER.search("Write files.\n\nOver 500 lines: one format, one reader and its writer.")
    assert not LONG_MODULE_MARKER.search("Write files.\n\nOver 500 lines:")
    assert not LONG_MODULE_MARKER.search("Write files; the reader is over 500 lines: no.")


def test_import_ncflow_leaves_heavy_optional_dependencies_alone():
    code = (
        "import sys, ncflow\n"
        f"print(' '.join(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY_OPTIONAL!r}))))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    loaded = run.stdout.split()
    assert not loaded, f"`import ncflow` imports {loaded}: import them inside the functions that use them"
