"""Issue 30, items 6 and 7: colour input, argument styles, scalar sigmas, the default window.

* Colour: one rule for the library and the command line
  (:mod:`dtalign.api.colour`): equal channels are read as grey with an
  INFO note, other colour images as their luma with a WARNING, and the
  command line says which it did.
* Pairs on the command line are one word joined by a comma everywhere; two
  words are refused with a message that shows the comma form.
* A scalar sigma applies to every vertex in the pipeline functions (not in
  the drop-in ``lm_subpixel_refine``, whose contract is per vertex).
* The search window has one documented default, the same in Python and on
  the command line.
"""

from __future__ import annotations

import inspect
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.cli import DEFAULT_WINDOW_PX, main
from dtalign.io import load_image, read_image, save_polyline_csv
from dtalign.pipeline import DEFAULT_SEARCH_WINDOW_VU, fit_polyline, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many

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


# --------------------------------------------------------------------------- arguments


@pytest.mark.parametrize(("argv", "written"), [
    (["overlay", "x.png", "--shape", "limb", "--image", "i.npy", "--polyline", "p.csv",
      "--displace", "3", "-2"], "--displace 3,-2, not --displace 3 -2"),
    (["fit", "a.npy", "a.csv", "--window", "30", "20"], "--window 30,20, not --window 30 20"),
    (["fit", "a.npy", "a.csv", "--plot", "x.png", "--zoom", "50", "100"],
     "--zoom 50,100, not --zoom 50 100"),
])
def test_two_word_pairs_are_refused_with_the_comma_form(argv, written, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "takes its two numbers as one word, joined by a comma" in err and written in err
    assert "odd number of files" not in err


def test_displace_takes_a_comma_pair_negative_first_too(tmp_path, capsys, monkeypatch):
    from dtalign.io import cassini

    # a stand-in frame and overlay: the option's parsing is what is tested
    monkeypatch.setattr(cassini, "load_cassini_overlay_frame", lambda path: _FakeFrame())
    monkeypatch.setattr(cassini, "overlay_polylines", lambda f, shape, n_lines: [
        scenes.Polyline("l", np.array([[10.0, 10.0], [10.0, 20.0], [20.0, 20.0]]),
                        np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.ones(3))])
    code = main(["overlay", "x.png", "--shape", "limb", "--image", str(tmp_path / "i.npy"),
                 "--polyline", str(tmp_path / "p.csv"), "--displace", "-2,3"])
    assert code == 0, capsys.readouterr().err
    from dtalign.io import load_polyline_csv

    moved = load_polyline_csv(tmp_path / "p.csv")
    assert np.allclose(moved.vertices_vu[0], (12.0, 7.0))  # moved by -(-2, 3)
    assert main(["overlay", "x.png", "--shape", "limb", "--image", str(tmp_path / "i.npy"),
                 "--polyline", str(tmp_path / "p.csv"), "--displace", "3"]) == 1
    assert "--displace takes two numbers separated by a comma (e.g. 3,-2)" \
        in capsys.readouterr().err


class _FakeFrame:
    image = np.zeros((30, 30))
    header_rows = 0


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
    assert DEFAULT_SEARCH_WINDOW_VU == (DEFAULT_WINDOW_PX, DEFAULT_WINDOW_PX) == (30, 30)
    for fn in (fit_polyline, dtalign.fit_polyline_products, fit_many, fit_images):
        default = inspect.signature(fn).parameters["search_window_vu"].default
        assert default == DEFAULT_SEARCH_WINDOW_VU, fn.__name__
        assert "(30, 30)" in (fn.__doc__ or ""), fn.__name__
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas)
    assert fit.search_window_vu == (30, 30)
    assert np.allclose(fit.offset_vu, TRUE, atol=0.2)


# --------------------------------------------------------------------------- item 8: small ones


