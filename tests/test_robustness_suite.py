"""The robustness suite: its scenes know their truth, and its harness counts right."""

from __future__ import annotations

import enum
import math
import os
import statistics
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.ndimage

from dtalign import robustness as rb
from dtalign.reference.image import compute_all_image_derivatives

FAMILIES = list(rb.FAMILIES)
SEEDS = (0, 1, 7)
DECOY_FAMILIES = ("parallel_rings", "crater_rim", "terminator_limb")


def _sample(field, points_vu):
    """Bilinear samples of a 2-D field at (v, u) points."""
    return scipy.ndimage.map_coordinates(field, np.asarray(points_vu).T, order=1, mode="nearest")


def _edge_crossings(image, points_vu, normals_vu, half_px=1.5):
    """Signed distance along each normal to where the profile crosses its mid-level.

    Each pixel of an anti-aliased edge holds the fraction of it on the
    bright side, so across the edge the image ramps from one level to the
    other over one pixel and crosses half-way at the edge itself.
    """
    t = np.linspace(-half_px, half_px, 61)
    pts = points_vu[:, None, :] + t[None, :, None] * normals_vu[:, None, :]
    prof = _sample(image, pts.reshape(-1, 2)).reshape(pts.shape[:2])
    rel = prof - 0.5 * (prof[:, :1] + prof[:, -1:])
    out = np.full(len(points_vu), np.nan)
    for i, r in enumerate(rel):
        k = np.flatnonzero(np.sign(r[:-1]) != np.sign(r[1:]))
        if k.size:
            j = k[0]
            out[i] = t[j] + (t[j + 1] - t[j]) * r[j] / (r[j] - r[j + 1])
    return out


def _reference_products(image, noise_sigma):
    _, edge_dt, gradient = compute_all_image_derivatives(image, noise_sigma)
    return edge_dt, gradient


@pytest.fixture(scope="module", params=[(f, s) for f in FAMILIES for s in SEEDS], ids=str)
def scene(request):
    family, seed = request.param
    return rb.FAMILIES[family](seed)


# --------------------------------------------------------------------------- scenes


def test_registry_names_match_the_scenes_and_the_public_functions():
    assert FAMILIES == [
        "parallel_rings", "crater_rim", "terminator_limb", "small_window", "heavy_noise", "outliers",
    ]
    for name, fn in rb.FAMILIES.items():
        assert fn is getattr(rb, name)
        assert name in rb.__all__
        assert fn(3).family == name and fn(3).seed == 3


@pytest.mark.parametrize("family", FAMILIES)
def test_family_is_deterministic_in_its_seed(family):
    a, b, other = rb.FAMILIES[family](5), rb.FAMILIES[family](5), rb.FAMILIES[family](6)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.polyline.vertices_vu, b.polyline.vertices_vu)
    np.testing.assert_array_equal(a.polyline.normals_vu, b.polyline.normals_vu)
    assert a.true_offset_vu == b.true_offset_vu and a.decoy_offset_vu == b.decoy_offset_vu
    assert a.search_window_vu == b.search_window_vu and a.description == b.description
    assert not np.array_equal(a.image, other.image)
    assert a.true_offset_vu != other.true_offset_vu


def test_scene_is_well_formed(scene):
    p = scene.polyline
    n = len(p)
    assert scene.image.shape == scene.clean_image.shape == (256, 256)
    assert scene.image.dtype == np.float64 and np.isfinite(scene.image).all()
    assert p.vertices_vu.shape == p.normals_vu.shape == (n, 2) and p.sigmas.shape == (n,)
    np.testing.assert_allclose(np.hypot(p.normals_vu[:, 0], p.normals_vu[:, 1]), 1.0, atol=1e-12)
    assert (p.sigmas > 0).all()
    assert all(isinstance(m, int) and m > 0 for m in scene.search_window_vu)
    assert scene.true_rotation_rad == 0.0
    assert scene.use_polarity == (scene.family != "parallel_rings")
    if scene.across_vu is not None:
        assert math.isclose(math.hypot(*scene.across_vu), 1.0, abs_tol=1e-12)
    assert scene.true_edge_mask.shape == (n,)
    # The noise is what the scene says it is.
    residual = scene.image - scene.clean_image
    assert abs(residual.std() / scene.noise_sigma - 1.0) < 0.02


