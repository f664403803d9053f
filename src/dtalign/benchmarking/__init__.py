"""Benchmark table: dtalign against its NumPy specification, in one process.

Run ``python -m dtalign.benchmarking`` (``nox -s bench``, ``dtalign bench``).
Every SPEC section 7 workload is timed on identical inputs with
:mod:`dtalign.reference` and with :mod:`dtalign`, alternating
(ref, jit, ref, jit, ...) so that load drifts on a shared machine hit both
sides alike; the table reports the medians, their ratio and the target.
Kernels are compiled (or loaded from Numba's cache) before any timing.
Wall time is :func:`time.perf_counter`; peak memory is the
:mod:`tracemalloc` peak of one call (Numba's allocations are traced too).

Besides the workloads the table has the batch throughput of
:mod:`dtalign.batch` (2 workers against 1), start-up times measured in fresh
subprocesses (``import dtalign``; the first fit with a warm on-disk cache;
with ``--startup full`` also the first-run compile time and a check that a
read-only install still caches), and two memory checks (image-sized
temporaries of the derivatives; LM peak on a 512 and a 2048 DT).

Nothing global is configured: the kernels are single-threaded.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TARGETS", "WORKLOADS", "Inputs", "build_inputs", "main", "run", "workload_call"]

#: Ratio targets (reference time / dtalign time, single thread); None = informational.
TARGETS: dict[str, float | None] = {
    "derivatives_1024": 5.0,
    "coarse_30": 300.0,
    "coarse_50": 300.0,
    "lm_n200": 50.0,
    "lm_trust_region": 50.0,
    "lm_rotation": 50.0,
    "lm_ridge": 40.0,
    "lm_n2000": None,
    "lm_n20000": 30.0,
    "lm_outliers": None,
    "end_to_end": 10.0,
}
WORKLOADS: tuple[str, ...] = tuple(TARGETS)
DESCRIPTIONS = {
    "derivatives_1024": "compute_all_image_derivatives, 1024x1024 disc",
    "coarse_30": "coarse_ncc_search +-30, 200-pixel limb",
    "coarse_50": "coarse_ncc_search +-50, 200-pixel limb",
    "lm_n200": "lm_subpixel_refine, translation, N=200",
    "lm_trust_region": "LM N=200, trust_region_px=1.0",
    "lm_rotation": "LM N=200, fit_rotation (true 0.01 rad)",
    "lm_ridge": "LM N=200, final_gradient_ridge=True",
    "lm_n2000": "LM translation, N=2,000",
    "lm_n20000": "LM translation, N=20,000",
    "lm_outliers": "LM N=200, 10% outliers displaced 30 px",
    "end_to_end": "derivatives + (mask, coarse +-30, LM tr=1) x 3 polylines",
}
#: Section names accepted by ``--only`` besides the workloads.
SECTIONS = ("batch", "startup", "memory")
BATCH_TARGET = 1.8
BATCH_FITS = 64
IMPORT_TARGET_S = 0.5
FIRST_FIT_TARGET_S = 1.0
DERIVATIVE_TEMPORARIES_TARGET = 3.0


# ---------------------------------------------------------------------------
# Inputs and workloads
# ---------------------------------------------------------------------------


@dataclass
class Inputs:
    """Everything the workloads read, built once (derivatives by the reference)."""

    image: np.ndarray
    noise_sigma: float
    dt: np.ndarray
    gradient: np.ndarray
    edge_mask: np.ndarray
    limb_mask: np.ndarray
    lm: dict[str, dict[str, Any]]
    navigation: Any


def build_inputs() -> Inputs:
    """Scenes of SPEC section 7 and their derivatives, computed once.

    The disc and its variants share one image (only the polylines differ),
    so one set of derivatives serves every coarse and LM workload. Each LM
    starts from the coarse seed of its own polyline, as in production.
    """
    from .. import reference as ref
    from .. import scenes

    base = scenes.disc_scene()
    _, dt, grad = ref.compute_all_image_derivatives(base.image, base.noise_sigma)
    edge = dt <= 0.5
    variants: dict[str, tuple[Any, dict[str, Any]]] = {
        "lm_n200": (base, {}),
        "lm_trust_region": (base, {"trust_region_px": 1.0}),
        "lm_ridge": (base, {"final_gradient_ridge": True}),
        "lm_rotation": (scenes.disc_scene(rotation_rad=0.01), {"fit_rotation": True}),
        "lm_n2000": (scenes.disc_scene(n_vertices=2000), {}),
        "lm_n20000": (scenes.disc_scene(n_vertices=20000), {}),
        "lm_outliers": (scenes.disc_scene(outlier_fraction=0.1), {}),
    }
    lm: dict[str, dict[str, Any]] = {}
    for name, (scene, extra) in variants.items():
        if not np.array_equal(scene.image, base.image):  # pragma: no cover - scene change
            raise RuntimeError(f"{name}: the scene image differs from the base disc")
        p = scene.polyline
        seed = ref.coarse_ncc_search(edge, ref.build_polyline_mask(p.vertices_vu, dt.shape), (30, 30))
        kw = {
            "vertices_vu": p.vertices_vu,
            "normals_vu": p.normals_vu,
            "sigma_normal_per_vertex_px": p.sigmas,
            "image_edge_dt": dt,
            "image_gradient_vu": grad,
            "initial_offset_vu": (float(seed[0]), float(seed[1])),
            **extra,
        }
        if extra.get("fit_rotation"):
            kw["pivot_distance_px"] = scene.pivot_distance_px
        lm[name] = kw
    limb = ref.build_polyline_mask(base.polyline.vertices_vu, dt.shape)
    return Inputs(base.image, base.noise_sigma, dt, grad, edge, limb, lm, scenes.navigation_scene())


def end_to_end(api: Any, scene: Any, window: tuple[int, int] = (30, 30)) -> list[Any]:
    """Derivatives, then mask + coarse search + LM (trust region 1 px) per polyline."""
    _, dt, grad = api.compute_all_image_derivatives(scene.image, scene.noise_sigma)
    edge = dt <= 0.5
    fits = []
    for p in scene.polylines:
        seed = api.coarse_ncc_search(edge, api.build_polyline_mask(p.vertices_vu, dt.shape), window)
        fits.append(
            api.lm_subpixel_refine(
                vertices_vu=p.vertices_vu,
                normals_vu=p.normals_vu,
                sigma_normal_per_vertex_px=p.sigmas,
                image_edge_dt=dt,
                image_gradient_vu=grad,
                initial_offset_vu=(float(seed[0]), float(seed[1])),
                trust_region_px=1.0,
            )
        )
    return fits


def workload_call(name: str, api: Any, inputs: Inputs) -> Callable[[], Any]:
    """A no-argument callable running workload ``name`` with ``api`` (a module)."""
    if name == "derivatives_1024":
        return lambda: api.compute_all_image_derivatives(inputs.image, inputs.noise_sigma)
    if name in ("coarse_30", "coarse_50"):
        m = int(name[-2:])
        return lambda: api.coarse_ncc_search(inputs.edge_mask, inputs.limb_mask, (m, m))
    if name == "end_to_end":
        return lambda: end_to_end(api, inputs.navigation)
    kw = inputs.lm[name]
    return lambda: api.lm_subpixel_refine(**kw)


def _same(a: Any, b: Any) -> bool:
    """Whether two workload results agree (a sanity check, not the parity suite)."""
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "offset_vu"):
        return bool(
            np.allclose(a.offset_vu, b.offset_vu, rtol=0, atol=1e-9)
            and abs(a.rotation_rad - b.rotation_rad) <= 1e-9
            and a.iterations == b.iterations
        )
    if isinstance(a, tuple) and a and isinstance(a[0], np.ndarray):
        return all(np.allclose(x, y, rtol=1e-10, atol=1e-10) for x, y in zip(a, b, strict=True))
    return bool(a == b)


# ---------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------


def _time(fn: Callable[[], Any], number: int) -> float:
    """Mean wall time of ``number`` calls, garbage collection paused (as timeit)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        return (time.perf_counter() - t0) / number
    finally:
        if enabled:
            gc.enable()


