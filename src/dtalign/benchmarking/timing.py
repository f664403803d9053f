"""Timing, the workload and batch sections, and the table they print.

Wall time is :func:`time.perf_counter` (garbage collection paused, as
timeit); both sides are sampled round-robin so that load drifts hit them
alike. Peak memory is the :mod:`tracemalloc` peak of one call.
"""

from __future__ import annotations

import gc
import hashlib
import math
import os
import platform
import statistics
import sys
import time
import tracemalloc
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .workloads import (
    BATCH_FITS,
    BATCH_IMAGES,
    BATCH_IMAGES_TARGET,
    BATCH_TARGET,
    DESCRIPTIONS,
    NOISE_OVERHEAD_TARGET,
    PROFILE_OVERHEAD_TARGET,
    REGION_FIT_TARGET,
    REGION_PROFILE_FIT_TARGET,
    TARGETS,
    Inputs,
    _same,
    compiled_api,
    fit_polyline_keywords,
    workload_call,
)

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
# Sections: workloads and batch
# ---------------------------------------------------------------------------


def measure_workloads(
    names: Sequence[str], inputs: Inputs, repeats: int, min_sample_s: float
) -> list[dict[str, Any]]:
    """Time, check and memory-profile each workload; one row dict per workload."""
    import dtalign.reference as reference

    dtalign = compiled_api()

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


def measure_noise_overhead(inputs: Inputs, repeats: int, min_sample_s: float) -> dict[str, Any]:
    """``fit_polyline`` with the noise estimated against the same call with it given.

    Both are :func:`dtalign.pipeline.fit_polyline` on the disc scene (the
    ``fit_polyline`` row's call), alternating; the noise given is the
    value the estimate returns, so both fits are identical. The row's ratio
    is estimated / given, and passes at or below
    :data:`~dtalign.benchmarking.workloads.NOISE_OVERHEAD_TARGET`.
    """
    from ..pipeline.fit import fit_polyline

    kw = fit_polyline_keywords(inputs)
    sigma = fit_polyline(inputs.image, **kw).noise_sigma  # its own estimate (its region's)

    def given() -> Any:
        return fit_polyline(inputs.image, noise_sigma=sigma, **kw)

    def estimated() -> Any:
        return fit_polyline(inputs.image, **kw)

    agree = _same(given().lm, estimated().lm)
    with _Load() as load:
        t_given, t_est = alternate([given, estimated], repeats, min_sample_s)
    return _overhead_row("fit_polyline_noise_overhead",
                         "fit_polyline: noise estimated / noise given (same run)",
                         t_given, t_est, NOISE_OVERHEAD_TARGET, agree, load.cores)


def _overhead_row(name: str, description: str, t_base: list[float], t_with: list[float],
                  target: float | None, agree: bool, load_cores: float | None) -> dict[str, Any]:
    """An overhead row: the ratio of the medians ``with / base`` of one run,
    passed when the results agree and the ratio is at most ``target`` (None:
    informational)."""
    ratio = statistics.median(t_with) / statistics.median(t_base)
    row = {
        "name": name, "kind": "overhead", "description": description,
        "reference_s": statistics.median(t_base), "dtalign_s": statistics.median(t_with),
        "ratio": ratio, "ratio_of_minima": min(t_with) / min(t_base), "target": target,
        "passed": agree and (target is None or ratio <= target), "results_agree": agree,
        "reference_times_s": t_base, "dtalign_times_s": t_with,
        "pair_ratios": [w / b for b, w in zip(t_base, t_with, strict=True)],
        "other_load_cores": load_cores,
    }
    _progress(_format_row(row))
    return row


