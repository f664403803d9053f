"""Bad-pixel masks: ``prepare_image(..., mask=...)`` and everything that passes one on.

What the masked products promise (:mod:`dtalign.pipeline.masked`): an
all-False mask is no mask, bit for bit; no edge on a masked pixel; the
noise estimate and the profile strips ignore masked pixels; a fit counts
the vertices on masked pixels. And on the defect scenes of
:func:`dtalign.scenes.add_defects`: masked, the fit is as good as the clean
one; unmasked, never ``ok`` and confidently wrong.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dtalign import reference, scenes, sphere_edge_profile
from dtalign.pipeline import fit_polyline, prepare_image
from dtalign.pipeline.batch import fit_images
from dtalign.pipeline.masked import masked_noise_sigma
from dtalign.pipeline.products import ImageProducts
from dtalign.pipeline.profile_fit import refine_with_profile
from dtalign.pipeline.status import FitReason

#: chi-square with 2 degrees of freedom at 99.9 %: the ellipse a fit's error must lie in.
CHI2_2_999 = -2.0 * math.log(1.0 - 0.999)

DISC = dict(shape=(400, 400), radius=120.0)
DISC_CENTRE = ((400 - 1) / 2.0, (400 - 1) / 2.0)


@pytest.fixture(scope="module")
def disc():
    return scenes.disc_scene(**DISC)


def _error(fit, truth):
    """``(|error|, its squared Mahalanobis distance under the fit's covariance)``."""
    e = np.subtract(fit.offset_vu, truth)
    cov = np.asarray(fit.covariance)[:2, :2]
    d2 = float(e @ np.linalg.pinv(cov) @ e) if np.isfinite(cov).all() else math.inf
    return float(np.hypot(*e)), d2


def _clean(d):
    d = dict(d)
    d.pop("timings_s")
    return d


# --------------------------------------------------------------------------- no bad pixel


def test_an_all_false_mask_is_no_mask_bit_for_bit(disc):
    plain = prepare_image(disc.image)
    zero = prepare_image(disc.image, mask=np.zeros(disc.image.shape, dtype=bool))
    assert zero.mask is None and plain.mask is None
    for name in ("gradient_magnitude", "edge_dt", "gradient_vu", "edge_mask", "image"):
        np.testing.assert_array_equal(getattr(zero, name), getattr(plain, name))
    assert zero.noise_sigma == plain.noise_sigma
    a = fit_polyline(disc.image, disc.polyline, search_window_vu=(30, 30))
    b = fit_polyline(disc.image, disc.polyline, search_window_vu=(30, 30),
                     mask=np.zeros(disc.image.shape, dtype=np.uint8))
    assert _clean(b.to_dict(arrays=True)) == _clean(a.to_dict(arrays=True))
    assert b.masked_vertices is None and "masked_vertices" not in b.to_dict()


def test_without_a_mask_nan_is_still_an_error(disc):
    img, _ = scenes.add_defects(disc.image, "missing_line_nan", limb_center_vu=DISC_CENTRE,
                                limb_radius_px=120.0)
    with pytest.raises(ValueError, match="finite"):
        prepare_image(img)
    # a mask, even all False, makes the NaN pixels bad ones
    products = prepare_image(img, mask=np.zeros(img.shape, dtype=bool))
    np.testing.assert_array_equal(products.mask, ~np.isfinite(img))


# --------------------------------------------------------------------------- the products


def test_no_edge_on_a_masked_pixel_and_none_around_an_isolated_ray(disc):
    img, mask = scenes.add_defects(disc.image, "cosmic_rays", limb_center_vu=DISC_CENTRE,
                                   limb_radius_px=120.0)
    masked = prepare_image(img, mask=mask)
    unmasked = prepare_image(img)
    assert not (masked.edge_mask & mask).any()
    # far from the limb (sky and disc interior) the masked image has the
    # clean image's edges: none at all, where every ray made some unmasked
    vv, uu = np.mgrid[0:400, 0:400]
    far = np.abs(np.hypot(vv - DISC_CENTRE[0], uu - DISC_CENTRE[1]) - 120.0) > 8.0
    assert unmasked.edge_mask[far].sum() > 100
    assert masked.edge_mask[far].sum() == prepare_image(disc.image).edge_mask[far].sum()


def test_the_noise_estimate_ignores_masked_pixels():
    rng = np.random.default_rng(5)
    image = 100.0 + rng.normal(0.0, 2.0, (200, 200))
    image[:, 100:] += rng.normal(0.0, 40.0, (200, 100))  # a textured half, masked
    mask = np.zeros(image.shape, dtype=bool)
    mask[:, 100:] = True
    sigma = masked_noise_sigma(np.where(mask, 0.0, image), mask)
    # the responses clear of the mask are those of the clean half alone
    assert sigma == reference.estimate_noise_sigma(image[:, :100])
    assert abs(sigma - 2.0) < 0.1 < abs(reference.estimate_noise_sigma(image) - 2.0)
    assert prepare_image(image, mask=mask).noise_sigma == sigma


#: The sphere's sunward limb point, from +v toward +u (its light comes from 45 deg, 0 = up).
LIT_DEG = 135.0


def _sphere(seed: int = 0):
    s = scenes.render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                             phase_deg=30.0, illumination_deg=45.0, offset_vu=(0.4, -0.7),
                             read_noise_dn=1.0, seed=seed)
    prof = sphere_edge_profile(s.limb.vertices_vu, center_vu=s.model_center_vu, radius_px=70.0,
                               phase_deg=30.0, illumination_deg=45.0, edge="limb")
    return s, prof


