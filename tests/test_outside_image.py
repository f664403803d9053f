"""A polyline off the image, and other natural first inputs, diagnosed right.

A polyline off the image is named as such first (``outside_image``,
``partly_outside_image``) and its rejections are not blamed on its normals;
a failed fit prints no ``inf`` sigma as if it meant something; a whole
circle passed for a limb lit on one side says that its unlit stretch finds
no edge. A fit whose vertices are all inside is unchanged.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from dtalign import scenes
from dtalign.cli import main
from dtalign.io.files import save_polyline_csv
from dtalign.pipeline import PolylineFit, fit_polyline, fit_polyline_products, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many
from dtalign.pipeline.status import (
    UNMEASURED_TEXT,
    FitReason,
    FitStatus,
    describe,
    fit_reasons,
    no_edge_run,
    outside_mask,
)

#: "inf" as a word (not the "inf" of "information").
INF = re.compile(r"\binf\b")

WINDOW = (6, 6)


def render(**kw):
    args = dict(shape=(320, 320), radius_px=90.0, phase_deg=35.0, illumination_deg=90.0,
                offset_vu=(0.37, -0.61), n_vertices=200, background_dn=20.0, albedo_dn=1500.0)
    return scenes.render_sphere(**{**args, **kw})


@pytest.fixture(scope="module")
def sphere():
    return render()


@pytest.fixture(scope="module")
def products(sphere):
    return prepare_image(sphere.image)


def moved(sphere, du):
    p = sphere.limb
    return scenes.Polyline("limb", p.vertices_vu + (0.0, du), p.normals_vu, p.sigmas)


@pytest.fixture(scope="module")
def fits(sphere, products):
    """The sunlit limb in place, half off the image (+110 px) and off it (+200 px)."""
    out = {}
    for du in (0, 110, 200):
        p = moved(sphere, du)
        out[du] = fit_polyline_products(products, p.vertices_vu, p.normals_vu, p.sigmas,
                                        search_window_vu=WINDOW)
    return out


def sigma_lines(text):
    return [line for line in text.splitlines() if "sigma" in line.split(":")[0]]


# --------------------------------------------------------------------------- outside the image


def test_a_polyline_off_the_image_is_named_outside_not_its_normals(fits):
    fit = fits[200]
    assert fit.status is FitStatus.FAILED
    assert fit.reasons == (FitReason.OUTSIDE_IMAGE, FitReason.DEGENERATE)
    assert fit.outside_image.sum() == 200 and fit.image_shape == (320, 320)
    assert fit.status_message.startswith(
        "failed: 200 of 200 vertices lie outside the 320 x 320 image: nothing inside to fit "
        "(is the polyline in this image's pixel frame, (v, u) = (row, column)? is the "
        "predicted pose this far off?); degenerate: no vertex of 200 kept any weight")
    assert "polarity" not in fit.status_message and "flip" not in fit.status_message


def test_a_polyline_half_off_the_image_counts_polarity_only_inside(fits):
    fit = fits[110]
    assert fit.reasons == (FitReason.OUTSIDE_IMAGE, FitReason.MOST_POLARITY_REJECTED)
    assert fit.outside_image.sum() == 126 and fit.lm.polarity_rejected_count == 198
    assert fit.status_message == (
        "failed: 126 of 200 vertices lie outside the 320 x 320 image, and only 2 of the 74 "
        "inside kept any weight: too few to fit (is the predicted pose off by more than the "
        "search window?); most vertices inside the image see the gradient the wrong way (72 "
        "of the 74 inside polarity-rejected, 2 inliers): is there an edge under them (is the "
        "polyline displaced)? are the normals pointing to the bright side? (they must point "
        "up the image gradient; flip them if not)")


def test_outside_is_the_polarity_tests_pixel(fits):
    # shifted by the coarse seed, rounded: outside rows 0..H-1 or columns 0..W-1
    fit = fits[110]
    iv, iu = np.rint(np.asarray(fit.vertices_vu) + fit.coarse_offset_vu).T
    expected = ~((iv >= 0) & (iv <= 319) & (iu >= 0) & (iu <= 319))
    assert np.array_equal(fit.outside_image, expected)
    assert np.array_equal(outside_mask(fit), expected)
    # an outside vertex is polarity-rejected: it has no gradient to read
    assert fit.polarity_rejected[fit.outside_image].all()


def test_a_fit_partly_outside_that_measures_the_inside_is_ok_with_a_note():
    sc = render(center_vu=(160.0, 260.0), illumination_deg=0.0)
    p = sc.limb
    fit = fit_polyline(sc.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=WINDOW)
    assert fit.status is FitStatus.OK
    assert fit.reasons == (FitReason.PARTLY_OUTSIDE_IMAGE,)
    assert fit.status_message == (
        "ok: 55 of 200 vertices lie outside the 320 x 320 image: the pose is measured by the "
        "145 inside (145 inliers), its sigmas by their geometry")
    assert not fit.outside_image[fit.lm.weights > 0].any()


def test_outside_vertices_that_kept_weight_without_the_polarity_test_are_suspect():
    sc = render(center_vu=(160.0, 260.0), illumination_deg=0.0)
    p = sc.limb
    fit = fit_polyline(sc.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=WINDOW,
                       use_polarity=False)
    assert fit.status is FitStatus.SUSPECT
    assert fit.reasons == (FitReason.OUTSIDE_IMAGE_WEIGHTED,)
    assert fit.status_message == (
        "suspect: 55 of 200 vertices lie outside the 320 x 320 image, and 55 of them kept "
        "weight beside the 145 inliers inside: without the polarity test they sample the "
        "distance transform clamped to the image border, the border's distance to an edge, "
        "not theirs (pass only the vertices inside, or use the polarity test)")


def test_to_dict_carries_the_shape_and_the_count(fits):
    fit = fits[110]
    d = fit.to_dict(arrays=True)
    assert d["image_shape"] == [320, 320] and d["outside_image"] == 126
    back = PolylineFit.from_dict(d)
    assert back.reasons == fit.reasons and back.status_message == fit.status_message
    assert back.to_dict(arrays=True) == d
    # a dict written before the shape was recorded: nothing counted outside (as before)
    old = {k: v for k, v in d.items() if k not in ("image_shape", "outside_image")}
    legacy = PolylineFit.from_dict(old)
    assert legacy.image_shape is None and legacy.outside_image.sum() == 0
    assert legacy.reasons == (FitReason.MOST_POLARITY_REJECTED,)


def test_fit_many_and_fit_images_give_the_same_reasons(sphere, products, fits):
    polys = [moved(sphere, du) for du in (0, 110, 200)]
    many = fit_many(products, polys, search_window_vu=WINDOW, workers=1)
    images = fit_images([(sphere.image, None, polys)], search_window_vu=WINDOW, workers=1)[0]
    for du, a, b in zip((0, 110, 200), many, images, strict=True):
        assert a.image_shape == b.image_shape == (320, 320)
        assert a.reasons == b.reasons == fits[du].reasons, du
        assert a.status_message == b.status_message == fits[du].status_message


# --------------------------------------------------------------------------- no inf in a failed fit's text


def test_a_failed_fit_prints_no_inf_sigma(fits):
    for du in (110, 200):
        fit = fits[du]
        assert not INF.search(fit.status_message), fit.status_message
        lines = sigma_lines(fit.summary())
        assert lines and all(line.endswith(f": {UNMEASURED_TEXT}") for line in lines
                             if "sigma_vu" in line), lines
        # the numbers themselves are kept (drop-in contract)
        assert fit.sigma_vu == (np.inf, np.inf)
        assert fit.to_dict()["sigma_vu"] == [None, None]


def test_a_failed_rotation_fit_prints_no_inf_anywhere_in_its_reasons(sphere):
    p = moved(sphere, 110)
    fit = fit_polyline(sphere.image, p.vertices_vu, p.normals_vu, p.sigmas,
                       search_window_vu=WINDOW, fit_rotation=True)
    assert fit.failed and FitReason.RANK_DEFICIENT in fit.reasons
    assert not INF.search(fit.status_message), fit.status_message
    summary = fit.summary()
    assert f"sigma_rotation_rad: {UNMEASURED_TEXT}" in summary


def test_an_ok_fit_prints_its_sigmas(fits):
    fit = fits[0]
    assert fit.status is FitStatus.OK
    assert UNMEASURED_TEXT not in fit.summary()


def test_the_command_line_names_outside_and_prints_no_inf(tmp_path, capsys, sphere):
    np.save(tmp_path / "sphere.npy", sphere.image)
    for du in (0, 110, 200):
        save_polyline_csv(tmp_path / f"limb{du}.csv", moved(sphere, du))
    image = str(tmp_path / "sphere.npy")
    code = main(["fit", image, str(tmp_path / "limb200.csv"), "--window", "6"])
    out, err = capsys.readouterr()
    assert code == 3
    assert "status       : failed: 200 of 200 vertices lie outside the 320 x 320 image" in out
    assert not INF.search(out), out
    code = main(["fit", image, str(tmp_path / "limb0.csv"), image, str(tmp_path / "limb110.csv"),
                 image, str(tmp_path / "limb200.csv"), "--window", "6"])
    out, err = capsys.readouterr()
    assert code == 3
    rows = out.splitlines()
    assert rows[-2].endswith("failed (outside_image, most_polarity_rejected)")
    assert rows[-1].endswith("failed (outside_image, degenerate)")
    assert rows[-3].endswith("  ok")
    assert "126 of 200 vertices lie outside the 320 x 320 image" in err


# --------------------------------------------------------------------------- fits inside: unchanged


def test_a_fit_inside_the_image_is_as_before(fits):
    fit = fits[0]
    assert fit.outside_image.sum() == 0
    assert fit.reasons == () and fit.status_message == "ok"
    # the shape only decides what is outside: without it the fit reads the same
    before = dataclasses.replace(fit, image_shape=None)
    assert before.reasons == fit.reasons and before.status_message == fit.status_message
    a, b = fit.to_dict(arrays=True), before.to_dict(arrays=True)
    for key in ("image_shape", "outside_image"):
        a.pop(key), b.pop(key)
    assert a == b
    assert no_edge_run(fit) is None


# --------------------------------------------------------------------------- a whole circle, half unlit


def circle(sc, n=200):
    theta = 2.0 * np.pi * np.arange(n) / n
    radial = np.column_stack([np.cos(theta), np.sin(theta)])
    return np.asarray(sc.model_center_vu) + sc.radius_px * radial, -radial


def test_a_whole_circle_ambiguous_says_its_unlit_stretch_finds_no_edge(sphere):
    vertices, normals = circle(sphere)
    fit = fit_polyline(sphere.image, vertices, normals, 1.0, search_window_vu=(30, 30))
    # the ambiguity stands (the unlit half finds the terminator in the rival basin) ...
    assert fit.status is FitStatus.AMBIGUOUS and fit.reasons == (FitReason.AMBIGUOUS,)
    # ... and the message says why
    assert fit.status_message.endswith(
        "; at this pose vertices 112-188 (77 of 200, one contiguous stretch of the polyline) "
        "find no edge while the rest fit (123 inliers of 123): is that part of the limb "
        "unlit? pass only the sunlit part")
    run = no_edge_run(fit)
    assert (run.first, run.last, run.length) == (112, 188, 77)


def test_a_whole_circle_mostly_rejected_names_the_stretch_before_the_normals():
    sc = render(phase_deg=120.0)
    vertices, normals = circle(sc)
    fit = fit_polyline(sc.image, vertices, normals, 1.0, search_window_vu=WINDOW)
    assert fit.status is FitStatus.FAILED and fit.reasons == (FitReason.MOST_POLARITY_REJECTED,)
    assert fit.status_message == (
        "failed: most vertices see the gradient the wrong way (101 of 200 polarity-rejected, "
        "96 inliers): vertices 100-199 and 0-4 (105 of 200, one contiguous stretch of the "
        "polyline) find no edge while the rest fit (95 inliers of 95): is that part of the "
        "limb unlit? pass only the sunlit part; if not, are the normals pointing to the "
        "bright side? (they must point up the image gradient; flip them if not)")


def test_normals_flipped_everywhere_get_no_unlit_hint(sphere):
    p = sphere.limb
    fit = fit_polyline(sphere.image, p.vertices_vu, -p.normals_vu, p.sigmas,
                       search_window_vu=WINDOW)
    assert fit.reasons[0] is FitReason.ALL_POLARITY_REJECTED
    assert no_edge_run(fit) is None and "unlit" not in fit.status_message


def test_describe_reads_records_without_a_shape(fits):
    # a record without image_shape (a hand-made one): nothing is outside
    fit = dataclasses.replace(fits[200], image_shape=None)
    assert fit_reasons(fit) == (FitReason.ALL_POLARITY_REJECTED, FitReason.DEGENERATE)
    assert describe(fit).startswith("failed: all 200 vertices polarity-rejected")
