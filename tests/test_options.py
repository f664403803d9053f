"""The LM's kernel options: one record, built in one place, one compiled type.

:func:`dtalign.api.options.lm_kernel_options` converts every field to one
Python type, so whatever numeric types a caller passes (NumPy scalars,
ints for floats), the compiled fit sees one named-tuple type and compiles
one specialisation for it.
"""

from __future__ import annotations

import inspect
import typing

import numba
import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign._kernels import fit as kfit
from dtalign._kernels import pipeline as kpipeline
from dtalign.api.checks import check_lm_inputs
from dtalign.api.options import LMKernelOptions, fit_arguments, lm_kernel_options

VARIANTS = [
    {},
    {"trust_region_px": 2, "damping": 1, "tukey_c": np.float64(4.0)},
    {"max_iterations": np.int64(7), "step_tolerance_px": np.float32(1e-3), "use_polarity": False},
    {"fit_rotation": True, "pivot_distance_px": 50.0, "final_gradient_ridge": True,
     "tikhonov_alpha": 0.5},
]


@pytest.fixture(scope="module")
def scene():
    return scenes.disc_scene(shape=(96, 96), radius=24.0, n_vertices=40)


def _checked(scene, **kw):
    _, dt, grad = dtalign.compute_all_image_derivatives(scene.image, scene.noise_sigma)
    p = scene.polyline
    call = dict(vertices_vu=p.vertices_vu, normals_vu=p.normals_vu,
                sigma_normal_per_vertex_px=p.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
                **kw)
    bound = inspect.signature(dtalign.lm_subpixel_refine).bind(**call)
    bound.apply_defaults()
    return call, check_lm_inputs(dict(bound.arguments))


@pytest.mark.parametrize("kw", VARIANTS)
def test_every_field_has_its_declared_type(scene, kw):
    _, a = _checked(scene, **kw)
    opts = lm_kernel_options(a)
    assert isinstance(opts, LMKernelOptions)
    hints = typing.get_type_hints(LMKernelOptions)
    assert set(hints.values()) == {bool, int, float}
    for name, value in zip(opts._fields, opts, strict=True):
        assert type(value) is hints[name], name


def test_ridge_override_and_the_fit_arguments(scene):
    _, a = _checked(scene, final_gradient_ridge=True)
    assert lm_kernel_options(a).ridge and not lm_kernel_options(a, ridge=False).ridge
    args = fit_arguments(a, ridge=False)
    assert args[-1] == lm_kernel_options(a, ridge=False)
    assert args[0] is a.dt and args[2] is a.vertices


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="nothing is compiled with the JIT disabled")
def test_the_compiled_fit_sees_one_options_type(scene):
    for kw in VARIANTS:
        call, _ = _checked(scene, **kw)
        dtalign.lm_subpixel_refine(**call)
    options_types = {sig[-1] for sig in kfit.fit.signatures}
    assert len(options_types) == 1, options_types
    # the pipeline's loop takes the same record type
    products = dtalign.prepare_image(scene.image, scene.noise_sigma)
    p = scene.polyline
    from dtalign.pipeline.batch import fit_many

    fit_many(products, [p, p], search_window_vu=(4, 4), workers=1)
    # (its inputs record LoopInputs ends with the options record)
    loop_types = {sig[0].types[-1] for sig in kpipeline.fit_polylines.signatures}
    assert loop_types <= options_types