def _loops(fn: Callable[[], Any], min_sample_s: float) -> int:
    """Calls per sample so that one sample lasts at least ``min_sample_s``."""
    once = max(_time(fn, 1), 1e-7)
    return max(1, math.ceil(min_sample_s / once))


def alternate(
    fns: Sequence[Callable[[], Any]], repeats: int, min_sample_s: float
) -> list[list[float]]:
    """Per-call times of each callable, sampled round-robin ``repeats`` times."""
    loops = [_loops(f, min_sample_s) for f in fns]
    samples: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for f, n, out in zip(fns, loops, samples, strict=True):
            out.append(_time(f, n))
    return samples


def peak_bytes(fn: Callable[[], Any]) -> int:
    """tracemalloc peak of one call (its result included), bytes."""
    was_tracing = tracemalloc.is_tracing()
    if not was_tracing:
        tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    result = fn()
    peak = tracemalloc.get_traced_memory()[1] - base
    del result
    if not was_tracing:
        tracemalloc.stop()
    return int(peak)


def _spread(xs: Sequence[float]) -> float:
    """Half the interquartile range relative to the median."""
    if len(xs) < 4:
        return (max(xs) - min(xs)) / (2 * statistics.median(xs))
    q = statistics.quantiles(xs, n=4)
    return (q[2] - q[0]) / (2 * statistics.median(xs))


