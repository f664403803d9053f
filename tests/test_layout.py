"""The package layout's rules, read from the source with :mod:`ast`.

* no import cycle in the graph of modules, counting the imports inside
  functions (lazy imports form cycles too);
* no module inside the package imports the package root (``import
  dtalign``, ``from dtalign import x``, ``from .. import x`` reaching the
  root): it imports the submodule by its path;
* no private (underscore) name crosses a subpackage boundary, neither
  imported (``from ..api.lm import _fit``) nor read off an imported module
  (``lm._fit``), except the private names the root re-exports (:ref:`contract-private`);
* the benchmark runner (``dtalign.benchmarking``) uses only public
  modules and names outside itself;
* dependencies point down: ``_kernels`` imports no layer above it, ``api``
  neither ``pipeline`` nor ``io``, and ``io.files`` not ``io.cassini``;
* no layer skips one: only ``api`` imports ``_kernels``.

A "unit" is the first name under ``dtalign`` (``api``, ``pipeline``,
``_kernels``, ``cli``, ...): a boundary is crossed when two modules' units differ.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "dtalign"

#: :ref:`contract-private`: private names importable from the package root.
SPEC_PRIVATE = {"_rotate_vertices", "_rotate_directions", "_INFINITY_DT_PENALTY_PX"}


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _modules() -> dict[str, tuple[Path, bool]]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, is_package)
    return out


MODULES = _modules()


def _unit(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2])


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


class _Import:
    """One imported name: the module it comes from and what it binds."""

    def __init__(self, target: str, name: str | None, bound: str, line: int,
                 from_root: bool = False) -> None:
        self.target = target  # the module imported (a submodule for ``from pkg import mod``)
        self.name = name  # the attribute imported from ``target``, or None for a module
        self.bound = bound  # the local name
        self.line = line
        self.from_root = from_root  # written ``from dtalign import ...`` / ``from .. import ...``


def _imports(module: str) -> list[_Import]:
    path, is_package = MODULES[module]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "dtalign":
                    bound = alias.asname or alias.name.split(".")[0]
                    out.append(_Import(alias.name, None, bound, node.lineno))
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, is_package, node)
            if target.split(".")[0] != "dtalign":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                bound = alias.asname or alias.name
                if sub in MODULES:  # ``from pkg import submodule``: an edge to the submodule
                    out.append(_Import(sub, None, bound, node.lineno, target == "dtalign"))
                else:
                    out.append(_Import(target, alias.name, bound, node.lineno))
    return out


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for module in MODULES:
        edges = set()
        for imp in _imports(module):
            if imp.target in MODULES and imp.target != module:
                edges.add(imp.target)
        graph[module] = edges
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_sees_lazy_imports():
    # pipeline.fit imports pipeline.jobs inside a function: an edge all the same
    assert "dtalign.pipeline.jobs" in _graph()["dtalign.pipeline.fit"]


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_the_package_root():
    offenders = [
        f"{module}:{imp.line}"
        for module in MODULES
        if module != "dtalign"
        for imp in _imports(module)
        if imp.target == "dtalign" or imp.from_root
    ]
    assert offenders == []


def test_no_module_imports_the_root_by_name_either():
    # importlib.import_module("dtalign") would dodge the import statements above
    found = []
    for module, (path, _) in MODULES.items():
        if module == "dtalign":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and node.args
                    and isinstance(node.args[0], ast.Constant) and node.args[0].value == "dtalign"
                    and getattr(node.func, "attr", getattr(node.func, "id", "")) in
                    ("import_module", "__import__")):
                found.append(f"{module}:{node.lineno}")
    assert found == []


def _module_aliases(module: str) -> dict[str, str]:
    """Local names bound to a module of the package, and which module."""
    return {imp.bound: imp.target for imp in _imports(module)
            if imp.name is None and imp.target in MODULES}


def _private_crossings(module: str) -> list[str]:
    found = []
    unit = _unit(module)
    for imp in _imports(module):
        if imp.name is not None and _is_private(imp.name) and _unit(imp.target) != unit:
            if module == "dtalign" and imp.name in SPEC_PRIVATE:
                continue
            found.append(f"{module}:{imp.line} imports {imp.target}.{imp.name}")
    aliases = {bound: target for bound, target in _module_aliases(module).items()
               if _unit(target) != unit}
    tree = ast.parse(MODULES[module][0].read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and _is_private(node.attr)):
            found.append(f"{module}:{node.lineno} reads {aliases[node.value.id]}.{node.attr}")
    return found


def test_no_private_name_crosses_a_subpackage_boundary():
    assert [c for module in MODULES for c in _private_crossings(module)] == []


def test_the_spec_private_names_stay_importable_from_the_root():
    import dtalign

    for name in SPEC_PRIVATE:
        assert getattr(dtalign, name) is not None


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _unit(m) == "dtalign.benchmarking"))
def test_the_benchmark_runner_uses_only_public_api(module):
    outside = []
    for imp in _imports(module):
        if _unit(imp.target) == "dtalign.benchmarking":
            continue
        parts = imp.target.split(".")[1:] + ([imp.name] if imp.name else [])
        if any(_is_private(p) for p in parts):
            outside.append(f"{module}:{imp.line} {imp.target} {imp.name or ''}")
    tree = ast.parse(MODULES[module][0].read_text(encoding="utf-8"))
    aliases = {bound: target for bound, target in _module_aliases(module).items()
               if _unit(target) != "dtalign.benchmarking"}
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and _is_private(node.attr)):
            outside.append(f"{module}:{node.lineno} {aliases[node.value.id]}.{node.attr}")
    assert outside == []


#: unit -> units it must not import (dependencies point down).
FORBIDDEN = {
    "dtalign._kernels": {"dtalign.api", "dtalign.pipeline", "dtalign.io", "dtalign.reference",
                         "dtalign.archive", "dtalign.cli", "dtalign.benchmarking"},
    "dtalign.api": {"dtalign.pipeline", "dtalign.io", "dtalign.reference", "dtalign.archive",
                    "dtalign.cli", "dtalign.benchmarking", "dtalign.plotting"},
    "dtalign.pipeline": {"dtalign.archive", "dtalign.cli", "dtalign.benchmarking",
                         "dtalign.plotting"},
    "dtalign.io": {"dtalign.pipeline", "dtalign.archive", "dtalign.cli", "dtalign.benchmarking"},
    "dtalign.reference": {"dtalign.pipeline", "dtalign.io", "dtalign.archive", "dtalign.cli"},
}


def test_dependencies_point_down():
    bad = []
    for module, edges in _graph().items():
        for target in edges:
            if _unit(target) in FORBIDDEN.get(_unit(module), ()):
                bad.append(f"{module} -> {target}")
    assert "dtalign.io.cassini" not in _graph()["dtalign.io.files"]
    assert sorted(bad) == []


def test_results_are_built_through_their_constructors():
    # no object.__new__ around the frozen results' __init__ / __post_init__
    found = []
    for module, (path, _) in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Attribute) and node.attr == "__new__"
                    and isinstance(node.value, ast.Name) and node.value.id == "object"):
                found.append(f"{module}:{node.lineno}")
    assert found == []


def test_dtalign_ridge_is_the_api_ridge_module():
    import dtalign.api.ridge
    import dtalign.ridge

    assert dtalign.ridge is dtalign.api.ridge
    assert dtalign.ridge.gradient_ridge_refine is dtalign.gradient_ridge_refine


# ---------------------------------------------------------------------------
# Layers without skipping: pipeline -> api -> _kernels. Only the
# api layer (and the kernels, and the compile helpers _jit/warmup/_numba_cache
# that exist to drive them) imports dtalign._kernels: the pipeline, the batch,
# I/O, the command line, the campaign, the benchmark runner and the NumPy
# reference reach compiled work through dtalign.api (dtalign.api.loop for what
# is no drop-in stage); the reference may read a kernel module's constants
# (the numbers both implementations share) and nothing else.
# ---------------------------------------------------------------------------

#: Modules that may import the kernels: the api layer, the kernels, and the
#: modules whose job is compiling them.
ALLOWED = ("dtalign.api", "dtalign._kernels", "dtalign._jit", "dtalign.warmup",
           "dtalign._numba_cache")


def _kernel_imports(path: Path, module: str, is_package: bool) -> set[str]:
    """Every module and ``module.name`` imported; constants (upper-case names)
    imported into the reference are left out."""
    reference = module.startswith("dtalign.reference")
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parts = module.split(".")
                if not is_package:
                    parts = parts[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            names = [a.name for a in node.names]
            if reference and all(n.isupper() for n in names):
                continue
            out.add(base)
            out.update(f"{base}.{n}" for n in names)
    return out


def _kernel_importers() -> list[str]:
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        module = ".".join(parts[:-1] if is_package else parts)
        if module.startswith(ALLOWED):
            continue
        hits = sorted(t for t in _kernel_imports(path, module, is_package)
                      if t == "dtalign._kernels" or t.startswith("dtalign._kernels."))
        if hits:
            bad.append(f"{module} -> {hits[0]}")
    return bad


def test_only_the_api_layer_imports_the_kernels():
    assert _kernel_importers() == []


def test_the_rule_sees_a_skipping_import(tmp_path, monkeypatch):
    pkg = tmp_path / "dtalign" / "pipeline"
    pkg.mkdir(parents=True)
    (pkg / "x.py").write_text("def f():\n    from .._kernels import coarse\n", encoding="utf-8")
    monkeypatch.setitem(globals(), "SRC", tmp_path)
    monkeypatch.setitem(globals(), "PACKAGE", tmp_path / "dtalign")
    assert _kernel_importers() == ["dtalign.pipeline.x -> dtalign._kernels"]