def test_the_profile_strips_leave_masked_pixels_out():
    s, prof = _sphere()
    img, mask = scenes.add_defects(s.image, "saturated_blob", limb_center_vu=s.center_vu,
                                   limb_radius_px=70.0, blob_at_deg=LIT_DEG)
    start = (0.4, -0.7)
    ref = refine_with_profile(img, prof, s.limb.vertices_vu, start, mask=mask)
    other = img.copy()
    other[mask] = -1e6  # whatever the masked pixels hold: the same refinement
    again = refine_with_profile(other, prof, s.limb.vertices_vu, start, mask=mask)
    assert again.to_dict() | {"time_s": 0.0} == ref.to_dict() | {"time_s": 0.0}
    clean = refine_with_profile(s.image, prof, s.limb.vertices_vu, start)
    assert ref.accepted and ref.n_pixels < clean.n_pixels


# --------------------------------------------------------------------------- the defect scenes


@pytest.mark.parametrize("kind", scenes.DEFECTS)
@pytest.mark.parametrize("seed", [0, 1])
def test_disc_defects_masked_fit_as_well_as_the_clean_fit(kind, seed):
    sc = scenes.disc_scene(seed=seed, **DISC)
    kw = dict(search_window_vu=(30, 30))
    clean = fit_polyline(sc.image, sc.polyline, **kw)
    clean_err, _ = _error(clean, sc.true_offset_vu)
    img, mask = scenes.add_defects(sc.image, kind, limb_center_vu=DISC_CENTRE,
                                   limb_radius_px=120.0, seed=seed)
    fit = fit_polyline(img, sc.polyline, mask=mask, **kw)
    err, d2 = _error(fit, sc.true_offset_vu)
    assert fit.status == "ok" and d2 < CHI2_2_999
    # the clean fit's error, or its one-sigma when it was luckier than that
    assert err <= 2.0 * max(clean_err, math.hypot(*clean.sigma_vu)), (err, clean_err)
    assert fit.masked_vertices is not None
    if kind == "missing_line_nan":
        with pytest.raises(ValueError, match="finite"):
            fit_polyline(img, sc.polyline, **kw)
        return
    bare = fit_polyline(img, sc.polyline, **kw)
    err, d2 = _error(bare, sc.true_offset_vu)
    # unmasked: flagged, or right within its own sigma
    assert bare.status != "ok" or (d2 < CHI2_2_999 and err < 1.0), (bare.status, err, d2)


