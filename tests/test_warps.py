"""Warps of ch. 3 / App. A: numba kernels vs a numpy reference, every differential quantity
vs finite differences, the closed forms of the thesis, and the sign convention vs real data."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.warps import (
    WARPS,
    Warp,
    make_warp,
    rodrigues,
    zoom_normalized_to_rate,
    zoom_rate_to_normalized,
)
from evmotion.errors import CalibrationError, ParameterError

H, W = 180, 240
K = np.array([[200.0, 0.5, 121.0], [0.0, 210.0, 88.0], [0.0, 0.0, 1.0]])
THETA = {
    "zoom": [3.0],
    "translation": [50.0, -30.0],
    "rotation": [1.0, -2.0, 3.0],
    "se2": [40.0, 10.0, 2.0],
    "inplane": [40.0, 10.0, 0.3, 0.5],
    "similarity": [40.0, 10.0, 2.0, 3.0],
    "affine": [40.0, 10.0, 1.0, 2.0, -1.0, 3.0],
    "homography": [1.0, 2.0, 30.0, -1.0, 3.0, 20.0, 1e-3, -2e-3],
}


def _events(n=64, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n), rng.uniform(-0.05, 0.05, n))


def _warp(name):
    return make_warp(name, (H, W), K=K)


def _reference_warp(w, x, y, dt, th):
    """Plain numpy: x' ~ M(dt) (x, y, 1) with M built independently of the kernels."""
    M, _ = w.matrices(dt, th)
    q = np.einsum("nij,nj->ni", M, np.stack([x, y, np.ones_like(x)], axis=1))
    return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]


def _reference_param_jacobian(w, x, y, dt, th):
    """Complex-step derivative of the numpy reference warp (exact to rounding)."""
    P = len(th)
    jx, jy = np.empty((len(x), P)), np.empty((len(x), P))
    for j in range(P):
        tc = th.astype(complex)
        tc[j] += 1e-30j
        M, _ = w.matrices(dt, tc)
        q = np.einsum("nij,nj->ni", M, np.stack([x, y, np.ones_like(x)], axis=1))
        jx[:, j] = np.imag(q[:, 0] / q[:, 2]) / 1e-30
        jy[:, j] = np.imag(q[:, 1] / q[:, 2]) / 1e-30
    return jx, jy