def test_json_writes_infinite_sigmas_as_null_and_from_dict_round_trips(scene):
    import json

    from dtalign.pipeline import PolylineFit

    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8),
                       fit_rotation=True, max_iterations=3)  # a circle: rotation sigma inf
    d = fit.to_dict(arrays=True)
    text = json.dumps(d, allow_nan=False)  # strict JSON: no Infinity, no NaN
    assert d["sigma_rotation_rad"] is None and '"inf"' not in text
    back = PolylineFit.from_dict(json.loads(text))
    assert back.to_dict(arrays=True) == d
    assert back.status == fit.status and back.reasons == fit.reasons
    assert back.sigma_vu == fit.sigma_vu and back.sigma_rotation_rad == fit.sigma_rotation_rad
    with pytest.raises(ValueError, match="to_dict\\(arrays=True\\)"):
        PolylineFit.from_dict(fit.to_dict())


def test_plot_titles_lead_with_the_status(scene, tmp_path):
    pytest.importorskip("matplotlib")
    from dtalign.plotting import plot_fit

    p = scene.polyline
    bad = fit_polyline(scene.image, p.vertices_vu, -p.normals_vu, p.sigmas, search_window_vu=(8, 8))
    fig = plot_fit(scene.image, p.vertices_vu, bad)
    title = fig.axes[0].get_title()
    assert title.startswith("status FAILED (most_polarity_rejected")
    assert "no offset measured" in title and "±" not in title.splitlines()[1]


def test_bench_exits_1_when_a_row_fails(monkeypatch, capsys):
    import dtalign.benchmarking as bench

    rows = [{"name": "x", "passed": True}, {"name": "y", "passed": False}]
    monkeypatch.setattr(bench, "run", lambda *a, **k: {
        "rows": rows, "total_s": 1.0, "warmup_s": 0.0, "other_load_cores": 0.0,
        "all_passed": False})
    monkeypatch.setattr(bench, "format_table", lambda rows: "| table |")
    assert bench.main(["--quick"]) == 1
    assert "1 row(s) FAIL: exit status 1" in capsys.readouterr().err
    assert bench.main(["--quick", "--allow-fail"]) == 0
    rows[1]["passed"] = True
    assert bench.main(["--quick"]) == 0


def test_quantised_noise_estimate_is_said(caplog):
    from dtalign.pipeline.products import QUANTISED_NOISE_STEP, quantised_noise_steps

    assert quantised_noise_steps(0.4942) == 2.0  # both Cassini frames' estimate
    assert QUANTISED_NOISE_STEP * 2 == pytest.approx(0.4942, abs=1e-12)
    assert quantised_noise_steps(2.006) is None
    caplog.set_level(logging.INFO, logger="dtalign")
    rng = np.random.default_rng(0)
    image = np.round(50.0 + 0.5 * rng.standard_normal((64, 64)))  # 8-bit-like, ~0.5 DN
    products = prepare_image(image)
    assert quantised_noise_steps(products.noise_sigma) is not None
    assert any("MAD of quantised pixels" in r.getMessage() for r in caplog.records)


def test_citation_file_names_this_version():
    root = Path(__file__).resolve().parents[1]
    text = (root / "CITATION.cff").read_text(encoding="utf-8")
    assert "cff-version: 1.2.0" in text and f'version: "{dtalign.__version__}"' in text
    assert "license: BSD-3-Clause" in text


def test_the_issues_flipped_demo_disc_is_failed_not_ambiguous():
    """Issue 30.1 as written: disc_scene(seed=2) with its normals negated was
    ``ambiguous`` at (0, 0) with 1 inlier; it is ``failed``, the polarity
    reason first."""
    s = scenes.disc_scene(seed=2)
    p = s.polyline
    fit = fit_polyline(s.image, p.vertices_vu, -p.normals_vu, p.sigmas, search_window_vu=(30, 30))
    assert fit.status == "failed"
    assert str(fit.reasons[0]) == "most_polarity_rejected"
    assert fit.status_message.startswith(
        "failed: most vertices see the gradient the wrong way")
