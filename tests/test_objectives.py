"""Focus objectives: values against numpy references, analytic gradients against finite
differences (image level and event level)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import correlate

from evmotion.core.iwe import accumulate
from evmotion.core.objectives import OBJECTIVES, events_value_grad, objective_value_grad
from evmotion.errors import ParameterError

SX = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], dtype=float)


def ref_gradmag(img):
    gx = correlate(img, SX)[1:-1, 1:-1]
    gy = correlate(img, SX.T)[1:-1, 1:-1]
    return float(np.mean(gx**2 + gy**2))


def ref_avg_ts(npos, nneg, spos, sneg, normalize):
    tp = spos / (npos + 1e-3)
    tn = sneg / (nneg + 1e-3)
    total = float((tp**2 + tn**2).sum())
    if normalize:
        total /= ((npos > 0) | (nneg > 0)).sum()
    return -total


def fd_image(fn, img, idx, eps=1e-6):
    a, b = img.copy(), img.copy()
    a[idx] += eps
    b[idx] -= eps
    return (fn(a) - fn(b)) / (2 * eps)


@pytest.fixture
def img():
    return np.random.default_rng(0).poisson(2.0, size=(12, 17)).astype(float)


def test_registry():
    assert set(OBJECTIVES) == {"variance", "gradient_magnitude", "avg_timestamp",
                               "avg_timestamp_norm"}


def test_variance_value_and_grad(img):
    val, g = objective_value_grad("variance", img)
    assert val == pytest.approx(img.var())
    for idx in [(0, 0), (5, 7), (11, 16)]:
        assert g[idx] == pytest.approx(fd_image(lambda a: a.var(), img, idx), rel=1e-6)


def test_gradient_magnitude_value_and_grad(img):
    val, g = objective_value_grad("gradient_magnitude", img)
    assert val == pytest.approx(ref_gradmag(img))
    for idx in [(0, 0), (1, 1), (5, 7), (11, 16), (0, 8)]:
        assert g[idx] == pytest.approx(fd_image(ref_gradmag, img, idx), rel=1e-5, abs=1e-8)


def ref_gradmag_adjoint(img):
    """dG/dIWE of ref_gradmag by plain numpy: each interior Sobel response scattered back
    to its 3x3 neighbourhood with the kernel weights (slices, no numba)."""
    h, w = img.shape
    n = (h - 2) * (w - 2)
    grad = np.zeros_like(img)
    if n <= 0:
        return grad
    gx = correlate(img, SX)[1:-1, 1:-1]
    gy = correlate(img, SX.T)[1:-1, 1:-1]
    for a in range(3):
        for b in range(3):
            grad[a:h - 2 + a, b:w - 2 + b] += 2.0 / n * (SX[a, b] * gx + SX.T[a, b] * gy)
    return grad


@pytest.mark.parametrize("shape", [(1, 1), (2, 6), (3, 3), (3, 8), (7, 3), (19, 23), (64, 97)])
def test_gradient_magnitude_matches_numpy_reference(shape):
    # the streaming kernel (ring of row buffers) against the plain definition, every pixel,
    # on border-sized images too; a reused output buffer must be fully overwritten
    rng = np.random.default_rng(sum(shape))
    img = rng.poisson(1.5, shape) * rng.uniform(0.5, 1.5, shape)
    out = np.full(shape, np.nan)
    val, g = objective_value_grad("gradient_magnitude", img, out=out)
    assert g is out
    ref_val = ref_gradmag(img) if min(shape) > 2 else 0.0
    assert val == pytest.approx(ref_val, rel=1e-12, abs=1e-300)
    np.testing.assert_allclose(g, ref_gradmag_adjoint(img), rtol=1e-12,
                               atol=1e-14 * max(np.abs(g).max(), 1.0))


@pytest.mark.parametrize("name", ["avg_timestamp", "avg_timestamp_norm"])
def test_avg_timestamp_value_and_grad(name):
    rng = np.random.default_rng(3)
    shape = (9, 11)
    imgs = {k: rng.uniform(0.5, 3, shape) * (rng.uniform(size=shape) > 0.3)
            for k in ("iwe_pos", "iwe_neg")}
    imgs["tiwe_pos"] = imgs["iwe_pos"] * rng.uniform(0, 1, shape)
    imgs["tiwe_neg"] = imgs["iwe_neg"] * rng.uniform(0, 1, shape)
    norm = name.endswith("norm")
    val, grads = objective_value_grad(name, **imgs)
    assert val == pytest.approx(ref_avg_ts(*imgs.values(), norm))
    for key in imgs:
        for idx in [(2, 3), (8, 10)]:
            if imgs["iwe_pos"][idx] == 0 or imgs["iwe_neg"][idx] == 0:
                continue

            def f(a, key=key):
                d = dict(imgs)
                d[key] = a
                return ref_avg_ts(*d.values(), norm)

            assert grads[key][idx] == pytest.approx(fd_image(f, imgs[key], idx, 1e-7), rel=1e-4)


@pytest.mark.parametrize("name", sorted(OBJECTIVES))
@pytest.mark.parametrize("kernel", ["bilinear", "gaussian"])
def test_event_level_gradient(name, kernel):
    rng = np.random.default_rng(4)
    n, shape = 400, (14, 18)
    x, y = rng.uniform(1, 16, n), rng.uniform(1, 12, n)
    pol = rng.integers(0, 2, n)
    tn = rng.uniform(0, 1, n)
    val, gx, gy = events_value_grad(name, x, y, shape, pol, tn, kernel=kernel)

    def f(xx, yy):
        return events_value_grad(name, xx, yy, shape, pol, tn, kernel=kernel)[0]

    eps = 1e-6
    for k in range(0, n, 37):
        if abs(x[k] - round(x[k])) < 1e-3 or abs(y[k] - round(y[k])) < 1e-3:
            continue
        xp, xm = x.copy(), x.copy()
        xp[k] += eps
        xm[k] -= eps
        assert gx[k] == pytest.approx((f(xp, y) - f(xm, y)) / (2 * eps), rel=1e-4, abs=1e-7)
        yp, ym = y.copy(), y.copy()
        yp[k] += eps
        ym[k] -= eps
        assert gy[k] == pytest.approx((f(x, yp) - f(x, ym)) / (2 * eps), rel=1e-4, abs=1e-7)


def test_sharper_image_scores_higher():
    rng = np.random.default_rng(5)
    x = rng.uniform(2, 30, 200)
    sharp = accumulate(np.round(x), np.full(200, 10.0), (20, 32))
    blurry = accumulate(x, np.full(200, 10.0), (20, 32), kernel="gaussian", sigma=2.0)
    for name in ("variance", "gradient_magnitude"):
        assert objective_value_grad(name, sharp)[0] > objective_value_grad(name, blurry)[0]


def test_errors():
    with pytest.raises(ParameterError, match="unknown objective"):
        objective_value_grad("entropy", np.zeros((3, 3)))
    with pytest.raises(ParameterError, match="tiwe_pos"):
        objective_value_grad("avg_timestamp", iwe_pos=np.zeros((3, 3)), iwe_neg=np.zeros((3, 3)))
    with pytest.raises(ParameterError, match="polarity"):
        events_value_grad("avg_timestamp", np.zeros(2), np.zeros(2), (3, 3))


def test_variance_stats(img):
    from evmotion.core.objectives import variance_stats

    mu, var = variance_stats(img)
    assert mu == pytest.approx(img.mean()) and var == pytest.approx(img.var())