@pytest.mark.parametrize("name", list(WARPS))
def test_kernel_matches_numpy_reference(name):
    w = _warp(name)
    th = np.array(THETA[name])
    x, y, dt = _events()
    xw, yw, jx, jy = w.warp(x, y, dt, th, jacobian=True)
    rx, ry = _reference_warp(w, x, y, dt, th)
    np.testing.assert_allclose(xw, rx, rtol=0, atol=1e-9)
    np.testing.assert_allclose(yw, ry, rtol=0, atol=1e-9)
    rjx, rjy = _reference_param_jacobian(w, x, y, dt, th)
    np.testing.assert_allclose(jx, rjx, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(jy, rjy, rtol=1e-9, atol=1e-9)
    # finite differences as an independent check of the parameter Jacobian
    for j in range(len(th)):
        h = 1e-6 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fd = (w.warp(x, y, dt, tp)[0] - w.warp(x, y, dt, tm)[0]) / (2 * h)
        np.testing.assert_allclose(jx[:, j], fd, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", list(WARPS))
def test_warp_into_and_identity(name):
    w = _warp(name)
    th = np.array(THETA[name])
    x, y, dt = _events()
    n, P = len(x), w.n_params
    xw, yw, jx, jy = np.empty(n), np.empty(n), np.empty((n, P)), np.empty((n, P))
    w.warp_into(x, y, dt, th, xw, yw, jx, jy)
    ref = w.warp(x, y, dt, th, jacobian=True)
    for a, b in zip((xw, yw, jx, jy), ref, strict=True):
        np.testing.assert_array_equal(a, b)
    assert w.identity().dtype == np.float64 and w.identity().shape == (P,)
    xi, yi = w.warp(x, y, dt, w.identity())
    np.testing.assert_allclose(xi, x, atol=1e-9)
    np.testing.assert_allclose(yi, y, atol=1e-9)
    # dt = 0 is the identity for any parameters
    x0, y0 = w.warp(x, y, np.zeros_like(dt), th)
    np.testing.assert_allclose(x0, x, atol=1e-9)
    assert w.n_params == len(w.param_names) == len(w.param_units)


@pytest.mark.parametrize("name", list(WARPS))
def test_differential_quantities_vs_finite_differences(name):
    w = _warp(name)
    th = np.array(THETA[name])
    x, y, dt = _events()
    e = 1e-6
    # flow (3.8) = d/dt of the warp
    fx, fy = w.flow(x, y, dt, th)
    np.testing.assert_allclose(fx, (w.warp(x, y, dt + e, th)[0] - w.warp(x, y, dt - e, th)[0])
                               / (2 * e), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(fy, (w.warp(x, y, dt + e, th)[1] - w.warp(x, y, dt - e, th)[1])
                               / (2 * e), rtol=1e-5, atol=1e-5)
    # divergence = trace of d(flow)/dx
    e = 1e-4
    div_fd = ((w.flow(x + e, y, dt, th)[0] - w.flow(x - e, y, dt, th)[0])
              + (w.flow(x, y + e, dt, th)[1] - w.flow(x, y - e, dt, th)[1])) / (2 * e)
    np.testing.assert_allclose(w.divergence(x, y, dt, th), div_fd, rtol=1e-5, atol=1e-6)
    # Jacobian and its determinant
    dx = (np.array(w.warp(x + e, y, dt, th)) - np.array(w.warp(x - e, y, dt, th))) / (2 * e)
    dy = (np.array(w.warp(x, y + e, dt, th)) - np.array(w.warp(x, y - e, dt, th))) / (2 * e)
    J = w.jacobian(x, y, dt, th)
    np.testing.assert_allclose(J[:, 0, 0], dx[0], atol=1e-7)
    np.testing.assert_allclose(J[:, 1, 0], dx[1], atol=1e-7)
    np.testing.assert_allclose(J[:, 0, 1], dy[0], atol=1e-7)
    np.testing.assert_allclose(J[:, 1, 1], dy[1], atol=1e-7)
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, th), dx[0] * dy[1] - dx[1] * dy[0],
                               atol=1e-7)


@pytest.mark.parametrize("name", list(WARPS))
def test_rcad_is_rate_of_area_change_along_trajectory(name):
    """rcad = d/dh det(dx(t+h)/dx(t)) at h = 0, with x(t) the event's trajectory."""
    w = _warp(name)
    th = np.array(THETA[name])
    x, y, dt = _events(16)
    xr, yr = w.warp(x, y, dt, th)  # the trajectory through each event, at t_ref

    def area(h):
        e = 1e-4

        def pos(xx, yy):
            # from (xx, yy) at t_k: back to t_ref, then forward to t_k + h
            a, b = w.warp(xx, yy, dt, th)
            return np.array(w.trajectory(a, b, dt + h, th))

        ddx = (pos(x + e, y) - pos(x - e, y)) / (2 * e)
        ddy = (pos(x, y + e) - pos(x, y - e)) / (2 * e)
        return ddx[0] * ddy[1] - ddx[1] * ddy[0]

    h = 1e-4
    np.testing.assert_allclose(w.rcad(x, y, dt, th), (area(h) - area(-h)) / (2 * h),
                               rtol=1e-4, atol=1e-4)
    # trajectory inverts the warp
    xb, yb = w.trajectory(xr, yr, dt, th)
    np.testing.assert_allclose(xb, x, atol=1e-8)
    np.testing.assert_allclose(yb, y, atol=1e-8)


@pytest.mark.parametrize("name", list(WARPS))
def test_parameter_gradients_of_quantities(name):
    w = _warp(name)
    th = np.array(THETA[name])
    x, y, dt = _events(16)
    for fn in (w.divergence, w.jacobian_det, w.rcad):
        _, g = fn(x, y, dt, th, grad=True)
        for j in range(len(th)):
            h = 1e-6 * max(1.0, abs(th[j]))
            tp, tm = th.copy(), th.copy()
            tp[j] += h
            tm[j] -= h
            np.testing.assert_allclose(g[:, j], (fn(x, y, dt, tp) - fn(x, y, dt, tm)) / (2 * h),
                                       rtol=1e-5, atol=1e-5)
    _, g = w.area_log_ratio(x, y, -0.02, 0.03, th, grad=True)
    for j in range(len(th)):
        h = 1e-6 * max(1.0, abs(th[j]))
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fd = (w.area_log_ratio(x, y, -0.02, 0.03, tp) - w.area_log_ratio(x, y, -0.02, 0.03, tm))
        np.testing.assert_allclose(g[:, j], fd / (2 * h), rtol=1e-5, atol=1e-5)


def _centred(x, y):
    return x - (W - 1) / 2, y - (H - 1) / 2


def test_closed_forms_zoom_translation():
    x, y, dt = _events()
    h = 3.0
    w = _warp("zoom")
    np.testing.assert_allclose(w.divergence(x, y, dt, [h]), -2 * h)  # f = -b_z x
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, [h]), (1 - dt * h) ** 2)
    np.testing.assert_allclose(w.rcad(x, y, dt, [h]), 2 * h / (1 - dt * h))  # (3.20)
    xc, yc = _centred(x, y)
    fx, fy = w.flow(x, y, dt, [h])
    np.testing.assert_allclose(fx, -h * xc)
    np.testing.assert_allclose(fy, -h * yc)
    T = 0.04
    np.testing.assert_allclose(w.area_log_ratio(x, y, 0.0, T, [h]),
                               -2 * np.log(abs(1 - h * T)))  # (3.21)
    w = _warp("translation")
    v = np.array([50.0, -30.0])
    np.testing.assert_allclose(w.divergence(x, y, dt, v), 0, atol=1e-12)
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, v), 1)
    np.testing.assert_allclose(w.area_log_ratio(x, y, 0, 0.05, v), 0, atol=1e-12)
    np.testing.assert_allclose(w.optical_flow(x, y, v)[0], 50.0)


