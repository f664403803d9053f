"""dtalign.pipeline.batch: threaded and process batches give exactly the serial results, in order."""

from __future__ import annotations

import inspect
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import _batch_scene
import dtalign
from _batch_scene import WINDOW
from dtalign import scenes
from dtalign.benchmarking.compare import results_equal
from dtalign.pipeline import fit_polyline_products, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many, map_ordered

nav = _batch_scene.nav  # the shared scene (a module-scoped fixture)
products = _batch_scene.products


@pytest.fixture(scope="module")
def polylines(nav):
    """Twelve distinct polylines: the three of the scene, shifted by whole and half pixels."""
    out = []
    for k in range(12):
        p = nav.polylines[k % 3]
        shift = np.array([0.5 * (k // 3), -0.25 * (k // 3)])
        out.append(scenes.Polyline(p.name, p.vertices_vu + shift, p.normals_vu, p.sigmas))
    return out


@pytest.fixture(scope="module")
def wide():
    """A scene whose DT is over FULL_SCAN_MAX_SIZE pixels: a NaN in it is found
    only where a fit reads it (in the compiled loop), not by the up-front
    checks. Its products and twelve polylines, as the ``polylines`` fixture."""
    from dtalign.api.checks import FULL_SCAN_MAX_SIZE

    scene = scenes.navigation_scene(shape=(288, 288), radius=60.0, n_vertices=80,
                                    offset_vu=(3.4, -2.2), search_window=12)
    assert scene.image.size > FULL_SCAN_MAX_SIZE
    polys = []
    for k in range(12):
        p = scene.polylines[k % 3]
        shift = np.array([0.5 * (k // 3), -0.25 * (k // 3)])
        polys.append((p.vertices_vu + shift, p.normals_vu, p.sigmas))
    return prepare_image(scene.image, scene.noise_sigma), polys


def _nan_corner(products, items, at):
    """``products`` with a NaN DT corner no polyline of the scene comes near,
    and ``items`` with polyline ``at`` moved into it."""
    import dataclasses

    h, w = products.shape
    dt = np.array(products.edge_dt)
    dt[h - 40 :, w - 40 :] = np.nan
    corner = np.array([h - 16.0, w - 16.0]) + np.arange(8.0)[:, None] * np.array([1.0, 1.2])
    items = list(items)
    items[at] = (corner, np.tile([1.0, 0.0], (8, 1)), np.ones(8))
    return dataclasses.replace(products, edge_dt=dt), items


def _serial(products, polylines, **options):
    return [
        fit_polyline_products(products, p.vertices_vu, p.normals_vu, p.sigmas,
                              search_window_vu=WINDOW, **options)
        for p in polylines
    ]


@pytest.mark.parametrize("workers", [1, 2, 3, 16])
def test_fit_many_equals_serial(products, polylines, workers):
    expected = _serial(products, polylines, trust_region_px=1.0)
    got = fit_many(products, polylines, search_window_vu=WINDOW, workers=workers,
                   trust_region_px=1.0)
    assert len(got) == len(expected)
    assert results_equal(got, expected)
    # Order: each result belongs to its own polyline (they all differ).
    offsets = [f.offset_vu for f in got]
    assert len(set(offsets)) == len(offsets)
    assert offsets == [f.offset_vu for f in expected]


def test_fit_many_options_and_tuple_polylines(products, polylines, nav):
    options = {"fit_rotation": True, "pivot_distance_px": nav.pivot_distance_px,
               "final_gradient_ridge": True}
    items = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in polylines[:6]]
    got = fit_many(products, items, search_window_vu=WINDOW, workers=2, **options)
    assert results_equal(got, _serial(products, polylines[:6], **options))
    assert all(f.fit_rotation for f in got)


def test_fit_many_empty_and_single(products, polylines):
    assert fit_many(products, [], search_window_vu=WINDOW) == []
    assert results_equal(fit_many(products, polylines[:1], search_window_vu=WINDOW),
                         _serial(products, polylines[:1]))


@pytest.mark.parametrize("executor", ["thread", "process"])
def test_fit_images_equals_serial(nav, executor):
    other = scenes.navigation_scene(shape=(256, 256), radius=50.0, n_vertices=60,
                                    offset_vu=(-2.6, 1.7), seed=3)
    items = [nav, (other.image, None, other.polylines), (nav.image, 2.0, nav.polylines[:1])]
    expected = []
    for image, noise, polys in [(nav.image, nav.noise_sigma, nav.polylines),
                                (other.image, None, other.polylines),
                                (nav.image, 2.0, nav.polylines[:1])]:
        expected.append(_serial(prepare_image(image, noise), polys))
    got = fit_images(items, search_window_vu=WINDOW, workers=2, executor=executor)
    assert [len(g) for g in got] == [3, 3, 1]
    assert results_equal(got, expected)
    assert got[1][0].noise_sigma == expected[1][0].noise_sigma  # estimated the same way


def test_public_functions_scale_in_a_thread_pool(nav):
    """The kernels release the GIL; threaded calls give the serial results."""
    _, dt, grad = dtalign.compute_all_image_derivatives(nav.image, nav.noise_sigma)
    edge = dt <= 0.5

    def one(p):
        mask = dtalign.build_polyline_mask(p.vertices_vu, dt.shape)
        seed = dtalign.coarse_ncc_search(edge, mask, WINDOW)
        return seed, dtalign.lm_subpixel_refine(
            vertices_vu=p.vertices_vu, normals_vu=p.normals_vu,
            sigma_normal_per_vertex_px=p.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
            initial_offset_vu=(float(seed[0]), float(seed[1])))

    polys = list(nav.polylines) * 4
    serial = [one(p) for p in polys]
    with ThreadPoolExecutor(max_workers=2) as pool:
        threaded = list(pool.map(one, polys))
    assert results_equal(threaded, serial)
    assert results_equal(map_ordered(one, polys, workers=2), serial)

    images = [nav.image, nav.image[::-1].copy(), nav.image.T.copy()]
    serial_d = [dtalign.compute_all_image_derivatives(im, 2.0) for im in images]
    threaded_d = map_ordered(lambda im: dtalign.compute_all_image_derivatives(im, 2.0),
                             images, workers=2)
    assert results_equal(threaded_d, serial_d)


def test_map_ordered_raises_first_error_in_order():
    def fn(x):
        if x in (3, 5):
            raise ValueError(f"bad {x}")
        return x * x

    assert map_ordered(fn, range(3), workers=2) == [0, 1, 4]
    with pytest.raises(ValueError, match="bad 3"):
        map_ordered(fn, range(8), workers=2)


def test_fit_many_propagates_fit_errors(products, polylines):
    p = polylines[0]
    bad = (p.vertices_vu, p.normals_vu, -p.sigmas)
    items = [polylines[1], bad, polylines[2]]
    with pytest.raises(ValueError, match="sigmas must be finite and > 0"):
        fit_many(products, items, search_window_vu=WINDOW, workers=2)
    with pytest.raises(TypeError, match="search_window_vu"):
        fit_many(products, polylines[:2], search_window_vu=(1.5, 2), workers=2)


@pytest.mark.parametrize("workers, exc, match", [
    (0, ValueError, "workers must be >= 1"),
    (-2, ValueError, "workers must be >= 1"),
    (1.5, TypeError, "workers must be an int"),
    ("2", TypeError, "workers must be an int"),
    (True, TypeError, "workers must be an int"),
    (None, TypeError, "workers must be an int"),
])
def test_bad_workers(products, polylines, workers, exc, match):
    with pytest.raises(exc, match=match):
        fit_many(products, polylines[:2], search_window_vu=WINDOW, workers=workers)
    with pytest.raises(exc, match=match):
        fit_images([], search_window_vu=WINDOW, workers=workers)
    with pytest.raises(exc, match=match):
        map_ordered(abs, [1], workers=workers)


def test_argument_errors(products, polylines, nav):
    with pytest.raises(TypeError, match="products must be an ImageProducts"):
        fit_many(nav.image, polylines, search_window_vu=WINDOW)
    with pytest.raises(TypeError, match="unexpected fit option.*'trust_region'"):
        fit_many(products, polylines, search_window_vu=WINDOW, trust_region=1.0)
    with pytest.raises(TypeError, match=r"polylines\[1\] must have vertices_vu"):
        fit_many(products, [polylines[0], "limb"], search_window_vu=WINDOW)
    with pytest.raises(TypeError, match=r"polylines\[0\] must have"):
        fit_many(products, [(1, 2)], search_window_vu=WINDOW)
    with pytest.raises(TypeError, match=r"items\[0\] must be an \(image, noise_sigma"):
        fit_images([nav.image], search_window_vu=WINDOW)
    with pytest.raises(TypeError, match=r"items\[0\] polylines must be an iterable"):
        fit_images([(nav.image, 2.0, 5)], search_window_vu=WINDOW)
    with pytest.raises(ValueError, match="executor must be one of"):
        fit_images([nav], search_window_vu=WINDOW, executor="gpu")
    with pytest.raises(TypeError, match="config must be an ImageDerivativesConfig"):
        fit_images([nav], search_window_vu=WINDOW, config={"dt_half_width_px": 10.0})
    with pytest.raises(TypeError, match="unexpected fit option"):
        fit_images([nav], search_window_vu=WINDOW, noise=2.0)
    with pytest.raises(TypeError, match="image must be 2-D"):
        fit_images([(nav.image[0], 2.0, nav.polylines)], search_window_vu=WINDOW, workers=2)


def test_results_equal(products, polylines):
    a, b = _serial(products, polylines[:2])
    again = _serial(products, polylines[:2])
    assert results_equal([a, b], again)
    assert not results_equal(a, b)
    assert not results_equal([a], [a, b])
    assert results_equal(np.array([np.nan, 1.0]), np.array([np.nan, 1.0]))
    assert not results_equal(np.zeros(2), np.zeros(3))
    assert not results_equal(a, a.lm)
    assert results_equal(float("nan"), float("nan"))


def _serial_error(products, items, **options):
    """The exception the serial loop raises for ``items`` (None if none)."""
    try:
        for v, n, s in items:
            fit_polyline_products(products, v, n, s, search_window_vu=WINDOW, **options)
    except (TypeError, ValueError) as exc:
        return exc
    return None


def _bad_variants(p):
    """Polylines that fail a different check each, as fitting them alone reports."""
    v, n, s = p.vertices_vu, p.normals_vu, p.sigmas
    nan_v = v.copy()
    nan_v[3, 0] = np.nan
    inf_n = n.copy()
    inf_n[5, 1] = np.inf
    huge = np.full_like(v, 1e308)
    return {
        "nan vertex": (nan_v, n, s),
        "inf normal": (v, inf_n, s),
        "zero sigma": (v, n, np.where(np.arange(s.size) == 7, 0.0, s)),
        "tiny sigma": (v, n, np.full_like(s, 1e-200)),
        "normals shape": (v, n[:-1], s),
        "sigmas shape": (v, n, s[:-1]),
        "vertices shape": (v[:, :1], n, s),
        "empty": (v[:0], n[:0], s[:0]),
        "strings": (v.astype(str), n, s),
        "centroid overflow": (huge, n, s),
    }


@pytest.mark.parametrize("kind", sorted(_bad_variants(scenes.disc_scene(n_vertices=16).polyline)))
@pytest.mark.parametrize("position", [0, 1, 5])
@pytest.mark.parametrize("workers", [1, 2])
def test_fit_many_raises_what_the_serial_loop_raises(products, polylines, kind, position, workers):
    items = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in polylines[:8]]
    items[position] = _bad_variants(polylines[position])[kind]
    expected = _serial_error(products, items)
    assert expected is not None
    with pytest.raises(type(expected)) as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=workers)
    assert str(info.value) == str(expected)
    assert info.value.__notes__ == [f"polylines[{position}]"]
    assert info.value.index == position


def test_fit_many_rotation_pivot_spread_error_in_the_middle(products, polylines):
    # With a far pivot, a polyline of huge coordinates overflows only when rotated.
    items = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in polylines[:4]]
    items[2] = (np.full((6, 2), 1e308), polylines[2].normals_vu[:6], polylines[2].sigmas[:6])
    # (2 * (v - pivot) must stay finite: 2 * (1e308 + 1e307) does not, 2 * (256 + 1e307) does)
    options = {"fit_rotation": True, "pivot_vu": (-1e307, 0.0), "pivot_distance_px": 50.0}
    expected = _serial_error(products, items, **options)
    assert expected is not None
    with pytest.raises(type(expected)):  # polyline 2 alone: the serial loop's error is its own
        fit_polyline_products(products, *items[2], search_window_vu=WINDOW, **options)
    fit_polyline_products(products, *items[1], search_window_vu=WINDOW, **options)
    with pytest.raises(type(expected)) as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=2, **options)
    assert str(info.value) == str(expected)
    assert info.value.__notes__ == ["polylines[2]"]
    assert info.value.index == 2


def test_fit_many_first_error_in_input_order_beats_later_ones(products, polylines):
    bad = _bad_variants(polylines[0])
    items = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in polylines[:10]]
    items[3] = bad["inf normal"]
    items[8] = bad["nan vertex"]
    with pytest.raises(ValueError, match=r"^normals_vu must be finite") as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=2)
    assert info.value.__notes__ == ["polylines[3]"]
    assert info.value.index == 3


