"""Tile flow interpolation, its adjoint, resampling and the fused B-spline IWE kernels
against plain-numpy references and finite differences."""

import numpy as np
import pytest

from evmotion.core import tileflow as tf


def _bspline_ref(d):
    return np.array([0.5 * (0.5 - d) ** 2, 0.75 - d * d, 0.5 * (0.5 + d) ** 2])


def _iwe_ref(x, y, flow, dtn, shape):
    h, w = shape
    img = np.zeros(shape)
    for k in range(x.size):
        xw = x[k] + dtn[k] * flow[k, 0]
        yw = y[k] + dtn[k] * flow[k, 1]
        cx, cy = int(np.floor(xw + 0.5)), int(np.floor(yw + 0.5))
        wx, wy = _bspline_ref(xw - cx), _bspline_ref(yw - cy)
        for a in range(3):
            for b in range(3):
                yy, xx = cy - 1 + a, cx - 1 + b
                if 0 <= yy < h and 0 <= xx < w:
                    img[yy, xx] += wy[a] * wx[b]
    return img


@pytest.fixture
def events():
    rng = np.random.default_rng(3)
    n = 300
    shape = (20, 30)
    x = rng.integers(0, shape[1], n).astype(float)
    y = rng.integers(0, shape[0], n).astype(float)
    flow = rng.normal(scale=4.0, size=(n, 2))
    dtn = rng.uniform(-1, 1, n)
    return x, y, flow, dtn, shape


def test_iwe_matches_numpy_reference(events):
    x, y, flow, dtn, shape = events
    np.testing.assert_allclose(tf.iwe_forward(x, y, flow, dtn, shape),
                               _iwe_ref(x, y, flow, dtn, shape), atol=1e-12)


def test_iwe_conserves_votes_inside():
    x = np.array([5.3, 10.0])
    y = np.array([4.7, 8.0])
    img = tf.iwe_forward(x, y, np.zeros((2, 2)), np.zeros(2), (16, 16))
    assert img.sum() == pytest.approx(2.0)


def test_iwe_backward_is_gradient(events):
    x, y, flow, dtn, shape = events
    g = np.random.default_rng(0).normal(size=shape)
    grad = tf.iwe_backward(x, y, flow, dtn, g)
    d = np.random.default_rng(1).normal(size=flow.shape)
    e = 1e-6
    fd = ((g * tf.iwe_forward(x, y, flow + e * d, dtn, shape)).sum()
          - (g * tf.iwe_forward(x, y, flow - e * d, dtn, shape)).sum()) / (2 * e)
    assert (grad * d).sum() == pytest.approx(fd, rel=1e-5, abs=1e-8)


def test_interpolation_matches_dense_matrices_and_is_subpixel():
    rng = np.random.default_rng(0)
    grid = tf.TileGrid(4, 5, (24, 40))
    params = rng.normal(size=(4, 5, 2))
    x = rng.uniform(0, 39, 200)
    y = rng.uniform(0, 23, 200)
    idx, w = tf.event_weights(x, y, grid)
    got = tf.interpolate(params, idx, w)
    ay = tf.axis_matrix(y, 4, 24)
    ax = tf.axis_matrix(x, 5, 40)
    ref = np.stack([np.einsum("ki,ij,kj->k", ay, params[..., c], ax) for c in range(2)], 1)
    np.testing.assert_allclose(got, ref, atol=1e-12)
    # sub-pixel: two positions in the same pixel get different flow
    i2, w2 = tf.event_weights(np.array([10.0, 10.4]), np.array([7.0, 7.0]), grid)
    f2 = tf.interpolate(params, i2, w2)
    assert not np.allclose(f2[0], f2[1])


def test_affine_flow_is_exact_to_the_border():
    grid = tf.TileGrid(4, 4, (32, 48))
    cy, cx = np.meshgrid(grid.centers_y(), grid.centers_x(), indexing="ij")
    params = np.stack([0.1 * cx - 0.2 * cy + 1, 0.3 * cx + 0.05 * cy], -1)
    dense = tf.dense_flow(params, grid.shape)
    yy, xx = np.mgrid[0:32, 0:48]
    np.testing.assert_allclose(dense[..., 0], 0.1 * xx - 0.2 * yy + 1, atol=1e-9)
    np.testing.assert_allclose(dense[..., 1], 0.3 * xx + 0.05 * yy, atol=1e-9)


def test_interpolate_adjoint_is_transpose():
    rng = np.random.default_rng(1)
    grid = tf.TileGrid(3, 2, (20, 20))
    x = rng.uniform(0, 19, 50)
    y = rng.uniform(0, 19, 50)
    idx, w = tf.event_weights(x, y, grid)
    p = rng.normal(size=(3, 2, 2))
    g = rng.normal(size=(50, 2))
    lhs = (tf.interpolate(p, idx, w) * g).sum()
    rhs = (p * tf.interpolate_adjoint(g, idx, w, grid)).sum()
    assert lhs == pytest.approx(rhs)


def test_resample_coarse_to_fine_keeps_constant_and_linear():
    p = np.full((1, 1, 2), 3.0)
    up = tf.resample(p, tf.scale_grid(3, (40, 60)))
    assert up.shape == (4, 4, 2) and np.allclose(up, 3.0)
    g2 = tf.scale_grid(2, (40, 60))
    g3 = tf.scale_grid(3, (40, 60))
    cy, cx = np.meshgrid(g2.centers_y(), g2.centers_x(), indexing="ij")
    lin = np.stack([cx, cy], -1)
    cy3, cx3 = np.meshgrid(g3.centers_y(), g3.centers_x(), indexing="ij")
    np.testing.assert_allclose(tf.resample(lin, g3), np.stack([cx3, cy3], -1), atol=1e-9)


def test_scale_grid_tile_counts():
    assert [tf.scale_grid(level, (260, 346)).nx for level in range(1, 6)] == [1, 2, 4, 8, 16]