def test_closed_forms_se2_similarity_inplane():
    x, y, dt = _events()
    vx, vy, wz, s = 40.0, 10.0, 2.0, 3.0
    w = _warp("se2")
    np.testing.assert_allclose(w.divergence(x, y, dt, [vx, vy, wz]),
                               -2 * wz * np.sin(dt * wz), atol=1e-12)  # (A.13)
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, [vx, vy, wz]), 1)  # (A.14)
    np.testing.assert_allclose(w.area_log_ratio(x, y, 0, 0.05, [vx, vy, wz]), 0, atol=1e-12)
    w = _warp("similarity")
    beta = 1 + dt * s
    div = (-s / beta**2) * 2 * np.cos(dt * wz) + wz / beta * 2 * np.sin(-dt * wz)  # (A.40)
    np.testing.assert_allclose(w.divergence(x, y, dt, [vx, vy, wz, s]), div)
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, [vx, vy, wz, s]), beta**-2)  # (A.42)
    t0, t1 = -0.01, 0.04  # (A.44): |J_{t0,t1}| = (beta(t1)/beta(t0))^2
    np.testing.assert_allclose(w.area_log_ratio(x, y, t0, t1, [vx, vy, wz, s]),
                               2 * np.log((1 + t1 * s) / (1 + t0 * s)))
    w = _warp("inplane")
    phi, bz = 0.3, 0.5
    np.testing.assert_allclose(w.divergence(x, y, dt, [vx, vy, phi, bz]),
                               2 - 2 * (bz + 1) * np.cos(phi))  # (A.25)
    det = (1 + dt) ** 2 - 2 * (1 + dt) * dt * (bz + 1) * np.cos(phi) + dt**2 * (bz + 1) ** 2
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, [vx, vy, phi, bz]), det)  # (A.27)
    # particular cases listed under (A.27): zoom and translation
    z = _warp("zoom")
    np.testing.assert_allclose(w.warp(x, y, dt, [0, 0, 0, bz]), z.warp(x, y, dt, [bz]))


