"""No function in the package is longer than a reader can hold at once.

Measured with :mod:`ast` on every function and method under ``src/dtalign``
except the compiled kernels (``_kernels/``) and the plain NumPy specification
(``reference/``), whose long bodies follow the numbered steps of the contract.

The rule, precisely: a function's *body length* is the number of source lines
from the first line of its first statement after the docstring (a decorated
nested function starts at its first decorator) to the function's last line
(``end_lineno``), both included. Blank lines and comments inside that span
count; the signature, the decorators and the docstring do not. A nested
function or class counts within its parent, and is measured on its own too.
A function that is only a docstring has length 0.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "dtalign"

#: The longest body allowed, in lines (issue 29).
MAX_BODY_LINES = 60

#: Folders left out: the kernels and the NumPy specification.
EXCLUDED = ("_kernels/", "reference/")

#: Functions allowed to stay longer for now, as ``path:qualname``, each to be
#: split and removed from here by the work that owns its module.
ALLOWED: set[str] = set()


def _first_line(stmt: ast.stmt) -> int:
    decorators = getattr(stmt, "decorator_list", None) or []
    return min([stmt.lineno] + [d.lineno for d in decorators])


def body_length(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the end."""
    body = node.body
    first = body[0]
    if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            and isinstance(first.value.value, str)):
        body = body[1:]
    if not body:
        return 0
    assert node.end_lineno is not None
    return node.end_lineno - _first_line(body[0]) + 1


def _functions(tree: ast.AST, prefix: str = ""):
    """``(qualname, node)`` for every function and method below ``tree``."""
    for child in ast.iter_child_nodes(tree):
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
            yield prefix + child.name, child
            yield from _functions(child, f"{prefix}{child.name}.")
        elif isinstance(child, ast.ClassDef):
            yield from _functions(child, f"{prefix}{child.name}.")
        else:
            yield from _functions(child, prefix)


def measure() -> dict[str, int]:
    """``path:qualname`` -> body length, for every function measured."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel.startswith(EXCLUDED):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for qualname, node in _functions(tree):
            out[f"{rel}:{qualname}"] = body_length(node)
    return out


LENGTHS = measure()


def test_the_rule_counts_what_it_says() -> None:
    source = (
        "def f(a,\n"
        "      b):\n"
        '    """Doc.\n'
        '\n'
        '    More doc."""\n'
        "    x = 1\n"
        "\n"
        "    # a comment\n"
        "    @staticmethod\n"
        "    def g():\n"
        '        """Only a docstring."""\n'
        "    return x\n"
        "def h(): pass\n"
    )
    names = dict(_functions(ast.parse(source)))
    assert body_length(names["f"]) == 7  # lines 6 to 12
    assert body_length(names["f.g"]) == 0
    assert body_length(names["h"]) == 1


def test_every_module_is_measured() -> None:
    # The walk reaches methods, nested functions and subpackages.
    assert "cli.py:main" in LENGTHS
    assert "pipeline/fit.py:PolylineFit.to_dict" in LENGTHS
    assert not any(name.startswith(EXCLUDED) for name in LENGTHS)


def test_no_function_body_is_longer_than_the_limit() -> None:
    long = {name: n for name, n in LENGTHS.items()
            if n > MAX_BODY_LINES and name not in ALLOWED}
    assert not long, (
        f"function bodies over {MAX_BODY_LINES} lines (docstring excluded); "
        f"split them into named steps: {dict(sorted(long.items()))}"
    )


def test_the_allow_list_holds_only_long_functions() -> None:
    # An entry that is gone or has become short is taken off the list.
    stale = {name: LENGTHS.get(name) for name in ALLOWED
             if LENGTHS.get(name, 0) <= MAX_BODY_LINES}
    assert not stale, f"take these off ALLOWED: {stale}"
