"""The fused warp kernels of CMaxCost (no stored (N, P) Jacobian) give the value and gradient
of the composed chain warp -> IWE -> objective -> adjoint -> Jacobian^T, on random windows."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.objectives import events_value_grad
from evmotion.core.warps import make_warp
from evmotion.methods.egomotion import CMaxCost

SHAPE = (60, 80)
K = np.array([[70.0, 0.0, 41.0], [0.0, 70.0, 29.5], [0.0, 0.0, 1.0]])


def _window(seed, n=4000):
    rng = np.random.default_rng(seed)
    # a few events land outside or on the border, exercising the clipped cells
    x = rng.uniform(-3.0, SHAPE[1] + 2.0, n)
    y = rng.uniform(-3.0, SHAPE[0] + 2.0, n)
    t = np.sort(rng.uniform(0.0, 0.05, n))
    p = rng.integers(0, 2, n)
    theta = rng.normal(0.0, 2.0, 3)
    return x, y, t - 0.02, p, t / t[-1], theta


def _composed(warp, x, y, dt, theta, obj, kernel, p, tn, weights):
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    G, gx, gy = events_value_grad(obj, xw, yw, SHAPE, p, tn, weights=weights, kernel=kernel,
                                  sigma=1.0)
    return G, gx @ jx + gy @ jy


@pytest.mark.parametrize("kernel", ["bilinear", "gaussian"])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude", "avg_timestamp"])
@pytest.mark.parametrize("seed", [0, 1])
def test_fused_rotation_equals_composed_chain(kernel, obj, seed):
    x, y, dt, p, tn, theta = _window(seed)
    warp = make_warp("rotation", SHAPE, K=K)
    use_pol = seed == 1 and obj != "avg_timestamp"
    cost = CMaxCost(warp, x, y, dt, SHAPE, obj, polarity=p, tn=tn, kernel=kernel,
                    use_polarity=use_pol)
    assert cost.fused
    val, g = cost.value_grad(theta)
    G, gref = _composed(warp, x, y, dt, theta, obj, kernel, p, tn, cost.weights)
    assert val == pytest.approx(-G / cost.g0, rel=1e-9)
    np.testing.assert_allclose(g, -gref / cost.g0, rtol=1e-9, atol=1e-12 * np.abs(gref).max())


def test_fused_rotation_with_rcad_equals_unfused_penalty():
    x, y, dt, p, tn, theta = _window(2)
    warp = make_warp("rotation", SHAPE, K=K)
    fused = CMaxCost(warp, x, y, dt, SHAPE, regularizer="rcad", weight=0.5, polarity=p)
    plain = CMaxCost(warp, x, y, dt, SHAPE, polarity=p)
    assert fused.fused
    v1, g1 = fused.value_grad(theta)
    v0, g0 = plain.value_grad(theta)
    R, gR = fused._penalty(theta)
    assert v1 == pytest.approx(v0 + R, rel=1e-12)
    np.testing.assert_allclose(g1, g0 + gR, rtol=1e-12, atol=1e-15)


def test_penalties_that_need_jacobians_keep_the_composed_path():
    x, y, dt, p, tn, _ = _window(3, n=200)
    warp = make_warp("rotation", SHAPE, K=K)
    for reg in ("divergence", "deformation", "whitening"):
        assert not CMaxCost(warp, x, y, dt, SHAPE, regularizer=reg, weight=1.0).fused
    assert not CMaxCost(make_warp("se2", SHAPE), x, y, dt, SHAPE).fused
