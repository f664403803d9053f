"""dtalign.pipeline.batch errors: an item's own error noted with its name, an index
attribute, and errors="collect" (issue 18.6/18.4)."""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import _batch_scene
from _batch_scene import WINDOW
from dtalign import scenes
from dtalign.benchmarking.compare import results_equal
from dtalign.pipeline import fit_polyline_products, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many

nav = _batch_scene.nav  # the shared scene (a module-scoped fixture)
products = _batch_scene.products


@pytest.fixture(scope="module")
def items(nav):
    """64 good polylines (the scene's three, shifted by whole and half pixels)."""
    out = []
    for k in range(64):
        p = nav.polylines[k % 3]
        shift = np.array([0.5 * (k // 3 % 5), -0.25 * (k // 3 % 7)])
        out.append((p.vertices_vu + shift, p.normals_vu, p.sigmas))
    return out


def _nan(item):
    v = item[0].copy()
    v[2, 1] = np.nan
    return (v, item[1], item[2])


def _alone(products, item, **options):
    """What fitting ``item`` alone gives: its fit, or the exception it raises."""
    try:
        return fit_polyline_products(products, *item, search_window_vu=WINDOW, **options)
    except (TypeError, ValueError) as exc:
        return exc


def _nan_dt_corner(nav):
    """Products whose DT has a NaN corner the kernel finds (too large to scan up front)
    and a polyline that reads it."""
    scene = scenes.navigation_scene(shape=(288, 288), radius=60.0, n_vertices=80,
                                    offset_vu=(3.4, -2.2), search_window=12)
    products = prepare_image(scene.image, scene.noise_sigma)
    h, w = products.shape
    dt = np.array(products.edge_dt)
    dt[h - 40 :, w - 40 :] = np.nan
    corner = np.array([h - 16.0, w - 16.0]) + np.arange(8.0)[:, None] * np.array([1.0, 1.2])
    reads_nan = (corner, np.tile([1.0, 0.0], (8, 1)), np.ones(8))
    return dataclasses.replace(products, edge_dt=dt), reads_nan, scene


def test_nan_polyline_at_31_of_64_is_named_and_carries_its_index(products, items):
    bad = list(items)
    bad[31] = _nan(items[31])
    alone = _alone(products, bad[31])
    assert isinstance(alone, ValueError)
    for workers in (1, 2, 3):
        with pytest.raises(ValueError) as info:
            fit_many(products, bad, search_window_vu=WINDOW, workers=workers)
        assert type(info.value) is type(alone) and str(info.value) == str(alone)
        assert info.value.__notes__ == ["polylines[31]"]
        assert info.value.index == 31


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_collect_returns_every_good_fit_and_each_error(products, items, nav, workers):
    broken, reads_nan, scene = _nan_dt_corner(nav)
    polys = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in scene.polylines] * 4
    bad_at = {0: _nan(polys[0]), 5: (polys[5][0], polys[5][1], -polys[5][2]),
              6: reads_nan, 9: (polys[9][0][:, :1], polys[9][1], polys[9][2]), 11: reads_nan}
    for i, item in bad_at.items():
        polys[i] = item
    got = fit_many(broken, polys, search_window_vu=WINDOW, workers=workers, errors="collect")
    assert len(got) == len(polys)
    for i, (item, result) in enumerate(zip(polys, got, strict=True)):
        alone = _alone(broken, item)
        if i in bad_at:
            assert isinstance(alone, ValueError), i
            assert type(result) is type(alone), i
            assert str(result) == str(alone) and result.__notes__ == [f"polylines[{i}]"]
            assert result.index == i
        else:
            assert not isinstance(alone, Exception), i
            assert results_equal(result, alone), i
    assert "the fit read a NaN" in str(got[6]) and "the fit read a NaN" in str(got[11])


def test_collect_with_only_good_or_only_bad_polylines(products, items):
    good = fit_many(products, items[:8], search_window_vu=WINDOW, workers=2, errors="collect")
    assert results_equal(good, fit_many(products, items[:8], search_window_vu=WINDOW))
    bad = [_nan(it) for it in items[:4]]
    got = fit_many(products, bad, search_window_vu=WINDOW, workers=2, errors="collect")
    assert [e.index for e in got] == [0, 1, 2, 3]
    assert all(isinstance(e, ValueError) and "vertices_vu" in str(e) for e in got)
    assert fit_many(products, [], search_window_vu=WINDOW, errors="collect") == []


def test_collect_still_raises_the_calls_own_errors(products, items):
    # a shared argument is the call's error, not every polyline's
    with pytest.raises(ValueError, match="tukey_c") as info:
        fit_many(products, items[:4], search_window_vu=WINDOW, errors="collect", tukey_c=-1.0)
    assert not hasattr(info.value, "index")
    with pytest.raises(TypeError, match="search_window_vu"):
        fit_many(products, items[:4], search_window_vu=(1.5, 2), errors="collect")
    with pytest.raises(ValueError, match="errors must be one of"):
        fit_many(products, items[:4], search_window_vu=WINDOW, errors="ignore")
    with pytest.raises(ValueError, match="errors must be one of"):
        fit_images([], search_window_vu=WINDOW, errors=None)


def test_raise_mode_names_the_first_polyline_but_not_a_shared_error(products, items):
    with pytest.raises(ValueError, match=r"^vertices_vu") as info:
        fit_many(products, [_nan(items[0])] + items[1:3], search_window_vu=WINDOW)
    assert info.value.__notes__ == ["polylines[0]"]
    assert info.value.index == 0
    expected = _alone(products, items[0], tukey_c=-1.0)
    with pytest.raises(ValueError) as info:
        fit_many(products, items[:3], search_window_vu=WINDOW, tukey_c=-1.0)
    assert str(info.value) == str(expected)  # as fit_polyline_products says it
    assert not hasattr(info.value, "index") and not hasattr(info.value, "__notes__")


def test_fit_images_names_the_image_and_the_path(nav, tmp_path):
    good = tmp_path / "frame.npy"
    np.save(good, nav.image)
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    missing = tmp_path / "missing.npy"
    polys = list(nav.polylines)
    bad_poly = _nan((polys[1].vertices_vu, polys[1].normals_vu, polys[1].sigmas))
    jobs = [
        (good, nav.noise_sigma, polys),
        (str(missing), nav.noise_sigma, polys),
        (nav.image, nav.noise_sigma, [polys[0], bad_poly, polys[2]]),
        (empty, nav.noise_sigma, polys),
        (nav.image[0], 2.0, polys),
        (nav.image, None, polys),
    ]
    expected_good = fit_images([(nav.image, nav.noise_sigma, polys)], search_window_vu=WINDOW)[0]
    for workers in (1, 2):
        got = fit_images(jobs, search_window_vu=WINDOW, workers=workers, errors="collect")
        assert len(got) == len(jobs)
        assert results_equal(got[0], expected_good)  # loaded from the file: the same fits
        assert isinstance(got[1], Exception) and got[1].index == 1
        assert got[1].__notes__ == [f"images[1] ({missing})"]
        assert isinstance(got[2], list) and len(got[2]) == 3
        assert results_equal(got[2][0], expected_good[0])
        assert results_equal(got[2][2], expected_good[2])
        assert isinstance(got[2][1], ValueError) and got[2][1].index == 1
        assert str(got[2][1]).startswith("vertices_vu")
        assert got[2][1].__notes__ == ["polylines[1]"]
        assert isinstance(got[3], Exception) and got[3].index == 3  # an empty .npy
        assert got[3].__notes__ == [f"images[3] ({empty})"]
        assert isinstance(got[4], TypeError) and got[4].index == 4
        assert got[4].__notes__ == ["images[4]"] and "2-D" in str(got[4])
        assert results_equal(got[5], fit_images([jobs[5]], search_window_vu=WINDOW)[0])
        # raising: the first failing image's own error, noted
        with pytest.raises(Exception) as info:
            fit_images(jobs, search_window_vu=WINDOW, workers=workers)
        assert info.value.__notes__ == [f"images[1] ({missing})"]
        assert info.value.index == 1
        with pytest.raises(ValueError) as info:
            fit_images(jobs[2:3], search_window_vu=WINDOW, workers=workers)
        assert str(info.value).startswith("vertices_vu")
        assert info.value.__notes__ == ["polylines[1]", "images[0]"]
        assert info.value.index == 0


def test_fit_images_on_a_callers_executor(nav):
    other = scenes.navigation_scene(shape=(256, 256), radius=50.0, n_vertices=60,
                                    offset_vu=(-2.6, 1.7), seed=3)
    jobs = [nav, other, (nav.image, 2.0, nav.polylines[:1])]
    expected = fit_images(jobs, search_window_vu=WINDOW, workers=1)
    with ThreadPoolExecutor(max_workers=2) as pool:
        assert results_equal(fit_images(jobs, search_window_vu=WINDOW, executor=pool), expected)
        bad = jobs + [(nav.image[0], 2.0, nav.polylines)]
        got = fit_images(bad, search_window_vu=WINDOW, executor=pool, errors="collect")
        assert results_equal(got[:3], expected)
        assert isinstance(got[3], TypeError) and got[3].index == 3
        with pytest.raises(TypeError, match="2-D") as info:
            fit_images(bad, search_window_vu=WINDOW, executor=pool)
        assert info.value.__notes__ == ["images[3]"]
        assert pool.submit(abs, -1).result() == 1  # left running


def test_fit_images_in_a_process_pool_names_the_item(nav, tmp_path):
    missing = tmp_path / "missing.npy"
    jobs = [nav, (missing, None, nav.polylines), (nav.image, 2.0, nav.polylines[:1])]
    got = fit_images(jobs, search_window_vu=WINDOW, workers=2, executor="process",
                     errors="collect")
    assert results_equal(got[0], fit_images([nav], search_window_vu=WINDOW, workers=1)[0])
    assert got[1].__notes__ == [f"images[1] ({missing})"] and got[1].index == 1
    assert len(got[2]) == 1


def test_an_images_error_is_the_very_exception_its_task_raised(nav):
    raised = [KeyError("k"), OSError(2, "No such file")]

    def loader(k):
        def load():
            raise raised[k]
        return load

    got = fit_images([loader(0), nav, loader(1)], search_window_vu=WINDOW, workers=2,
                     errors="collect")
    assert got[0] is raised[0] and str(got[0]) == "'k'"  # KeyError formats its own message
    assert got[0].__notes__ == ["images[0]"] and got[0].index == 0
    assert got[2] is raised[1] and got[2].errno == 2
    assert str(got[2]) == "[Errno 2] No such file" and got[2].__notes__ == ["images[2]"]