def test_true_offset_puts_the_model_on_the_intended_edge(scene):
    """On the clean image, the model moved by the truth lies on edge pixels, bright side ahead."""
    edge_dt, gradient = _reference_products(scene.clean_image, 2.0)
    on_edge = scene.true_vertices_vu[scene.true_edge_mask]
    dt = _sample(edge_dt, on_edge)
    assert np.median(dt) < 0.5 and np.percentile(dt, 90) < 1.0
    # Normals point to the bright side: up the gradient.
    g = np.stack([_sample(gradient[..., k], on_edge) for k in range(2)], axis=1)
    agree = np.sum(g * scene.polyline.normals_vu[scene.true_edge_mask], axis=1)
    assert (agree > 0).mean() > 0.95
    # The image edge crosses its mid-level at the true vertices, per vertex.
    crossing = _edge_crossings(
        scene.clean_image, on_edge, scene.polyline.normals_vu[scene.true_edge_mask]
    )
    assert np.isfinite(crossing).all() and np.max(np.abs(crossing)) < 0.15
    # The zero shift is not the answer.
    assert scene.error_px((0.0, 0.0)) >= 2.0


@pytest.mark.parametrize("family", [f for f in FAMILIES if f != "heavy_noise"])
@pytest.mark.parametrize("seed", SEEDS)
def test_true_edge_survives_the_noise(family, seed):
    scene = rb.FAMILIES[family](seed)
    edge_dt, _ = _reference_products(scene.image, scene.noise_sigma)
    dt = _sample(edge_dt, scene.true_vertices_vu[scene.true_edge_mask])
    assert np.median(dt) < 0.5 and np.percentile(dt, 90) < 1.0


@pytest.mark.parametrize("family", DECOY_FAMILIES)
@pytest.mark.parametrize("seed", SEEDS)
def test_decoy_edge_exists_with_the_polarity_the_family_names(family, seed):
    scene = rb.FAMILIES[family](seed)
    edge_dt, gradient = _reference_products(scene.image, scene.noise_sigma)
    decoy = scene.decoy_vertices_vu
    assert decoy.shape == scene.polyline.vertices_vu.shape
    dt = _sample(edge_dt, decoy)
    assert np.median(dt) < 0.5 and np.percentile(dt, 90) < 1.0
    crossing = _edge_crossings(scene.clean_image, decoy, scene.polyline.normals_vu)
    assert np.isfinite(crossing).all() and np.max(np.abs(crossing)) < 0.15
    # The decoy vertices are indexed like the model's: compare the decoy
    # edge's gradient with the model normal at the same index.
    g = np.stack([_sample(gradient[..., k], decoy) for k in range(2)], axis=1)
    agree = np.sum(g * scene.polyline.normals_vu, axis=1)
    if family == "parallel_rings":
        assert (agree > 0).mean() > 0.95  # same polarity
    else:
        assert (agree < 0).mean() > 0.95  # reversed polarity
    # The decoy is a different answer, wrong by more than the tolerance.
    assert scene.decoy_offset_vu is not None
    assert scene.error_px(scene.decoy_offset_vu) > 2.0 * rb.CORRECT_TOLERANCE_PX


@pytest.mark.parametrize("seed", range(6))
def test_parallel_rings_geometry(seed):
    scene = rb.parallel_rings(seed)
    across = np.asarray(scene.across_vu)
    np.testing.assert_allclose(scene.polyline.normals_vu, np.tile(across, (len(scene.polyline), 1)))
    spacing = scene.error_px(scene.decoy_offset_vu)
    assert 5.0 <= spacing <= 20.0
    # The model moved by the decoy offset lands on the decoy edge exactly.
    moved = scene.polyline.vertices_vu + np.asarray(scene.decoy_offset_vu)
    np.testing.assert_allclose(moved, scene.decoy_vertices_vu, atol=1e-9)
    # The along-edge part of the truth does not count.
    tangent = np.array([-across[1], across[0]])
    assert scene.error_px(np.asarray(scene.true_offset_vu) + 7.0 * tangent) < 1e-9


