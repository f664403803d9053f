"""``fit_many`` with edge profiles on one thread and on two, alternated.

Sixteen copies of one rendered sphere's limb (or terminator) polyline, each
with its edge profile (:func:`dtalign.sphere_edge_profile`, the PSF's sigma
estimated), fitted on one image's products by
:func:`~dtalign.pipeline.batch.fit_many` with ``workers=1`` and
``workers=2`` in turn. A profile refinement takes several times a fit's own
time, so this measures whether the refinements share the batch's threads
(docs/benchmarks.rst, "What was tried").

Run ``python benchmarks/profile_batch.py`` (``--pairs N``, ``--seed S``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Sequence

from dtalign.api.profiles import sphere_edge_profile
from dtalign.benchmarking import coverage as cov
from dtalign.pipeline.batch import fit_many
from dtalign.pipeline.products import prepare_image

#: Polylines a call: enough chunks for both threads, few enough for a quick run.
POLYLINES = 16


def measure(family: str, seed: int, pairs: int) -> tuple[float, float]:
    """Median seconds of one call on one thread and on two, ``pairs`` alternated pairs."""
    case = cov.FAMILIES[family](seed)
    x, p = case.extra, case.polyline
    prof = sphere_edge_profile(p.vertices_vu, center_vu=x["center_vu"], radius_px=x["radius_px"],
                               phase_deg=x["phase_deg"], illumination_deg=x["illumination_deg"],
                               edge=x["edge"], psf_sigma_px=None)
    products = prepare_image(case.image, case.noise_sigma)
    polys = [(p.vertices_vu, p.normals_vu, p.sigmas, prof)] * POLYLINES

    def run(workers: int) -> None:
        fit_many(products, polys, search_window_vu=case.search_window_vu, workers=workers,
                 use_polarity=case.use_polarity, ambiguity=False)

    run(1)
    run(2)  # compiled and warm
    times: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(pairs):
        for workers in (1, 2):
            t0 = time.perf_counter()
            run(workers)
            times[workers].append(time.perf_counter() - t0)
    return statistics.median(times[1]), statistics.median(times[2])


def main(argv: Sequence[str] | None = None) -> int:
    """Print one line per family: the two medians and their ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=7, help="alternated pairs of calls")
    parser.add_argument("--seed", type=int, default=3, help="the rendered sphere's seed")
    args = parser.parse_args(argv)
    for family in ("sphere_limb", "sphere_terminator"):
        one, two = measure(family, args.seed, args.pairs)
        print(f"{family}: 1 thread {one * 1e3:.1f} ms, 2 threads {two * 1e3:.1f} ms, "
              f"ratio {one / two:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
