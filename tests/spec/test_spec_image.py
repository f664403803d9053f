""":ref:`contract-image` (image side), checked by properties that follow from its text."""

from __future__ import annotations

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")


def _step(h=24, w=24, col=12):
    img = np.zeros((h, w))
    img[:, col:] = 100.0
    return img


def test_constant_zero_image():
    img = np.zeros((16, 20))
    g = dtalign.compute_image_gradient_vu(img)
    assert g.shape == (16, 20, 2) and g.dtype == np.float64
    np.testing.assert_array_equal(g, 0.0)
    mag, dt = dtalign.build_image_edge_dt(img, 1.0)
    assert mag.shape == dt.shape == (16, 20)
    np.testing.assert_array_equal(mag, 0.0)
    # no edge pixel: the DT is dt_half_width_px everywhere
    np.testing.assert_array_equal(dt, 64.0)
    _, dt5 = dtalign.build_image_edge_dt(img, 0.0,
                                         config=dtalign.ImageDerivativesConfig(dt_half_width_px=5.0))
    np.testing.assert_array_equal(dt5, 5.0)


def test_products_consistent():
    img = _step()
    mag, dt, g = dtalign.compute_all_image_derivatives(img, 2.0)
    g2 = dtalign.compute_image_gradient_vu(img)
    mag2, dt2 = dtalign.build_image_edge_dt(img, 2.0)
    np.testing.assert_allclose(g, g2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mag, mag2, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(dt, dt2)
    np.testing.assert_allclose(mag, np.hypot(g[..., 0], g[..., 1]), rtol=1e-12, atol=1e-12)
    assert np.all(dt >= 0) and np.all(dt <= 64.0)


def test_config_sigma_is_the_gradient_sigma():
    img = _step()
    cfg = dtalign.ImageDerivativesConfig(image_gradient_sigma_px=2.0)
    mag, _, g = dtalign.compute_all_image_derivatives(img, 2.0, config=cfg)
    g2 = dtalign.compute_image_gradient_vu(img, sigma_px=2.0)
    np.testing.assert_allclose(g, g2, rtol=1e-12, atol=1e-12)
    g_default = dtalign.compute_image_gradient_vu(img)
    assert not np.allclose(g2, g_default)


def test_step_edge_gradient_and_dt():
    img = _step()
    mag, dt, g = dtalign.compute_all_image_derivatives(img, 2.0)
    rows = slice(6, 18)
    # dark -> bright along +u: g_u > 0 at the step, g_v ~ 0 away from the borders
    assert np.all(g[rows, 11:13, 1] > 0)
    np.testing.assert_allclose(g[rows, 4:20, 0], 0.0, atol=1e-9)
    # the step is an edge: DT zero on one of its two central columns, distance grows away
    assert np.all(np.min(dt[rows, 11:13], axis=1) == 0.0)
    d = dt[12, :]
    assert d[5] > d[8] > d[10] >= 0.0


def test_dt_is_euclidean_distance_to_edge_pixels():
    # DT: exact Euclidean distance to the nearest edge pixel, clipped at dt_half_width_px
    img = np.zeros((20, 20))
    img[8:12, 8:12] = 100.0
    _, dt = dtalign.build_image_edge_dt(img, 2.0)
    edges = np.argwhere(dt == 0.0)
    assert len(edges) > 0
    vv, uu = np.mgrid[0:20, 0:20]
    dist = np.min(np.hypot(vv[..., None] - edges[:, 0], uu[..., None] - edges[:, 1]), axis=-1)
    np.testing.assert_allclose(dt, np.minimum(dist, 64.0), rtol=1e-12, atol=1e-12)
    cfg = dtalign.ImageDerivativesConfig(dt_half_width_px=2.5)
    _, dt_c = dtalign.build_image_edge_dt(img, 2.0, config=cfg)
    np.testing.assert_allclose(dt_c, np.minimum(dist, 2.5), rtol=1e-12, atol=1e-12)