@pytest.mark.parametrize("seed", range(6))
def test_small_window_truth_is_outside_the_window(seed):
    scene = rb.small_window(seed)
    assert not scene.reachable
    margin = np.asarray(scene.search_window_vu)
    assert np.max(np.abs(scene.true_offset_vu) - margin) >= 3.0
    assert scene.decoy_offset_vu is not None
    assert np.all(np.abs(scene.decoy_offset_vu) <= margin)


@pytest.mark.parametrize("seed", range(6))
def test_heavy_noise_contrast_is_one_or_two_sigmas(seed):
    scene = rb.heavy_noise(seed)
    contrast = scene.clean_image.max() - scene.clean_image.min()
    assert 0.7 <= contrast / scene.noise_sigma <= 1.5


@pytest.mark.parametrize("seed", range(6))
def test_outliers_displace_thirty_percent_of_the_vertices(seed):
    scene = rb.outliers(seed)
    n = len(scene.polyline)
    displaced = ~scene.true_edge_mask
    assert displaced.sum() == round(0.3 * n)
    edge_dt, _ = _reference_products(scene.clean_image, 2.0)
    dt = _sample(edge_dt, scene.true_vertices_vu[displaced])
    assert np.all(dt > 1.0)  # displaced by 2-12 px, so off the edge


# --------------------------------------------------------------------------- harness


def _truth_fit(scene):
    return SimpleNamespace(offset_vu=scene.true_offset_vu)


def _wrong_offset(scene):
    if scene.decoy_offset_vu is not None:
        return scene.decoy_offset_vu
    return (scene.true_offset_vu[0] + 1.0, scene.true_offset_vu[1])


def _decoy_fit(status):
    def fit(scene):
        return SimpleNamespace(offset_vu=_wrong_offset(scene), status=status)

    return fit


def test_truth_returning_fit_is_all_correct_where_correct_is_reachable():
    rows = rb.evaluate(_truth_fit, seeds=range(3), warmup=False)
    assert [r.family for r in rows] == FAMILIES
    for r in rows:
        assert r.n == 3 and len(r.trials) == 3
        assert [t.seed for t in r.trials] == [0, 1, 2]
        assert all(t.error_px == 0.0 and t.status == "ok" for t in r.trials)
        assert r.flagged == 0.0
        if r.family == "small_window":
            assert not r.reachable
            assert r.correct == 0.0 and r.confidently_wrong == 1.0
        else:
            assert r.reachable
            assert r.correct == 1.0 and r.confidently_wrong == 0.0


def test_decoy_returning_fit_with_status_ok_is_all_confidently_wrong():
    rows = rb.evaluate(_decoy_fit("ok"), seeds=range(3), warmup=False)
    for r in rows:
        assert (r.correct, r.confidently_wrong, r.flagged) == (0.0, 1.0, 0.0), r.family


def test_decoy_returning_fit_flagged_ambiguous_is_all_flagged():
    rows = rb.evaluate(_decoy_fit("ambiguous"), seeds=range(3), warmup=False)
    for r in rows:
        assert (r.correct, r.confidently_wrong, r.flagged) == (0.0, 0.0, 1.0), r.family
        assert all(t.status == "ambiguous" for t in r.trials)


def test_harness_counts_a_mix_per_seed():
    # Seed 0 correct and ok, seed 1 wrong and ok, seed 2 correct but flagged,
    # seed 3 wrong and failed: each fraction is 1/4 or 2/4.
    def fit(scene):
        wrong = scene.seed in (1, 3)
        status = {0: "ok", 1: "ok", 2: "suspicious", 3: "failed"}[scene.seed]
        offset = _wrong_offset(scene) if wrong else scene.true_offset_vu
        return SimpleNamespace(offset_vu=offset, status=status)

    (row,) = rb.evaluate(fit, families=["crater_rim"], seeds=range(4), warmup=False)
    assert (row.correct, row.confidently_wrong, row.flagged) == (0.5, 0.25, 0.5)
    assert [t.correct for t in row.trials] == [True, False, True, False]
    assert [t.confidently_wrong for t in row.trials] == [False, True, False, False]