class _Load:
    """CPU used by *other* processes during a block, in cores (Linux only)."""

    def __enter__(self) -> _Load:
        self.start = self._snap()
        return self

    def __exit__(self, *exc: object) -> None:
        end = self._snap()
        self.cores: float | None = None
        if self.start is not None and end is not None:
            busy = (end[0] - self.start[0]) / os.sysconf("SC_CLK_TCK")
            own = end[1] - self.start[1]
            self.cores = max(0.0, (busy - own) / max(end[2] - self.start[2], 1e-9))

    @staticmethod
    def _snap() -> tuple[float, float, float] | None:
        try:
            with open("/proc/stat") as fh:
                vals = [int(x) for x in fh.readline().split()[1:9]]
        except OSError:
            return None
        t = os.times()
        return float(sum(vals) - vals[3] - vals[4]), t.user + t.system, time.monotonic()


# ---------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------


def measure_workloads(
    names: Sequence[str], inputs: Inputs, repeats: int, min_sample_s: float
) -> list[dict[str, Any]]:
    """Time, check and memory-profile each workload; one row dict per workload."""
    import dtalign

    from .. import reference

    rows = []
    for name in names:
        ref_fn = workload_call(name, reference, inputs)
        jit_fn = workload_call(name, dtalign, inputs)
        agree = _same(ref_fn(), jit_fn())
        with _Load() as load:
            ref_t, jit_t = alternate([ref_fn, jit_fn], repeats, min_sample_s)
        ref_med, jit_med = statistics.median(ref_t), statistics.median(jit_t)
        ratio = ref_med / jit_med
        target = TARGETS[name]
        rows.append(
            {
                "name": name,
                "kind": "speed",
                "description": DESCRIPTIONS[name],
                "reference_s": ref_med,
                "dtalign_s": jit_med,
                "ratio": ratio,
                "ratio_of_minima": min(ref_t) / min(jit_t),
                "target": target,
                "passed": agree and (target is None or ratio >= target),
                "results_agree": agree,
                "reference_times_s": ref_t,
                "dtalign_times_s": jit_t,
                "pair_ratios": [r / j for r, j in zip(ref_t, jit_t, strict=True)],
                "spread": {"reference": _spread(ref_t), "dtalign": _spread(jit_t)},
                "peak_reference_bytes": peak_bytes(ref_fn),
                "peak_dtalign_bytes": peak_bytes(jit_fn),
                "other_load_cores": load.cores,
            }
        )
        _progress(_format_row(rows[-1]))
    return rows