def measure_profile_overhead(repeats: int, min_sample_s: float) -> dict[str, Any]:
    """``fit_polyline`` with an edge profile against the plain call, same scene.

    A rendered Lambert sphere (:func:`dtalign.scenes.render_sphere`: 300 x
    300, radius 85 px, phase 35 deg, Gaussian PSF 1 px) and its sunlit
    limb; the profile (:func:`dtalign.sphere_edge_profile`, PSF unknown:
    estimated) is built once, outside the timing. Both calls alternate;
    the ratio is with / without, and passes at or below
    :data:`~dtalign.benchmarking.workloads.PROFILE_OVERHEAD_TARGET` when
    the refinement is accepted and lands nearer the planted offset.
    """
    from ..api.profiles import sphere_edge_profile
    from ..pipeline.fit import fit_polyline
    from ..scenes import render_sphere

    sc = render_sphere(shape=(300, 300), center_vu=(150.3, 149.7), radius_px=85.0,
                       phase_deg=35.0, illumination_deg=30.0, offset_vu=(0.37, -0.21),
                       background_dn=10.0, psf_sigma_px=1.0)
    limb = sc.limb
    profile = sphere_edge_profile(limb.vertices_vu, center_vu=sc.model_center_vu,
                                  radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                                  illumination_deg=sc.illumination_deg)
    args = (sc.image, limb.vertices_vu, limb.normals_vu, limb.sigmas)

    def plain() -> Any:
        return fit_polyline(*args, search_window_vu=(6, 6))

    def profiled() -> Any:
        return fit_polyline(*args, search_window_vu=(6, 6), edge_profile=profile)

    truth = np.asarray(sc.true_offset_vu)
    p, q = plain(), profiled()
    better = bool(q.profile.accepted and np.hypot(*(np.asarray(q.offset_vu) - truth))
                  < np.hypot(*(np.asarray(p.offset_vu) - truth)))
    with _Load() as load:
        t_plain, t_prof = alternate([plain, profiled], repeats, min_sample_s)
    return _overhead_row("fit_polyline_profile_overhead",
                         "fit_polyline: with an edge profile / plain (sphere limb, same run)",
                         t_plain, t_prof, PROFILE_OVERHEAD_TARGET, better, load.cores)


def measure_region(inputs: Inputs, repeats: int, min_sample_s: float) -> list[dict[str, Any]]:
    """The one-call fit against one full-frame derivatives call of its image.

    :func:`dtalign.pipeline.fit_polyline` computes the products on the
    region its polyline can reach (:mod:`dtalign.pipeline.region`); each row
    alternates it with :func:`dtalign.compute_all_image_derivatives` of the
    whole frame and gives fit / derivatives:

    * ``region_fit``: the disc (the ``fit_polyline`` row's call), noise
      estimated; ``region_fit_noise_given``: the same, the noise given;
      both pass at or below :data:`~dtalign.benchmarking.workloads.REGION_FIT_TARGET`
      when the fit equals the full frame's (offsets within 1e-9 px, same
      status);
    * ``region_fit_profile``: a rendered 1024 x 1024 Lambert sphere's limb
      with its edge profile (PSF estimated), noise estimated; passes at or
      below :data:`~dtalign.benchmarking.workloads.REGION_PROFILE_FIT_TARGET`
      when its refinement is accepted and its status equals the full frame's;
    * ``full_frame_fit``: for comparison, the same fit on full-frame
      products (``prepare_image`` then ``fit_polyline_products``), the
      pipeline before regions (informational).
    """
    from ..api.image import compute_all_image_derivatives
    from ..api.profiles import sphere_edge_profile
    from ..pipeline.fit import fit_polyline, fit_polyline_products
    from ..pipeline.products import prepare_image
    from ..scenes import render_sphere

    kw = fit_polyline_keywords(inputs)
    poly = (kw.pop("vertices_vu"), kw.pop("normals_vu"), kw.pop("sigmas"))
    sigma = fit_polyline(inputs.image, *poly, **kw).noise_sigma

    def derivatives() -> Any:
        return compute_all_image_derivatives(inputs.image, inputs.noise_sigma)

    def estimated() -> Any:
        return fit_polyline(inputs.image, *poly, **kw)

    def given() -> Any:
        return fit_polyline(inputs.image, *poly, noise_sigma=sigma, **kw)

    def full_frame() -> Any:
        return fit_polyline_products(prepare_image(inputs.image), *poly, **kw)

    def agree(a: Any, b: Any) -> bool:
        return bool(np.allclose(a.offset_vu, b.offset_vu, rtol=0.0, atol=1e-9)
                    and a.status == b.status)

    sc = render_sphere(shape=(1024, 1024), center_vu=(512.3, 511.6), radius_px=150.0,
                       phase_deg=35.0, illumination_deg=30.0, offset_vu=(0.37, -0.21),
                       background_dn=10.0, psf_sigma_px=1.0, read_noise_dn=1.0, oversample=4)
    limb = sc.limb
    profile = sphere_edge_profile(limb.vertices_vu, center_vu=sc.model_center_vu,
                                  radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                                  illumination_deg=sc.illumination_deg)
    limb_args = (sc.image, limb.vertices_vu, limb.normals_vu, limb.sigmas)

    def sphere_derivatives() -> Any:
        return compute_all_image_derivatives(sc.image, sc.noise_sigma)

    def profiled() -> Any:
        return fit_polyline(*limb_args, search_window_vu=(30, 30), edge_profile=profile)

    q = profiled()
    q_full = fit_polyline_products(prepare_image(sc.image), *limb_args[1:],
                                   search_window_vu=(30, 30), edge_profile=profile)
    full = full_frame()
    rows = []
    with _Load() as load:
        t_d, t_est, t_given, t_full = alternate([derivatives, estimated, given, full_frame],
                                                repeats, min_sample_s)
        t_sd, t_prof = alternate([sphere_derivatives, profiled], repeats, min_sample_s)
    rows.append(_overhead_row("region_fit", "fit_polyline / full-frame derivatives (disc, "
                              "noise estimated)", t_d, t_est, REGION_FIT_TARGET,
                              agree(estimated(), full), load.cores))
    rows.append(_overhead_row("region_fit_noise_given", "fit_polyline / full-frame "
                              "derivatives (disc, noise given)", t_d, t_given, REGION_FIT_TARGET,
                              agree(given(), fit_polyline_products(
                                  prepare_image(inputs.image, sigma), *poly, **kw)),
                              load.cores))
    rows.append(_overhead_row("region_fit_profile", "fit_polyline with an edge profile / "
                              "full-frame derivatives (1024 x 1024 sphere limb)", t_sd, t_prof,
                              REGION_PROFILE_FIT_TARGET,
                              bool(q.profile.accepted and q.status == q_full.status),
                              load.cores))
    rows.append(_overhead_row("full_frame_fit", "prepare_image + fit_polyline_products / "
                              "full-frame derivatives (disc, the pipeline without regions)",
                              t_d, t_full, None, True, load.cores))
    return rows