def test_harness_tolerance_is_half_a_pixel_across_the_edge():
    def fit(scene):
        across = np.asarray(scene.across_vu)
        return SimpleNamespace(offset_vu=np.asarray(scene.true_offset_vu) + shift * across)

    for shift, expected in ((0.49, 1.0), (-0.49, 1.0), (0.51, 0.0), (-0.51, 0.0)):
        (row,) = rb.evaluate(fit, families=["parallel_rings"], seeds=range(2), warmup=False)
        assert row.correct == expected, shift


def test_harness_non_finite_offset_is_wrong():
    def fit(scene):
        return SimpleNamespace(offset_vu=(math.nan, 0.0))

    (row,) = rb.evaluate(fit, families=["outliers"], seeds=[0], warmup=False)
    assert row.correct == 0.0 and row.confidently_wrong == 1.0
    assert math.isnan(row.trials[0].error_px)


def test_harness_times_each_call_and_warms_up_once():
    calls = []

    def fit(scene):
        calls.append((scene.family, scene.seed))
        return SimpleNamespace(offset_vu=scene.true_offset_vu)

    rows = rb.evaluate(fit, families=["heavy_noise", "outliers"], seeds=[4, 2])
    assert calls == [("heavy_noise", 4), ("heavy_noise", 4), ("heavy_noise", 2), ("outliers", 4), ("outliers", 2)]
    for r in rows:
        assert all(t.time_s >= 0.0 for t in r.trials)
        assert r.median_time_s == statistics.median(t.time_s for t in r.trials)


def test_harness_reads_an_enum_status_by_its_value():
    class Verdict(str, enum.Enum):  # prints as "Verdict.OK": the value is what counts
        OK = "ok"
        AMBIGUOUS = "ambiguous"

    from dtalign.pipeline.status import FitStatus

    for status, flagged in ((Verdict.OK, 0.0), (Verdict.AMBIGUOUS, 1.0), (FitStatus.OK, 0.0),
                            (FitStatus.FAILED, 1.0)):
        def fit(scene, status=status):
            return SimpleNamespace(offset_vu=scene.true_offset_vu, status=status)

        (row,) = rb.evaluate(fit, families=["outliers"], seeds=[0, 1], warmup=False)
        assert row.flagged == flagged, status
        assert row.trials[0].status == status.value


def test_harness_refuses_an_unknown_family():
    with pytest.raises(ValueError, match="families: unknown family 'rings'"):
        rb.evaluate(_truth_fit, families=["rings"], seeds=[0])


def test_format_table_is_markdown_with_one_line_per_family():
    rows = rb.evaluate(_decoy_fit("ok"), families=["parallel_rings", "small_window"], seeds=range(2))
    lines = rb.format_table(rows).splitlines()
    assert len(lines) == 2 + 2
    assert lines[0].startswith("| family | scenes | reachable | correct | confidently wrong | flagged |")
    assert all(line.count("|") == 8 for line in lines)
    assert lines[2].startswith("| parallel_rings | 2 | yes | 0.00 | 1.00 | 0.00 | ")
    assert lines[3].startswith("| small_window | 2 | no | 0.00 | 1.00 | 0.00 | ")


def test_importing_robustness_does_not_import_numba():
    script = (
        "import sys, dtalign.robustness; "
        "print(sorted(m for m in sys.modules if m == 'numba' or m.startswith('dtalign._kernels')))"
    )
    src = os.path.abspath(os.path.join(os.path.dirname(rb.__file__), os.pardir))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


# --------------------------------------------------------------------------- the plain pipeline


def test_plain_pipeline_smoke_run_is_confidently_wrong_somewhere():
    rows = rb.evaluate(rb.plain_fit, seeds=range(2))
    table = rb.format_table(rows)
    lines = table.splitlines()
    assert len(lines) == 2 + len(FAMILIES)
    assert [line.split("|")[1].strip() for line in lines[2:]] == FAMILIES
    assert all(r.n == 2 and r.median_time_s > 0.0 for r in rows)
    # What the multi-start fits are for: the plain pipeline answers wrong
    # with nothing saying so on at least one hard scene.
    assert any(r.confidently_wrong > 0.0 for r in rows)


def test_main_prints_the_table(capsys):
    assert rb.main(["--seeds", "1", "--families", "crater_rim", "outliers"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| crater_rim | 1 | yes |")
    assert lines[3].startswith("| outliers | 1 | yes |")
