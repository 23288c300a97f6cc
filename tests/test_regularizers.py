"""Collapse regularizers (3.6): maps vs a plain-numpy reference, analytic gradients vs finite
differences, the thesis' closed forms and qualitative behaviour, whitening."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import bilinear_adjoint_numpy
from evmotion.core.regularizers import (
    DEFAULT_WEIGHTS,
    REGULARIZERS,
    PenaltyOptions,
    regularizer_maps,
    regularizer_value_grad,
    whiten,
    window_span,
)
from evmotion.core.warps import make_warp
from evmotion.errors import EmptyWindowError, ParameterError

H, W = 40, 50
K = np.array([[45.0, 0, 25.0], [0, 45.0, 19.0], [0, 0, 1]])
T = 0.05
THETA = {
    "zoom": [8.0],
    "rotation": [1.0, -20.0, 3.0],
    "inplane": [40.0, 10.0, 0.3, 5.0],
    "similarity": [40.0, 10.0, 2.0, 9.0],
    "affine": [40.0, 10.0, 5.0, 2.0, -1.0, 9.0],
    "homography": [5.0, 2.0, 30.0, -1.0, 9.0, 20.0, 1e-2, -2e-2],
}


def _events(n=800, seed=0):
    rng = np.random.default_rng(seed)
    dt = np.sort(rng.uniform(0, T, n))
    return rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n), dt


def _bilinear_reference(xw, yw, values, shape):
    """Plain numpy bilinear votes (np.add.at), written independently of core.iwe."""
    h, w = shape
    out = np.zeros(shape)
    x0, y0 = np.floor(xw).astype(int), np.floor(yw).astype(int)
    fx, fy = xw - x0, yw - y0
    for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                       (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        np.add.at(out, (yi[ok], xi[ok]), (values * wt)[ok])
    return out


@pytest.mark.parametrize("name", ["zoom", "rotation", "homography"])
def test_maps_match_numpy_reference(name):
    w = make_warp(name, (H, W), K=K)
    th = np.array(THETA[name])
    x, y, dt = _events()
    xw, yw = w.warp(x, y, dt, th)
    cnt = _bilinear_reference(xw, yw, np.ones_like(x), (H, W))
    div = w.divergence(x, y, dt, th) * (dt.max() - dt.min())
    det = np.abs(w.jacobian_det(x, y, dt, th))
    sup = cnt > 1e-9
    diwe = np.where(sup, _bilinear_reference(xw, yw, div, (H, W)) / np.where(sup, cnt, 1), 0)
    iwa = 1 + np.where(sup, _bilinear_reference(xw, yw, det - 1, (H, W))
                       / np.where(sup, cnt, 1), 0)
    m = regularizer_maps("divergence", w, x, y, dt, th, (H, W))
    np.testing.assert_allclose(m["diwe"], diwe, atol=1e-10)
    np.testing.assert_allclose(m["count"], cnt, atol=1e-10)
    v, _ = regularizer_value_grad("divergence", w, x, y, dt, th, (H, W))
    sel = sup & (diwe < -0.2)
    assert v == pytest.approx(-diwe[sel].mean() if sel.any() else 0.0)
    m = regularizer_maps("deformation", w, x, y, dt, th, (H, W))
    np.testing.assert_allclose(m["iwa"], iwa, atol=1e-10)
    v, _ = regularizer_value_grad("deformation", w, x, y, dt, th, (H, W))
    sel = sup & (iwa < 0.8)
    assert v == pytest.approx((1 - iwa[sel]).mean() if sel.any() else 0.0)


@pytest.mark.parametrize("reg", list(REGULARIZERS))
@pytest.mark.parametrize("name", list(THETA))
def test_gradients_vs_finite_differences(reg, name):
    w = make_warp(name, (H, W), K=K)
    th = np.array(THETA[name])
    x, y, dt = _events(400, seed=1)
    v, g = regularizer_value_grad(reg, w, x, y, dt, th, (H, W))
    assert v > 0  # these parameters collapse: every penalty is active
    for j in range(len(th)):
        h = 1e-7 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fd = (regularizer_value_grad(reg, w, x, y, dt, tp, (H, W))[0]
              - regularizer_value_grad(reg, w, x, y, dt, tm, (H, W))[0]) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=1e-5, abs=1e-7)
    # precomputed warped events and Jacobians give the same result, and so do warped events
    # alone (up to rounding: the warp kernels with and without Jacobians may round the
    # warped events differently (~1e-14 px), and the rotation contracts its recomputed
    # Jacobian; a pixel's adjoint (d_k - mean) / count cancels to a few ulps of d_k where
    # one event votes alone, so such rounding moves the gradient by up to ~1e-11 of its
    # largest component)
    xw, yw, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    for kw in ({"jac": (jx, jy)}, {}):
        v2, g2 = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw, **kw)
        assert v2 == pytest.approx(v, rel=1e-12)
        np.testing.assert_allclose(g2, g, rtol=1e-10, atol=1e-10 * np.abs(g).max())


def test_zoom_closed_forms():
    w = make_warp("zoom", (H, W))
    x, y, dt = _events()
    span = window_span(dt)
    for bz in (0.05, 0.3, 0.9):  # thesis (3.7) parameter, per window
        h = bz / span
        th = np.array([h])
        # divergence per window is -2 b_z everywhere: penalty 2 b_z once below -0.2
        v, g = regularizer_value_grad("divergence", w, x, y, dt, th, (H, W))
        assert v == pytest.approx(2 * bz if 2 * bz > 0.2 else 0.0)
        # RCAD (3.21) over the window [0, T] with t_ref = t_1: -2 log|1 - b_z|
        t0, t1 = dt.min(), dt.max()
        v, g = regularizer_value_grad("rcad", w, x, y, dt, th, (H, W))
        assert v == pytest.approx(2 * np.log(abs((1 - t0 * h) / (1 - t1 * h))))
        assert g[0] == pytest.approx(2 * (t1 / (1 - t1 * h) - t0 / (1 - t0 * h)))
    # expansion: negative RCAD, no divergence/deformation penalty
    th = np.array([-0.5 / span])
    assert regularizer_value_grad("rcad", w, x, y, dt, th, (H, W))[0] < 0
    assert regularizer_value_grad("divergence", w, x, y, dt, th, (H, W))[0] == 0
    assert regularizer_value_grad("deformation", w, x, y, dt, th, (H, W))[0] == 0
    # barrier: RCAD grows without bound as b_z -> 1
    vals = [regularizer_value_grad("rcad", w, x, y, dt, np.array([b / span]), (H, W))[0]
            for b in (0.5, 0.9, 0.99, 0.999)]
    assert np.all(np.diff(vals) > 0) and vals[-1] > 10


def test_well_posed_warps_are_not_penalized():
    x, y, dt = _events()
    for name, th in (("translation", [300.0, -100.0]), ("se2", [100.0, 20.0, 3.0])):
        w = make_warp(name, (H, W), K=K)
        for reg in REGULARIZERS:
            v, g = regularizer_value_grad(reg, w, x, y, dt, np.array(th), (H, W))
            assert v == 0 and not np.any(g)
    w = make_warp("rotation", (H, W), K=K)
    # small rotation: the (3.28) map stays inside the margin; about z: no deformation
    for om in ([0.5, -0.3, 0.2], [0.0, 0.0, 4.0]):
        for reg in REGULARIZERS:
            assert regularizer_value_grad(reg, w, x, y, dt, np.array(om), (H, W))[0] == 0
    m = regularizer_maps("rcad", w, x, y, dt, np.array([0.0, 0.0, 40.0]), (H, W))
    np.testing.assert_allclose(m["rcad"], 0, atol=1e-12)


def test_rcad_map_rotation_and_general():
    x, y, dt = _events()
    w = make_warp("rotation", (H, W), K=K)
    om = np.array([0.6, -0.4, 0.2])
    m = regularizer_maps("rcad", w, x, y, dt, om, (H, W))["rcad"]
    # dense, and ~ (3.28) with the trajectory frozen at t_ref: 3 T (wx y - wy x)
    yy, xx = np.mgrid[0:H, 0:W]
    xn, yn = (xx - K[0, 2]) / K[0, 0], (yy - K[1, 2]) / K[1, 1]
    span = dt.max() - dt.min()
    approx = 3 * span * (om[0] * yn - om[1] * xn)
    np.testing.assert_allclose(m, approx, atol=0.1 * np.abs(approx).max())
    # the grid kernel of the penalty equals the generic area log-ratio (rotation, homography)
    from evmotion.core.collapse.rcad import _area_coeffs, _k_rcad_grid

    wh = make_warp("homography", (H, W))
    for warp, th in ((w, 30 * om), (wh, np.array(THETA["homography"]))):
        c0, c1 = _area_coeffs(warp, th, -0.01), _area_coeffs(warp, th, 0.03)
        g = np.empty(warp.n_params)
        val, n = _k_rcad_grid(H, W, 7, *c0[:3], *c1[:3], -np.inf, g)
        g += c1[3] - c0[3]
        gy, gx = np.mgrid[3:H:7, 3:W:7]
        b, gb = warp.area_log_ratio(gx.ravel().astype(float), gy.ravel().astype(float), -0.01,
                                    0.03, th, grad=True)
        assert n == b.size
        assert val == pytest.approx(b.mean(), abs=1e-12)
        np.testing.assert_allclose(g, gb.mean(axis=0), rtol=1e-9, atol=1e-12)
    # the homography with a zero projective row has the affine closed form
    wa = make_warp("affine", (H, W))
    tha = np.array(THETA["affine"])
    thh = np.array([tha[2], tha[3], tha[0], tha[4], tha[5], tha[1], 0, 0])
    va, _ = regularizer_value_grad("rcad", wa, x, y, dt, tha, (H, W))
    vh, _ = regularizer_value_grad("rcad", wh, x, y, dt, thh, (H, W))
    assert vh == pytest.approx(va)


def test_whitening():
    rng = np.random.default_rng(3)
    x, y, dt = _events(300)
    w = make_warp("affine", (H, W))
    th = np.array(THETA["affine"])
    xw, yw, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    zx, zy, zjx, zjy = whiten(xw, yw, jx, jy, center=(25.0, 20.0), scale=7.0)
    z = np.stack([zx - 25.0, zy - 20.0]) / 7.0
    np.testing.assert_allclose(z.mean(axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(z @ z.T / len(x), np.eye(2), atol=1e-12)
    for j in range(len(th)):
        h = 1e-6 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        a = whiten(*w.warp(x, y, dt, tp), center=(25.0, 20.0), scale=7.0)
        b = whiten(*w.warp(x, y, dt, tm), center=(25.0, 20.0), scale=7.0)
        np.testing.assert_allclose(zjx[:, j], (a[0] - b[0]) / (2 * h), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(zjy[:, j], (a[1] - b[1]) / (2 * h), rtol=1e-5, atol=1e-6)
    with pytest.raises(EmptyWindowError, match="collinear"):
        whiten(np.arange(5.0), 2 * np.arange(5.0))
    del rng


def test_errors_and_defaults():
    w = make_warp("zoom", (H, W))
    x, y, dt = _events(10)
    with pytest.raises(ParameterError, match="unknown regularizer 'div'"):
        regularizer_value_grad("div", w, x, y, dt, np.array([1.0]), (H, W))
    with pytest.raises(EmptyWindowError):
        regularizer_value_grad("divergence", w, x[:0], y[:0], dt[:0], np.array([1.0]), (H, W))
    with pytest.raises(ParameterError, match="shape"):
        regularizer_value_grad("rcad", w, x, y, dt, np.array([1.0]), (0, W))
    with pytest.raises(ParameterError, match="bilinear"):
        regularizer_value_grad("divergence", w, x, y, dt, np.array([1.0]), (H, W),
                               options=PenaltyOptions(kernel="gaussian"))
    assert DEFAULT_WEIGHTS["mvsec"] == {"divergence": 2.0, "deformation": 5.0, "rcad": 0.2}
    assert DEFAULT_WEIGHTS["dsec"] == {"divergence": 50.0, "deformation": 100.0, "rcad": 1.0}
    assert DEFAULT_WEIGHTS["ecd"]["divergence"] == 5.0
    assert DEFAULT_WEIGHTS["ecd"]["deformation"] == 10.0


def test_real_rotation_window_vs_collapse(shared_data):
    """ECD boxes: at the IMU angular velocity the rotation warp's divergence/deformation stay
    an order of magnitude below those of a collapsing zoom (Sec. 3.6.3)."""
    d = shared_data / "ecd_rotation_windows" / "boxes_rotation"
    if not d.is_dir():
        pytest.skip(f"{d} not found")
    c = np.loadtxt(d / "calib.txt")
    Kc = np.array([[c[0], 0, c[2]], [0, c[1], c[3]], [0, 0, 1]])
    ev = np.loadtxt(d / "events.txt")
    t, x, y = ev[:, 0], ev[:, 1], ev[:, 2]
    dt = t - t[len(t) // 2]
    om = np.loadtxt(d / "motion.txt")
    w = make_warp("rotation", (180, 240), K=Kc)
    rot = regularizer_maps("divergence", w, x, y, dt, om, (180, 240))["diwe"]
    z = make_warp("zoom", (180, 240))
    col = regularizer_maps("divergence", z, x, y, dt, np.array([0.9 / window_span(dt)]),
                           (180, 240))["diwe"]
    assert np.abs(rot).max() < 0.1 * np.abs(col).max()
    for reg in REGULARIZERS:
        assert regularizer_value_grad(reg, w, x, y, dt, om, (180, 240))[0] == 0
        assert regularizer_value_grad(reg, z, x, y, dt, np.array([0.9 / window_span(dt)]),
                                      (180, 240))[0] > 0.2


def test_trim_and_backward_kernels_match_numpy():
    """The trim pass (padded, interleaved adjoint images), the branch-free per-event
    backward pass and the stored-Jacobian contraction against plain numpy, events inside,
    across and outside the border included; d/dd_k against finite differences."""
    from evmotion.core.collapse.trimmed import _backward_events, _contract
    from evmotion.core.iwe import accumulate
    from evmotion.core.trim import tile_grid, trim_pass

    rng = np.random.default_rng(5)
    n = 500
    xw, yw = rng.uniform(-2, W + 1, n), rng.uniform(-2, H + 1, n)
    xw[:3] = [np.nan, -1.0, W - 1.0]
    d = rng.normal(size=n)
    cnt = accumulate(xw, yw, (H, W))
    num = accumulate(xw, yw, (H, W), weights=d)
    pads = np.full(2 * (H + 2) * (W + 2), np.nan)
    size = (H + 2) * (W + 2)
    near = np.ones(tile_grid((H, W)), np.uint8)
    total, n_sel = trim_pass(cnt, num, -0.3, pads[:size], pads[size:], near)
    sup = cnt > 1e-9
    mean = np.divide(num, cnt, out=np.zeros((H, W)), where=sup)
    sel = sup & (mean < -0.3)
    assert n_sel == sel.sum() > 20 and total == pytest.approx(mean[sel].sum(), rel=1e-12)
    img = pads.reshape(2, H + 2, W + 2)
    gS = np.where(sel, 1.0 / np.where(sup, cnt, 1.0), 0.0)
    np.testing.assert_allclose(img[0, 1:-1, 1:-1], -mean * gS, rtol=1e-15)
    np.testing.assert_allclose(img[1, 1:-1, 1:-1], gS, rtol=1e-15)
    ring = np.ones((H + 2, W + 2), bool)
    ring[1:-1, 1:-1] = False
    assert not img[:, ring].any()
    # arbitrary adjoint images (not only those of a trim) through the same padded layout
    gS, gN = rng.normal(size=(H, W)), rng.normal(size=(H, W))
    img[0, 1:-1, 1:-1] = gN
    img[1, 1:-1, 1:-1] = gS
    gx, gy, gd = np.empty(n), np.empty(n), np.empty(n)
    _backward_events(xw, yw, d, pads, H, W, 0.5, gx, gy, gd)
    ax, ay, sS = bilinear_adjoint_numpy(xw, yw, gS)
    bx, by, _ = bilinear_adjoint_numpy(xw, yw, gN)
    off = ~((xw > -1) & (xw < W) & (yw > -1) & (yw < H))
    ref = [np.where(off, 0.0, 0.5 * v) for v in (d * ax + bx, d * ay + by, sS)]
    for got, want in zip((gx, gy, gd), ref, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # d/dd_k of 0.5 sum(gS * num) is half the bilinear sample of gS at the event
    e = 1e-6
    for k in range(3, n, 50):
        dp = d.copy()
        dp[k] += e
        fd = 0.5 * ((gS * accumulate(xw, yw, (H, W), weights=dp)).sum()
                    - (gS * accumulate(xw, yw, (H, W), weights=d)).sum()) / e
        assert gd[k] == pytest.approx(fd, abs=1e-6)
    jx, jy, dd = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    out = np.empty(3)
    _contract(gx, gy, gd, jx, jy, dd, out)
    np.testing.assert_allclose(out, gx @ jx + gy @ jy + gd @ dd, rtol=1e-12)
    _contract(gx, gy, gd, jx, jy, np.zeros((0, 0)), out)
    np.testing.assert_allclose(out, gx @ jx + gy @ jy, rtol=1e-12)


def test_no_map_when_every_value_is_above_the_margin():
    """The shortcut that skips the DIWE/IWA maps when no per-event value is below the margin
    (a vote-weighted pixel mean cannot be) agrees with the maps; values at the margin itself
    take the full path."""
    from evmotion.core.collapse.values import all_above as _all_above

    rng = np.random.default_rng(7)
    d = rng.uniform(-0.1, 3.0, 1000)
    assert _all_above(d, -0.2)[0] and not _all_above(d, -0.05)[0]
    assert not _all_above(np.full(10, -0.2), -0.2)[0]
    assert not _all_above(np.array([1.0, -np.inf]), -0.2)[0]
    assert not _all_above(np.array([1.0, np.inf]), -0.2)[0]
    x, y, dt = _events(600, seed=3)
    for name, th in (("rotation", [0.5, -0.3, 0.2]), ("similarity", [40.0, 10.0, 2.0, -3.0]),
                     ("zoom", [-2.0])):
        w = make_warp(name, (H, W), K=K)
        for reg, key in (("divergence", "diwe"), ("deformation", "iwa")):
            maps = regularizer_maps(reg, w, x, y, dt, np.array(th), (H, W))
            v, g = regularizer_value_grad(reg, w, x, y, dt, np.array(th), (H, W))
            assert not maps["trimmed"].any() and v == 0 and not np.any(g)
            assert np.any(maps["count"] > 0) and np.isfinite(maps[key]).all()


@pytest.mark.parametrize("om", [[0.5, -0.3, 0.2], [10.0, 5.0, -30.0], [30.0, -20.0, 40.0]])
def test_rotation_values_from_warped_points_match_numpy(om):
    """The rotation's per-event divergence and det J computed from the warped pixels
    (:func:`_k_rot_values`, every Rodrigues series mode) against the generic plain-numpy
    formulas of :class:`Warp` (matrices of the trajectory, no numba)."""
    from evmotion.core.warps import Warp
    from evmotion.core.warps.rotation import rot_values as _k_rot_values

    w = make_warp("rotation", (H, W), K=K)
    x, y, dt = _events(300, seed=4)
    dt = dt - 0.02
    th = np.array(om)
    xw, yw = w.warp(x, y, dt, th)
    span = dt.max() - dt.min()
    d, fac = np.empty(300), np.empty(300)
    _k_rot_values(xw, yw, dt, th, w._kinv, True, span, d, fac)
    np.testing.assert_allclose(d, Warp.divergence(w, x, y, dt, th) * span, rtol=1e-9,
                               atol=1e-11)
    assert np.all(fac == span)
    _k_rot_values(xw, yw, dt, th, w._kinv, False, 1.0, d, fac)
    det = Warp.jacobian_det(w, x, y, dt, th)
    np.testing.assert_allclose(d, np.abs(det) - 1.0, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(fac, np.where(det >= 0, 1.0, -1.0))


@pytest.mark.parametrize("om", [[0.5, -0.3, 0.2], [10.0, 5.0, -30.0], [30.0, -20.0, 40.0]])
def test_rotation_values_fused_with_the_warp(om):
    """:func:`_warp_values` (the warp and the per-event values in one pass, CMax's pair
    path) gives the warp's pixels and :func:`_k_rot_values`' d and fac, every series mode."""
    from evmotion.core.collapse.values import warp_values as _warp_values
    from evmotion.core.warps.rotation import rot_values as _k_rot_values

    w = make_warp("rotation", (H, W), K=K)
    x, y, dt = _events(300, seed=4)
    dt = dt - 0.02
    th = np.array(om, dtype=float)
    xw_ref, yw_ref = w.warp(x, y, dt, th)
    span = dt.max() - dt.min()
    for kind, T_k in (("divergence", span), ("deformation", 1.0)):
        xw, yw = np.empty(300), np.empty(300)
        d, fac = (a.copy() for a in _warp_values(kind, w, x, y, dt, th, xw, yw, None))
        np.testing.assert_array_equal(xw, xw_ref)
        np.testing.assert_array_equal(yw, yw_ref)
        d_ref, fac_ref = np.empty(300), np.empty(300)
        _k_rot_values(xw_ref, yw_ref, dt, th, w._kinv, kind == "divergence", T_k, d_ref,
                      fac_ref)
        np.testing.assert_allclose(d, d_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(fac, fac_ref)
    # other warps are only warped
    wz = make_warp("zoom", (H, W), K=K)
    xw, yw = np.empty(300), np.empty(300)
    assert _warp_values("divergence", wz, x, y, dt, np.array([8.0]), xw, yw, None) is None
    np.testing.assert_array_equal(xw, wz.warp(x, y, dt, [8.0])[0])


def test_rcad_grid_threshold_matches_numpy():
    """The log-free threshold and summed logarithms of the RCAD grid select the points a
    plain-numpy evaluation of the map selects and give their mean, at margins cutting
    through the map's range (midway between map values: at a value itself the rounding
    decides), and where exp of the margin over- or underflows (a logarithm per point)."""
    from evmotion.core.collapse.rcad import _area_coeffs, _k_rcad_grid

    w = make_warp("rotation", (H, W), K=K)
    th = np.array([12.0, -8.0, 5.0])
    c0, c1 = _area_coeffs(w, th, -0.02), _area_coeffs(w, th, 0.03)
    gy, gx = np.mgrid[2:H:5, 2:W:5]
    s0 = c0[0][0] * gx + c0[0][1] * gy + c0[0][2]
    s1 = c1[0][0] * gx + c1[0][1] * gy + c1[0][2]
    vals = c1[2] - c0[2] - 3 * np.log(np.abs(s1 / s0))
    srt = np.unique(vals)
    mids = [(srt[i] + srt[i + 1]) / 2 for i in (0, len(srt) // 10, len(srt) // 2, -2)]
    for margin in mids + [-np.inf, srt[-1] + 1.0, 1e3, 3e3]:
        g = np.empty(3)
        v, n = _k_rcad_grid(H, W, 5, *c0[:3], *c1[:3], margin, g)
        sel = vals > margin
        assert n == sel.sum()
        assert v == pytest.approx(vals[sel].mean() if n else 0.0, rel=1e-12)


def test_span_argument():
    """A given (min dt, max dt) gives the same penalties as the one computed from dt."""
    x, y, dt = _events(500, seed=6)
    span = (float(dt.min()), float(dt.max()))
    for name in ("zoom", "rotation", "similarity"):
        w = make_warp(name, (H, W), K=K)
        th = np.array(THETA[name])
        for reg in REGULARIZERS:
            v, g = regularizer_value_grad(reg, w, x, y, dt, th, (H, W))
            v2, g2 = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), span=span)
            assert v2 == v and v > 0
            np.testing.assert_array_equal(g2, g)


@pytest.mark.parametrize("name", ["zoom", "rotation", "similarity", "inplane"])
def test_vjp_chain_rule_on_few_and_many_trimmed_pixels(name):
    """Without stored Jacobians the adjoint runs through the warp's fused pass
    (Warp.reduce_pair): same gradient as the stored-Jacobian chain rule whether few or all
    pixels are trimmed."""
    w = make_warp(name, (H, W), K=K)
    th = np.array(THETA[name])
    x, y, dt = _events(900, seed=8)
    xw, yw, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    for reg in ("divergence", "deformation"):
        maps = regularizer_maps(reg, w, x, y, dt, th, (H, W))
        vals = maps["diwe" if reg == "divergence" else "iwa"][maps["count"] > 1e-9]
        for margin in (np.quantile(vals, 0.02), vals.max() + 1.0):
            v, g = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw, jac=(jx, jy),
                                          options=PenaltyOptions(margin=margin))
            v2, g2 = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw,
                                            options=PenaltyOptions(margin=margin))
            if name in ("zoom", "inplane") and reg == "divergence":
                continue  # constant divergence: no per-pixel maps
            assert v2 == v and v != 0
            np.testing.assert_allclose(g2, g, rtol=1e-11, atol=1e-13 * np.abs(g).max())


def test_time_span_matches_numpy():
    from evmotion.core.collapse.values import time_span as _time_span

    rng = np.random.default_rng(9)
    for a in (rng.normal(size=1001), -rng.uniform(1, 2, 7), np.array([2.5]),
              np.array([-np.inf, 0.0, np.inf]), np.array([-5e-324, 5e-324]),
              rng.uniform(0, 0.05, 30_000)):
        assert _time_span(a) == (a.min(), a.max())
    assert _time_span(np.zeros(0)) == (0.0, 0.0)
    assert window_span([0.01, 0.03, 0.02]) == pytest.approx(0.02)


@pytest.mark.parametrize("name", ["zoom", "translation", "se2", "similarity", "inplane"])
def test_fast_values_loops_agree(name):
    """The closed-form values-only loops (short series inline) equal the general ones, whose
    derivatives :meth:`Warp.reduce_pair` is tested against (test_egomotion_fused)."""
    from evmotion.core.warps import WARP_CLASSES as _FAST

    def _k_fast_values(cls, *args):  # the closed forms are the warp classes' now
        cls.event_values(None, *args)

    th = np.array({"zoom": [8.0], "translation": [3.0, 1.0], "se2": [40.0, 10.0, 30.0],
                   "similarity": [40.0, 10.0, 30.0, 9.0],
                   "inplane": [40.0, 10.0, 3.0, -5.0]}[name])
    rng = np.random.default_rng(10)
    for is_div, span in ((True, 0.15), (False, 0.15), (True, 0.005)):
        # 0.005 s: every angle below the short-series bound
        dt = rng.uniform(-span * 2 / 3, span / 3, 1500)
        d, g = np.empty(1500), np.empty((1500, th.size))
        _k_fast_values(_FAST[name], is_div, dt, th, 0.15, d, g, True)
        d0 = np.empty(1500)
        _k_fast_values(_FAST[name], is_div, dt, th, 0.15, d0, np.zeros((0, 0)), False)
        np.testing.assert_allclose(d0, d, rtol=1e-13, atol=1e-15)


def test_count_argument_gives_identical_results():
    """The data term's bilinear IWE passed as the vote-count map: same penalties and
    gradients (bit for bit where the values are voted sparsely; where they are voted
    interleaved with the counts, up to the order of the trim's sum); a wrong image is
    refused."""
    from evmotion.core.iwe import accumulate

    x, y, dt = _events(700, seed=11)
    for name in ("zoom", "rotation", "similarity"):
        w = make_warp(name, (H, W), K=K)
        th = np.array(THETA[name])
        xw, yw = w.warp(x, y, dt, th)
        iwe = accumulate(xw, yw, (H, W))
        before = iwe.copy()
        for reg in ("divergence", "deformation"):
            v, g = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw)
            v2, g2 = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw, count=iwe)
            assert v2 == pytest.approx(v, rel=1e-14) and (v > 0 or name == "zoom")
            np.testing.assert_allclose(g2, g, rtol=1e-13, atol=1e-15 * np.abs(g).max())
        np.testing.assert_array_equal(iwe, before)
    with pytest.raises(ParameterError, match="count"):
        regularizer_value_grad("deformation", w, x, y, dt, th, (H, W), xw, yw,
                               count=np.zeros((H, W + 1)))


def _whiten_numpy(xw, yw, jx, jy, center, scale):
    """Plain-numpy whitening (matrix form) and its Jacobian: the reference of the compiled
    :func:`whiten`."""
    p = np.stack([xw, yw], axis=1)
    n = p.shape[0]
    c = p - p.mean(axis=0)
    lam, V = np.linalg.eigh(c.T @ c / n)
    f = lam ** -0.5
    Cm = (V * f) @ V.T
    z = c @ Cm.T
    dc = np.stack([jx - jx.mean(axis=0), jy - jy.mean(axis=0)], axis=1)
    off = ((f[1] - f[0]) / (lam[1] - lam[0]) if abs(lam[1] - lam[0]) > 1e-12 * lam[1]
           else -0.5 * lam[0] ** -1.5)
    F = np.array([[-0.5 * lam[0] ** -1.5, off], [off, -0.5 * lam[1] ** -1.5]])
    zj = np.empty((n, 2, jx.shape[1]))
    for j in range(jx.shape[1]):
        dCj = (c.T @ dc[:, :, j] + dc[:, :, j].T @ c) / n
        dCm = V @ (F * (V.T @ dCj @ V)) @ V.T
        zj[:, :, j] = c @ dCm.T + dc[:, :, j] @ Cm.T
    return (center[0] + scale * z[:, 0], center[1] + scale * z[:, 1], scale * zj[:, 0],
            scale * zj[:, 1])


@pytest.mark.parametrize("name", ["similarity", "homography"])
def test_whiten_matches_numpy_reference(name):
    w = make_warp(name, (H, W), K=K)
    th = np.array(THETA[name])
    x, y, dt = _events(700, seed=12)
    xw, yw, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    got = whiten(xw, yw, jx, jy, center=(25.0, 20.0), scale=7.0)
    ref = _whiten_numpy(xw, yw, jx, jy, (25.0, 20.0), 7.0)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.abs(b).max())
    zx, zy = whiten(xw, yw, center=(25.0, 20.0), scale=7.0)
    np.testing.assert_array_equal(zx, got[0])
    np.testing.assert_array_equal(zy, got[1])


def test_rcad_of_a_warp_without_area_coefficients_is_the_grid_mean():
    """A warp added as docs/adding_a_warp.rst shows has no closed form nor area
    coefficients: RCAD raised an IndexError (probe AI). It now takes the grid mean from the
    warp's own trajectory matrices; on the homography that reference equals the kernel."""
    from evmotion.core.collapse.rcad import _rcad_reference, rcad_checked

    w = make_warp("homography", (H, W), K=K)
    th = np.array([3.0, 1.0, 20.0, -2.0, 4.0, -15.0, 0.002, -0.001])
    for margin in (-np.inf, 0.0, 0.01):
        v, g = rcad_checked(w, th, -0.02, 0.03, (H, W), margin, 5)
        v_ref, g_ref = _rcad_reference(w, th, -0.02, 0.03, (H, W), margin, 5, True)
        assert v_ref == pytest.approx(v, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(g_ref, g, rtol=1e-7, atol=1e-10)