def measure_batch(repeats: int) -> list[dict[str, Any]]:
    """Throughput of :mod:`dtalign.batch` with 2 worker threads against 1.

    ``batch_64_fits``: :func:`~dtalign.batch.fit_many`, 64 fits (the three
    navigation polylines in turn) against one image's products.
    ``batch_images``: :func:`~dtalign.batch.fit_images`, 4 navigation
    images of 3 polylines each (informational). Each is alternated with a
    control, SHA-256 of 512 KiB blocks on the same pool (C code that releases
    the GIL): its ratio (``control_ratio``) is what the machine allowed at
    that moment; below ~1.8 another process held the second core.
    """
    from .. import scenes
    from ..batch import fit_images, fit_many, map_ordered, results_equal
    from ..pipeline import prepare_image

    scene = scenes.navigation_scene()
    products = prepare_image(scene.image, scene.noise_sigma)
    polys = [scene.polylines[i % len(scene.polylines)] for i in range(BATCH_FITS)]
    images = [scenes.navigation_scene(seed=k) for k in range(4)]
    cases = {
        "batch_64_fits": (
            f"fit_many: {BATCH_FITS} fits on one image, 1 vs 2 threads", BATCH_TARGET,
            lambda w: fit_many(products, polys, search_window_vu=(30, 30), workers=w,
                               trust_region_px=1.0)),
        "batch_images": (
            "fit_images: 4 images x 3 polylines, 1 vs 2 threads", None,
            lambda w: fit_images(images, search_window_vu=(30, 30), workers=w,
                                 trust_region_px=1.0)),
    }
    # Control: a C routine that releases the GIL (SHA-256 of 512 KiB), run the
    # same way. If it does not scale either, the machine had no free core.
    buf = bytes(range(256)) * 2048
    control = {w: (lambda w=w: map_ordered(lambda _: hashlib.sha256(buf).digest(),
                                           range(BATCH_FITS), workers=w)) for w in (1, 2)}
    rows = []
    for name, (description, target, run) in cases.items():
        one, two = (lambda run=run: run(1)), (lambda run=run: run(2))
        agree = results_equal(one(), two())
        with _Load() as load:
            t1, t2, c1, c2 = alternate([one, two, control[1], control[2]], repeats, 0.0)
        ratio = statistics.median(t1) / statistics.median(t2)
        control_ratio = statistics.median(c1) / statistics.median(c2)
        rows.append({
            "name": name, "kind": "batch", "description": description,
            "reference_s": statistics.median(t1), "dtalign_s": statistics.median(t2),
            "ratio": ratio, "ratio_of_minima": min(t1) / min(t2), "target": target,
            "passed": agree and (target is None or ratio >= target), "results_agree": agree,
            "control_ratio": control_ratio,
            "reference_times_s": t1, "dtalign_times_s": t2,
            "pair_ratios": [a / b for a, b in zip(t1, t2, strict=True)],
            "other_load_cores": load.cores,
        })
        _progress(_format_row(rows[-1]))
    return rows


def measure_memory() -> dict[str, Any]:
    """Image-sized temporaries of the derivatives; LM peak on a 512 and a 2048 DT."""
    import dtalign

    from .. import reference, scenes

    out: dict[str, Any] = {}
    scene = scenes.disc_scene()
    image_bytes = scene.image.size * 8
    returned = 4 * image_bytes  # magnitude, DT and the two gradient planes
    apis: tuple[tuple[str, Any], ...] = (("reference", reference), ("dtalign", dtalign))
    for label, api in apis:
        api.compute_all_image_derivatives(scene.image, 2.0)  # compiled / loaded first
        peak = peak_bytes(partial(api.compute_all_image_derivatives, scene.image, 2.0))
        out[f"derivatives_{label}_peak_bytes"] = peak
        out[f"derivatives_{label}_temporaries"] = (peak - returned) / image_bytes
    for size in (512, 2048):
        s = scenes.disc_scene(shape=(size, size))
        _, dt, grad = dtalign.compute_all_image_derivatives(s.image, s.noise_sigma)
        p = s.polyline
        kw = {
            "vertices_vu": p.vertices_vu,
            "normals_vu": p.normals_vu,
            "sigma_normal_per_vertex_px": p.sigmas,
            "image_edge_dt": dt,
            "image_gradient_vu": grad,
            "initial_offset_vu": (7.0, -5.0),
        }
        for label, api in apis:
            api.lm_subpixel_refine(**kw)
            out[f"lm_{size}_{label}_peak_bytes"] = peak_bytes(partial(api.lm_subpixel_refine, **kw))
    growth = out["lm_2048_dtalign_peak_bytes"] - out["lm_512_dtalign_peak_bytes"]
    out["lm_dtalign_growth_bytes"] = growth
    out["lm_dtalign_independent_of_image"] = growth < 64 * 1024
    return out