def test_fit_many_kernel_error_before_a_bad_polyline_comes_first(wide):
    # Polyline 0 reads a NaN of the DT, which only the kernel finds (the DT
    # is too large for the up-front scan); polyline 1 is malformed. The
    # serial loop stops at polyline 0.
    products, items = _nan_corner(*wide, at=0)
    items = [items[0], _bad_variants(scenes.Polyline("p", *wide[1][1]))["nan vertex"]]
    expected = _serial_error(products, items)
    assert expected is not None and "the fit read a NaN" in str(expected)
    with pytest.raises(ValueError) as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=2)
    assert str(info.value) == str(expected)
    assert info.value.__notes__ == ["polylines[0]"]
    assert info.value.index == 0


def test_fit_many_converts_layouts_like_the_serial_calls(products, polylines):
    items = []
    for k, p in enumerate(polylines):
        v, n, s = p.vertices_vu, p.normals_vu, p.sigmas
        if k % 4 == 1:
            v, n, s = v.astype(np.float32), n.tolist(), s.astype(np.float32)
        elif k % 4 == 2:
            v, n = np.asfortranarray(v), n[::-1][::-1].copy(order="F")
        elif k % 4 == 3:
            v = v.astype(">f8")
        items.append((v, n, s))
    serial = [fit_polyline_products(products, *it, search_window_vu=WINDOW) for it in items]
    assert results_equal(fit_many(products, items, search_window_vu=WINDOW, workers=2), serial)


