"""The fused warp adjoints of CMaxCost (no stored (N, P) Jacobian) give the value and
gradient of the composed chain warp -> IWE -> objective -> adjoint -> Jacobian^T, on random
windows, for every warp up to 4 DOF, every objective, both IWE kernels, with and without
polarity weights, with small and large rotation angles (every series mode), and for events
on and beyond the image border."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import assert_grad_matches_central_differences, bilinear_adjoint_numpy
from evmotion.core.iwe import accumulate, accumulate_backward
from evmotion.core.iwe import vote_bilinear as _vote_bilinear
from evmotion.core.objectives import events_value_grad
from evmotion.core.regularizers import regularizer_value_grad, whiten
from evmotion.core.warps import make_warp
from evmotion.errors import ParameterError
from evmotion.methods.cmax import _TILE, CMaxCost, _tile_order

SHAPE = (60, 80)
K = np.array([[70.0, 0.0, 41.0], [0.0, 70.0, 29.5], [0.0, 0.0, 1.0]])
FUSED = ("zoom", "translation", "rotation", "se2", "inplane", "similarity")
#: typical parameter magnitudes; "fast" scales rates so that |dt w| reaches > 1 rad
SCALE = {"zoom": [3.0], "translation": [150.0, 150.0], "rotation": [2.0, 2.0, 2.0],
         "se2": [150.0, 150.0, 3.0], "inplane": [150.0, 150.0, 0.3, 2.0],
         "similarity": [150.0, 150.0, 3.0, 2.0], "affine": [150.0, 150.0, 2.0, 2.0, 2.0, 2.0],
         "homography": [2.0, 2.0, 150.0, 2.0, 2.0, 150.0, 0.01, 0.01]}


def _window(seed, n=4000):
    rng = np.random.default_rng(seed)
    # a few events land outside or on the border, exercising the clipped cells
    x = rng.uniform(-3.0, SHAPE[1] + 2.0, n)
    y = rng.uniform(-3.0, SHAPE[0] + 2.0, n)
    t = np.sort(rng.uniform(0.0, 0.05, n))
    p = rng.integers(0, 2, n)
    return x, y, t - 0.02, p, t / t[-1]


def _theta(name, seed, fast=1.0):
    rng = np.random.default_rng(100 + seed)
    s = np.array(SCALE[name])
    return rng.normal(0.0, 0.5, s.size) * s * fast


def _composed(warp, x, y, dt, theta, obj, kernel, p, tn, weights):
    """Plain chain: stored Jacobians, per-event pixel gradients, one matrix product."""
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    G, gx, gy = events_value_grad(obj, xw, yw, SHAPE, p, tn, weights=weights, kernel=kernel,
                                  sigma=1.0)
    return G, gx @ jx + gy @ jy


def _check(cost, warp, x, y, dt, theta, obj, kernel, p, tn):
    val, g = cost.value_grad(theta)
    G, gref = _composed(warp, x, y, dt, theta, obj, kernel, p, tn, cost.weights)
    assert val == pytest.approx(-G / cost.g0, rel=1e-9)
    np.testing.assert_allclose(g, -gref / cost.g0, rtol=1e-9, atol=1e-12 * np.abs(gref).max())
    assert cost.value(theta) == pytest.approx(val, rel=1e-9)


@pytest.mark.parametrize("name", FUSED)
@pytest.mark.parametrize("kernel", ["bilinear", "gaussian"])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude", "avg_timestamp"])
@pytest.mark.parametrize("seed", [0, 1])
def test_fused_equals_composed_chain(name, kernel, obj, seed):
    x, y, dt, p, tn = _window(seed)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, seed)
    use_pol = seed == 1 and obj != "avg_timestamp"
    cost = CMaxCost(warp, x, y, dt, SHAPE, obj, polarity=p, tn=tn, kernel=kernel,
                    use_polarity=use_pol)
    assert cost.fused
    _check(cost, warp, x, y, dt, theta, obj, kernel, p, tn)


@pytest.mark.parametrize("name", ["rotation", "se2", "similarity"])
@pytest.mark.parametrize("fast", [8.0, 30.0])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude"])
def test_fused_equals_composed_at_large_angles(name, fast, obj):
    # |dt w| up to ~0.5 and ~2 rad: the long Rodrigues series and the closed form (rotation),
    # libm's sin/cos (SE(2), similarity)
    x, y, dt, p, tn = _window(4)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 4, fast)
    cost = CMaxCost(warp, x, y, dt, SHAPE, obj, polarity=p, use_polarity=True)
    _check(cost, warp, x, y, dt, theta, obj, "bilinear", p, tn)


@pytest.mark.parametrize("name", ["affine", "homography"])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude"])
def test_composed_path_equals_chain(name, obj):
    x, y, dt, p, tn = _window(5)
    warp = make_warp(name, SHAPE)
    theta = _theta(name, 5)
    cost = CMaxCost(warp, x, y, dt, SHAPE, obj, polarity=p, use_polarity=True)
    assert not cost.fused
    _check(cost, warp, x, y, dt, theta, obj, "bilinear", p, tn)


@pytest.mark.parametrize("name", FUSED)
def test_vjp_and_reduce_bilinear_match_numpy(name):
    x, y, dt, p, _ = _window(6, n=600)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 6)
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    rng = np.random.default_rng(7)
    gx, gy = rng.normal(size=x.size), rng.normal(size=x.size)
    out = warp.vjp(x, y, dt, xw, yw, theta, gx, gy, np.empty(warp.n_params))
    np.testing.assert_allclose(out, gx @ jx + gy @ jy, rtol=1e-10, atol=1e-12)
    # reduce_bilinear: dL/dIWE = scale (g - shift), weighted events, with and without work
    g = rng.normal(size=SHAPE)
    wts = np.where(p > 0, 1.0, -0.5)
    bx, by = accumulate_backward(xw, yw, SHAPE, 0.3 * (g - 1.7), weights=wts)
    ref = bx @ jx + by @ jy
    for work in (None, np.empty((SHAPE[0] + 2) * (SHAPE[1] + 2) + 5)):
        out = warp.reduce_bilinear(x, y, dt, xw, yw, theta, g, np.empty(warp.n_params), wts,
                                   shift=1.7, scale=0.3, work=work)
        np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    # reduce_pair: dL/dIWE = A for the IWE of ones and B for that of per-event values d
    A, B, d = rng.normal(size=SHAPE), rng.normal(size=SHAPE), rng.normal(size=x.size)
    ax, ay = accumulate_backward(xw, yw, SHAPE, A)
    bx, by = accumulate_backward(xw, yw, SHAPE, B, weights=d)
    ref = 0.4 * ((ax + bx) @ jx + (ay + by) @ jy)
    pads = np.zeros((2, SHAPE[0] + 2, SHAPE[1] + 2))
    pads[0, 1:-1, 1:-1] = A
    pads[1, 1:-1, 1:-1] = B
    out = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d,
                           np.empty(warp.n_params), 0.4)
    np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    with pytest.raises(ParameterError, match="pads"):
        warp.reduce_pair(x, y, dt, xw, yw, theta, pads.ravel()[1:], d,
                         np.empty(warp.n_params))


@pytest.mark.parametrize("fast", [1.0, 12.0])
@pytest.mark.parametrize("name", FUSED)
def test_reduce_pair_chains_the_values_derivatives(name, fast):
    """reduce_pair with derivs: the values are the warp's divergence times T or |det J| - 1,
    and their theta-derivatives (warp.divergence / jacobian_det with grad=True, stored)
    times the bilinear sample of B at each event are added to the votes' chain rule (plain
    numpy); fast=12: |dt omega| beyond 1 rad (every series mode of the rotation)."""
    x, y, dt, _, _ = _window(8, n=800)
    # events by column, so that with B nonzero on a few columns only some blocks of events
    # reach it (the rotation skips the values' part of the others)
    o = np.argsort(x)
    x, y, dt = x[o], y[o], dt[o]
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 8, fast)
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    rng = np.random.default_rng(9)
    A, B0 = rng.normal(size=SHAPE), rng.normal(size=SHAPE)
    div, ddiv = warp.divergence(x, y, dt, theta, grad=True)
    det, ddet = warp.jacobian_det(x, y, dt, theta, grad=True)
    for B in (B0, np.where(np.arange(SHAPE[1]) % 40 < 6, B0, 0.0)):
        ax, ay, _ = bilinear_adjoint_numpy(xw, yw, A)
        bx, by, sB = bilinear_adjoint_numpy(xw, yw, B)
        sB = np.where((xw > -1) & (xw < SHAPE[1]) & (yw > -1) & (yw < SHAPE[0]), sB, 0.0)
        pads = np.zeros((2, SHAPE[0] + 2, SHAPE[1] + 2))
        pads[0, 1:-1, 1:-1] = A
        pads[1, 1:-1, 1:-1] = B
        # the values are the warp's own (the dt-only warps recompute them)
        for derivs, d, dd in (("divergence", 0.07 * div, 0.07 * ddiv),
                              ("deformation", np.abs(det) - 1.0,
                               np.sign(det)[:, None] * ddet)):
            votes = (ax + d * bx) @ jx + (ay + d * by) @ jy
            ref = 0.4 * (votes + sB @ dd)
            out = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d,
                                   np.empty(warp.n_params), 0.4, derivs, 0.07)
            np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-11 * np.abs(ref).max())
    with pytest.raises(ParameterError, match="derivs"):
        warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d,
                         np.empty(warp.n_params), 1.0, "rcad")


@pytest.mark.parametrize("name", ["rotation", "similarity", "inplane"])
def test_fused_with_rcad_equals_unfused_penalty(name):
    x, y, dt, p, _ = _window(2)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 2)
    fused = CMaxCost(warp, x, y, dt, SHAPE, regularizer="rcad", weight=0.5, polarity=p)
    plain = CMaxCost(warp, x, y, dt, SHAPE, polarity=p)
    assert fused.fused
    v1, g1 = fused.value_grad(theta)
    v0, g0 = plain.value_grad(theta)
    R, gR = fused._penalty(theta)
    assert v1 == pytest.approx(v0 + R, rel=1e-12)
    np.testing.assert_allclose(g1, g0 + gR, rtol=1e-12, atol=1e-15)


def test_fused_warps_store_no_jacobians():
    x, y, dt, p, tn = _window(3, n=200)
    for name in FUSED:
        warp = make_warp(name, SHAPE, K=K)
        for reg in (None, "divergence", "deformation", "rcad"):
            cost = CMaxCost(warp, x, y, dt, SHAPE, regularizer=reg, weight=1.0)
            assert cost.fused and cost.jx is None
        cost = CMaxCost(warp, x, y, dt, SHAPE, regularizer="whitening", weight=1.0)
        assert not cost.fused and cost.jx is not None
    assert not CMaxCost(make_warp("affine", SHAPE), x, y, dt, SHAPE).fused


#: contracting (collapse-enabling) motions, so that the penalties are active
COLLAPSE = {"rotation": [8.0, -8.0, 1.0], "similarity": [30.0, -20.0, 0.5, 15.0],
            "zoom": [15.0], "inplane": [30.0, -20.0, 0.05, 15.0],
            "affine": [30.0, -20.0, 12.0, 1.0, -1.0, 12.0]}


@pytest.mark.parametrize("name", list(COLLAPSE))
@pytest.mark.parametrize("reg", ["divergence", "deformation"])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude"])
def test_penalties_equal_the_composed_chain(name, reg, obj):
    # the data term through the fused adjoint, the penalty through the warp's vjp (or the
    # stored Jacobians of the affine warp), both over the events in the cost's tile order;
    # the penalty reuses the data term's IWE as its count map and the cost's time span
    x, y, dt, p, tn = _window(13)
    warp = make_warp(name, SHAPE, K=K)
    theta = np.array(COLLAPSE[name])
    cost = CMaxCost(warp, x, y, dt, SHAPE, objective=obj, regularizer=reg, weight=0.7,
                    polarity=p)
    v, g = cost.value_grad(theta)
    G, gref = _composed(warp, x, y, dt, theta, obj, "bilinear", p, tn, None)
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    R, gR = regularizer_value_grad(reg, warp, x, y, dt, theta, SHAPE, xw, yw, jac=(jx, jy))
    assert R > 0.1
    assert v == pytest.approx(-G / cost.g0 + 0.7 * R, rel=1e-9)
    assert cost.value(theta) == pytest.approx(v, rel=1e-9)
    ref = -gref / cost.g0 + 0.7 * gR
    np.testing.assert_allclose(g, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    # the fused warps chain both terms in one pass (the penalty's adjoint images folded
    # into the data term's): the gradient against central differences of the cost
    assert cost._pair == (name != "affine")
    if name == "affine":
        return
    assert_grad_matches_central_differences(cost.value, theta, g, 1e-7, 1e-5, 1e-6)


@pytest.mark.parametrize("name", FUSED)
def test_events_without_votes_are_dropped(name):
    # like the composed adjoint, which skips them: a NaN event or one far outside the image
    # contributes nothing, even where its Jacobian is not finite
    x, y, dt, p, _ = _window(8, n=300)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 8)
    g = np.random.default_rng(9).normal(size=SHAPE)
    keep = np.ones(x.size, bool)
    keep[[5, 6]] = False
    x[5] = np.nan
    y[6] = 1e300

    def reduce(x, y, dt):
        xw, yw = warp.warp(x, y, dt, theta)
        return warp.reduce_bilinear(x, y, dt, xw, yw, theta, g, np.empty(warp.n_params),
                                    shift=0.5, scale=2.0)

    out = reduce(x, y, dt)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, reduce(x[keep], y[keep], dt[keep]), rtol=1e-12)


def test_assigned_weights_reach_the_fused_path():
    # the EM of segmentation assigns soft labels to cost.weights between optimizations
    x, y, dt, p, tn = _window(11)
    warp = make_warp("se2", SHAPE)
    theta = _theta("se2", 11)
    cost = CMaxCost(warp, x, y, dt, SHAPE, polarity=p)
    cost.weights = np.random.default_rng(12).uniform(0.0, 1.0, x.size)
    _check(cost, warp, x, y, dt, theta, "variance", "bilinear", p, tn)
    with pytest.raises(ParameterError, match="weights must have shape"):
        cost.weights = np.ones(3)


def test_tile_order_is_a_stable_sort_by_sensor_tile():
    rng = np.random.default_rng(14)
    x, y = rng.uniform(-20, 200, 5000), rng.uniform(-20, 150, 5000)
    x[[0, 1, 2]] = [np.nan, np.inf, -np.inf]
    y[[3, 4]] = [1e300, np.nan]
    h, w = 130, 170
    nx, ny = -(-w // _TILE), -(-h // _TILE)

    def cell(v, n):  # numpy reference: clamped tile index, NaN in the first tile
        c = np.floor(np.where(np.isnan(v), 0.0, np.clip(v, 0.0, 1e9)) / _TILE)
        return np.minimum(c, n - 1).astype(int)

    key = cell(y, ny) * nx + cell(x, nx)
    np.testing.assert_array_equal(_tile_order(x, y, (h, w)), np.argsort(key, kind="stable"))


@pytest.mark.parametrize("name", ["zoom", "similarity"])
@pytest.mark.parametrize("obj", ["variance", "gradient_magnitude"])
def test_whitening_equals_the_chain_through_whitened_jacobians(name, obj):
    x, y, dt, p, tn = _window(15)
    warp = make_warp(name, SHAPE, K=K)
    theta = _theta(name, 15)
    cost = CMaxCost(warp, x, y, dt, SHAPE, obj, regularizer="whitening", weight=1.0)
    v, g = cost.value_grad(theta)
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    zx, zy, zjx, zjy = whiten(xw, yw, jx, jy, center=cost._wcenter, scale=cost._wscale)
    G, gx, gy = events_value_grad(obj, zx, zy, SHAPE, p, tn, kernel="bilinear")
    ref = -(gx @ zjx + gy @ zjy) / cost.g0
    assert v == pytest.approx(-G / cost.g0, rel=1e-9)
    np.testing.assert_allclose(g, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("shape", [(60, 80), (7, 5), (1, 3)])
def test_vote_equals_accumulate_bit_for_bit(shape):
    h, w = shape
    rng = np.random.default_rng(16)
    n = 3000
    x = rng.uniform(-2.0, w + 1.0, n)
    y = rng.uniform(-2.0, h + 1.0, n)
    # exact borders and integers, and events without votes
    x[:8] = [0.0, w - 1.0, -1.0, w, -0.5, w - 0.5, np.nan, 2.0]
    y[:8] = [0.0, h - 1.0, 0.5, 0.5, h - 1.0, -0.999, 1.0, np.inf]
    for wts in (None, rng.normal(size=n)):
        out = np.full(shape, 7.0)
        _vote_bilinear(x, y, np.empty(0) if wts is None else wts, out)
        np.testing.assert_array_equal(out, accumulate(x, y, shape, wts))


@pytest.mark.parametrize("name", ["rotation", "similarity", "affine"])
def test_divergence_plus_deformation_is_the_weighted_sum(name):
    # the thesis' "Div. + Def." (Tables 3.1/3.2): each penalty with its own weight, added
    x, y, dt, p, _ = _window(17)
    warp = make_warp(name, SHAPE, K=K)
    theta = np.array(COLLAPSE[name])
    lam = {"divergence": 0.7, "deformation": 1.9}
    both = CMaxCost(warp, x, y, dt, SHAPE, regularizer="divergence+deformation", weight=lam,
                    polarity=p)
    assert not both._pair and both.weight == lam
    v, g = both.value_grad(theta)
    G, gG = CMaxCost(warp, x, y, dt, SHAPE, polarity=p).value_grad(theta)
    ref_v, ref_g = G, gG.copy()
    for reg, w in lam.items():
        vr, gr = CMaxCost(warp, x, y, dt, SHAPE, regularizer=reg, weight=w,
                          polarity=p).value_grad(theta)
        ref_v += vr - G
        ref_g += gr - gG
    assert both.parts(theta)["penalty"] > 0.5
    assert v == pytest.approx(ref_v, rel=1e-9)
    np.testing.assert_allclose(g, ref_g, rtol=1e-8, atol=1e-10 * np.abs(ref_g).max())
    if name != "affine":
        # the trimmed means are piecewise smooth (the trimmed pixel set moves with theta);
        # the affine warp's penalties change piece within any usable step here
        assert_grad_matches_central_differences(both.value, theta, g, 1e-7, 1e-4, 1e-5)
    # one float weighs both terms
    same = CMaxCost(warp, x, y, dt, SHAPE, regularizer="divergence+deformation", weight=0.7,
                    polarity=p)
    assert same.weight == {"divergence": 0.7, "deformation": 0.7}


def test_regularizer_weights_are_checked():
    x, y, dt, p, _ = _window(3)
    warp = make_warp("zoom", SHAPE)
    for reg, weight in (("divergence+deformation", {"divergence": 1.0}),
                        ("divergence+deformation", {"divergence": 1.0, "rcad": 1.0}),
                        ("divergence", {"divergence": 1.0}), ("deformation", float("nan")),
                        ("rcad", -1.0), ("divergence", "1"), ("rcad", "abc"),
                        ("divergence+deformation", {"divergence": "1", "deformation": 1.0})):
        with pytest.raises(ParameterError, match="weight"):
            CMaxCost(warp, x, y, dt, SHAPE, regularizer=reg, weight=weight)