# The subprocess of the start-up section: argv = [input dir, "warm"|"cold"].
_STARTUP_SCRIPT = r"""
import json, sys, time
t_np = time.perf_counter()
import numpy as np
t_np = time.perf_counter() - t_np
d = sys.argv[1]
a = {k: np.load(f"{d}/{k}.npy") for k in ("dt", "grad", "verts", "norms", "sigmas", "image")}
t0 = time.perf_counter()
import dtalign
t_import = time.perf_counter() - t0
imported_numba = "numba" in sys.modules
def fit():
    edge = a["dt"] <= 0.5
    mask = dtalign.build_polyline_mask(a["verts"], a["dt"].shape)
    seed = dtalign.coarse_ncc_search(edge, mask, (30, 30))
    return dtalign.lm_subpixel_refine(
        vertices_vu=a["verts"], normals_vu=a["norms"], sigma_normal_per_vertex_px=a["sigmas"],
        image_edge_dt=a["dt"], image_gradient_vu=a["grad"],
        initial_offset_vu=(float(seed[0]), float(seed[1])))
fit()
t_first = time.perf_counter() - t0
t1 = time.perf_counter(); fit(); t_second = time.perf_counter() - t1
t1 = time.perf_counter(); dtalign.compute_all_image_derivatives(a["image"], 2.0)
t_deriv = time.perf_counter() - t1
import numba, os
probe = os.path.join(os.path.dirname(dtalign.__file__), ".dtalign-write-probe")
try:
    open(probe, "w").close()
    os.remove(probe)
    writable = True
except OSError:
    writable = False
print(json.dumps({"package_writable": writable, "import_s": t_import, "import_numpy_s": t_np, "import_loads_numba": imported_numba,
                  "first_fit_s": t_first, "second_fit_s": t_second,
                  "first_derivatives_64px_s": t_deriv, "numba_cache_dir": numba.config.CACHE_DIR,
                  "dtalign_file": dtalign.__file__}))
"""


def _subprocess(
    args: list[str], env: dict[str, str], readonly: Path | None = None
) -> dict[str, Any]:
    """Run ``python args`` and parse the JSON it prints last.

    With ``readonly``, that directory is made read-only for the child: by
    permissions, and, when running as root (who ignores permissions), by a
    read-only bind mount in a private mount namespace (``unshare -m``).
    """
    cmd = [sys.executable, *args]
    if readonly is not None and hasattr(os, "geteuid") and os.geteuid() == 0:
        if shutil.which("unshare"):
            script = ('mount --bind "$1" "$1" && mount -o remount,ro,bind "$1" "$1" '
                      '|| exit 97; shift; exec "$@"')
            cmd = ["unshare", "-m", "sh", "-c", script, "sh", str(readonly), *cmd]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode in (1, 97) and cmd[0] == "unshare":  # no mount rights: permissions only
        t0 = time.perf_counter()
        proc = subprocess.run(cmd[7:], env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"start-up subprocess failed:\n{proc.stderr[-2000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process_wall_s"] = wall
    return dict(result)


def _count_files(root: Path, suffixes: tuple[str, ...] = (".nbi", ".nbc")) -> int:
    return sum(1 for p in root.rglob("*") if p.suffix in suffixes) if root.exists() else 0