def test_batch_fit_results_are_read_only_and_independent(products, polylines):
    fits = fit_many(products, polylines, search_window_vu=WINDOW, workers=2)
    for f in fits:
        for arr in (f.vertices_vu, f.normals_vu, f.lm.residuals_px, f.lm.weights, f.lm.covariance):
            assert not arr.flags.writeable
        for arr in (f.lm.residuals_px, f.lm.weights, f.lm.covariance):
            with pytest.raises(ValueError):  # shared output rows, locked at their base
                arr.flags.writeable = True
        assert set(f.timings_s) >= {"fit"}
    fits[0].timings_s["fit"] = -1.0
    assert fits[1].timings_s["fit"] >= 0.0


def test_nested_map_ordered_does_not_deadlock(products, polylines):
    # fn itself fans out (nested map_ordered): must finish, in order.
    def inner(k):
        return fit_many(products, polylines[k : k + 3], search_window_vu=WINDOW, workers=2)

    with ThreadPoolExecutor(max_workers=1) as guard:  # a deadlock fails instead of hanging
        got = guard.submit(map_ordered, inner, range(4), workers=2).result(timeout=120)
    for k, fits in enumerate(got):
        assert results_equal(fits, _serial(products, polylines[k : k + 3]))


@pytest.mark.parametrize("workers", [1, 2, 3, 16])
def test_fit_many_kernel_failure_in_the_middle_raises_the_serial_error(wide, workers):
    # Polyline 7 reads a NaN of the DT (found only by the kernel): the
    # serial loop's error, named, whatever the threads were doing.
    broken, items = _nan_corner(*wide, at=7)
    expected_error = _serial_error(broken, items)
    assert expected_error is not None and "the fit read a NaN" in str(expected_error)
    with pytest.raises(ValueError) as info:
        fit_many(broken, items, search_window_vu=WINDOW, workers=workers)
    assert str(info.value) == str(expected_error)
    assert info.value.__notes__ == ["polylines[7]"]
    assert info.value.index == 7


