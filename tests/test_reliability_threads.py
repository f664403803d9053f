"""Threads and determinism: concurrent fits equal serial ones, bit for bit.

Archive runs fit many frames concurrently from a ThreadPoolExecutor. The
kernels are compiled with ``nogil=True`` and must share nothing mutable, so
concurrent calls give results bit-identical to serial calls, repeated calls
are bit-identical, and nothing in dtalign changes Numba's global
configuration or keeps module-level mutable state that changes across calls.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
import random
import subprocess
import sys
import textwrap
import threading
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
import pytest

import dtalign
from dtalign.scenes import disc_scene, navigation_scene

THREADS = 8
#: With NUMBA_DISABLE_JIT=1 (the coverage session) kernels run as Python, ~1000x
#: slower: the same checks on smaller images with fewer repetitions.
PYTHON_KERNELS = bool(numba.config.DISABLE_JIT)
REPEAT = 1 if PYTHON_KERNELS else 6


@functools.cache
def _products():
    k = 3 if PYTHON_KERNELS else 1
    disc = disc_scene(shape=(160 // k, 170 // k), radius=45.0 / k, n_vertices=120 // k, offset_vu=(2.3, -1.6),
                      seed=11)
    nav = navigation_scene(shape=(200 // k, 200 // k), radius=50.0 / k, n_vertices=60 // k, offset_vu=(1.2, 0.8),
                           rotation_rad=0.01, seed=5)
    out = {}
    for name, sc in (("disc", disc), ("nav", nav)):
        mag, dt, grad = dtalign.compute_all_image_derivatives(sc.image, sc.noise_sigma)
        out[name] = (sc, mag, dt, grad)
    return out


def _jobs():
    """Name -> zero-argument callable; each call allocates its own outputs."""
    prods = _products()
    jobs = {}
    for name, (sc, mag, dt, grad) in prods.items():
        for poly in sc.polylines:
            base = dict(vertices_vu=poly.vertices_vu, normals_vu=poly.normals_vu,
                        sigma_normal_per_vertex_px=poly.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
                        initial_offset_vu=(1.0, -1.0))
            rot = dict(base, fit_rotation=True, pivot_vu=sc.pivot_vu, pivot_distance_px=sc.pivot_distance_px)
            key = f"{name}-{poly.name}"
            jobs[f"lm-{key}"] = functools.partial(dtalign.lm_subpixel_refine, **base)
            jobs[f"lm-rotation-{key}"] = functools.partial(dtalign.lm_subpixel_refine, **rot)
            jobs[f"lm-ridge-{key}"] = functools.partial(dtalign.lm_subpixel_refine, **base,
                                                        final_gradient_ridge=True, trust_region_px=3.0)
            jobs[f"lm-rotation-ridge-{key}"] = functools.partial(
                dtalign.lm_subpixel_refine, **rot, final_gradient_ridge=True, tikhonov_alpha=0.01)
            jobs[f"ridge-{key}"] = functools.partial(
                dtalign.gradient_ridge_refine, vertices_vu=poly.vertices_vu, normals_vu=poly.normals_vu,
                sigma_normal_per_vertex_px=poly.sigmas, gradient_magnitude=mag,
                initial_offset_vu=sc.true_offset_vu, fit_rotation=True, pivot_distance_px=20.0)
            pmask = dtalign.build_polyline_mask(poly.vertices_vu, dt.shape)
            jobs[f"coarse-{key}"] = functools.partial(dtalign.coarse_ncc_search, dt <= 0.5, pmask, (12, 12))
            jobs[f"polarity-{key}"] = functools.partial(dtalign.polarity_filter, poly.vertices_vu,
                                                        poly.normals_vu, grad, offset_vu=(2.0, -2.0))
            jobs[f"sample-{key}"] = functools.partial(dtalign.sample_dt_bilinear, dt, poly.vertices_vu)
        jobs[f"derivatives-{name}"] = functools.partial(dtalign.compute_all_image_derivatives,
                                                        sc.image, sc.noise_sigma)
        jobs[f"gradient-{name}"] = functools.partial(dtalign.compute_image_gradient_vu, sc.image.astype(np.float32),
                                                     sigma_px=2.0)
    return jobs


def _bits(value):
    """A hashable, bit-exact fingerprint of any result."""
    if isinstance(value, np.ndarray):
        return ("nd", value.dtype.str, value.shape, np.ascontiguousarray(value).tobytes())
    if dataclasses.is_dataclass(value):
        return tuple(_bits(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, tuple):
        return tuple(_bits(v) for v in value)
    if isinstance(value, float):
        return ("f", np.float64(value).tobytes())
    return (type(value).__name__, value)


@pytest.fixture(scope="module")
def serial():
    jobs = _jobs()
    return {name: _bits(job()) for name, job in jobs.items()}


def test_repeated_serial_runs_are_bit_identical(serial):
    jobs = _jobs()
    for _ in range(max(REPEAT // 2, 1)):
        for name, job in jobs.items():
            assert _bits(job()) == serial[name], name


@pytest.mark.parametrize("workers", [4, THREADS])
def test_concurrent_runs_match_serial_bit_for_bit(serial, workers):
    jobs = _jobs()
    order = [name for name in jobs for _ in range(REPEAT)]
    random.Random(workers).shuffle(order)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [(name, pool.submit(jobs[name])) for name in order]
        results = [(name, fut.result()) for name, fut in futures]
    assert len(results) == len(order) >= 36 * REPEAT
    for name, result in results:
        assert _bits(result) == serial[name], name


def test_same_fit_hammered_from_all_threads(serial):
    """Many threads in the same kernel at once (shared inputs, separate outputs)."""
    jobs = _jobs()
    names = [n for n in jobs if n.startswith(("lm-rotation-ridge-", "derivatives-"))]
    with ThreadPoolExecutor(max_workers=THREADS) as pool:
        for name in names:
            for result in pool.map(lambda _, j=jobs[name]: j(), range(REPEAT * THREADS // 2)):
                assert _bits(result) == serial[name], name


def test_inputs_shared_between_threads_are_not_modified():
    prods = _products()
    before = {k: [a.copy() for a in v[1:]] for k, v in prods.items()}
    images = {k: v[0].image.copy() for k, v in prods.items()}
    jobs = _jobs()
    with ThreadPoolExecutor(max_workers=THREADS) as pool:
        list(pool.map(lambda j: j(), list(jobs.values()) * (1 if PYTHON_KERNELS else 2)))
    for k, v in prods.items():
        for a, b in zip(v[1:], before[k], strict=True):
            assert a.tobytes() == b.tobytes()
        assert v[0].image.tobytes() == images[k].tobytes()


# --------------------------------------------------------------------------
# Global state: Numba configuration and dtalign's module-level containers
# --------------------------------------------------------------------------


def _numba_globals():
    return (numba.config.NUMBA_NUM_THREADS, numba.config.THREADING_LAYER, numba.get_num_threads(),
            numba.config.BOUNDSCHECK, numba.config.DISABLE_JIT, numba.config.CACHE_DIR,
            os.environ.get("NUMBA_NUM_THREADS"), os.environ.get("NUMBA_THREADING_LAYER"))


def _dtalign_modules():
    return {name: mod for name, mod in sorted(sys.modules.items())
            if (name == "dtalign" or name.startswith("dtalign.")) and mod is not None}


def _mutable_state():
    """Deep copies of every module-level list/dict/set/bytearray/ndarray of dtalign."""
    state = {}
    for mname, mod in _dtalign_modules().items():
        for attr, value in vars(mod).items():
            if attr.startswith("__"):
                continue
            if isinstance(value, (list, dict, set, bytearray)):
                state[(mname, attr)] = copy.deepcopy(value)
            elif isinstance(value, np.ndarray):
                state[(mname, attr)] = (value.copy(), value.flags.writeable)
    return state


def _equal(a, b) -> bool:
    if isinstance(a, tuple) and a and isinstance(a[0], np.ndarray):
        return a[1] == b[1] and a[0].tobytes() == b[0].tobytes()
    try:
        return bool(a == b)
    except Exception:  # containers holding arrays
        return repr(a) == repr(b)


def _batch_jobs():
    """Batch calls (threads, a process pool) over the disc and navigation scenes."""
    from dtalign.pipeline import batch

    prods = _products()
    sc, nav = prods["disc"][0], prods["nav"][0]
    products = dtalign.pipeline.prepare_image(nav.image, nav.noise_sigma)
    polys = list(nav.polylines) * 3
    return {
        "fit_many": functools.partial(batch.fit_many, products, polys, search_window_vu=(6, 6),
                                      workers=3),
        "fit_many-collect": functools.partial(batch.fit_many, products, polys,
                                              search_window_vu=(6, 6), workers=2,
                                              errors="collect"),
        "fit_images": functools.partial(batch.fit_images, [sc, nav], search_window_vu=(6, 6),
                                        workers=2),
        "map_ordered": functools.partial(batch.map_ordered, abs, range(-5, 5), workers=3),
    }


def test_fits_change_no_global_state(serial):
    jobs = {**_jobs(), **_batch_jobs()}
    for job in jobs.values():  # every public module is imported by now
        job()
    numba_before = _numba_globals()
    state_before = _mutable_state()
    assert state_before, "the scan found no module-level containers at all"
    with ThreadPoolExecutor(max_workers=4) as pool:
        list(pool.map(lambda j: j(), list(jobs.values())))
    for job in jobs.values():
        job()
    assert _numba_globals() == numba_before
    state_after = _mutable_state()
    assert state_after.keys() == state_before.keys()
    changed = [key for key in state_before if not _equal(state_before[key], state_after[key])]
    assert not changed, f"module-level state changed across calls: {changed}"


def test_batch_keeps_no_module_level_state_or_threads():
    """dtalign.pipeline.batch holds no containers between calls and leaves no thread running."""
    from dtalign.pipeline import batch

    before = threading.active_count()
    for job in _batch_jobs().values():
        job()
    assert threading.active_count() == before
    kept = {name for name, value in vars(batch).items() if not name.startswith("__")
            and isinstance(value, (list, dict, set, bytearray, np.ndarray, threading.Thread))}
    assert kept == set()


def test_import_and_fits_leave_numba_configuration_alone():
    """In a fresh interpreter: Numba's settings before dtalign == after import and fits."""
    script = textwrap.dedent(
        """
        import numba
        from numba.core import config as cfg
        def snap():
            return (cfg.NUMBA_NUM_THREADS, cfg.THREADING_LAYER, numba.get_num_threads(),
                    cfg.BOUNDSCHECK, cfg.DISABLE_JIT, cfg.FASTMATH if hasattr(cfg, "FASTMATH") else None)
        before = snap()
        import numpy as np, dtalign
        from dtalign.scenes import disc_scene
        sc = disc_scene(shape=(64, 64), radius=16.0, n_vertices=24, seed=1)
        mag, dt, grad = dtalign.compute_all_image_derivatives(sc.image, sc.noise_sigma)
        p = sc.polyline
        dtalign.lm_subpixel_refine(vertices_vu=p.vertices_vu, normals_vu=p.normals_vu,
            sigma_normal_per_vertex_px=p.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
            fit_rotation=True, pivot_distance_px=5.0, final_gradient_ridge=True)
        dtalign.coarse_ncc_search(dt <= 0.5, dtalign.build_polyline_mask(p.vertices_vu, dt.shape), (3, 3))
        after = snap()
        print("SAME" if before == after else f"CHANGED {before} -> {after}")
        """
    )
    env = dict(os.environ)
    src = os.path.abspath(os.path.join(os.path.dirname(dtalign.__file__), os.pardir))
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "SAME", proc.stdout


