"""The pipeline's data model: one polyline record, one options record, one
builder of a fit, and a status found once.

* a :class:`~dtalign.Polyline` (its edge profile included) is what a fit
  takes, alone or as its arrays, with the same result;
* :class:`~dtalign.FitOptions` holds every option of a call, the search
  window included, and nothing of one polyline's;
* one function of :mod:`dtalign.pipeline.fit` constructs the pipeline's
  :class:`~dtalign.pipeline.PolylineFit` (``from_dict`` reads one back);
* :func:`dtalign.pipeline.status.assess` runs once per fit, when the fit is
  concluded, and every reading of the status afterwards reads what it stored;
* the parameter count of a fit is written in one place.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import re
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import FitOptions, Polyline, scenes
from dtalign.pipeline import fit as fit_module
from dtalign.pipeline import fit_polyline, fit_polyline_products, prepare_image
from dtalign.pipeline.batch import fit_many
from dtalign.scenes import render_sphere

SRC = Path(dtalign.__file__).resolve().parent


@pytest.fixture(scope="module")
def disc():
    return scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=(3.4, -2.2))


@pytest.fixture(scope="module")
def sphere():
    sc = render_sphere(shape=(160, 160), center_vu=(80.2, 79.6), radius_px=45.0, phase_deg=30.0,
                       illumination_deg=40.0, offset_vu=(0.3, -0.6))
    L = sc.limb
    prof = dtalign.sphere_edge_profile(L.vertices_vu, center_vu=sc.model_center_vu,
                                       radius_px=45.0, phase_deg=30.0, illumination_deg=40.0)
    return sc, prof


def _same(a, b):
    da, db = a.to_dict(arrays=True), b.to_dict(arrays=True)
    for d in (da, db):
        d.pop("timings_s")
        if d["profile"] is not None:
            d["profile"].pop("time_s")
    return da == db


# --------------------------------------------------------------------------- the polyline record


def test_a_polyline_record_fits_as_its_arrays(disc):
    p = disc.polyline
    record = Polyline("disc", p.vertices_vu, p.normals_vu, p.sigmas)
    plain = fit_polyline(disc.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8))
    assert _same(fit_polyline(disc.image, record, search_window_vu=(8, 8)), plain)
    products = prepare_image(disc.image)
    assert _same(fit_polyline_products(products, record, search_window_vu=(8, 8)), plain)


def test_a_polyline_carries_its_kind_and_edge_profile(sphere):
    sc, prof = sphere
    L = sc.limb
    with_arrays = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas,
                               search_window_vu=(6, 6), edge_profile=prof)
    record = dataclasses.replace(L, edge_profile=prof)
    alone = fit_polyline(sc.image, record, search_window_vu=(6, 6))
    assert alone.profile is not None and alone.edge_kind == "limb"
    assert _same(alone, with_arrays)
    products = prepare_image(sc.image)
    (batched,) = fit_many(products, [record], search_window_vu=(6, 6))
    assert _same(batched, with_arrays)
    with pytest.raises(TypeError, match="edge_profile is given twice"):
        fit_polyline(sc.image, record, search_window_vu=(6, 6), edge_profile=prof)
    kind = fit_polyline(sc.image, dataclasses.replace(L, edge_kind="terminator"),
                        search_window_vu=(6, 6))
    assert kind.edge_kind == "terminator" and "terminator_without_profile" in kind.reasons


def test_arrays_need_their_normals_and_sigmas(disc):
    with pytest.raises(TypeError, match="give a Polyline"):
        fit_polyline(disc.image, disc.polyline.vertices_vu)


# --------------------------------------------------------------------------- the options record


def test_the_search_window_is_an_option_and_the_profile_is_not(disc):
    names = {f.name for f in dataclasses.fields(FitOptions)}
    assert "search_window_vu" in names and "edge_profile" not in names
    assert FitOptions().search_window_vu == dtalign.pipeline.DEFAULT_SEARCH_WINDOW_VU
    p = disc.polyline
    by_keyword = fit_polyline(disc.image, p, search_window_vu=(8, 8))
    by_record = fit_polyline(disc.image, p, options=FitOptions(search_window_vu=(8, 8)))
    assert by_record.search_window_vu == (8, 8) and _same(by_record, by_keyword)
    with pytest.raises(TypeError, match="unexpected fit option"):
        fit_many(prepare_image(disc.image), [p], edge_profile=None)


def test_the_parameter_count_is_a_property():
    assert FitOptions().n_params == 2 and FitOptions(fit_rotation=True).n_params == 3


def test_the_parameter_count_is_written_once():
    # the package's one definition, and the NumPy specification's own
    pattern = re.compile(r"3 if [\w.]*fit_rotation else 2")
    found = sorted(str(path.relative_to(SRC)) for path in SRC.rglob("*.py")
                   if pattern.search(path.read_text(encoding="utf-8")))
    assert found == ["_kernels/params.py", "reference/fitting.py"]


# --------------------------------------------------------------------------- one builder


def test_one_function_constructs_a_polyline_fit():
    # (PolylineFit.from_dict reads a fit back with cls(...))
    callers = set()
    for path in SRC.rglob("*.py"):
        for fn in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(fn, ast.FunctionDef) and any(
                    isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id == "PolylineFit" for node in ast.walk(fn)):
                callers.add(f"{path.relative_to(SRC)}:{fn.name}")
    assert callers == {"pipeline/fit.py:new_fit"}


# --------------------------------------------------------------------------- status once


def test_the_status_is_found_once_per_fit_and_stored(disc, sphere, monkeypatch):
    calls = []
    real = fit_module.assess

    def counted(fit):
        calls.append(fit)
        return real(fit)

    monkeypatch.setattr(fit_module, "assess", counted)
    fit = fit_polyline(disc.image, disc.polyline, search_window_vu=(8, 8))
    assert len(calls) == 1
    for _ in range(2):
        assert fit.status == "ok" and fit.reasons == () and fit.status_message == "ok"
        fit.to_dict()
        str(fit)
    assert len(calls) == 1
    sc, prof = sphere
    products = prepare_image(sc.image)
    polys = [sc.limb, dataclasses.replace(sc.limb, edge_profile=prof), sc.terminator]
    fits = fit_many(products, polys, search_window_vu=(6, 6), workers=2)
    assert len(calls) == 4
    assert {id(f) for f in calls[1:]} == {id(f) for f in fits}
    assert [f.status_message for f in fits] and len(calls) == 4


def test_a_changed_fit_is_assessed_anew(disc):
    p = disc.polyline
    fit = fit_polyline(disc.image, p, search_window_vu=(8, 8))
    other = dataclasses.replace(fit, edge_kind="terminator")
    assert "terminator_without_profile" in other.reasons and fit.reasons == ()
    assert np.array_equal(other.offset_vu, fit.offset_vu)


def test_secondary_covariance_views_live_behind_uncertainty_and_lm(disc):
    """The result leads with one covariance (``sigma_vu``); the M-estimator's
    and the geometry's readings are under ``fit.uncertainty``, the DT-LM
    stage's own under ``fit.lm``, not as properties of the fit."""
    cls = fit_module.PolylineFit
    props = {n for n, v in vars(cls).items()
             if not n.startswith("_") and isinstance(v, (property, functools.cached_property))}
    assert len(props) <= 16, sorted(props)
    moved = {"covariance_mestimator", "covariance_scaled", "variance_factor", "sigma_vu_scaled",
             "normal_covariance", "covariance_unobservable_inf"}
    assert not moved & props
    assert not {"converged", "degenerate", "rms_px", "inlier_count", "dt_offset_vu"} & props
    fit = fit_polyline(disc.image, disc.polyline, search_window_vu=(30, 30))
    u = fit.uncertainty
    np.testing.assert_array_equal(fit.covariance, u.covariance)
    np.testing.assert_array_equal(u.covariance_mestimator, fit.lm.covariance)
    np.testing.assert_array_equal(u.covariance_scaled, fit.lm.covariance * u.variance_factor)
    assert fit.observable_rank == 2 and u.source == "dt"