@pytest.mark.parametrize(("nan_at", "bad_at"), [(1, 9), (6, 9), (6, 2), (2, 6), (9, 10), (10, 9)])
@pytest.mark.parametrize("workers", [2, 3])
def test_fit_many_kernel_and_check_errors_come_in_serial_order(
        wide, nan_at, bad_at, workers):
    # A kernel failure (polyline nan_at reads a NaN of the DT) and a malformed
    # polyline (bad_at), in either order, early or late in the list, raise
    # what the serial loop raises first.
    products, items = _nan_corner(*wide, at=nan_at)
    v, n, s = items[bad_at]
    items[bad_at] = (v, n, np.where(np.arange(s.size) == 7, 0.0, s))
    expected = _serial_error(products, items)
    assert expected is not None
    assert ("the fit read a NaN" in str(expected)) == (nan_at < bad_at)
    with pytest.raises(type(expected)) as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=workers)
    first = min(nan_at, bad_at)
    assert str(info.value) == str(expected)
    assert info.value.__notes__ == [f"polylines[{first}]"]
    assert info.value.index == first


def test_calls_leave_no_threads_behind(products, polylines):
    # Each call's pool is shut down before it returns, whatever happened.
    before = threading.active_count()
    fit_many(products, polylines, search_window_vu=WINDOW, workers=3)
    assert threading.active_count() == before
    with pytest.raises(RuntimeError, match="boom"):
        map_ordered(_boom_at(5), range(50), workers=4)
    assert threading.active_count() == before
    assert map_ordered(lambda x: x * x, range(50), workers=2) == [x * x for x in range(50)]
    # many calls at once: each has its own pool and queue
    expected = _serial(products, polylines[:3])
    with ThreadPoolExecutor(max_workers=12) as pool:
        got = list(pool.map(lambda _: fit_many(products, polylines[:3], search_window_vu=WINDOW,
                                                 workers=3), range(24)))
    assert all(results_equal(g, expected) for g in got)


