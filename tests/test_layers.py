"""Layers without skipping (issue 29): pipeline -> api -> ``_kernels``.

Only the api layer (and the kernels themselves, and the compile helpers
``_jit``/``warmup`` that exist to drive them) import ``dtalign._kernels``
(the NumPy reference may read a kernel module's constants, the numbers
both implementations share, and nothing else):
the pipeline, the batch, I/O, the command line, the campaign, the
benchmark runner and the plain-NumPy reference reach compiled work through
``dtalign.api`` (:mod:`dtalign.api.loop` for what is no drop-in stage).
Read from the source with :mod:`ast`, imports inside functions included.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "dtalign"

#: Modules that may import the kernels: the api layer, the kernels, and the
#: modules whose job is compiling them.
ALLOWED = ("dtalign.api", "dtalign._kernels", "dtalign._jit", "dtalign.warmup",
           "dtalign._numba_cache")


def _imports(path: Path, module: str, is_package: bool) -> set[str]:
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
        hits = sorted(t for t in _imports(path, module, is_package)
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
