"""The worked example of docs/upstream.rst runs and says what the page says."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

PAGE = Path(__file__).resolve().parent.parent / "docs" / "upstream.rst"


@pytest.mark.skipif(not PAGE.exists(), reason="docs not in this checkout")
def test_the_eight_step_example_runs():
    text = PAGE.read_text()
    block = text.split(".. code-block:: python\n\n", 1)[1]
    code = "\n".join(line[3:] for line in re.split(r"\n(?=\S)", block, maxsplit=1)[0].splitlines())
    namespace: dict = {}
    exec(compile(code, str(PAGE), "exec"), namespace)
    assert namespace["seed"].offset_vu == (7, -5)
    fit = namespace["fit"]
    assert abs(fit.offset_vu[0] - 7.3) < 0.1 and abs(fit.offset_vu[1] + 4.6) < 0.1
    assert namespace["rival"].distance_px > 3.0
    assert not namespace["spurious"]
    cap = namespace["verdict"].confidence_cap
    assert (cap is None) == fit.converged