def _loop_call(products: Any, polylines: Any, workers: int) -> Callable[[], Any]:
    """A no-argument run of the compiled loop :func:`~dtalign.pipeline.batch.fit_many`
    calls (coarse search and LM, GIL released), over ``workers`` contiguous
    chunks of the polylines on as many threads, its inputs checked and
    prepared once here: what ``fit_many`` costs without its Python (checks,
    a call per polyline, result objects)."""
    from concurrent.futures import ThreadPoolExecutor

    from ..api.options import FitOptions
    from ..pipeline import jobs

    parts = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in polylines]
    # fit_many's defaults with the production trust region; the examination
    # after the loop is not the loop
    shared = jobs.plan(products, jobs.check_options(
        FitOptions(search_window_vu=(30, 30), trust_region_px=1.0, ambiguity=False)))
    batch, error = jobs.prepare(shared, parts)
    if error is not None:
        raise error
    args, codes, out = jobs.loop_inputs(shared, batch)
    bounds = [batch.n * w // workers for w in range(workers + 1)]

    def call() -> None:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(lambda w: jobs.fit_polylines(args, bounds[w], bounds[w + 1], codes,
                                                       out), range(workers)))

    return call


def measure_batch(repeats: int) -> list[dict[str, Any]]:
    """Throughput of :mod:`dtalign.pipeline.batch` with 2 worker threads against 1.

    ``batch_64_fits``: :func:`~dtalign.pipeline.batch.fit_many`, 64 fits (the three
    navigation polylines in turn) against one image's products.
    ``batch_images``: :func:`~dtalign.pipeline.batch.fit_images`, 16 navigation
    images of 3 polylines each. Each is alternated with a
    control, SHA-256 of 512 KiB blocks on the same pool (C code that releases
    the GIL): its ratio (``control_ratio``) is what the machine allowed at
    that moment; below ~1.8 another process held the second core. A second
    control (``fp_control_ratio``) runs compiled work bound by
    floating-point throughput (:mod:`~dtalign.benchmarking.fpload`, units
    of about a fit each) the same way. SHA-256 is latency-bound, so it still scales
    on two virtual CPUs that share one physical core's execution units;
    code that keeps the FP pipes busy does not. A third control runs
    ``fit_many``'s compiled loop alone on the same 64 fits
    (``loop_control_ratio``: no Python at all while the threads fit). That
    loop's scaling follows the FP-throughput control, not the SHA-256 one:
    it is what the machine allows the compiled fits. A batch ratio below
    the loop's is the Python each fit needs under the GIL (the settling
    and the conclusions: docs/benchmarks.rst, "What was tried").

    Each row is judged by :func:`~dtalign.benchmarking.scaling.judge`
    against its target and its own control (``judged_by``: ``rule``,
    ``required_ratio``); ``batch_64_fits`` with the share of its fits that
    runs GIL-free, the compiled loop's time alone over the row's on one
    worker (``parallel_share``).
    """
    import dtalign.scenes as scenes

    from ..pipeline.batch import fit_images, fit_many, map_ordered
    from ..pipeline.products import prepare_image
    from . import fpload, scaling
    from .compare import results_equal

    scene = scenes.navigation_scene()
    products = prepare_image(scene.image, scene.noise_sigma)
    polys = [scene.polylines[i % len(scene.polylines)] for i in range(BATCH_FITS)]
    images = [scenes.navigation_scene(seed=k) for k in range(BATCH_IMAGES)]
    cases = {
        # ambiguity=False: the fits alone, not the rival-basin examination
        # (~30x a fit), whose scaling is that of dtalign.pipeline.hypotheses
        "batch_64_fits": (
            f"fit_many: {BATCH_FITS} fits on one image, 1 vs 2 threads", BATCH_TARGET,
            lambda w: fit_many(products, polys, search_window_vu=(30, 30), workers=w,
                               trust_region_px=1.0, ambiguity=False)),
        "batch_images": (
            f"fit_images: {BATCH_IMAGES} images x 3 polylines, 1 vs 2 threads",
            BATCH_IMAGES_TARGET,
            lambda w: fit_images(images, search_window_vu=(30, 30), workers=w,
                                 trust_region_px=1.0, ambiguity=False)),
    }
    # Control: a C routine that releases the GIL (SHA-256 of 512 KiB), run the
    # same way. If it does not scale either, the machine had no free core.
    buf = bytes(range(256)) * 2048
    control = {w: (lambda w=w: map_ordered(lambda _: hashlib.sha256(buf).digest(),
                                           range(BATCH_FITS), workers=w)) for w in (1, 2)}
    # Control: compiled floating-point work (fpload), what two threads of
    # FP-throughput-bound code get from this machine.
    fp = {w: (lambda w=w: map_ordered(lambda _: fpload.unit(), range(BATCH_FITS), workers=w))
          for w in (1, 2)}
    loops = {w: _loop_call(products, polys, w) for w in (1, 2)}
    rows = []
    for name, (description, target, run) in cases.items():
        one, two = (lambda run=run: run(1)), (lambda run=run: run(2))
        agree = results_equal(one(), two())
        with _Load() as load:
            t1, t2, c1, c2, f1, f2, k1, k2 = alternate(
                [one, two, control[1], control[2], fp[1], fp[2], loops[1], loops[2]],
                repeats, 0.0)
        ratio = statistics.median(t1) / statistics.median(t2)
        control_ratio = statistics.median(c1) / statistics.median(c2)
        fp_ratio = statistics.median(f1) / statistics.median(f2)
        loop_ratio = statistics.median(k1) / statistics.median(k2)
        # the 64 fits' share that runs GIL-free: their compiled loop alone
        share = (min(1.0, statistics.median(k1) / statistics.median(t1))
                 if name == "batch_64_fits" else 1.0)
        controls = {"control_ratio": control_ratio, "fp_control_ratio": fp_ratio}
        own = scaling.CONTROLS[name]
        verdict = scaling.judge(ratio, target, controls[own.key], share, own.fraction)
        rows.append({
            "name": name, "kind": "batch", "description": description,
            "reference_s": statistics.median(t1), "dtalign_s": statistics.median(t2),
            "ratio": ratio, "ratio_of_minima": min(t1) / min(t2), "target": target,
            "passed": agree and verdict.passed, "results_agree": agree,
            "rule": verdict.rule, "required_ratio": verdict.required, "parallel_share": share,
            "judged_by": own.key, **controls,
            "loop_control_ratio": loop_ratio,
            "loop_control_s": statistics.median(k1),
            "reference_times_s": t1, "dtalign_times_s": t2,
            "pair_ratios": [a / b for a, b in zip(t1, t2, strict=True)],
            "other_load_cores": load.cores,
        })
        _progress(_format_row(rows[-1]))
    return rows


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