def measure_startup(full: bool) -> dict[str, Any]:
    """Fresh-process start-up: import, first fit with a warm cache; optionally cold/read-only."""
    from .. import reference, scenes

    pkg_dir = Path(__file__).resolve().parents[1]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(pkg_dir.parent), env.get("PYTHONPATH", "")])
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="dtalign-startup-") as tmp:
        scene = scenes.disc_scene()
        _, dt, grad = reference.compute_all_image_derivatives(scene.image, scene.noise_sigma)
        p = scene.polyline
        arrays = {"dt": dt, "grad": grad, "verts": p.vertices_vu, "norms": p.normals_vu,
                  "sigmas": p.sigmas, "image": scene.image[:64, :64].copy()}
        for key, value in arrays.items():
            np.save(Path(tmp) / f"{key}.npy", value)
        script = ["-c", _STARTUP_SCRIPT, tmp]
        _subprocess(script, env)  # make sure the cache is warm
        warm = [_subprocess(script, env) for _ in range(3)]
        out["warm"] = warm[-1]
        out["import_s"] = statistics.median(r["import_s"] for r in warm)
        out["first_fit_s"] = statistics.median(r["first_fit_s"] for r in warm)
        out["import_loads_numba"] = any(r["import_loads_numba"] for r in warm)
        if not full:
            return out
        # Cold: an empty NUMBA_CACHE_DIR, then the same directory warm.
        # Read-only install: a copy of the package without write permission,
        # Numba falling back to its user-wide cache (XDG_CACHE_HOME here).
        cold_env = dict(env, NUMBA_CACHE_DIR=str(Path(tmp) / "numba-cache"))
        ro_root = Path(tmp) / "ro"
        shutil.copytree(pkg_dir, ro_root / "dtalign", ignore=shutil.ignore_patterns("__pycache__"))
        xdg = Path(tmp) / "xdg"
        ro_env = dict(env, PYTHONPATH=str(ro_root), XDG_CACHE_HOME=str(xdg))
        ro_env.pop("NUMBA_CACHE_DIR", None)
        for path in [ro_root, *ro_root.rglob("*")]:
            path.chmod(path.stat().st_mode & ~0o222)
        try:
            # The two compiling runs are independent: one per core.
            with ThreadPoolExecutor(max_workers=2) as pool:
                cold = pool.submit(_subprocess, script, cold_env)
                ro_first = pool.submit(_subprocess, script, ro_env, readonly=ro_root)
                out["cold"], out["readonly_first"] = cold.result(), ro_first.result()
            out["cold_then_warm"] = _subprocess(script, cold_env)
            out["readonly_second"] = _subprocess(script, ro_env, readonly=ro_root)
            out["readonly_files_in_package"] = _count_files(ro_root)
            out["readonly_files_in_user_cache"] = _count_files(xdg)
            out["readonly_user_cache_dir"] = str(xdg / "numba")
        finally:
            for path in [ro_root, *ro_root.rglob("*")]:
                path.chmod(path.stat().st_mode | 0o200)
        out["compile_s"] = out["cold"]["first_fit_s"] + out["cold"]["first_derivatives_64px_s"]
        out["readonly_package_was_writable"] = out["readonly_first"]["package_writable"]
        out["readonly_caches"] = (
            not out["readonly_package_was_writable"]
            and out["readonly_files_in_user_cache"] > 0
            and out["readonly_files_in_package"] == 0
            and out["readonly_second"]["first_fit_s"] < 0.5 * out["readonly_first"]["first_fit_s"]
        )
    return out


def _startup_rows(s: dict[str, Any]) -> list[dict[str, Any]]:
    rows = [
        {"name": "import_dtalign", "kind": "startup", "dtalign_s": s["import_s"],
         "target_s": IMPORT_TARGET_S, "passed": s["import_s"] < IMPORT_TARGET_S,
         "description": "import dtalign, fresh process"},
        {"name": "first_fit_warm_cache", "kind": "startup", "dtalign_s": s["first_fit_s"],
         "target_s": FIRST_FIT_TARGET_S, "passed": s["first_fit_s"] < FIRST_FIT_TARGET_S,
         "description": "import + first mask/coarse/LM fit, warm Numba cache"},
    ]
    if "compile_s" in s:
        rows.append({"name": "first_run_compile", "kind": "startup", "dtalign_s": s["compile_s"],
                     "target_s": None, "passed": True,
                     "description": "fit + derivatives, empty NUMBA_CACHE_DIR"})
        rows.append({"name": "readonly_install_caches", "kind": "startup",
                     "dtalign_s": s["readonly_second"]["first_fit_s"], "target_s": None,
                     "passed": bool(s["readonly_caches"]),
                     "description": "read-only package: second process first fit"})
    return rows


def _memory_rows(m: dict[str, Any]) -> list[dict[str, Any]]:
    temps = m["derivatives_dtalign_temporaries"]
    return [
        {"name": "derivatives_temporaries", "kind": "memory",
         "reference": f"{m['derivatives_reference_temporaries']:.1f}", "dtalign": f"{temps:.1f}",
         "target": f"<= {DERIVATIVE_TEMPORARIES_TARGET:g}",
         "passed": temps <= DERIVATIVE_TEMPORARIES_TARGET,
         "description": "image-sized float64 temporaries beyond the returned arrays"},
        {"name": "lm_peak_512_vs_2048", "kind": "memory",
         "reference": f"{_mib(m['lm_512_reference_peak_bytes'])} / "
                      f"{_mib(m['lm_2048_reference_peak_bytes'])}",
         "dtalign": f"{_mib(m['lm_512_dtalign_peak_bytes'])} / "
                    f"{_mib(m['lm_2048_dtalign_peak_bytes'])}",
         "target": "same", "passed": bool(m["lm_dtalign_independent_of_image"]),
         "description": "LM N=200 peak with a 512^2 / 2048^2 DT"},
    ]


