"""Photometric edge profiles: the record's checks, the kernels against their
NumPy specification, and the accuracy targets on a fixed seeded subset of
rendered spheres (the bias table of docs/profiles.rst is the full sweep)."""

from __future__ import annotations

import numpy as np
import pytest

from dtalign import EdgeProfile, fit_polyline, sphere_edge_profile
from dtalign.pipeline import profile_fit
from dtalign.reference import profile as ref_kernels
from dtalign.scenes import render_sphere


def _scene(phase=35.0, ill=30.0, radius=85.0, off=(0.37, -0.21), psf=None, psf_kind="gaussian",
           **kw):
    return render_sphere(shape=(300, 300), center_vu=(150.3, 149.7), radius_px=radius,
                         phase_deg=phase, illumination_deg=ill, offset_vu=off,
                         background_dn=10.0, psf_sigma_px=psf, psf=psf_kind, **kw)


def _profile(sc, psf_sigma_px=0.0, law="lambert", edge="limb"):
    p = sc.limb if edge == "limb" else sc.terminator
    return sphere_edge_profile(p.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge=edge, law=law,
                               psf_sigma_px=psf_sigma_px)


def _err(fit, sc):
    return float(np.hypot(*(np.asarray(fit.offset_vu) - sc.true_offset_vu)))


def test_edge_profile_is_validated():
    off = (np.arange(8) - 3.5) * 0.5
    good = dict(offsets_px=off, values=np.zeros((2, 8)), normals_vu=[[1.0, 0.0], [0.0, 1.0]],
                curvature_px=[0.0, 0.0])
    EdgeProfile(**good)
    with pytest.raises(ValueError, match="offsets_px"):
        EdgeProfile(**{**good, "offsets_px": off ** 3})
    with pytest.raises(ValueError, match="values"):
        EdgeProfile(**{**good, "values": np.zeros((2, 7))})
    with pytest.raises(ValueError, match="normals_vu"):
        EdgeProfile(**{**good, "normals_vu": [[2.0, 0.0], [0.0, 1.0]]})
    with pytest.raises(ValueError, match="psf_sigma_px"):
        EdgeProfile(**good, psf_sigma_px=-1.0)
    with pytest.raises(ValueError, match="edge"):
        EdgeProfile(**good, edge="rim")
    with pytest.raises(ValueError, match="edge"):
        sphere_edge_profile([[0.0, 10.0]], center_vu=(0, 0), radius_px=10, phase_deg=30,
                            illumination_deg=0, edge="rim")


def test_terminator_profile_is_accepted():
    sc = _scene(phase=60.0)
    prof = _profile(sc, edge="terminator")
    assert prof.edge == "terminator"
    # normals toward the lit side: brightness rises along them
    assert (prof.values[:, -1] >= prof.values[:, 0]).all()
    assert np.allclose((prof.normals_vu * sc.terminator.normals_vu).sum(axis=1), 1.0)
    # the fit does not assume a limb: no soft-edge verdict for a kink; and the DT lock of a
    # terminator is pixels off, which the refinement does not hide behind an "ok"
    T = sc.terminator
    fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=(8, 8),
                       edge_profile=prof)
    assert "soft_edge" not in fit.reasons
    assert not (_err(fit, sc) > 0.5 and fit.status == "ok")


@pytest.mark.parametrize("psf_kind, known", [("gaussian", False), ("core+wings", True)])
def test_kernels_match_reference(psf_kind, known):
    sc = _scene(psf=0.8 if psf_kind == "gaussian" else 1.0, psf_kind=psf_kind)
    fit = fit_polyline(sc.image, sc.limb.vertices_vu, sc.limb.normals_vu, sc.limb.sigmas,
                       search_window_vu=(6, 6))
    prof = _profile(sc, psf_sigma_px=sc.psf_sigma_px if known else None)
    a = profile_fit.refine_with_profile(sc.image, prof, sc.limb.vertices_vu, fit.offset_vu)
    b = profile_fit.refine_with_profile(sc.image, prof, sc.limb.vertices_vu, fit.offset_vu,
                                        kernels=ref_kernels)
    np.testing.assert_allclose(a.offset_vu, b.offset_vu, atol=1e-9)
    np.testing.assert_allclose(a.psf_sigma_px, b.psf_sigma_px, atol=1e-9)
    np.testing.assert_allclose([a.wing_fraction, a.wing_sigma_px],
                               [b.wing_fraction, b.wing_sigma_px], atol=1e-9)
    assert a.iterations == b.iterations and a.n_pixels == b.n_pixels
    if psf_kind == "core+wings":  # the wings' path was taken
        assert a.wing_fraction > 0.0


