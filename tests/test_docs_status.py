"""The status page lists the four statuses and every reason, from the enums.

``docs/conf.py`` writes ``docs/_generated/status_tables.rst`` from
:func:`dtalign.pipeline.status._doc_tables` at each build and
``docs/status.rst`` includes it; the committed copy must equal what the
enums give now, and every status and reason must have its meaning.
"""

from __future__ import annotations

from pathlib import Path

from dtalign.pipeline.status import (
    REASON_MEANING,
    SEVERITY,
    STATUS_MEANING,
    FitReason,
    FitStatus,
    _doc_tables,
)

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_every_status_and_reason_has_a_meaning_and_a_severity():
    assert set(STATUS_MEANING) == set(FitStatus) and len(FitStatus) == 4
    assert set(REASON_MEANING) == set(FitReason) == set(SEVERITY)


def test_the_committed_tables_are_the_enums_tables():
    committed = (DOCS / "_generated" / "status_tables.rst").read_text(encoding="utf-8")
    assert committed == _doc_tables(), "regenerate: build the docs (docs/conf.py writes it)"
    for status in FitStatus:
        assert f"   * - ``{status.value}``" in committed
    for reason in FitReason:
        assert f"   * - ``{reason.value}``" in committed


def test_the_status_page_includes_them_and_says_four():
    page = (DOCS / "status.rst").read_text(encoding="utf-8")
    assert ".. include:: _generated/status_tables.rst" in page
    assert "one\nof four strings" in page or "one of four strings" in page
    assert "of three strings" not in page


def test_the_guide_says_how_to_choose_vertex_sigmas():
    guide = (DOCS / "guide.rst").read_text(encoding="utf-8")
    assert "Choosing the vertex sigmas" in guide
