"""Compile the pipeline's kernels ahead of time: :func:`dtalign.warm_up`.

Numba compiles each kernel on its first call (about a minute or more on a
cold cache) and caches the machine code on disk, so only the first process
pays. :func:`dtalign.warm_up` makes that first call at a moment of the caller's
choosing (a service's start, a notebook's first cell, an image build that
should ship a warm cache), on a small synthetic scene, through the same
public functions a user calls: every kernel those use is compiled, or
loaded from the cache when it is already warm.
"""

from __future__ import annotations

import logging
import time

__all__ = ["warm_up"]

logger = logging.getLogger("dtalign")


def warm_up() -> float:
    """Compile (or load from the disk cache) every kernel the pipeline uses.

    Runs, on a small seeded disc scene (128 x 128, 48 vertices):
    :func:`~dtalign.pipeline.products.prepare_image` with the noise
    estimated, :func:`~dtalign.pipeline.fit_polyline_products` in
    translation and with rotation, the trust region, the Tikhonov pull and
    the gradient-ridge polish, the rival-basin examination, and
    :func:`~dtalign.pipeline.batch.fit_many`'s compiled loop. The drop-in
    functions (:func:`dtalign.lm_subpixel_refine`, ...) share these kernels.

    On a cold cache this takes a minute or more (announced at INFO on the
    ``dtalign`` logger when the first kernel compiles); on a warm one,
    well under a second. Safe to call more than once and from any thread.

    Returns
    -------
    float
        Wall time of the call, seconds (logged at INFO too).

    Examples
    --------
    >>> import dtalign
    >>> seconds = dtalign.warm_up()  # once, e.g. at a service's start
    """
    from .pipeline.batch import fit_many
    from .pipeline.fit import fit_polyline_products
    from .pipeline.products import prepare_image
    from .scenes import disc_scene

    t0 = time.perf_counter()
    scene = disc_scene(shape=(128, 128), radius=40.0, n_vertices=48, offset_vu=(2.3, -1.6),
                       search_window=6)
    p = scene.polyline
    poly = (p.vertices_vu, p.normals_vu, p.sigmas)
    # a clean scene: its fits are ok, so nothing but the compile notice is logged
    products = prepare_image(scene.image)  # the noise estimate too
    window = scene.search_window_vu
    fit_polyline_products(products, *poly, search_window_vu=window)
    fit_polyline_products(products, *poly, search_window_vu=window, fit_rotation=True,
                          trust_region_px=1.0, tikhonov_alpha=0.1,
                          final_gradient_ridge=True, seeds=2)
    fit_many(products, [poly, poly], search_window_vu=window, workers=1)
    elapsed = time.perf_counter() - t0
    logger.info("dtalign kernels ready (%.1f s)", elapsed)
    return elapsed