def _boom_at(bad):
    def fn(x):
        if x == bad:
            raise RuntimeError("boom")
        return x
    return fn


def test_map_ordered_starts_nothing_after_a_failure():
    started = []

    def fn(x):
        started.append(x)
        if x == 3:
            raise ValueError("bad 3")
        time.sleep(0.005)  # releases the GIL: the failing thread sets the stop meanwhile
        return x

    with pytest.raises(ValueError, match="bad 3"):
        map_ordered(fn, range(200), workers=2)
    # the other thread finishes what it holds; nothing like the 196 items left
    assert set(started) >= {0, 1, 2, 3}
    assert len(started) < 20


def test_default_workers_are_the_usable_cpus():
    import os

    from dtalign.pipeline import batch

    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert batch.DEFAULT_WORKERS == usable
    assert inspect.signature(fit_many).parameters["workers"].default == usable


def _fit_in_forked_child(args):
    products, polylines = args
    fits = fit_many(products, polylines, search_window_vu=WINDOW, workers=2)
    return [f.offset_vu for f in fits]


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_fit_many_in_a_forked_child_does_not_wait_for_the_parents_helpers(products, polylines):
    import multiprocessing

    fit_many(products, polylines, search_window_vu=WINDOW, workers=2)  # helpers parked here
    expected = [f.offset_vu for f in _serial(products, polylines)]
    with multiprocessing.get_context("fork").Pool(1) as pool:
        got = pool.apply_async(_fit_in_forked_child, ((products, polylines),)).get(timeout=120)
    assert got == expected


