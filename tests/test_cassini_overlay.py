"""The Cassini overlay tracer on synthetic frames: the package never needs the real files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from dtalign import sphere_edge_profile
from dtalign.io import cassini


def _disc_frame(center, radius, size=200, text_at=None):
    """A bright disc on black with a one-pixel red circle drawn at ``radius``."""
    vv, uu = np.mgrid[:size, :size].astype(np.float64)
    r = np.hypot(vv - center[0], uu - center[1])
    image = np.where(r < radius, 200.0, 5.0)
    mask = np.abs(r - radius) < 0.5
    if text_at is not None:  # a label block off the limb
        v0, u0 = text_at
        mask[v0:v0 + 5, u0:u0 + 20] = True
    return cassini.CassiniFrame(image=image, overlay_mask=mask, overlay_strength=mask * 1.0,
                                header_rows=0, path=Path("synthetic.png"))


def test_overlay_circle_finds_the_drawn_circle_despite_a_label():
    frame = _disc_frame((97.3, 104.6), 61.5, text_at=(5, 5))
    (cv, cu), radius = cassini.overlay_circle(frame)
    assert math.hypot(cv - 97.3, cu - 104.6) < 0.2
    assert abs(radius - 61.5) < 0.2


def test_overlay_circle_is_the_one_the_limb_normals_come_from():
    frame = _disc_frame((100.0, 98.0), 70.0)
    center, radius = cassini.overlay_circle(frame)
    (limb,) = cassini.overlay_polylines(frame, shape="limb")
    profile = sphere_edge_profile(limb.vertices_vu, center_vu=center, radius_px=radius,
                                  phase_deg=0.0, illumination_deg=0.0)
    np.testing.assert_allclose(profile.normals_vu, limb.normals_vu, atol=1e-12)


def test_overlay_circle_needs_an_overlay():
    frame = _disc_frame((100.0, 100.0), 50.0)
    empty = cassini.CassiniFrame(image=frame.image, overlay_mask=np.zeros_like(frame.overlay_mask),
                                 overlay_strength=frame.overlay_strength * 0.0, header_rows=0,
                                 path=frame.path)
    with pytest.raises(ValueError, match="no overlay"):
        cassini.overlay_circle(empty)
