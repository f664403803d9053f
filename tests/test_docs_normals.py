"""One normal convention: normals point to the bright side, and every text says so.

The polarity test keeps a vertex only where ``n . g > 0`` with ``g`` the
image gradient (dark -> bright), so a limb's normals point *into* the disc.
The guide's worked example (limb / terminator / ring of
``scenes.navigation_scene``) is checked against ``polarity_filter`` here, and
the README, the pages and the docstrings are checked not to say "outward".
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.io import load_polyline_csv
from dtalign.pipeline import fit_polyline_products

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "dtalign"


@pytest.fixture(scope="module")
def scene():
    return scenes.navigation_scene()


@pytest.fixture(scope="module")
def gradient(scene):
    return dtalign.compute_image_gradient_vu(scene.image)


def test_worked_example_directions(scene):
    limb, terminator, ring = scene.polylines
    h, w = scene.image.shape
    centre = np.array([(h - 1) / 2.0, (w - 1) / 2.0]) - np.asarray(scene.true_offset_vu)
    # limb: into the disc, toward its centre
    assert np.all(np.sum(limb.normals_vu * (centre - limb.vertices_vu), axis=1) > 0)
    # terminator of a body lit from +u: toward the day side (+u)
    assert np.all(terminator.normals_vu[:, 1] > 0)
    # upper edge of a band below it: into the band (+v, down the image)
    assert np.allclose(ring.normals_vu, [1.0, 0.0])


def test_bright_side_normals_pass_the_polarity_test(scene, gradient):
    for poly in scene.polylines:
        accepted = dtalign.polarity_filter(
            poly.vertices_vu, poly.normals_vu, gradient, offset_vu=scene.true_offset_vu
        )
        assert accepted.mean() > 0.95, poly.name
        flipped = dtalign.polarity_filter(
            poly.vertices_vu, -poly.normals_vu, gradient, offset_vu=scene.true_offset_vu
        )
        assert flipped.mean() < 0.05, poly.name


def test_outward_limb_normals_reject_every_vertex(scene):
    """What the guide warns about: flipped normals reject the vertices on the
    true edge; the fit lands where stray edges agree, and says so."""
    products = dtalign.prepare_image(scene.image, scene.noise_sigma)
    limb = scene.polylines[0]
    good = fit_polyline_products(products, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                                 search_window_vu=(30, 30))
    bad = fit_polyline_products(products, limb.vertices_vu, -limb.normals_vu, limb.sigmas,
                                search_window_vu=(30, 30))
    assert good.lm.inlier_count == len(limb) and good.status == "ok"
    assert 2 * bad.lm.polarity_rejected_count > len(limb)
    assert bad.status in ("suspect", "ambiguous", "failed")
    assert "wrong way" in bad.status_message
    # on the true edge, every vertex of the flipped limb is rejected
    shifted = limb.vertices_vu + np.round(scene.true_offset_vu)
    assert not dtalign.polarity_filter(shifted, -limb.normals_vu, products.gradient_vu).any()


def test_csv_example_in_the_cli_page_points_into_the_disc(tmp_path):
    """The CSV sample of docs/cli.rst: a vertex at the top of a disc, normal down."""
    text = (ROOT / "docs" / "cli.rst").read_text(encoding="utf-8")
    block = re.search(r"v,u,nv,nu,sigma\n((?:\s+[\d.,-]+\n)+)", text)
    assert block is not None
    path = tmp_path / "sample.csv"
    rows = [x.strip() for x in block.group(1).splitlines() if "," in x]
    path.write_text("v,u,nv,nu,sigma\n" + "\n".join(rows) + "\n")
    poly = load_polyline_csv(path)
    assert np.all(poly.normals_vu[:, 0] > 0.9)  # +v: down the image, into a disc below


# --------------------------------------------------------------------------- the texts


def _pages() -> dict[str, str]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.rst")),
             *sorted((ROOT / "docs" / "api").glob("*.rst"))]
    return {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in files}


def _docstrings() -> dict[str, str]:
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in [tree, *ast.walk(tree)]:
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node)
                if doc:
                    name = getattr(node, "name", "<module>")
                    out[f"{path.relative_to(ROOT)}:{name}"] = doc
    return out


OUTWARD_NORMAL = re.compile(r"outward\W+(?:\w+\W+){0,3}normal|normal\w*\W+(?:\w+\W+){0,4}outward", re.I)


def test_no_text_calls_the_normals_outward():
    texts = {**_pages(), **_docstrings()}
    offenders = [name for name, text in texts.items() if OUTWARD_NORMAL.search(" ".join(text.split()))]
    assert offenders == []


@pytest.mark.parametrize(
    "where",
    ["README.md", "docs/guide.rst", "docs/cli.rst", "docs/index.rst", "docs/contract.rst"],
)
def test_pages_state_the_convention(where):
    assert "bright side" in " ".join((ROOT / where).read_text(encoding="utf-8").split())


@pytest.mark.parametrize(
    "func",
    [
        dtalign.lm_subpixel_refine,
        dtalign.gradient_ridge_refine,
        dtalign.polarity_filter,
        dtalign.fit_polyline,
        dtalign.fit_polyline_products,
        load_polyline_csv,
    ],
    ids=lambda f: f.__name__,
)
def test_docstrings_state_the_convention(func):
    doc = " ".join((func.__doc__ or "").split())
    if func is dtalign.fit_polyline and "bright side" not in doc:
        doc = " ".join((fit_polyline_products.__doc__ or "").split())  # "as fit_polyline_products"
    assert "bright side" in doc