#: The table's names of the batch rows' controls, by their keys.
_CONTROL_NAMES = {"control_ratio": "SHA-256 control", "fp_control_ratio": "FP throughput"}


def _cells(row: dict[str, Any]) -> tuple[str, ...]:
    status = "pass" if row["passed"] else "FAIL"
    if row["kind"] == "overhead":  # columns: noise given, noise estimated; ratio est / given
        if not row.get("results_agree", True):
            status = "FAIL (results differ)"
        if row["target"] is None:
            status = "info"
        target = "-" if row["target"] is None else f"<= {row['target']:g}x"
        return (row["name"], _fmt_s(row["reference_s"]), _fmt_s(row["dtalign_s"]),
                f"{row['ratio']:.2f}x", target, status, "-", "-")
    if row["kind"] in ("speed", "batch"):
        if not row.get("results_agree", True):
            status = "FAIL (results differ)"
        elif row.get("rule") in ("control-bound", "below control", "below floor"):
            # below target: the rule of scaling.judge it passed or failed by, and its control
            by = _CONTROL_NAMES.get(row.get("judged_by", ""), "its control")
            status += f", {row['rule']} ({by}): needs {row['required_ratio']:.2f}x"
        target = "-" if row["target"] is None else f">= {row['target']:g}x"
        if row["target"] is None:
            status = "info"
        if "control_ratio" in row:  # what the machine itself allowed (GIL-free C code)
            status += f" (control {row['control_ratio']:.2f}x"
            if "fp_control_ratio" in row:  # and FP-throughput-bound compiled code
                status += f", FP throughput {row['fp_control_ratio']:.2f}x"
            if "loop_control_ratio" in row:  # and fit_many's compiled loop alone
                status += f", compiled loop alone {row['loop_control_ratio']:.2f}x"
            status += ")"
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