def test_wings_folded_into_the_profile_are_the_two_component_model():
    """The full run's profile with the wings folded in (``wing_mixed``, blurred
    by the core alone) is the model of the core plus the wings, read directly."""
    from dtalign._kernels import profile as kp

    sc = _scene(psf=1.0, psf_kind="core+wings")
    prof = _profile(sc, psf_sigma_px=1.0)
    pb = profile_fit._problem(sc.image, prof, sc.limb.vertices_vu, (0.0, 0.0), 0.0, None, kp)
    params = np.array([0.0, 0.0, 150.0, 10.0, 1.0, 0.3, 0.5, 0.2, 4.0])
    mixed = profile_fit._with_wings(pb, params)
    for kernels in (kp, ref_kernels):  # the kernel and its specification
        np.testing.assert_allclose(
            kernels.wing_mixed(pb.values, pb.o0, pb.h, 0.2, float(np.sqrt(15.0)),
                               np.ascontiguousarray(7.5 * pb.curv)), mixed.values, atol=1e-12)
    kk, ii, jj = kp.select_pixels(300, 300, pb.verts, pb.normals, pb.tau, 3.5)
    pv, pu = ii.astype(float), jj.astype(float)
    obs = np.zeros(ii.shape[0])

    def model(p, values, shape, wings):
        t = kp.all_tables(values, shape, pb.o0, pb.h, pb.j0, pb.nb, p[4])
        w = kp.all_tables(values, shape, pb.o0, pb.h, pb.j0, pb.nb, p[8]) if wings else t
        r, _ = kp.evaluate(obs, kk, pv, pu, pb.verts, pb.normals, pb.curv, *t[:6], True, t[6],
                           t[7], *w[:6], wings, w[6], w[7], p)
        return -r

    direct = model(params, pb.values, pb.shape, True)
    folded = model(np.concatenate([params[:7], [0.0, 0.0]]), mixed.values, mixed.shape, False)
    # a few 1e-4 of the gain: the wide component's table interpolated onto the profile's grid
    assert np.abs(direct - folded).max() < 5e-4 * params[2]
    assert np.abs(direct - model(np.concatenate([params[:7], [0.0, 0.0]]), pb.values, pb.shape,
                                 False)).max() > 100 * np.abs(direct - folded).max()


CASES = [  # phase, illumination, radius, psf, psf known, noise
    (20.0, 0.0, 50.0, None, True, False),
    (35.0, 30.0, 85.0, None, True, False),
    (60.0, 200.0, 120.0, None, True, False),
    (35.0, 135.0, 85.0, 1.0, True, False),
    (45.0, 77.0, 85.0, 1.5, False, False),
    (35.0, 300.0, 100.0, 0.7, False, True),
    (40.0, 250.0, 90.0, None, True, True),
]


@pytest.mark.parametrize("case", CASES)
def test_profile_fit_meets_targets(case):
    phase, ill, radius, psf, known, noisy = case
    kw = dict(poisson_gain=4.0, read_noise_dn=1.0, seed=3) if noisy else {}
    sc = _scene(phase=phase, ill=ill, radius=radius, psf=psf, **kw)
    L = sc.limb
    plain = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6))
    prof = _profile(sc, psf_sigma_px=(psf or 0.0) if known else None)
    fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6),
                       edge_profile=prof)
    assert fit.profile is not None and fit.profile.accepted
    assert fit.lm.offset_vu == plain.offset_vu
    assert _err(fit, sc) <= 0.03  # the 95th-percentile target; the table's median is far below
    assert _err(fit, sc) < _err(plain, sc)


WINGS_CASES = [  # phase, illumination, radius, offset, noise
    (25.0, 10.0, 60.0, (0.37, -0.21), False),
    (40.0, 140.0, 95.0, (-1.18, 0.44), True),
    (55.0, 230.0, 115.0, (0.05, 1.31), False),
    (33.0, 310.0, 75.0, (2.27, -0.48), True),
]