# ---------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------


def _fmt_s(t: float | None) -> str:
    if t is None:
        return "-"
    if t < 1e-3:
        return f"{t * 1e6:.1f} us"
    if t < 1.0:
        return f"{t * 1e3:.2f} ms"
    return f"{t:.2f} s"


def _mib(b: int | None) -> str:
    return "-" if b is None else f"{b / 2**20:.2f} MiB"


HEADER = ("workload", "reference", "dtalign", "ratio", "target", "status", "peak ref", "peak dtalign")


def _cells(row: dict[str, Any]) -> tuple[str, ...]:
    status = "pass" if row["passed"] else "FAIL"
    if row["kind"] in ("speed", "batch"):
        if not row.get("results_agree", True):
            status = "FAIL (results differ)"
        target = "-" if row["target"] is None else f">= {row['target']:g}x"
        if row["target"] is None:
            status = "info"
        if "control_ratio" in row:  # what the machine itself allowed (GIL-free C code)
            status += f" (control {row['control_ratio']:.2f}x)"
        return (row["name"], _fmt_s(row["reference_s"]), _fmt_s(row["dtalign_s"]),
                f"{row['ratio']:.1f}x" if row["kind"] == "speed" else f"{row['ratio']:.2f}x",
                target, status,
                _mib(row.get("peak_reference_bytes")), _mib(row.get("peak_dtalign_bytes")))
    if row["kind"] == "startup":
        target = "-" if row["target_s"] is None else f"< {row['target_s']:g} s"
        return (row["name"], "-", _fmt_s(row["dtalign_s"]), "-", target, status, "-", "-")
    return (row["name"], row["reference"], row["dtalign"], "-", row["target"], status, "-", "-")


def _format_row(row: dict[str, Any]) -> str:
    return "  ".join(_cells(row))


def format_table(rows: list[dict[str, Any]]) -> str:
    """The plain-text table."""
    cells = [HEADER, *(_cells(r) for r in rows)]
    widths = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    line = "  ".join("-" * w for w in widths)
    text = [line]
    for i, c in enumerate(cells):
        text.append("  ".join(x.ljust(w) for x, w in zip(c, widths, strict=True)).rstrip())
        if i == 0:
            text.append(line)
    text.append(line)
    return "\n".join(text)


def format_rst(report: dict[str, Any]) -> str:
    """The table as an RST list-table, with the machine it was measured on."""
    m = report["machine"]
    out = [
        ".. Generated by ``python -m dtalign.benchmarking --rst``; do not edit.",
        "",
        f"Measured {report['created']} on {m['cpu_count']} CPU(s) ({m['processor']}), "
        f"Python {m['python']}, NumPy {m['numpy']}, Numba {m['numba']}; "
        f"{report['settings']['mode']} run, medians of {report['settings']['repeats']} "
        "alternating samples. Ratio = reference time / dtalign time. Batch rows: "
        "the columns are 1 and 2 worker threads, the control is GIL-free C code "
        "run the same way (what the machine allowed). Start-up rows: fresh "
        "processes. Memory rows: image-sized float64 temporaries, and the LM "
        "peak with a 512^2 / 2048^2 DT (tracemalloc).",
        "",
        ".. list-table::",
        "   :header-rows: 1",
        "",
    ]
    for cells in [HEADER, *(_cells(r) for r in report["rows"])]:
        out.append("   * - " + cells[0])
        out.extend(f"     - {c}" for c in cells[1:])
    return "\n".join(out) + "\n"


