"""The declared dependency floors are the ones CI installs and tests.

``pyproject.toml`` declares ``name>=X`` for each runtime dependency;
``.ci/floors.txt`` pins ``name==X`` for CI's floor step and ``nox -s
floors``. A floor raised in one place and not the other would be a floor
nobody tests.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pins() -> dict[str, str]:
    lines = (ROOT / ".ci" / "floors.txt").read_text(encoding="utf-8").splitlines()
    pins = [line.split("#")[0].strip() for line in lines]
    return dict(p.split("==") for p in pins if p)


def _release(version: str) -> tuple[int, ...]:
    """``"2.2"`` and ``"2.2.0"`` alike: (2, 2, 0)."""
    parts = tuple(int(x) for x in version.split("."))
    return parts + (0,) * (3 - len(parts))


@pytest.mark.skipif(not (ROOT / "pyproject.toml").is_file(), reason="no source checkout")
def test_declared_floors_are_the_pinned_ones() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = {}
    for dep in project["dependencies"]:
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)>=([0-9.]+)", dep)
        assert m, f"{dep!r}: every runtime dependency declares a floor, as name>=X"
        declared[m[1]] = _release(m[2])
    assert declared == {name: _release(v) for name, v in _pins().items()}
    assert project["requires-python"] == ">=3.11"


def test_running_at_or_above_the_floors() -> None:
    """What this process runs on satisfies the declared floors (Python included)."""
    import importlib.metadata

    assert sys.version_info >= (3, 11)
    if not (ROOT / ".ci" / "floors.txt").is_file():
        pytest.skip("no source checkout")
    for name, floor in _pins().items():
        have = importlib.metadata.version(name)
        assert tuple(map(int, re.findall(r"\d+", have)[:3])) >= _release(floor), (
            f"{name} {have} is below the declared floor {floor}"
        )