def test_closed_forms_affine_homography():
    x, y, dt = _events()
    th = np.array(THETA["affine"])
    G = th[2:].reshape(2, 2)
    w = _warp("affine")
    A = np.eye(2) + dt[:, None, None] * G
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, th), 1 / np.linalg.det(A))
    Ai = np.linalg.inv(A)
    np.testing.assert_allclose(w.divergence(x, y, dt, th),
                               np.trace(-Ai @ G @ Ai, axis1=1, axis2=2))  # (A.51)
    t0, t1 = -0.01, 0.04  # (A.53)
    np.testing.assert_allclose(
        w.area_log_ratio(x, y, t0, t1, th),
        np.log(abs(np.linalg.det(np.eye(2) + t1 * G) / np.linalg.det(np.eye(2) + t0 * G))))
    # homography with a zero projective row is the affine warp
    hom = _warp("homography")
    thh = np.array([th[2], th[3], th[0], th[4], th[5], th[1], 0.0, 0.0])
    np.testing.assert_allclose(hom.warp(x, y, dt, thh), w.warp(x, y, dt, th), atol=1e-9)
    # (A.4): det J = det(M) / (e3^T M x)^3 with M = H^-1
    thh = np.array(THETA["homography"])
    Gh = np.array([thh[:3], thh[3:6], [thh[6], thh[7], 0.0]])
    xc, yc = _centred(x, y)
    Mi = np.linalg.inv(np.eye(3) + dt[:, None, None] * Gh)
    q3 = Mi[:, 2, 0] * xc + Mi[:, 2, 1] * yc + Mi[:, 2, 2]
    np.testing.assert_allclose(hom.jacobian_det(x, y, dt, thh), np.linalg.det(Mi) / q3**3)


def test_closed_forms_rotation():
    x, y, dt = _events()
    om = np.array(THETA["rotation"])
    w = _warp("rotation")
    xn = np.linalg.solve(K, np.stack([x, y, np.ones_like(x)]))
    # (3.23) divergence at the reference time
    np.testing.assert_allclose(w.divergence(x, y, 0 * dt, om),
                               3 * (xn[0] * om[1] - xn[1] * om[0]), rtol=1e-10)
    # (3.28) integrand: rate of area change at dt = 0 is 3 (wx y - wy x)
    np.testing.assert_allclose(w.rcad(x, y, 0 * dt, om),
                               3 * (om[0] * xn[1] - om[1] * xn[0]), rtol=1e-10)
    # (3.24) det J = (r3^T x^b)^-3 with r3 the third row of R(dt omega)
    R = rodrigues(dt[:, None] * om[None])
    r3x = np.einsum("ni,in->n", R[:, 2, :], xn)
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, om), r3x**-3, rtol=1e-10)
    # rotation about the optical axis: no divergence at t_ref, no deformation
    oz = np.array([0.0, 0.0, 5.0])
    np.testing.assert_allclose(w.jacobian_det(x, y, dt, oz), 1, rtol=1e-12)
    np.testing.assert_allclose(w.area_log_ratio(x, y, -0.02, 0.03, oz), 0, atol=1e-12)
    # (3.28): the area log-ratio is the integral of the rate along the trajectory
    t0, t1 = -0.02, 0.03
    nodes, weights = np.polynomial.legendre.leggauss(12)
    ts = (t1 - t0) / 2 * nodes + (t1 + t0) / 2
    integral = sum(wk * w.rcad(*w.trajectory(x, y, np.full_like(x, tk), om),
                               np.full_like(x, tk), om)
                   for tk, wk in zip(ts, weights, strict=True)) * (t1 - t0) / 2
    np.testing.assert_allclose(w.area_log_ratio(x, y, t0, t1, om), integral, rtol=1e-8)


