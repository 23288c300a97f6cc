"""The warp kernels' per-window cases (Rodrigues series modes of the rotation, series or
libm trigonometry of SE(2)/similarity, Jacobian or not) against the numpy reference, and
the fused cost gradient of every warp up to 4 DOF against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.warps import make_warp
from evmotion.core.warps.common import max_abs as _max_abs
from evmotion.core.warps.so3 import rod_coeffs as _rod_coeffs
from evmotion.core.warps.so3 import rod_coeffs_exact as _rod_coeffs_exact
from evmotion.core.warps.so3 import rod_coeffs_short as _rod_coeffs_short
from evmotion.core.warps.so3 import sincos as _sincos
from evmotion.methods.egomotion import CMaxCost

H, W = 120, 160
K = np.array([[150.0, 0.3, 81.0], [0.0, 155.0, 58.0], [0.0, 0.0, 1.0]])


def _events(n=300, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n), rng.uniform(-0.05, 0.05, n)


def _reference(w, x, y, dt, th):
    M, _ = w.matrices(dt, th)
    q = np.einsum("nij,nj->ni", M, np.stack([x, y, np.ones_like(x)], axis=1))
    return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]


# |dt omega| up to 0.05 |omega|: below 0.22 rad (short series), below 1 rad (long series),
# above (closed form); |dt wz| below and above 1 rad (series or libm sin/cos)
@pytest.mark.parametrize(("name", "theta"), [
    ("rotation", [1.0, -2.0, 3.0]), ("rotation", [6.0, -9.0, 8.0]),
    ("rotation", [20.0, -30.0, 25.0]), ("se2", [40.0, 10.0, 5.0]), ("se2", [40.0, 10.0, 30.0]),
    ("similarity", [40.0, 10.0, 30.0, 3.0]), ("inplane", [40.0, 10.0, 0.3, 0.5]),
    ("zoom", [3.0]), ("translation", [50.0, -30.0])])
def test_every_kernel_case_matches_reference(name, theta):
    w = make_warp(name, (H, W), K=K)
    th = np.array(theta)
    x, y, dt = _events()
    xw, yw = w.warp(x, y, dt, th)
    xj, yj, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    rx, ry = _reference(w, x, y, dt, th)
    np.testing.assert_allclose(xw, rx, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(yw, ry, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(xj, xw, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(yj, yw, rtol=1e-12, atol=1e-10)
    for j in range(th.size):
        h = 1e-6 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fx = (w.warp(x, y, dt, tp)[0] - w.warp(x, y, dt, tm)[0]) / (2 * h)
        fy = (w.warp(x, y, dt, tp)[1] - w.warp(x, y, dt, tm)[1]) / (2 * h)
        np.testing.assert_allclose(jx[:, j], fx, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(jy[:, j], fy, rtol=1e-5, atol=1e-5)


def test_max_abs_matches_numpy():
    rng = np.random.default_rng(1)
    a = rng.normal(size=1001)
    assert _max_abs(a) == np.abs(a).max()
    assert _max_abs(np.array([0.0, -np.inf, 2.0])) == np.inf
    assert np.isnan(_max_abs(np.array([1.0, np.nan, -3.0])))
    assert _max_abs(np.zeros(0)) == 0.0


@pytest.mark.parametrize(("name", "theta"), [
    ("zoom", [2.0]), ("translation", [60.0, -40.0]), ("rotation", [0.8, -0.6, 1.1]),
    ("se2", [60.0, -40.0, 1.5]), ("inplane", [60.0, -40.0, 0.1, 1.0]),
    ("similarity", [60.0, -40.0, 1.5, 2.0])])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude"])
def test_fused_gradient_matches_finite_differences(name, theta, obj):
    rng = np.random.default_rng(2)
    n = 3000
    x, y = rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n)
    dt = np.sort(rng.uniform(0.0, 0.05, n)) - 0.025
    p = rng.integers(0, 2, n)
    w = make_warp(name, (H, W), K=K)
    cost = CMaxCost(w, x, y, dt, (H, W), obj, polarity=p, use_polarity=True)
    assert cost.fused
    th = np.array(theta)
    _, g = cost.value_grad(th)
    for j in range(th.size):
        h = 1e-6 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fd = (cost.value(tp) - cost.value(tm)) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=1e-4, abs=1e-6 * np.abs(g).max())


def test_series_are_exact_to_rounding():
    # the polynomial forms the kernels use instead of libm, on their whole ranges
    for a in np.linspace(-1.0, 1.0, 2001):
        sn, c = _sincos(a)
        assert sn == pytest.approx(np.sin(a), rel=4e-16, abs=1e-300)
        assert c == pytest.approx(np.cos(a), rel=4e-16)
    # against the closed form where it has no cancellation, and the long series elsewhere
    for z in np.linspace(0.2, 1.0, 401):
        for u, v in zip(_rod_coeffs(z), _rod_coeffs_exact(z), strict=True):
            assert u == pytest.approx(v, rel=1e-14)
    for z in np.linspace(0.0, 0.05, 401):
        for u, v in zip(_rod_coeffs_short(z), _rod_coeffs(z), strict=True):
            assert u == pytest.approx(v, rel=4e-16)