def machine_info() -> dict[str, Any]:
    """CPU count and the versions the numbers depend on."""
    import numba
    import scipy

    return {
        "cpu_count": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "loadavg": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------


def warm_up(names: Sequence[str], inputs: Inputs) -> float:
    """Compile (or load from cache) every kernel the workloads use; returns seconds."""
    import dtalign

    t0 = time.perf_counter()
    for name in names:
        workload_call(name, dtalign, inputs)()
    return time.perf_counter() - t0


def run(
    only: Sequence[str] | None = None, *, quick: bool = False, repeats: int | None = None,
    startup: str | None = None,
) -> dict[str, Any]:
    """Run the benchmark; returns the report (what ``--json`` writes).

    Parameters
    ----------
    only : sequence of str, optional
        Workload and section names (:data:`WORKLOADS`, :data:`SECTIONS`);
        everything when None.
    quick : bool
        Fewer repeats and shorter samples (CI, CLI).
    repeats : int, optional
        Alternating samples per side (default 9 quick, 15 full).
    startup : {"quick", "full", "none"}, optional
        Start-up section depth; default "quick" with ``quick``, else "full"
        (adds the cold compile and the read-only install check).
    """
    wanted = set(only) if only else set(WORKLOADS) | set(SECTIONS)
    unknown = wanted - set(WORKLOADS) - set(SECTIONS)
    if unknown:
        raise ValueError(f"unknown workload(s): {', '.join(sorted(unknown))}")
    names = [n for n in WORKLOADS if n in wanted]
    repeats = repeats or (9 if quick else 15)
    min_sample = 0.005 if quick else 0.02
    startup = startup or ("quick" if quick else "full")
    t0 = time.perf_counter()
    _progress("building inputs ...")
    inputs = build_inputs()
    _progress("warming up (compiling or loading the Numba cache) ...")
    warm_s = warm_up(names or ["lm_n200"], inputs)
    rows: list[dict[str, Any]] = []
    with _Load() as load:
        rows += measure_workloads(names, inputs, repeats, min_sample)
        if "batch" in wanted:
            rows += measure_batch(max(repeats, 9))
        memory = measure_memory() if "memory" in wanted else None
        if memory is not None:
            rows += _memory_rows(memory)
    start = None
    if "startup" in wanted and startup != "none":
        _progress("start-up (fresh subprocesses) ...")
        start = measure_startup(full=startup == "full")
        rows += _startup_rows(start)
    return {
        "schema": 1,
        "created": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "machine": machine_info(),
        "settings": {"mode": "quick" if quick else "full", "repeats": repeats,
                     "min_sample_s": min_sample, "timer": "time.perf_counter",
                     "startup": startup},
        "warmup_s": warm_s,
        "total_s": time.perf_counter() - t0,
        "other_load_cores": load.cores,
        "rows": rows,
        "memory": memory,
        "startup": start,
        "all_passed": all(r["passed"] for r in rows),
    }


def build_parser() -> argparse.ArgumentParser:
    """Command-line options of :func:`main`."""
    p = argparse.ArgumentParser(
        prog="python -m dtalign.benchmarking",
        description="dtalign against its NumPy specification: one table of medians and ratios.",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats (CI, CLI)")
    p.add_argument("--only", default=None,
                   help=f"comma-separated names: {', '.join(WORKLOADS + SECTIONS)}")
    p.add_argument("--repeats", type=int, default=None, help="alternating samples per side")
    p.add_argument("--startup", choices=("quick", "full", "none"), default=None,
                   help="start-up section depth (default: quick with --quick, else full)")
    p.add_argument("--json", default="benchmarks/results/latest.json",
                   help="where to write the JSON report ('' to skip)")
    p.add_argument("--rst", default=None, help="also write the table as RST to this path")
    p.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    p.add_argument("--list", action="store_true", help="list the workloads and exit")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark from the command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        Options without the program name (``sys.argv[1:]`` when None).
    """
    args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    if args.list:
        for name in WORKLOADS:
            target = TARGETS[name]
            print(f"{name:18s} {'-' if target is None else f'>= {target:g}x':>9s}  "
                  f"{DESCRIPTIONS[name]}")
        print("sections: " + ", ".join(SECTIONS))
        return 0
    only = [s.strip() for s in args.only.split(",") if s.strip()] if args.only else None
    try:
        report = run(only, quick=args.quick, repeats=args.repeats, startup=args.startup)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_table(report["rows"]))
    print(f"total {report['total_s']:.1f} s (warm-up {report['warmup_s']:.1f} s); "
          f"other processes used {report['other_load_cores'] or 0:.2f} core(s) meanwhile")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=1, default=str) + "\n")
        print(f"wrote {path}")
    if args.rst:
        path = Path(args.rst)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(format_rst(report))
        print(f"wrote {path}")
    return 1 if args.strict and not report["all_passed"] else 0