def rst_table(head: Sequence[str], body: Sequence[Sequence[str]], title: str | None = None) -> str:
    """An RST simple table of text cells: the first column left-aligned, the
    others (numbers) right-aligned; ``title`` in bold above it (the bias and
    error tables of ``benchmarks/profile_bias.py`` and ``terminator_error.py``)."""
    rows = [list(head), *map(list, body)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    line = "  ".join("=" * w for w in widths)

    def fmt(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    table = [line, fmt(rows[0]), line, *map(fmt, rows[1:]), line]
    return "\n".join(([f"**{title}**", ""] if title else []) + table)


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
        "run the same way (what the machine allowed), FP throughput is compiled "
        "floating-point-bound work run the same way (what it allowed such code), "
        "and the compiled loop alone "
        "is fit_many's compiled fitting loop without its Python. The noise-overhead row: "
        "the columns are fit_polyline with the noise given and estimated, the ratio "
        "estimated / given. Start-up rows: fresh "
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


#: The README section :func:`replace_readme_table` rewrites.
README_START = "<!-- bench-table:start (python -m dtalign.benchmarking --readme README.md) -->"
README_END = "<!-- bench-table:end -->"


def format_markdown(report: dict[str, Any]) -> str:
    """The table in Markdown, with the machine it was measured on."""
    m = report["machine"]
    rows = [HEADER, *(_cells(r) for r in report["rows"])]
    out = [
        f"Measured {report['created']} on {m['cpu_count']} CPU(s), Python {m['python']}, "
        f"NumPy {m['numpy']}, Numba {m['numba']}; {report['settings']['mode']} run, medians "
        f"of {report['settings']['repeats']} alternating samples; ratio = reference / dtalign "
        "(batch rows: 1 thread / 2 threads).",
        "",
        "| " + " | ".join(rows[0]) + " |",
        "|" + "---|" * len(rows[0]),
    ]
    out.extend("| " + " | ".join(c.replace("|", "/") for c in cells) + " |" for cells in rows[1:])
    return "\n".join(out) + "\n"


def replace_readme_table(text: str, report: dict[str, Any]) -> str:
    """``text`` (a README) with the table between the bench-table markers replaced.

    Raises
    ------
    ValueError
        If the markers are missing or out of order.
    """
    start = text.find(README_START)
    end = text.find(README_END)
    if start < 0 or end < start:
        raise ValueError(f"the README has no '{README_START}' ... '{README_END}' section")
    head = text[: start + len(README_START)]
    return head + "\n" + format_markdown(report) + text[end:]


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