def test_import_does_not_import_numba_or_scipy():
    """``import dtalign`` is lazy (its docstring promises it): no Numba, no SciPy."""
    script = ("import sys, dtalign; print(sorted(m for m in ('numba', 'scipy') if m in sys.modules))")
    env = dict(os.environ)
    src = os.path.abspath(os.path.join(os.path.dirname(dtalign.__file__), os.pardir))
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


# --------------------------------------------------------------------------
# Compilation flags: every kernel releases the GIL
# --------------------------------------------------------------------------


def _dispatchers():
    import dtalign._kernels as kernels_pkg

    _jobs()  # make sure every kernel module is imported
    found = {}
    for mname, mod in _dtalign_modules().items():
        if not mname.startswith(kernels_pkg.__name__):
            continue
        for value in vars(mod).values():
            if isinstance(value, numba.core.registry.CPUDispatcher):
                found[f"{value.py_func.__module__}.{value.py_func.__qualname__}"] = value
    return found


@pytest.mark.skipif(PYTHON_KERNELS, reason="NUMBA_DISABLE_JIT=1: no compiled kernels to inspect")
def test_every_kernel_is_nogil_cached_and_exact():
    found = _dispatchers()
    assert len(found) >= 10, sorted(found)
    for name in ("lm", "ridge", "coarse", "image", "sampling", "robust"):
        assert any(f".{name}." in key for key in found), name
    for name, disp in found.items():
        opts = disp.targetoptions
        assert opts.get("nogil") is True, name
        # cache=True: Numba's FunctionCache, as dtalign's checked subclass (docs/caching.rst)
        assert type(disp._cache).__name__ == "CheckedFunctionCache", name
        assert not opts.get("fastmath"), name
        assert not opts.get("parallel"), name  # no hidden thread pool of Numba's own
