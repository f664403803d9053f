"""Rewrite the cached renders ``tests/test_validation_renders.py`` reads.

``python -m benchmarks.validate.fixtures`` renders the renderer's checks
(:mod:`.checks`) and the fixed subset :data:`SUBSET` of the harness's
scenes (seed :data:`SEED`, the same draws as a run of that seed; and
:data:`SUBSET_SEED1` of seed 1) and writes
each as a compressed ``.npz`` in ``tests/data/validation/``: the image as
float32 and the render's metadata (the scene's parameters as JSON: planted
and model centres, radius, Sun, phase, PSF, family, seeds; the Mitsuba,
Dr.Jit and GalSim versions). The renders are deterministic (seeded
stratified sampler, seeded noise), so rerunning rewrites the same images.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import checks, families
from .render import versions

OUT = Path(__file__).resolve().parents[2] / "tests" / "data" / "validation"
SEED = 0
#: (family, edge, index) of the test's scenes, all from seed SEED
SUBSET = (
    ("model_right", "limb", 0), ("model_right", "limb", 1), ("model_right", "limb", 2),
    ("model_right", "limb", 3), ("model_right", "terminator", 0),
    ("model_right", "terminator", 1), ("psf_mismatch", "limb", 0), ("psf_mismatch", "limb", 1),
    ("psf_mismatch", "limb", 2), ("law_mismatch", "limb", 0), ("craters", "limb", 0),
    ("triaxial", "limb", 0), ("triaxial", "terminator", 3), ("night_floor", "terminator", 0),
    ("capped_limb", "limb", 0), ("night_floor", "terminator", 2),
    ("night_additive", "terminator", 2), ("albedo_texture", "limb", 1),
)
#: (family, edge, index) of seed 1's scenes the test reads as well (``scene_s1_*``):
#: terminators whose pixels fix the pose weakly, and whose model is wrong
SUBSET_SEED1 = (("psf_mismatch", "terminator", 0), ("craters", "terminator", 0))


def _save(path: Path, image: np.ndarray, meta: dict) -> None:
    np.savez_compressed(path, image=image.astype(np.float32), meta=np.array(json.dumps(meta)))


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    ver = versions()
    for name in checks.CHECKS:
        _save(OUT / f"check_{name}.npz", checks.render_check(name),
              {"check": name, **ver})
        print("check", name, flush=True)
    for family, edge, index in SUBSET:
        p = families.draw(family, edge, index, SEED)
        _save(OUT / f"scene_{family}_{edge}_{index}.npz", families.render_scene(p),
              {"scene": p, **ver})
        print("scene", family, edge, index, flush=True)
    for family, edge, index in SUBSET_SEED1:
        p = families.draw(family, edge, index, 1)
        _save(OUT / f"scene_s1_{family}_{edge}_{index}.npz", families.render_scene(p),
              {"scene": p, **ver})
        print("scene (seed 1)", family, edge, index, flush=True)
    total = sum(f.stat().st_size for f in OUT.glob("*.npz"))
    print(f"{OUT}: {total / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