@pytest.mark.parametrize("kind", ["saturated_blob", "cosmic_rays"])
def test_sphere_limb_with_profile_masked(kind):
    s, prof = _sphere()
    kw = dict(search_window_vu=(8, 8), edge_profile=prof)
    clean = fit_polyline(s.image, s.limb, **kw)
    clean_err, _ = _error(clean, s.true_offset_vu)
    img, mask = scenes.add_defects(s.image, kind, limb_center_vu=s.center_vu, limb_radius_px=70.0,
                                   saturation_dn=1.5 * s.image.max(), blob_at_deg=LIT_DEG)
    fit = fit_polyline(img, s.limb, mask=mask, **kw)
    err, d2 = _error(fit, s.true_offset_vu)
    assert fit.profile.accepted and fit.status == "ok" and d2 < CHI2_2_999
    assert err <= 2.0 * max(clean_err, math.hypot(*clean.sigma_vu)), (err, clean_err)
    bare = fit_polyline(img, s.limb, **kw)
    err, d2 = _error(bare, s.true_offset_vu)
    assert bare.status != "ok" or (d2 < CHI2_2_999 and err < 1.0), (bare.status, err, d2)


def test_a_fit_names_the_masked_pixels_it_touches():
    s, prof = _sphere()
    img, mask = scenes.add_defects(s.image, "saturated_blob", limb_center_vu=s.center_vu,
                                   limb_radius_px=70.0, saturation_dn=1.5 * s.image.max(),
                                   blob_at_deg=LIT_DEG)
    fit = fit_polyline(img, s.limb, search_window_vu=(8, 8), mask=mask)
    assert fit.masked_vertices > 0
    assert FitReason.MASKED_PIXELS in fit.reasons and fit.status == "ok"
    assert f"{fit.masked_vertices} of 200 vertices lie on masked pixels" in fit.status_message
    d = json.loads(json.dumps(fit.to_dict(arrays=True)))
    assert d["masked_vertices"] == fit.masked_vertices and "masked_pixels" in d["reasons"]
    assert type(fit).from_dict(d).masked_vertices == fit.masked_vertices


# --------------------------------------------------------------------------- bad input


def test_bad_masks_are_refused_by_name(disc):
    shape = disc.image.shape
    with pytest.raises(ValueError, match=r"mask must have the image's shape \(400, 400\)"):
        prepare_image(disc.image, mask=np.zeros((400, 399), dtype=bool))
    with pytest.raises(TypeError, match="mask must be a boolean array"):
        prepare_image(disc.image, mask=np.zeros(shape))
    with pytest.raises(ValueError, match="mask must hold only 0 and 1"):
        prepare_image(disc.image, mask=np.full(shape, 255, dtype=np.uint8))
    with pytest.raises(ValueError, match="mask leaves no valid pixel"):
        prepare_image(disc.image, mask=np.ones(shape, dtype=bool))
    with pytest.raises(ValueError, match="mask must have the image's shape"):
        ImageProducts(shape=(2, 2), noise_sigma=1.0, gradient_magnitude=np.zeros((2, 2)),
                      edge_dt=np.zeros((2, 2)), gradient_vu=np.zeros((2, 2, 2)),
                      edge_mask=np.zeros((2, 2), dtype=bool), mask=np.zeros((3, 2), dtype=bool))


def test_a_batch_names_the_item_whose_mask_is_bad(disc):
    good = (disc.image, None, [disc.polyline], np.zeros(disc.image.shape, dtype=bool))
    bad = {"image": disc.image, "polylines": [disc.polyline], "mask": np.zeros((3, 3), bool)}
    with pytest.raises(ValueError, match="mask must have the image's shape") as info:
        fit_images([good, bad], search_window_vu=(30, 30), workers=1)
    assert "images[1]" in info.value.__notes__
    out = fit_images([good, bad], search_window_vu=(30, 30), workers=1, errors="collect")
    assert isinstance(out[1], ValueError) and out[0][0].status == "ok"
    with pytest.raises(TypeError, match=r"items\[0\] as a mapping needs"):
        fit_images([{"image": disc.image, "polylines": [], "flags": 1}])


# --------------------------------------------------------------------------- the batch, CLI, campaign