def test_rodrigues_large_and_small_angles():
    for r in (np.array([1e-9, 0, 0]), np.array([0.3, -0.2, 0.1]), np.array([2.0, 1.0, -1.5])):
        R = rodrigues(r)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R @ r, r, atol=1e-12)  # the axis is fixed
    x, y, _ = _events(8)
    w = _warp("rotation")
    dt = np.linspace(-0.05, 0.05, len(x))
    # the three Rodrigues paths: short and long series, exact sin/cos above 1 rad
    for om in ([1.0, -2.0, 3.0], [5.0, -4.0, 3.0], [20.0, -10.0, 5.0]):
        om = np.array(om)
        xw, yw, jx, jy = w.warp(x, y, dt, om, jacobian=True)
        np.testing.assert_allclose((xw, yw), _reference_warp(w, x, y, dt, om), atol=1e-9)
        rjx, rjy = _reference_param_jacobian(w, x, y, dt, om)
        np.testing.assert_allclose(jx, rjx, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(jy, rjy, rtol=1e-9, atol=1e-9)


def test_zoom_normalized_time():
    assert zoom_normalized_to_rate(0.2, 0.05) == pytest.approx(4.0)
    assert zoom_rate_to_normalized(4.0, 0.05) == pytest.approx(0.2)
    with pytest.raises(ParameterError, match="window_s"):
        zoom_normalized_to_rate(0.2, 0.0)
    # (3.7) with t~ = dt / T is the rate warp with rate = b_z / T
    x, y, dt = _events()
    dt = np.abs(dt)
    T, bz = 0.05, 0.4
    w = _warp("zoom")
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    xw, _ = w.warp(x, y, dt, [zoom_normalized_to_rate(bz, T)])
    np.testing.assert_allclose(xw - c[0], (1 - dt / T * bz) * (x - c[0]))


def test_bad_input_errors():
    with pytest.raises(CalibrationError, match="intrinsics K"):
        make_warp("rotation", (H, W))
    with pytest.raises(CalibrationError, match="3x3"):
        make_warp("rotation", (H, W), K=np.eye(2))
    with pytest.raises(ParameterError, match="unknown warp 'zom'"):
        make_warp("zom", (H, W))
    w = _warp("similarity")
    x, y, dt = _events(4)
    with pytest.raises(ParameterError, match=r"shape \(4,\)"):
        w.warp(x, y, dt, np.zeros(3))
    with pytest.raises(ParameterError, match="finite"):
        w.warp(x, y, dt, np.array([0, 0, np.nan, 0]))
    with pytest.raises(ParameterError, match="equal length"):
        w.warp(x, y[:2], dt, np.zeros(4))
    out = np.empty(4)
    with pytest.raises(ParameterError, match="'x' must be a C-contiguous float64"):
        w.warp_into(x.astype(np.float32), y, dt, np.zeros(4), out, out.copy())
    with pytest.raises(ParameterError, match="'jy'"):
        w.warp_into(x, y, dt, np.zeros(4), out, out.copy(), np.empty((4, 4)), np.empty((4, 3)))


def test_rotation_sign_convention_on_real_data(shared_data):
    """The motion field of the IMU angular velocity must equal the data set's GT flow."""
    d = shared_data / "ecd_rotation_windows" / "boxes_rotation"
    if not d.is_dir():
        pytest.skip(f"{d} not found")
    c = np.loadtxt(d / "calib.txt")
    Kc = np.array([[c[0], 0, c[2]], [0, c[1], c[3]], [0, 0, 1]])
    om = np.loadtxt(d / "motion.txt")
    t = np.loadtxt(d / "events.txt", usecols=0)
    T = t[-1] - t[0]
    flow = np.load(d / "flow.npy")[0]
    w = make_warp("rotation", (180, 240), K=Kc)
    yy, xx = np.mgrid[0:180, 0:240].astype(float)
    u, v = w.optical_flow(xx.ravel(), yy.ravel(), om)
    np.testing.assert_allclose(u * T, flow[0].ravel(), atol=1e-5)
    np.testing.assert_allclose(v * T, flow[1].ravel(), atol=1e-5)


@pytest.mark.parametrize("omega", [[1.0, -2.0, 3.0], [6.0, -4.0, 8.0], [20.0, -15.0, 30.0],
                                   [0.0, 0.0, 0.0]])
def test_rotation_analytic_derivatives_match_numpy_reference(omega):
    """The rotation kernel's analytic omega-derivatives of div f and det J equal the
    complex-step derivatives of the generic numpy closed forms from M and dM/dt; without
    derivatives (the value-only kernel, another code path) the values are the same."""
    w = _warp("rotation")
    x, y, dt = _events(200)
    th = np.array(omega)
    for fn, ref in ((w.divergence, Warp._div), (w.jacobian_det, Warp._det)):
        val, g = fn(x, y, dt, th, grad=True)
        rval, rg = Warp._with_grad(w, lambda a, b, c, d, ref=ref: ref(w, a, b, c, d),
                                   x, y, dt, th, True)
        np.testing.assert_allclose(val, rval, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(fn(x, y, dt, th), rval, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(g, rg, rtol=1e-8, atol=1e-10)