@pytest.mark.parametrize("known", [True, False], ids=["core given", "estimated"])
def test_core_and_wings_psf_meets_targets(known):
    """What the fit is not told, a non-Gaussian PSF (the renderer's core plus
    wings: 20 % of the light in a Gaussian 4 times wider): median error <=
    0.03 px and never worse than the plain fit, with the core's sigma given
    as the profile's ``psf_sigma_px`` and with the PSF estimated."""
    errors = []
    for phase, ill, radius, off, noisy in WINGS_CASES:
        kw = dict(poisson_gain=20.0, read_noise_dn=1.0, seed=5) if noisy else {}
        sc = _scene(phase=phase, ill=ill, radius=radius, off=off, psf=1.0, psf_kind="core+wings",
                    albedo_dn=200.0, **kw)
        L = sc.limb
        plain = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas,
                             search_window_vu=(6, 6))
        fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas,
                           search_window_vu=(6, 6),
                           edge_profile=_profile(sc, psf_sigma_px=1.0 if known else None))
        assert fit.profile is not None and fit.profile.accepted and fit.status == "ok"
        assert _err(fit, sc) < _err(plain, sc)
        # the wings are found (the renderer's 20 %), not absorbed by the core
        assert 0.1 < fit.profile.wing_fraction < 0.4
        errors.append(_err(fit, sc))
    assert np.median(errors) <= 0.03


@pytest.mark.parametrize("phase", [3.0, 8.0, 12.0, 16.0])
def test_low_phase_never_confidently_wrong(phase):
    sc = _scene(phase=phase)
    L = sc.limb
    fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6),
                       edge_profile=_profile(sc))
    assert not (_err(fit, sc) > 0.5 and fit.status == "ok")


def test_batch_paths_refine_like_the_one_call_fit():
    from dtalign.pipeline import fit_polyline_products, prepare_image
    from dtalign.pipeline.batch import fit_images, fit_many

    sc = _scene(psf=0.7)
    L = sc.limb
    prof = _profile(sc, psf_sigma_px=0.7)
    products = prepare_image(sc.image)
    one = fit_polyline_products(products, L.vertices_vu, L.normals_vu, L.sigmas,
                                search_window_vu=(6, 6), edge_profile=prof)
    many = fit_many(products, [(L.vertices_vu, L.normals_vu, L.sigmas, prof), L],
                    search_window_vu=(6, 6), workers=1)
    assert many[0].offset_vu == one.offset_vu and many[0].profile.accepted
    assert many[1].profile is None and many[1].offset_vu == one.lm.offset_vu
    images = fit_images([(sc.image, None, [(L.vertices_vu, L.normals_vu, L.sigmas, prof)])],
                        search_window_vu=(6, 6), workers=1)
    assert images[0][0].offset_vu == one.offset_vu
    with pytest.raises(TypeError, match=r"polylines\[0\]"):
        fit_many(products, [(L.vertices_vu, L.normals_vu, L.sigmas, "nope")],
                 search_window_vu=(6, 6), workers=1)


def test_threaded_batches_refine_in_parallel_with_the_serial_results_and_errors(monkeypatch):
    # the refinements run on the batch's threads: the same fits, and the
    # first bad profile in input order is the one raised
    import threading

    import dtalign.pipeline.batch as batch
    from dtalign.benchmarking.compare import results_equal
    from dtalign.pipeline import prepare_image
    from dtalign.pipeline.batch import fit_many

    where = []

    def spy(*args, **kwargs):
        where.append(threading.current_thread().name)
        return conclude(*args, **kwargs)

    conclude = batch.conclude
    monkeypatch.setattr(batch, "conclude", spy)
    sc = _scene(psf=0.7)
    L = sc.limb
    good = (L.vertices_vu, L.normals_vu, L.sigmas, _profile(sc, psf_sigma_px=0.7))
    short = (L.vertices_vu, L.normals_vu, L.sigmas, sphere_edge_profile(
        L.vertices_vu[:-1], center_vu=sc.model_center_vu, radius_px=sc.radius_px,
        phase_deg=sc.phase_deg, illumination_deg=sc.illumination_deg, psf_sigma_px=0.7))
    wrong = (L.vertices_vu, L.normals_vu, L.sigmas, "nope")
    products = prepare_image(sc.image)
    polys = [good, L, good, wrong, good, short, good, L]
    serial = fit_many(products, polys, search_window_vu=(6, 6), workers=1, errors="collect")
    where.clear()
    threaded = fit_many(products, polys, search_window_vu=(6, 6), workers=2, errors="collect")
    # on the pool's workers ("dtalign-batch_0", ...), not its driver
    assert len(where) == 6 and all(name.startswith("dtalign-batch_") for name in where)
    assert [type(f).__name__ for f in serial] == [type(f).__name__ for f in threaded]
    assert isinstance(threaded[3], TypeError) and threaded[3].__notes__ == ["polylines[3]"]
    assert isinstance(threaded[5], ValueError) and threaded[5].__notes__ == ["polylines[5]"]
    assert str(serial[3]) == str(threaded[3]) and str(serial[5]) == str(threaded[5])
    kept = [i for i in range(len(polys)) if i not in (3, 5)]
    assert results_equal([serial[i] for i in kept], [threaded[i] for i in kept])
    assert all(threaded[i].profile.accepted for i in (0, 2, 4, 6))
    for workers in (1, 2):
        with pytest.raises(TypeError, match=r"polylines\[3\]"):
            fit_many(products, polys, search_window_vu=(6, 6), workers=workers)


