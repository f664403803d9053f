"""Reliability at the extremes: large arrays, extreme magnitudes, crashes.

Large image-sized arrays are not scanned for NaN/inf on entry: a value the
fit reads is refused by name, one it never reads cannot change the result.
Finite but extreme magnitudes give a finite result or a ValueError naming
the argument. The scariest inputs run in a subprocess so a crash would
show as a failed test, not a dead test run.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import dtalign
from dtalign.api import checks as _validation
from test_reliability_inputs import COV, INF, LM, NAN, RIDGE, _scene, assert_lm_sane

# --------------------------------------------------------------------------
# Large arrays: not scanned up front, refused when a non-finite value is read
# --------------------------------------------------------------------------

BIG = (272, 272)  # 73984 values > FULL_SCAN_MAX_SIZE: not scanned on entry


def _big_call(fn: str, arr_name: str, where: str, value: float):
    """Run ``fn`` on the big scene with one poisoned value in ``arr_name``.

    ``where == "read"``: the 3 x 3 pixels under the first vertex (every fit
    reads them); ``"far"``: the image corner, 100+ px from the polyline
    (never read).
    """
    b = _scene(BIG)
    arrays = {"dt": b.dt, "image_edge_dt": b.dt, "image_gradient_vu": b.grad, "gradient_magnitude": b.mag}
    base = {
        "sample_dt_bilinear": dict(dt=b.dt, vertices_vu=b.v),
        "polarity_filter": dict(vertices_vu=b.v, normals_vu=b.n, image_gradient_vu=b.grad, offset_vu=b.offset),
        LM: dict(vertices_vu=b.v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s, image_edge_dt=b.dt,
                 image_gradient_vu=b.grad, initial_offset_vu=(1.0, -1.0), final_gradient_ridge=True,
                 fit_rotation=True, pivot_distance_px=30.0),
        RIDGE: dict(vertices_vu=b.v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s,
                    gradient_magnitude=b.mag, initial_offset_vu=b.offset),
    }[fn]
    if value is not None:
        poisoned = arrays[arr_name].copy()
        shift = (0.0, 0.0) if fn == "sample_dt_bilinear" else b.offset
        iv, iu = (np.rint(b.v[0] + np.asarray(shift)).astype(int) if where == "read" else (1, 1))
        poisoned[iv - 1 : iv + 2, iu - 1 : iu + 2] = value
        base[arr_name] = poisoned
    return getattr(dtalign, fn)(**base)


BIG_CASES = [("sample_dt_bilinear", "dt"), ("polarity_filter", "image_gradient_vu"),
             (LM, "image_edge_dt"), (LM, "image_gradient_vu"), (RIDGE, "gradient_magnitude")]


@pytest.mark.parametrize("value", [NAN, INF, -INF], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize(("fn", "arr"), BIG_CASES, ids=[f"{f}-{a}" for f, a in BIG_CASES])
class TestLargeArrayRegime:
    def test_refused_when_read(self, fn, arr, value):
        assert _scene(BIG).dt.size > _validation.FULL_SCAN_MAX_SIZE
        try:
            _big_call(fn, arr, "read", value)
        except np.linalg.LinAlgError:  # a ValueError subclass: do not let it pass below
            raise
        except ValueError as exc:
            assert f"{arr} must be finite" in str(exc), exc
        else:
            pytest.fail(f"a {value} read from {arr} was not refused")

    def test_value_never_read_does_not_change_the_result(self, fn, arr, value):
        # Documented design: a large array is not scanned, and a value the
        # fit never reads cannot influence it, so the result is bit-identical
        # to the clean array's (not an error).
        clean = _big_call(fn, arr, "far", None)
        got = _big_call(fn, arr, "far", value)
        if isinstance(got, np.ndarray):
            np.testing.assert_array_equal(got, clean)
        else:
            assert got == clean if not hasattr(got, "covariance") else _lm_equal(got, clean)


def _lm_equal(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)


def test_scan_threshold_boundary():
    """At exactly FULL_SCAN_MAX_SIZE values a never-read NaN is still refused."""
    n = int(math.isqrt(_validation.FULL_SCAN_MAX_SIZE))
    assert n * n == _validation.FULL_SCAN_MAX_SIZE
    dt = np.ones((n, n))
    dt[-1, -1] = NAN
    with pytest.raises(ValueError, match="dt must be finite"):
        dtalign.sample_dt_bilinear(dt, [[1.0, 1.0]])
    dt = np.ones((n + 1, n))  # one row more: not scanned, NaN never read
    dt[-1, -1] = NAN
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(dt, [[1.0, 1.0]]), [1.0])
    big_image = np.zeros((300, 300))
    big_image[299, 299] = NAN  # images are always scanned (the filter reads every pixel)
    with pytest.raises(ValueError, match="finite"):
        dtalign.compute_image_gradient_vu(big_image)


# --------------------------------------------------------------------------
# Extreme but finite magnitudes: a finite result or a ValueError naming an argument
# --------------------------------------------------------------------------

_HUGE_DT = np.zeros((12, 12))
_HUGE_DT[6, 5] = 1e300  # J = 5e299 at the vertex below: J^T W J overflows
_V3 = np.array([[5.0, 5.0], [5.0, 7.0], [7.0, 5.0]])
_N3 = np.tile([1.0, 0.0], (3, 1))
_LM3 = dict(vertices_vu=_V3, normals_vu=_N3, sigma_normal_per_vertex_px=np.ones(3),
            image_edge_dt=np.ones((12, 12)), use_polarity=False)
EXTREME = [
    pytest.param(LM, dict(_LM3, image_edge_dt=_HUGE_DT), "image_edge_dt", id="lm-dt-1e300",),
    pytest.param(COV, dict(jacobian=np.array([[1e200, 0.0], [0.0, 1.0]]), weights=np.ones(2)),
                 "jacobian", id="cov-jacobian-1e200",),
    pytest.param(RIDGE, dict(vertices_vu=[[2.0, 2.0]], normals_vu=[[1e308, 1e308]],
                             sigma_normal_per_vertex_px=[1.0], gradient_magnitude=np.arange(25.0).reshape(5, 5),
                             initial_offset_vu=(0, 0), initial_rotation_rad=0.5),
                 "normals_vu", id="ridge-normals-1e308"),
    pytest.param(LM, dict(_LM3, vertices_vu=[[1e308, 1.0], [1e308, 2.0]], normals_vu=_N3[:2],
                          sigma_normal_per_vertex_px=np.ones(2), initial_rotation_rad=0.1),
                 "vertices_vu", id="lm-centroid-overflow",),
    pytest.param(LM, dict(_LM3, vertices_vu=[[1e308, 1e308]], normals_vu=_N3[:1],
                          sigma_normal_per_vertex_px=np.ones(1), initial_rotation_rad=0.1,
                          pivot_vu=(-1e308, -1e308)),
                 "pivot_vu", id="lm-pivot-far",),
    pytest.param(LM, dict(_LM3, initial_offset_vu=(1e308, -1e308), fit_rotation=True, pivot_distance_px=1.0),
                 None, id="lm-offset-1e308"),
    pytest.param(LM, dict(_LM3, initial_rotation_rad=1e308, fit_rotation=True, pivot_distance_px=1e300),
                 None, id="lm-rotation-1e308"),
    pytest.param("polarity_filter", dict(vertices_vu=[[1e308, -1e308]], normals_vu=[[1.0, 0.0]],
                                         image_gradient_vu=np.ones((5, 5, 2)), offset_vu=(1e308, -1e308)),
                 None, id="polarity-offset-overflow"),
    pytest.param("sample_dt_bilinear", dict(dt=np.where(np.eye(4) > 0, 1.7e308, -1.7e308),
                                            vertices_vu=[[0.5, 0.5], [1.5, 2.0], [1e308, -1e308]]),
                 None, id="sample-dt-1.7e308"),
    pytest.param("compute_all_image_derivatives", dict(image_ext=np.where(np.eye(8) > 0, 1e300, -1e300),
                                                       image_noise_sigma=1e300), None, id="image-1e300"),
]


@pytest.mark.parametrize(("fn", "kw", "culprit"), EXTREME)
def test_extreme_finite_inputs(fn, kw, culprit):
    try:
        out = getattr(dtalign, fn)(**kw)
    except ValueError as exc:  # acceptable only if it names the culprit
        if type(exc) is not ValueError:  # e.g. numpy.linalg.LinAlgError from inside a kernel
            raise
        assert culprit is not None and culprit in str(exc), exc
        return
    assert culprit is None, f"expected a refusal naming {culprit}"
    outs = out if isinstance(out, tuple) and not hasattr(out, "covariance") else (out,)
    for o in outs:
        if hasattr(o, "covariance"):
            assert_lm_sane(o, len(kw["vertices_vu"]), 3 if kw.get("fit_rotation") else 2)
        else:
            assert not np.isnan(np.asarray(o, dtype=float)).any()


# --------------------------------------------------------------------------
# Subprocess smoke: the scariest inputs must not kill the interpreter
# --------------------------------------------------------------------------

SMOKE = textwrap.dedent(
    """
    import numpy as np, dtalign as d
    v3 = np.array([[5.0, 5.0], [5.0, 7.0], [7.0, 5.0]]); n3 = np.tile([1.0, 0.0], (3, 1))
    big = np.zeros((12, 12)); big[6, 5] = 1e300
    lm = dict(vertices_vu=v3, normals_vu=n3, sigma_normal_per_vertex_px=np.ones(3),
              image_edge_dt=np.ones((12, 12)), use_polarity=False)
    cases = {
      "inf-hessian": lambda: d.lm_subpixel_refine(**dict(lm, image_edge_dt=big, fit_rotation=True,
          pivot_distance_px=2.0)),
      "ridge-1x1": lambda: d.gradient_ridge_refine(vertices_vu=[[1e300, -1e300]], normals_vu=[[1.0, 0.0]],
          sigma_normal_per_vertex_px=[1.0], gradient_magnitude=np.ones((1, 1)), initial_offset_vu=(0, 0)),
      "coarse-huge-window": lambda: d.coarse_ncc_search(np.ones((1, 3)), np.ones((1, 3)), (2**62, 2**63 - 1)),
      "mask-huge-vertices": lambda: d.build_polyline_mask([[1e308, -1e308], [2.0**63, 2.0**64]], (3, 3)),
      "polarity-huge": lambda: d.polarity_filter([[2**63, -2.0**63]], [[1.0, 1.0]], np.ones((1, 1, 2)),
          offset_vu=(2.0**63, 0.0)),
      "image-1x1": lambda: d.compute_all_image_derivatives(np.ones((1, 1)), 0.0),
      "image-long": lambda: d.compute_all_image_derivatives(np.ones((1, 300)), 0.0,
          config=d.ImageDerivativesConfig(image_gradient_sigma_px=50.0, dt_half_width_px=1e300)),
    }
    for name, fn in cases.items():
        try:
            fn()
            print(name, "ok", flush=True)
        except Exception as exc:
            print(name, type(exc).__name__, flush=True)
    print("DONE", flush=True)
    """
)


def test_scary_inputs_do_not_crash_the_process():
    # The overflowing-position cases (lm-centroid-overflow, lm-pivot-far,
    # ridge-normals-1e308 above) are not here: they read out of bounds (a NaN
    # cast to an index), which NUMBA_BOUNDSCHECK=1 turns into IndexError; they
    # are pinned as strict xfails until the source is fixed.
    env = dict(os.environ)
    src = os.path.join(os.path.dirname(dtalign.__file__), os.pardir)
    env["PYTHONPATH"] = os.pathsep.join([os.path.abspath(src), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", SMOKE], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, (proc.returncode, proc.stdout, proc.stderr[-2000:])
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if " " in line)
    assert proc.stdout.rstrip().endswith("DONE")
    for name, outcome in lines.items():  # a refusal is fine, an error from inside is not
        assert outcome in ("ok", "ValueError", "LinAlgError"), (name, outcome)
