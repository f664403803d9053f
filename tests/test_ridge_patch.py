"""The ridge polish reads the gradient magnitude three ways; all give the same bits.

From the LM driver it samples a lazily filled magnitude patch: a profile
wholly inside the patch is read as one block (its tiles filled first), any
other sample goes through ``sample_magnitude`` (tile test per sample, or
per-pixel hypot outside the patch). Both must equal sampling the full
magnitude image (``np.hypot`` of the gradient), as the public
``gradient_ridge_refine`` does.
"""

from __future__ import annotations

import numpy as np
import pytest

from dtalign import scenes
from dtalign._kernels import ridge as rk
from dtalign.api.constants import DEFAULT_LM_STEP_TOLERANCE, DEFAULT_RIDGE_SAMPLE_STEP_PX
from dtalign.api.image import _use_libm_hypot
from dtalign.reference import compute_all_image_derivatives

HALF = 6


@pytest.fixture(scope="module")
def scene():
    s = scenes.disc_scene(shape=(192, 192), radius=50.0, n_vertices=120, offset_vu=(2.3, -1.6))
    _, _, grad = compute_all_image_derivatives(s.image, s.noise_sigma)
    return s, np.ascontiguousarray(grad)


def _ridge(scene, grad, magnitude, patch_reach, pose, fit_rotation):
    s = scene.polyline
    pts = np.ascontiguousarray(s.vertices_vu)
    n = pts.shape[0]
    for a in (pts, s.normals_vu, s.sigmas):
        a.flags.writeable = False
    if patch_reach is None:  # the public path: a magnitude image, no gradient
        patch, tiles, r0, c0 = np.zeros((0, 0)), np.zeros((1, 1), np.uint8), 0, 0
        grad = np.zeros((0, 0, 2))
    else:
        patch, tiles, r0, c0 = rk.magnitude_patch(grad, pts, pose[0], pose[1], patch_reach)
    return rk.ridge_loop(
        rk.MagnitudeField(magnitude, patch, tiles, grad, r0, c0, _use_libm_hypot()), pts,
        s.normals_vu, s.sigmas, np.ones(n), np.array(pose), np.array([96.0, 96.0]), fit_rotation,
        60.0 if fit_rotation else 0.0,
        rk.RidgeSettings(10, DEFAULT_LM_STEP_TOLERANCE, 4.685, HALF, DEFAULT_RIDGE_SAMPLE_STEP_PX),
    )


@pytest.mark.parametrize("fit_rotation", [False, True])
@pytest.mark.parametrize("reach", [
    HALF * DEFAULT_RIDGE_SAMPLE_STEP_PX + rk.PATCH_MARGIN,  # every profile inside the patch
    HALF * DEFAULT_RIDGE_SAMPLE_STEP_PX - 1.0,  # profile ends fall outside: per-sample path
    0.0,  # a patch barely covering the vertices: mostly per-pixel hypot
])
def test_patch_paths_equal_the_magnitude_image(scene, fit_rotation, reach):
    s, grad = scene
    magnitude = np.ascontiguousarray(np.hypot(grad[..., 0], grad[..., 1]))
    pose = (2.0, -1.0, 0.004 if fit_rotation else 0.0)
    expected = _ridge(s, grad, magnitude, None, pose, fit_rotation)
    got = _ridge(s, grad, np.zeros((0, 0)), reach, pose, fit_rotation)
    assert got[3] == expected[3] == rk.RIDGE_OK
    assert got[1] == expected[1] and got[2] == expected[2]
    assert got[0].tobytes() == expected[0].tobytes()
