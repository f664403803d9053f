"""The command-line output the docs show is the output the program prints.

``docs/cli.rst`` and ``docs/status.rst`` (its line-by-line reading) each
show ``dtalign demo --repeat 2`` with its output. The command is taken from
the block's ``$`` line, run in-process, and its standard output compared
with the block line for line. Only the stage times of the ``wall time``
line are normalised (each ``12.3 ms`` becomes ``<t> ms``): they are
measured wall-clock times and differ from run to run. Every other figure
(the noise estimate, the pose, its sigmas, the iteration count, the
status) is deterministic for a fixed seed and must match as printed.

The HTML layout that shows such lines whole is checked here as well: the
theme's page leaves room for the widest of these output lines.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from dtalign.cli import main

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = ("cli.rst", "status.rst")

#: A measured stage time of the ``wall time`` line, e.g. ``34.7 ms``.
STAGE_TIME = re.compile(r"\d+(?:\.\d+)? ms\b")


def console_blocks(text: str) -> list[list[str]]:
    """The dedented lines of each ``.. code-block:: console`` directive of an rst page."""
    blocks = []
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not re.match(r"\s*\.\. code-block:: console\s*$", line):
            continue
        body: list[str] = []
        for raw in lines[i + 1:]:
            if raw.strip() and not raw.startswith((" ", "\t")):
                break
            body.append(raw)
        while body and not body[0].strip():
            body.pop(0)
        while body and not body[-1].strip():
            body.pop()
        indent = min(len(x) - len(x.lstrip()) for x in body if x.strip())
        blocks.append([x[indent:] for x in body])
    return blocks


def demo_blocks(page: str) -> list[tuple[list[str], list[str]]]:
    """``(argv, output lines)`` of each block of a page that runs ``dtalign demo`` and shows its output."""
    out = []
    for block in console_blocks((DOCS / page).read_text(encoding="utf-8")):
        command = block[0]
        if command.startswith("$ dtalign demo") and len(block) > 1 and "--save" not in command:
            out.append((shlex.split(command[2:])[1:], block[1:]))
    return out


def normalised(lines: list[str]) -> list[str]:
    """The lines with the ``wall time`` line's stage times replaced: they vary run to run."""
    return [STAGE_TIME.sub("<t> ms", x) if x.startswith("wall time") else x for x in lines]


def test_the_normalisation_touches_stage_times_only():
    lines = ["fitted    : dv = 7.2821 ± 0.0504 px",
             "wall time : derivatives 34.7 ms, coarse 0.3 ms, lm 12 ms"]
    assert normalised(lines) == [lines[0], "wall time : derivatives <t> ms, coarse <t> ms, lm <t> ms"]


@pytest.mark.parametrize("page", PAGES)
def test_each_page_shows_the_demo(page):
    (argv, shown), = demo_blocks(page)
    assert argv == ["demo", "--repeat", "2"]
    assert shown[0].startswith("scene     : ") and shown[-1].startswith("wall time : ")


@pytest.fixture(scope="module")
def demo_output() -> dict[tuple[str, ...], list[str]]:
    """The demo's printed lines, per argument list, run once each."""
    return {}


@pytest.mark.parametrize("page", PAGES)
def test_documented_demo_output_is_the_real_output(page, demo_output, capsys):
    (argv, shown), = demo_blocks(page)
    key = tuple(argv)
    if key not in demo_output:
        capsys.readouterr()
        assert main(list(argv)) == 0
        demo_output[key] = capsys.readouterr().out.rstrip("\n").splitlines()
    assert normalised(shown) == normalised(demo_output[key])


# --------------------------------------------------------------------------- the page fits them

#: alabaster's sidebar and body padding, the code block's padding
#: (docs/_static/dtalign.css) and a 14px monospace character, in px.
SIDEBAR_PX, BODY_PADDING_PX, PRE_PADDING_PX, CHARACTER_PX = 220, 60, 24, 8.4


def _conf() -> dict[str, object]:
    conf: dict[str, object] = {"__file__": str(DOCS / "conf.py")}
    exec(compile((DOCS / "conf.py").read_text(encoding="utf-8"), str(DOCS / "conf.py"), "exec"), conf)
    return conf


def test_code_blocks_are_not_cut_at_80_columns():
    conf = _conf()
    options = conf["html_theme_options"]
    # the basic theme's 800px body cap left about 80 columns for a code block
    assert options["body_max_width"] == "none"
    assert "dtalign.css" in conf["html_css_files"]
    css = (DOCS / "_static" / "dtalign.css").read_text(encoding="utf-8")
    assert re.search(r"div\.body pre \{[^}]*white-space: pre;[^}]*overflow-x: auto;", css)
    assert "padding: 7px 12px;" in css and "font-size: 14px;" in css
    page_px = int(str(options["page_width"]).removesuffix("px"))
    columns = (page_px - SIDEBAR_PX - BODY_PADDING_PX - PRE_PADDING_PX) / CHARACTER_PX
    widest = max(len(x) for page in PAGES for _, shown in demo_blocks(page) for x in shown)
    assert widest > 80 and columns >= widest
