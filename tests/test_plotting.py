"""Plots of a fit: PNGs are written, non-empty, and matplotlib stays optional."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from dtalign import scenes
from dtalign.pipeline import fit_polyline, fit_polyline_products, prepare_image

matplotlib = pytest.importorskip("matplotlib")

from dtalign.plotting import plot_fit, plot_residual_histogram  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def outlier_fit():
    scene = scenes.disc_scene(
        shape=(256, 256), radius=60.0, n_vertices=120, offset_vu=(3.4, -2.2), outlier_fraction=0.1
    )
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(10, 10))
    return scene, fit


def _is_png(path):
    data = path.read_bytes()
    return len(data) > 5000 and data.startswith(PNG_MAGIC)


def test_plot_fit_writes_png(tmp_path, outlier_fit):
    scene, fit = outlier_fit
    assert fit.tukey_rejected.any() and fit.polarity_rejected.any()  # both markers drawn
    out = tmp_path / "fit.png"
    fig = plot_fit(scene.image, scene.polyline.vertices_vu, fit, out)
    assert _is_png(out)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("Tukey-rejected" in t for t in labels)
    assert any("polarity-rejected" in t for t in labels)
    assert any("covariance ellipse ×" in t for t in labels)


def test_plot_fit_rank_deficient_and_no_path(tmp_path):
    scene = scenes.navigation_scene(shape=(300, 300), radius=50.0, n_vertices=80)
    ring = scene.polylines[2]
    fit = fit_polyline_products(
        prepare_image(scene.image, 2.0), ring.vertices_vu, ring.normals_vu, ring.sigmas,
        search_window_vu=(10, 10),
    )
    fig = plot_fit(scene.image, ring.vertices_vu, fit, title="ring")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "unobservable direction" in labels
    out = tmp_path / "ring.png"
    fig.savefig(out)
    assert _is_png(out)


def test_residual_histogram(tmp_path, outlier_fit):
    _, fit = outlier_fit
    out = tmp_path / "hist.png"
    plot_residual_histogram(fit, out, sigma_px=1.0)
    assert _is_png(out)


def test_plot_fit_checks_vertex_count(outlier_fit):
    scene, fit = outlier_fit
    with pytest.raises(ValueError, match="vertices"):
        plot_fit(scene.image, scene.polyline.vertices_vu[:10], fit)


def test_missing_matplotlib_message(monkeypatch, outlier_fit):
    scene, fit = outlier_fit
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ImportError, match="pip install matplotlib"):
        plot_fit(scene.image, scene.polyline.vertices_vu, fit)
    with pytest.raises(ImportError, match="pip install matplotlib"):
        plot_residual_histogram(fit)


def test_plotting_does_not_touch_pyplot_backend(outlier_fit):
    before = matplotlib.get_backend()
    scene, fit = outlier_fit
    plot_fit(scene.image, scene.polyline.vertices_vu, fit)
    assert matplotlib.get_backend() == before
    assert np.isfinite(fit.offset_vu).all()


@pytest.fixture(scope="module")
def scene():
    """A 200 x 200 disc of radius 50 px, its 100-vertex limb displaced by (3.4, -2.2) px."""
    return scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=(3.4, -2.2))


def test_plot_titles_lead_with_the_status(scene, tmp_path):
    pytest.importorskip("matplotlib")
    from dtalign.plotting import plot_fit

    p = scene.polyline
    bad = fit_polyline(scene.image, p.vertices_vu, -p.normals_vu, p.sigmas, search_window_vu=(8, 8))
    fig = plot_fit(scene.image, p.vertices_vu, bad)
    title = fig.axes[0].get_title()
    assert title.startswith("status FAILED (most_polarity_rejected")
    assert "no offset measured" in title and "±" not in title.splitlines()[1]