def test_fit_images_reads_a_mask_from_each_kind_of_item(disc, tmp_path):
    img, mask = scenes.add_defects(disc.image, "saturated_blob", limb_center_vu=DISC_CENTRE,
                                   limb_radius_px=120.0)
    want = fit_polyline(img, disc.polyline, search_window_vu=(30, 30), mask=mask).offset_vu
    np.save(tmp_path / "mask.npy", mask.astype(np.uint8) * 255)  # a 0/255 file: nonzero is bad

    class Record:
        image, noise_sigma, polylines = img, None, [disc.polyline]

    record = Record()
    record.mask = mask
    items = [(img, None, [disc.polyline], mask),
             {"image": img, "polylines": [disc.polyline], "mask": mask},
             record,
             (img, None, [disc.polyline], str(tmp_path / "mask.npy"))]
    for fits in fit_images(items, search_window_vu=(30, 30), workers=1):
        assert fits[0].offset_vu == want
    # a Scene has no mask attribute: unmasked, as before
    assert fit_images([disc], search_window_vu=(30, 30), workers=1)[0][0].masked_vertices is None


def test_cli_mask_and_mask_nonfinite(disc, tmp_path, capsys):
    from dtalign.api.constants import DEFAULT_SEARCH_WINDOW_VU
    from dtalign.cli import main
    from dtalign.io import save_polyline_csv

    img, mask = scenes.add_defects(disc.image, "missing_line_nan", limb_center_vu=DISC_CENTRE,
                                   limb_radius_px=120.0)
    np.save(tmp_path / "img.npy", img)
    np.save(tmp_path / "mask.npy", mask)
    save_polyline_csv(tmp_path / "p.csv", disc.polyline)
    args = ["fit", str(tmp_path / "img.npy"), str(tmp_path / "p.csv"), "--json"]
    assert main(args) == 1
    assert "NaN or inf pixels" in capsys.readouterr().err
    want = fit_polyline(img, disc.polyline, mask=mask,
                        search_window_vu=DEFAULT_SEARCH_WINDOW_VU).offset_vu
    for extra in (["--mask-nonfinite"], ["--mask", str(tmp_path / "mask.npy")]):
        assert main([*args, *extra]) == 0
        row = json.loads(capsys.readouterr().out)
        assert tuple(row["offset_vu"]) == want and row["masked_vertices"] == 0
    assert main([*args, "--mask", str(tmp_path / "none.npy")]) == 1
    assert "--mask" in capsys.readouterr().err


def test_manifest_mask_fields(disc, tmp_path):
    from dtalign.archive import fit_item, read_manifest
    from dtalign.archive.manifest import write_manifest
    from dtalign.io import save_polyline_csv

    img, mask = scenes.add_defects(disc.image, "missing_line_nan", limb_center_vu=DISC_CENTRE,
                                   limb_radius_px=120.0)
    np.save(tmp_path / "img.npy", img)
    np.save(tmp_path / "mask.npy", mask)
    save_polyline_csv(tmp_path / "p.csv", disc.polyline)
    base = {"image": "img.npy", "polylines": "p.csv"}
    path = write_manifest(tmp_path / "m.jsonl", [
        {**base, "id": "plain"}, {**base, "id": "masked", "mask": "mask.npy"},
        {**base, "id": "nonfinite", "mask_nonfinite": True}])
    plain, masked, nonfinite = read_manifest(path)
    assert masked.mask_path == str(tmp_path.resolve() / "mask.npy") and nonfinite.mask_nonfinite
    # an item without a mask keeps its fingerprint; a mask changes it
    assert plain.to_record() == {**base, "id": "plain", "polylines": ["p.csv"], "window": [30, 30]}
    assert len({plain.fingerprint, masked.fingerprint, nonfinite.fingerprint}) == 3
    assert fit_item(plain, "r")["failure"]["stage"] == "read"
    want = fit_polyline(img, disc.polyline, mask=mask, search_window_vu=(30, 30)).offset_vu
    for item in (masked, nonfinite):
        (row,) = fit_item(item, "r")["results"]
        assert (row["offset_v"], row["offset_u"]) == want
    (tmp_path / "m.csv").write_text("image,polylines,mask_nonfinite\nimg.npy,p.csv,maybe\n")
    with pytest.raises(ValueError, match="line 2: mask_nonfinite must be true or false"):
        read_manifest(tmp_path / "m.csv")
