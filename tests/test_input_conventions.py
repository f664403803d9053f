"""How inputs are read: colour images, scalar sigmas, the default search window.

* Colour: one rule for the library and the command line
  (:mod:`dtalign.api.colour`): equal channels are read as grey with an
  INFO note, other colour images as their luma with a WARNING, and the
  command line says which it did.
* A scalar sigma applies to every vertex in the pipeline functions (not in
  the drop-in ``lm_subpixel_refine``, whose contract is per vertex).
* The search window has one documented default, the same in Python and on
  the command line.

The command line's pairs of numbers (one word, joined by a comma) are
checked in ``tests/test_cli.py``.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.io import load_image, read_image, save_polyline_csv
from dtalign.pipeline import DEFAULT_SEARCH_WINDOW_VU, fit_polyline, prepare_image
from dtalign.pipeline.batch import fit_many

TRUE = (3.4, -2.2)


@pytest.fixture(scope="module")
def scene():
    return scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=TRUE)


def _python_m(*argv, cwd):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(dtalign.__file__).resolve().parents[1])
    return subprocess.run([sys.executable, "-m", "dtalign", *argv], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


def _rgb(grey, red_line=False):
    """The grey image as 8-bit RGB, optionally with a red overlay line on it."""
    g = np.clip(grey, 0, 255).astype(np.uint8)
    rgb = np.stack([g, g, g], axis=-1)
    if red_line:
        rgb[100, 20:180] = (255, 0, 0)
    return rgb


# --------------------------------------------------------------------------- colour


def test_a_grey_image_saved_as_rgb_fits_as_grey_with_an_info_note(scene, caplog):
    caplog.set_level(logging.INFO, logger="dtalign")
    p = scene.polyline
    rgb = _rgb(scene.image + 100.0)
    grey = rgb[..., 1].astype(np.float64)
    fit = fit_polyline(rgb, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8))
    same = fit_polyline(grey, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8))
    assert fit.offset_vu == same.offset_vu  # exactly the grey values
    notes = [r for r in caplog.records if "equal channels" in r.getMessage()]
    assert len(notes) == 1 and notes[0].levelno == logging.INFO


def test_a_colour_image_is_converted_to_luma_with_a_warning_in_python_and_in_io(
        scene, caplog, tmp_path):
    pytest.importorskip("PIL")
    from PIL import Image

    caplog.set_level(logging.INFO, logger="dtalign")
    rgb = _rgb(scene.image + 100.0, red_line=True)
    products = prepare_image(rgb, 2.0)
    expected = rgb[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    assert products.shape == rgb.shape[:2]
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "luma" in warned[0].getMessage()
    assert "overlay" in warned[0].getMessage()
    # the file reader applies the same rule, and says so the same way
    Image.fromarray(rgb).save(tmp_path / "c.png")
    image, note = read_image(tmp_path / "c.png")
    assert note is not None and note.luma and np.allclose(image, expected)
    caplog.clear()
    assert np.array_equal(load_image(tmp_path / "c.png"), image)
    assert [r.levelno for r in caplog.records if "luma" in r.getMessage()] == [logging.WARNING]


def test_the_cli_says_what_it_did_with_a_colour_image(scene, tmp_path):
    pytest.importorskip("PIL")
    from PIL import Image

    p = scene.polyline
    save_polyline_csv(tmp_path / "disc.csv", p)
    Image.fromarray(_rgb(scene.image + 100.0)).save(tmp_path / "grey.png")
    Image.fromarray(_rgb(scene.image + 100.0, red_line=True)).save(tmp_path / "red.png")
    proc = _python_m("fit", "grey.png", "disc.csv", "--window", "8", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "dtalign: note: image grey.png: RGB with equal channels, read as its grey values" \
        in proc.stderr
    proc = _python_m("fit", "red.png", "disc.csv", "--window", "8", cwd=tmp_path)
    assert "dtalign: warning: image red.png: colour RGB image converted to grey (luma" \
        in proc.stderr
    assert proc.stderr.count("luma") == 1  # said once, not by the library a second time


# --------------------------------------------------------------------------- sigmas, window


def test_a_scalar_sigma_applies_to_every_vertex(scene):
    p = scene.polyline
    products = prepare_image(scene.image, scene.noise_sigma)
    full = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, np.full(len(p), 0.7),
                        search_window_vu=(8, 8))
    one = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, 0.7, search_window_vu=(8, 8))
    assert one.offset_vu == full.offset_vu
    assert np.array_equal(one.covariance, full.covariance)
    many = fit_many(products, [(p.vertices_vu, p.normals_vu, 0.7)] * 2, search_window_vu=(8, 8))
    assert [f.offset_vu for f in many] == [
        fit_many(products, [(p.vertices_vu, p.normals_vu, np.full(len(p), 0.7))],
                 search_window_vu=(8, 8))[0].offset_vu] * 2
    with pytest.raises(ValueError, match="sigmas"):
        fit_polyline(scene.image, p.vertices_vu, p.normals_vu, -1.0, search_window_vu=(8, 8))
    with pytest.raises((TypeError, ValueError), match="sigmas"):
        fit_polyline(scene.image, p.vertices_vu, p.normals_vu, True, search_window_vu=(8, 8))


def test_the_drop_in_lm_keeps_its_per_vertex_sigmas(scene):
    p = scene.polyline
    products = prepare_image(scene.image, scene.noise_sigma)
    with pytest.raises(ValueError):
        dtalign.lm_subpixel_refine(
            vertices_vu=p.vertices_vu, normals_vu=p.normals_vu, sigma_normal_per_vertex_px=0.7,
            image_edge_dt=products.edge_dt, image_gradient_vu=products.gradient_vu)


def test_one_documented_default_window_in_python_and_on_the_cli(scene):
    # the window is an option of the call: one default, FitOptions', which
    # the command line's --window shows
    assert dtalign.FitOptions().search_window_vu == DEFAULT_SEARCH_WINDOW_VU == (30, 30)
    assert "(30, 30)" in (dtalign.FitOptions.__doc__ or "")
    from dtalign.cli import build_parser

    assert "default 30,30" in build_parser()._subparsers._group_actions[0].choices[
        "fit"].format_help().replace("\n", " ").replace("  ", " ")
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas)
    assert fit.search_window_vu == (30, 30)
    assert np.allclose(fit.offset_vu, TRUE, atol=0.2)
