"""IWE forward/adjoint: numba kernels against plain-numpy references, finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.iwe import accumulate, accumulate_backward, accumulate_into
from evmotion.errors import ParameterError


def ref_bilinear(x, y, shape, w=None):
    h, wd = shape
    w = np.ones_like(x) if w is None else w
    img = np.zeros(shape)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    for dx, dy, b in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                      (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < wd) & (yi >= 0) & (yi < h)
        np.add.at(img, (yi[ok], xi[ok]), (w * b)[ok])
    return img


def ref_gauss(x, y, shape, sigma, w=None):
    from math import erf, sqrt
    h, wd = shape
    w = np.ones_like(x) if w is None else w
    r = 3 * sigma
    fl = np.exp(-r * r / (2 * sigma**2))
    z = sigma * sqrt(2 * np.pi) * erf(r / (sigma * sqrt(2))) - 2 * r * fl
    yy, xx = np.mgrid[0:h, 0:wd]
    img = np.zeros(shape)
    for k in range(x.size):
        kx = np.clip(np.exp(-(xx - x[k]) ** 2 / (2 * sigma**2)) - fl, 0, None)
        ky = np.clip(np.exp(-(yy - y[k]) ** 2 / (2 * sigma**2)) - fl, 0, None)
        img += w[k] * kx * ky / z**2
    return img


@pytest.fixture
def events():
    rng = np.random.default_rng(0)
    n = 300
    # some events outside and straddling the border on purpose
    return rng.uniform(-3, 23, n), rng.uniform(-3, 17, n), rng.normal(size=n)


@pytest.mark.parametrize("weighted", [False, True])
def test_bilinear_matches_reference(events, weighted):
    x, y, w = events
    w = w if weighted else None
    np.testing.assert_allclose(accumulate(x, y, (15, 20), w), ref_bilinear(x, y, (15, 20), w),
                               atol=1e-12)


@pytest.mark.parametrize("sigma", [0.7, 1.0, 1.5])
def test_gaussian_matches_reference(events, sigma):
    x, y, w = events
    np.testing.assert_allclose(accumulate(x, y, (15, 20), w, kernel="gaussian", sigma=sigma),
                               ref_gauss(x, y, (15, 20), sigma, w), atol=1e-12)


def test_mass_conserved_inside():
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 19, 500), rng.uniform(0, 14, 500)
    assert accumulate(x, y, (15, 20)).sum() == pytest.approx(500)
    # the Gaussian spreads past the border: only events 4 px inside keep their mass
    x, y = rng.uniform(4, 15, 500), rng.uniform(4, 10, 500)
    assert accumulate(x, y, (15, 20), kernel="gaussian").sum() == pytest.approx(500, rel=0.01)


def test_outside_and_nan_dropped():
    img = accumulate(np.array([-5.0, np.nan, 100.0]), np.array([1.0, 1.0, 1.0]), (4, 4))
    assert img.sum() == 0
    gx, gy = accumulate_backward(np.array([-5.0, np.nan]), np.array([1.0, 1.0]), (4, 4),
                                 np.ones((4, 4)))
    assert np.all(gx == 0) and np.all(gy == 0)


@pytest.mark.parametrize("kernel", ["bilinear", "gaussian"])
def test_backward_is_adjoint_and_matches_finite_differences(events, kernel):
    x, y, w = events
    rng = np.random.default_rng(2)
    g = rng.normal(size=(15, 20))

    def loss(xx, yy):
        return float((accumulate(xx, yy, (15, 20), w, kernel=kernel) * g).sum())

    gx, gy = accumulate_backward(x, y, (15, 20), g, w, kernel=kernel)
    eps = 1e-6
    # avoid sampling exactly at a kink of the bilinear kernel
    for k in range(0, x.size, 7):
        if abs(x[k] - round(x[k])) < 1e-3 or abs(y[k] - round(y[k])) < 1e-3:
            continue
        xp, xm = x.copy(), x.copy()
        xp[k] += eps
        xm[k] -= eps
        assert gx[k] == pytest.approx((loss(xp, y) - loss(xm, y)) / (2 * eps), abs=1e-6)
        yp, ym = y.copy(), y.copy()
        yp[k] += eps
        ym[k] -= eps
        assert gy[k] == pytest.approx((loss(x, yp) - loss(x, ym)) / (2 * eps), abs=1e-6)


def test_into_reuses_buffer_and_validates():
    buf = np.full((5, 5), 7.0)
    accumulate_into(np.array([2.0]), np.array([2.0]), buf)
    assert buf.sum() == 1.0
    with pytest.raises(ParameterError, match="kernel"):
        accumulate(np.zeros(1), np.zeros(1), (3, 3), kernel="box")
    with pytest.raises(ParameterError, match="weights"):
        accumulate(np.zeros(2), np.zeros(2), (3, 3), weights=np.ones(3))
    with pytest.raises(ParameterError, match="shape"):
        accumulate(np.zeros(2), np.zeros(2), (3,))


def test_fused_backward_reduce_matches_unfused(events):
    from evmotion.core.iwe import accumulate_backward_reduce

    x, y, w = events
    rng = np.random.default_rng(3)
    g = rng.normal(size=(15, 20))
    jx, jy = rng.normal(size=(x.size, 4)), rng.normal(size=(x.size, 4))
    gx, gy = accumulate_backward(x, y, (15, 20), 0.5 * (g - 0.3), w)
    out = accumulate_backward_reduce(x, y, g, jx, jy, np.empty(4), w, shift=0.3, scale=0.5)
    np.testing.assert_allclose(out, gx @ jx + gy @ jy, rtol=1e-12, atol=1e-12)


def ref_bilinear_backward(x, y, g, w):
    """Plain-numpy derivative of sum(g * IWE) with respect to each event position: the
    bilinear weights' derivatives times the four pixels (0 off the image)."""
    h, wd = g.shape
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    gx = np.zeros_like(x)
    gy = np.zeros_like(x)
    for dx, dy, bx, by in ((0, 0, -(1 - fy), -(1 - fx)), (1, 0, 1 - fy, -fx),
                           (0, 1, -fy, 1 - fx), (1, 1, fy, fx)):
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < wd) & (yi >= 0) & (yi < h)
        v = np.where(ok, g[np.clip(yi, 0, h - 1), np.clip(xi, 0, wd - 1)], 0.0)
        gx += w * bx * v
        gy += w * by * v
    return gx, gy


def test_bilinear_backward_matches_numpy_reference(events):
    x, y, w = events
    g = np.random.default_rng(1).normal(size=(15, 20))
    for wts in (None, w):
        gx, gy = accumulate_backward(x, y, (15, 20), g, wts)
        rx, ry = ref_bilinear_backward(x, y, g, np.ones_like(x) if wts is None else wts)
        np.testing.assert_allclose(gx, rx, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gy, ry, rtol=1e-12, atol=1e-12)