@pytest.mark.parametrize("workers", [1, 2])
def test_progress_counts_a_polyline_with_a_profile_once_it_is_refined(monkeypatch, workers):
    # the refinement is most of such a polyline's time: a bar that reached its
    # total at the fits would then wait with nothing left to show
    import threading

    import dtalign.pipeline.batch as batch
    from dtalign.pipeline import prepare_image
    from dtalign.pipeline.batch import fit_many

    lock, refined = threading.Lock(), [0]

    def spy(*args, **kwargs):
        try:
            return conclude(*args, **kwargs)
        finally:
            if args[2] is not None:  # a refinement (a polyline with a profile)
                with lock:
                    refined[0] += 1

    conclude = batch.conclude
    monkeypatch.setattr(batch, "conclude", spy)
    sc = _scene(psf=0.7)
    L = sc.limb
    prof = _profile(sc, psf_sigma_px=0.7)
    good = (L.vertices_vu, L.normals_vu, L.sigmas, prof)
    wrong = (L.vertices_vu, L.normals_vu, L.sigmas, "nope")  # fails before its refinement
    bad_vertex = L.vertices_vu.copy()
    bad_vertex[2, 1] = np.nan
    unfit = (bad_vertex, L.normals_vu, L.sigmas, prof)  # fails before its fit
    polys = [good, L, good, wrong, good, unfit, good, L]
    # at each call, at most the plain polylines, the failed ones and those refined are done
    calls = []

    def progress(done, total):
        with lock:
            calls.append((done, total, refined[0]))

    out = fit_many(prepare_image(sc.image), polys, search_window_vu=(6, 6), workers=workers,
                   errors="collect", progress=progress)
    assert [type(f).__name__ for f in out] == ["PolylineFit", "PolylineFit", "PolylineFit",
                                               "TypeError", "PolylineFit", "ValueError",
                                               "PolylineFit", "PolylineFit"]
    n = len(polys)
    assert [(d, t) for d, t, _ in calls] == [(i, n) for i in range(1, n + 1)]
    assert all(done <= 2 + 2 + seen for done, _, seen in calls), calls
    assert calls[-1][2] == 4  # the total is reached once the four refinements are done


def test_profile_with_wrong_vertex_count_is_refused():
    sc = _scene()
    L = sc.limb
    prof = _profile(sc)
    with pytest.raises(ValueError, match="edge_profile"):
        fit_polyline(sc.image, L.vertices_vu[:-1], L.normals_vu[:-1], L.sigmas[:-1],
                     search_window_vu=(6, 6), edge_profile=prof)
    with pytest.raises(TypeError, match="edge_profile"):
        fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas,
                     search_window_vu=(6, 6), edge_profile=object())


def test_far_model_is_discarded_and_said():
    sc = _scene()
    L = sc.limb
    # a model sphere 3 px off the polyline's: the refinement walks away and is discarded
    prof = sphere_edge_profile(L.vertices_vu, center_vu=np.add(sc.model_center_vu, (3.0, 0.0)),
                               radius_px=85.0, phase_deg=35.0, illumination_deg=30.0)
    fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6),
                       edge_profile=prof)
    assert not fit.profile.accepted and fit.profile.reason
    assert "profile_rejected" in fit.reasons and fit.status == "suspect"
    assert fit.offset_vu == fit.lm.offset_vu
    assert "profile refinement rejected" in fit.status_message


