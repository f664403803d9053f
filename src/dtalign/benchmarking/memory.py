"""Memory section: image-sized temporaries of the derivatives, LM peak vs DT size."""

from __future__ import annotations

from functools import partial
from typing import Any

from .timing import _mib, peak_bytes
from .workloads import DERIVATIVE_TEMPORARIES_TARGET, compiled_api, lm_keywords


def measure_memory() -> dict[str, Any]:
    """Image-sized temporaries of the derivatives; LM peak on a 512 and a 2048 DT."""
    import dtalign.reference as reference
    import dtalign.scenes as scenes

    dtalign = compiled_api()

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
        kw = lm_keywords(s.polyline, dt, grad, (7.0, -5.0))
        for label, api in apis:
            api.lm_subpixel_refine(**kw)
            out[f"lm_{size}_{label}_peak_bytes"] = peak_bytes(partial(api.lm_subpixel_refine, **kw))
    growth = out["lm_2048_dtalign_peak_bytes"] - out["lm_512_dtalign_peak_bytes"]
    out["lm_dtalign_growth_bytes"] = growth
    out["lm_dtalign_independent_of_image"] = growth < 64 * 1024
    return out


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
