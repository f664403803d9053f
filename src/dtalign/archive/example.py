"""A synthetic campaign to try :func:`dtalign.archive.run` (``dtalign archive --make-example``)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..api import checks as check
from .manifest import write_manifest

__all__ = ["make_example"]

PathLike = str | os.PathLike[str]

#: Largest true offset of an example frame along each axis, px: well inside
#: the default search window of 30.
_MAX_OFFSET_PX = 8.0


def make_example(
    directory: PathLike, *, frames: int = 8, size: int = 512, seed: int = 0,
    broken: bool = False,
) -> Path:
    """Write synthetic frames, their polylines and a manifest; returns the manifest's path.

    Each frame is :func:`dtalign.scenes.navigation_scene` (a half-lit body
    and a ring edge, noise 2 DN) with its own seeded true offset, saved as
    ``frames/fNNN.npy`` with three polyline CSVs (``limb``, ``terminator``,
    ``ring``). ``manifest.jsonl`` lists them (noise sigma given, the
    production trust region of 1 px), and ``truth.jsonl`` holds each
    frame's true offset.

    Parameters
    ----------
    directory : str or path-like
        Created when missing.
    frames : int, optional
        Number of frames (8).
    size : int, optional
        Frame height and width in pixels (512; >= 128).
    seed : int, optional
        Seed of the offsets and noise.
    broken : bool, optional
        Also list a missing image and a corrupt one, to see the failures table.
    """
    from ..io.files import save_polyline_csv
    from ..scenes import navigation_scene

    check.int_at_least(frames, "frames")
    check.int_at_least(size, "size", 128)
    root = Path(directory)
    (root / "frames").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    records: list[dict[str, Any]] = []
    truth: list[dict[str, Any]] = []
    for k in range(frames):
        offset = (float(rng.uniform(-_MAX_OFFSET_PX, _MAX_OFFSET_PX)),
                  float(rng.uniform(-_MAX_OFFSET_PX, _MAX_OFFSET_PX)))
        scene = navigation_scene(shape=(size, size), radius=size * 0.15, offset_vu=offset,
                                 seed=seed * 100_003 + k)
        name = f"f{k:03d}"
        np.save(root / "frames" / f"{name}.npy", scene.image)
        polys: list[str] = []
        for p in scene.polylines:
            rel = f"frames/{name}-{p.name}.csv"
            save_polyline_csv(root / rel, p)
            polys.append(rel)
        records.append({"id": name, "image": f"frames/{name}.npy", "polylines": polys,
                        "noise_sigma": scene.noise_sigma, "options": {"trust_region_px": 1.0}})
        truth.append({"id": name, "true_offset_v": offset[0], "true_offset_u": offset[1]})
    if broken:
        (root / "frames" / "corrupt.npy").write_bytes(b"this is not an image")
        first = records[0]["polylines"]
        records.append({"id": "missing", "image": "frames/missing.npy", "polylines": first})
        records.append({"id": "corrupt", "image": "frames/corrupt.npy", "polylines": first})
    with open(root / "truth.jsonl", "w", encoding="utf-8") as fh:
        fh.writelines(json.dumps(t) + "\n" for t in truth)
    return write_manifest(root / "manifest.jsonl", records)