class _Subclass(np.ndarray):
    """An ndarray subclass: not a plain array to the checks."""


def _plain_variants():
    """Polylines that :func:`dtalign.pipeline.jobs._plain` accepts or refuses, by name."""
    rng = np.random.default_rng(5)
    v = rng.normal(size=(7, 2))
    n = v / np.hypot(v[:, :1], v[:, 1:])
    s = np.ones(7)
    return {
        "plain": (v, n, s),
        "fortran": (np.asfortranarray(v), np.asfortranarray(n), s),
        "strided": (np.repeat(v, 2, axis=0)[::2], n, s[::1]),
        "float32 vertices": (v.astype(np.float32), n, s),
        "big-endian normals": (v, n.astype(">f8"), s),
        "int sigmas": (v, n, s.astype(np.int64)),
        "list vertices": (v.tolist(), n, s),
        "subclass vertices": (v.view(_Subclass), n, s),
        "three columns": (np.c_[v, v[:, :1]], np.c_[n, n[:, :1]], s),
        "one column normals": (v, n[:, :1], s),
        "3-D vertices": (v[:, :, None], n, s),
        "short normals": (v, n[:-1], s),
        "short sigmas": (v, n, s[:-1]),
        "2-D sigmas": (v, n, s[:, None]),
        "empty": (v[:0], n[:0], s[:0]),
    }


@pytest.mark.parametrize("kind", sorted(_plain_variants()))
@pytest.mark.parametrize("position", [0, 3])
def test_bulk_shape_check_agrees_with_the_per_polyline_one(kind, position):
    from dtalign.pipeline.jobs import _concatenated, _plain

    good = _plain_variants()["plain"]
    items = [good] * 5
    items[position] = _plain_variants()[kind]
    vs, ns, ss = (list(x) for x in zip(*items, strict=True))
    got = _concatenated(vs, ns, ss)
    if all(_plain(*it) for it in items):
        assert got is not None
        for arr, parts in zip(got[:3], (vs, ns, ss), strict=True):
            assert arr.dtype == np.float64 and np.array_equal(arr, np.concatenate(parts))
        assert got[3] == [len(v) for v in vs]
    else:
        assert got is None


def test_the_pipelines_lm_arguments_equal_the_drop_ins_checks(products, polylines):
    """A fit's LM arguments are the call's checked options with the polyline's
    checked item (what ``fit_from`` passes): field for field what
    ``lm_subpixel_refine``'s own checks make of the same keywords."""
    from dtalign.api.checks import check_lm_inputs
    from dtalign.api.options import FitOptions
    from dtalign.pipeline import jobs

    p = polylines[1]
    options = FitOptions(fit_rotation=True, pivot_distance_px=40.0, max_iterations=7,
                         damping=1e-3, step_tolerance_px=1e-4, tukey_c=4.685, pinvh_rcond=1e-12,
                         trust_region_px=1.0, initial_rotation_rad=0.01)
    shared = jobs.plan(products, jobs.check_options(options))
    it = jobs.item(shared, p.vertices_vu, p.normals_vu, p.sigmas)
    given = shared.lm._replace(vertices=it.vertices, normals=it.normals, sigmas=it.sigmas,
                               offset=(1.0, -2.0), pivot=it.pivot, pivot_distance=it.distance)
    full = check_lm_inputs({
        "vertices_vu": p.vertices_vu, "normals_vu": p.normals_vu,
        "sigma_normal_per_vertex_px": p.sigmas, "image_edge_dt": products.edge_dt,
        "image_gradient_vu": products.gradient_vu, "initial_offset_vu": (1.0, -2.0),
        "fit_rotation": True, "pivot_vu": None, "pivot_distance_px": 40.0,
        **options.lm_keywords(),
    })
    assert full._fields == given._fields
    for name, a, b in zip(full._fields, full, given, strict=True):
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.flags.writeable == b.flags.writeable, name
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            assert a == b, name