def test_cli_fit_with_a_sphere_model(tmp_path, capsys):
    import json

    from dtalign.cli import main
    from dtalign.io import save_polyline_csv

    sc = _scene()
    np.save(tmp_path / "s.npy", sc.image)
    save_polyline_csv(tmp_path / "s.csv", sc.limb)
    v, u = sc.model_center_vu
    sphere = f"{v},{u},85,35,30"
    main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--window", "6",
          "--sphere", sphere, "--psf-sigma", "0", "--json"])
    out, _ = capsys.readouterr()
    d = json.loads(out)
    assert d["profile"]["accepted"]
    assert np.hypot(*(np.asarray(d["offset_vu"]) - sc.true_offset_vu)) < 0.03
    assert d["dt_offset_vu"] != d["offset_vu"]
    code = main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--window", "6",
                 "--sphere", sphere])
    out, _ = capsys.readouterr()
    assert code == 0 and "profile      : accepted" in out
    code = main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--sphere", "1,2,3"])
    _, err = capsys.readouterr()
    assert code != 0 and "--sphere" in err
    code = main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--law", "minnaert,0.7"])
    _, err = capsys.readouterr()
    assert code != 0 and "--law needs --sphere" in err


def test_campaign_item_with_a_sphere_stores_both_offsets(tmp_path):
    import json

    from dtalign.archive import fit_item, read_manifest
    from dtalign.io import save_polyline_csv

    sc = _scene()
    np.save(tmp_path / "s.npy", sc.image)
    save_polyline_csv(tmp_path / "s.csv", sc.limb)
    sphere = {"center_vu": list(sc.model_center_vu), "radius_px": 85.0, "phase_deg": 35.0,
              "illumination_deg": 30.0, "psf_sigma_px": 0.0}
    (tmp_path / "m.jsonl").write_text(
        json.dumps({"image": "s.npy", "polylines": ["s.csv"], "window": 6, "spheres": [sphere]})
        + "\n" + json.dumps({"id": "plain", "image": "s.npy", "polylines": ["s.csv"], "window": 6})
        + "\n")
    items = read_manifest(tmp_path / "m.jsonl")
    assert items[0].spheres == (sphere,) and items[1].spheres == ()
    row = fit_item(items[0])["results"][0]
    assert row["profile_accepted"] is True
    assert np.hypot(row["offset_v"] - sc.true_offset_vu[0],
                    row["offset_u"] - sc.true_offset_vu[1]) < 0.03
    assert (row["dt_offset_v"], row["dt_offset_u"]) != (row["offset_v"], row["offset_u"])
    plain = fit_item(items[1])["results"][0]
    assert plain["profile_accepted"] is None
    assert (plain["dt_offset_v"], plain["dt_offset_u"]) == (plain["offset_v"], plain["offset_u"])
    assert (plain["offset_v"], plain["offset_u"]) == (row["dt_offset_v"], row["dt_offset_u"])
    (tmp_path / "bad.jsonl").write_text(json.dumps(
        {"image": "s.npy", "polylines": ["s.csv"], "spheres": [{"radius_px": 3}]}) + "\n")
    with pytest.raises(ValueError, match="spheres"):
        read_manifest(tmp_path / "bad.jsonl")


def test_plot_profile_fit(tmp_path):
    pytest.importorskip("matplotlib")
    from dtalign.plotting import plot_profile_fit

    sc = _scene(psf=1.0)
    L = sc.limb
    prof = _profile(sc, psf_sigma_px=None)
    fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6),
                       edge_profile=prof)
    fig = plot_profile_fit(fit, sc.image, prof, tmp_path / "p.png", n_normals=3)
    assert (tmp_path / "p.png").stat().st_size > 0 and len(fig.axes) == 3
    # the model runs through the pixels: residuals at the noise-free scene's level
    from dtalign.pipeline.profile_fit import profile_samples

    for smp in profile_samples(sc.image, prof, L.vertices_vu, fit.profile, [50, 100]):
        assert np.abs(smp["residual"]).max() < 0.05 * fit.profile.gain
        assert smp["dt_shift"] != 0.0
    plain = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6))
    with pytest.raises(ValueError, match="profile"):
        plot_profile_fit(plain, sc.image, prof)


def test_a_refined_fit_round_trips_through_its_dict():
    """``from_dict`` keeps the refined offset, the DT-LM one and the refinement."""
    import json

    from dtalign.pipeline import PolylineFit

    sc = _scene()
    L = sc.limb
    fit = fit_polyline(sc.image, L.vertices_vu, L.normals_vu, L.sigmas, search_window_vu=(6, 6),
                       edge_profile=_profile(sc))
    assert fit.profile is not None and fit.profile.accepted
    assert fit.offset_vu != fit.lm.offset_vu
    d = fit.to_dict(arrays=True)
    back = PolylineFit.from_dict(json.loads(json.dumps(d, allow_nan=False)))
    assert back.offset_vu == fit.offset_vu and back.lm.offset_vu == fit.lm.offset_vu
    assert back.profile == fit.profile
    assert back.to_dict(arrays=True) == d
