"""The camera-rotation warp (3.22): ``x'_n ~ exp(dt omega^) x_n`` in normalized coordinates.

Forward kernel and Jacobian per Rodrigues series mode (:func:`rot_series_mode`), the fused
adjoint (plain, and over blocks of events with the collapse values' derivatives), the
divergence (3.23) and det J (3.24) with their analytic omega-derivatives, and the per-event
collapse values computed from the warped points.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core.warps.adjoint import (
    DIV_BLOCK,
    AdjointInput,
    FusedAdjoint,
    event_cell,
    src_diff,
    store_sums,
    warped_cell,
)
from evmotion.core.warps.base import Warp
from evmotion.core.warps.common import (
    BLOCK,
    EMPTY1,
    EMPTY2,
    FAST_FINITE,
    max_abs,
    rows01,
)
from evmotion.core.warps.so3 import cross, rod_block, rod_mode, rot_matrix
from evmotion.jitcache import kernel_case

__all__ = ["RotationWarp", "rot_series_mode", "rot_values", "rot_warp_values"]

@njit(cache=True, error_model="numpy", inline="always")
def _rot_point(x, y, t, a, b, w, ki):
    """Rodrigues rotation of K^-1 (x, y, 1) by t omega, with its projection (``w``: omega;
    ``ki``: K^-1, row by row)."""
    i00, i01, i02, i10, i11, i12, i20, i21, i22 = ki
    n = (i00 * x + i01 * y + i02, i10 * x + i11 * y + i12, i20 * x + i21 * y + i22)
    c1 = cross(w, n)
    c2 = cross(w, c1)
    at = a * t
    bt = b * t * t
    q0 = n[0] + at * c1[0] + bt * c2[0]
    q1 = n[1] + at * c1[1] + bt * c2[1]
    q2 = n[2] + at * c1[2] + bt * c2[2]
    iz = 1.0 / q2
    return q0 * iz, q1 * iz, q0, q1, q2, iz


@njit(cache=True, error_model="numpy")
def _rot_warp_event(x, y, t, a, b, w, km, ki):
    """Warped pixel of one event: :func:`_rot_warp_norm`, then K (``km``, ``ki``: the first
    two rows of K and K^-1, :func:`~evmotion.core.warps.common.rows01`)."""
    k00, k01, k02, k10, k11, k12 = km
    X, Y = _rot_warp_norm(x, y, t, a, b, w, ki)
    return k00 * X + k01 * Y + k02, k10 * X + k11 * Y + k12


@njit(cache=True, error_model="numpy", inline="always")
def _rot_warp_norm(x, y, t, a, b, w, ki):
    """Warped normalized point of one event: :func:`_rot_point` with K^-1's last row
    (0, 0, 1) written in (``ki``: the first two rows of K^-1)."""
    i00, i01, i02, i10, i11, i12 = ki
    xn = i00 * x + i01 * y + i02
    yn = i10 * x + i11 * y + i12
    c1 = cross(w, (xn, yn, 1.0))
    c2 = cross(w, c1)
    at = a * t
    bt = b * t * t
    iz = 1.0 / (1.0 + at * c1[2] + bt * c2[2])
    return (xn + at * c1[0] + bt * c2[0]) * iz, (yn + at * c1[1] + bt * c2[1]) * iz


def _rot_warp_case(mode, jac):
    """The rotation warp kernel in series mode ``mode`` (:func:`_rot_rates`), with the
    Jacobian (``jac``) or not: one case, compiled on first use
    (:func:`evmotion.jitcache.kernel_case`)."""
    if jac:
        @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
        def rot_warp_jac(x, y, dt, w, Kmat, Kinv, xw, yw, jx, jy):
            _rot_jac_loop(mode, (x, y, dt, xw, yw, jx, jy, w, Kmat, Kinv))

        return rot_warp_jac

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def rot_warp(x, y, dt, w, Kmat, Kinv, xw, yw, jx, jy):
        w3 = (w[0], w[1], w[2])
        ww = w3[0] * w3[0] + w3[1] * w3[1] + w3[2] * w3[2]
        km = rows01(Kmat)
        ki = rows01(Kinv)
        for k in range(x.shape[0]):
            t = dt[k]
            a, b, _ = rod_mode(t * t * ww, mode)
            xw[k], yw[k] = _rot_warp_event(x[k], y[k], t, a, b, w3, km, ki)

    return rot_warp


@njit(cache=True, error_model="numpy", inline="always")
def _rot_jac_event(x, y, t, a, b, c, w, km, ki):
    """Warped pixel and its omega-derivatives ``(xw, yw, jx0, jx1, jx2, jy0, jy1, jy2)``
    (``w``: omega and |omega|^2; ``km``: the first two rows of K; ``ki``: K^-1, row by
    row)."""
    wx, wy, wz, ww = w
    k00, k01, k02, k10, k11, k12 = km
    X, Y, _, _, _, _ = _rot_point(x, y, t, a, b, (wx, wy, wz), ki)
    # d(X, Y)/d omega = -t L J_l(t omega) with L the rotational interaction matrix
    # at the warped point, rows L0 = (XY, -(1 + X^2), Y), L1 = (1 + Y^2, -XY, -X),
    # and J_l = g Id + b t omega^ + c t^2 omega omega^T, g = 1 - c t^2 |omega|^2:
    # row u of L J_l is g u + b t (u x omega) + c t^2 (u . omega) omega
    bt1 = b * t
    ct2 = c * t * t
    g = 1.0 - ct2 * ww
    xy = X * Y
    u0, u1, u2 = xy, -1.0 - X * X, Y
    v0, v1, v2 = 1.0 + Y * Y, -xy, -X
    su = ct2 * (u0 * wx + u1 * wy + u2 * wz)
    sv = ct2 * (v0 * wx + v1 * wy + v2 * wz)
    dx0 = -t * (g * u0 + bt1 * (u1 * wz - u2 * wy) + su * wx)
    dx1 = -t * (g * u1 + bt1 * (u2 * wx - u0 * wz) + su * wy)
    dx2 = -t * (g * u2 + bt1 * (u0 * wy - u1 * wx) + su * wz)
    dy0 = -t * (g * v0 + bt1 * (v1 * wz - v2 * wy) + sv * wx)
    dy1 = -t * (g * v1 + bt1 * (v2 * wx - v0 * wz) + sv * wy)
    dy2 = -t * (g * v2 + bt1 * (v0 * wy - v1 * wx) + sv * wz)
    return (k00 * X + k01 * Y + k02, k10 * X + k11 * Y + k12, k00 * dx0 + k01 * dy0,
            k00 * dx1 + k01 * dy1, k00 * dx2 + k01 * dy2, k10 * dx0 + k11 * dy0,
            k10 * dx1 + k11 * dy1, k10 * dx2 + k11 * dy2)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_jac_loop(mode, args):
    x, y, dt, xw, yw, jx, jy, w, Kmat, Kinv = args
    wx, wy, wz = w[0], w[1], w[2]
    ww = wx * wx + wy * wy + wz * wz
    km = rows01(Kmat)
    i00, i01, i02, i10, i11, i12 = rows01(Kinv)
    ki = (i00, i01, i02, i10, i11, i12, Kinv[2, 0], Kinv[2, 1], Kinv[2, 2])
    w4 = (wx, wy, wz, ww)
    # flat views: stride-3 stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        a, b, c = rod_mode(t * t * ww, mode)
        xw[k], yw[k], jxf[3 * k], jxf[3 * k + 1], jxf[3 * k + 2], jyf[3 * k], jyf[3 * k + 1], \
            jyf[3 * k + 2] = _rot_jac_event(x[k], y[k], t, a, b, c, w4, km, ki)


@njit(cache=True, error_model="numpy")
def _rot_vjp_event(X, Y, t, b, c, w, gX, gY):
    """``gX dX/domega + gY dY/domega`` (3 terms) at the warped normalized point (X, Y)
    (``w``: omega and |omega|^2); the formula of the Jacobian in :func:`_rot_jac_event`,
    contracted instead of stored."""
    return _rot_vjp_u(X, Y, t, b, c, w, gX, gY, (0.0, 0.0, 0.0))


@njit(cache=True, error_model="numpy", inline="always")
def _rot_vjp_u(X, Y, t, b, c, w, gX, gY, e):
    """:func:`_rot_vjp_event` with the 3-tuple ``e`` added to its vector ``u`` (``-t J_l^T
    u`` is the result)."""
    wx, wy, wz, ww = w
    e0, e1, e2 = e
    bt1 = b * t
    ct2 = c * t * t
    g = 1.0 - ct2 * ww
    xy = X * Y
    # contract the rows first: gX L0 + gY L1, a single 3-vector u
    u0 = gX * xy + gY * (1.0 + Y * Y) + e0
    u1 = -gX * (1.0 + X * X) - gY * xy + e1
    u2 = gX * Y - gY * X + e2
    su = ct2 * (u0 * wx + u1 * wy + u2 * wz)
    return (-t * (g * u0 + bt1 * (u1 * wz - u2 * wy) + su * wx),
            -t * (g * u1 + bt1 * (u2 * wx - u0 * wz) + su * wy),
            -t * (g * u2 + bt1 * (u0 * wy - u1 * wx) + su * wz))


@njit(cache=True, error_model="numpy")
def _rot_adj_event(xv, yv, t, b, c, gx, gy, w, k2, ki):
    """:func:`_rot_vjp_event` from the warped pixel and its pixel gradient: the normalized
    point comes back through K^-1 (affine), the gradient through K^T, so no division
    (``w``: omega and |omega|^2; ``k2``: K's 2x2 block; ``ki``: the first two rows of
    K^-1)."""
    k00, k01, k10, k11 = k2
    i00, i01, i02, i10, i11, i12 = ki
    X = i00 * xv + i01 * yv + i02
    Y = i10 * xv + i11 * yv + i12
    return _rot_vjp_event(X, Y, t, b, c, w, gx * k00 + gy * k10, gx * k01 + gy * k11)


@njit(cache=True, inline="always")
def _rot_rates(dt, w):
    """omega's components, |omega|^2 and the Rodrigues series mode for the window's largest
    |dt| (0: short series, 1: long series, 2: closed form)."""
    wx, wy, wz = w[0], w[1], w[2]
    ww = wx * wx + wy * wy + wz * wz
    tm = max_abs(dt)
    zmax = tm * tm * ww
    return wx, wy, wz, ww, 0 if zmax < 0.05 else (1 if zmax < 1.0 else 2)


@njit(cache=True, inline="always")
def _rot_bc(z, mode):
    """The Rodrigues coefficients (b, c) in series mode ``mode`` (:func:`_rot_rates`)."""
    _, b, c = rod_mode(z, mode)
    return b, c


@njit(cache=True, inline="always")
def _rot_prm(prm):
    """The scalars of the rotation adjoint's ``prm``, grouped: omega and |omega|^2, K's 2x2
    block and the first two rows of K^-1."""
    wx, wy, wz = prm[0], prm[1], prm[2]
    return ((wx, wy, wz, wx * wx + wy * wy + wz * wz), (prm[3], prm[4], prm[5], prm[6]),
            (prm[7], prm[8], prm[9], prm[10], prm[11], prm[12]))


@njit(cache=True, error_model="numpy", inline="always")
def _rot_loop(mode, fuse, use_w, pair, ev, prm, src):
    """The rotation's adjoint loop over the events ``ev`` (:mod:`~.adjoint`): its three sums
    and, in pair mode, that of ``|gd|`` (:func:`~.adjoint.pad_diff`)."""
    gx, gy, wts, _, _, _, _, _ = src
    w4, k2, ki = _rot_prm(prm)
    ww = w4[3]
    a0 = a1 = a2 = a3 = 0.0
    for k in range(ev[3].shape[0]):
        gd = 0.0
        xv, yv, t, a, fx, fy, i = warped_cell(fuse, use_w, pair, k, ev, src)
        if fuse:
            gX, gY, gd = src_diff(pair, a, fx, fy, wts[k] if pair else 0.0, i, src)
        else:
            gX, gY = gx[k], gy[k]
        b, c = _rot_bc(t * t * ww, mode)
        d0, d1, d2 = _rot_adj_event(xv, yv, t, b, c, gX, gY, w4, k2, ki)
        a0 += d0
        a1 += d1
        a2 += d2
        a3 += abs(gd)
    return a0, a1, a2, a3


@njit(cache=True, error_model="numpy", inline="always")
def _rot_block_loop(mode, pair, vk, ev, prm, src, blk):
    """:func:`_rot_loop` (fused) over the blocks of :data:`DIV_BLOCK` events listed in
    ``blk`` (all if empty), in pair mode with the values' derivatives (``vk``: 1 divergence,
    2 det J): the votes' adjoint over every event of a block, then the values' part (linear
    in the pixel gradient, so it splits off exactly: :func:`_rot_value_adj`, or the det J
    weight through :func:`_rot_vjp_event`) only where some event has a nonzero ``gd``: near
    collapse a minority of the events reach a trimmed pixel, clustered (in-line, it cost
    about as much as the rest of the loop). No per-event buffer: each loop only sums, so
    both vectorize. (A list, not flags tested per block: a test in the outer loop slowed
    the inner one by half.)"""
    x, y, dt, xw, yw = ev
    gx, gy, wts, pad, h, wd, scale, T = src
    w4, _, ki = _rot_prm(prm)
    i00, i01, i02, i10, i11, i12 = ki
    ww = w4[3]
    listed = blk.shape[0] > 0
    nb = blk.shape[0] if listed else -(-xw.shape[0] // DIV_BLOCK)
    a0 = a1 = a2 = 0.0
    for bi in range(nb):
        k0 = (blk[bi] if listed else bi) * DIV_BLOCK
        # views per block, so that the loops index from 0: an index numba cannot prove
        # non-negative gets a wraparound select, and its loads become gathers
        k1 = k0 + DIV_BLOCK
        ts, xs, ys = dt[k0:k1], xw[k0:k1], yw[k0:k1]
        sub = (x, y, ts, xs, ys)
        ssrc = (gx, gy, wts[k0:k1] if pair else wts, pad, h, wd, scale, T)
        if not pair:
            d0, d1, d2, _ = _rot_loop(mode, True, False, False, sub, prm, ssrc)
            a0 += d0
            a1 += d1
            a2 += d2
            continue
        d0, d1, d2, active = _rot_loop(mode, True, True, True, sub, prm, ssrc)
        a0 += d0
        a1 += d1
        a2 += d2
        if vk == 0 or active == 0.0:
            continue
        for k in range(ts.shape[0]):
            xv, yv, t, a, fx, fy, i = event_cell(xs[k], ys[k], ts[k], k, False, True, ssrc)
            _, _, gd = src_diff(True, a, fx, fy, 0.0, i, ssrc)
            ra, b, c = rod_mode(t * t * ww, mode)
            X = i00 * xv + i01 * yv + i02
            Y = i10 * xv + i11 * yv + i12
            if vk == 1:
                d0, d1, d2 = _rot_value_adj(X, Y, t, (ra, b, c), gd, T, w4)
            else:
                kap = _rot_det_weight(X, Y, t, ra, b, w4, gd)
                d0, d1, d2 = _rot_vjp_event(X, Y, t, b, c, w4, kap * X, kap * Y)
            a0 += d0
            a1 += d1
            a2 += d2
    return a0, a1, a2, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _rot_det_weight(X, Y, t, a, b, w, gd):
    """``kap``: ``gd`` times the omega-derivative of the event's ``|det J| - 1`` is that of
    ``kap (X, Y)`` as a normalized pixel gradient (:func:`_rot_value_adj`)."""
    _, _, r02, _, _, r12, _, _, r22 = rot_matrix(a, b, t, w)
    iz = r02 * X + r12 * Y + r22
    return gd * 3.0 * abs(iz * iz * iz) / (1.0 + X * X + Y * Y)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_value_adj(X, Y, t, abc, gd, T, w):
    """``gd`` times the omega-derivative of the event's divergence times ``T`` (its
    ``|det J| - 1``: :func:`_rot_det_weight`), from the warped normalized point (X, Y)
    alone (``abc``: the Rodrigues coefficients; ``w``: omega and |omega|^2).

    The value is a function ``D(X, Y, omega)`` (:func:`_rot_value_event`), so
    ``dD/domega = D_X dX/domega + D_Y dY/domega + D_omega``: the
    first two terms are a pixel gradient for :func:`_rot_vjp_event`. Since ``|q| = |v|``
    (q = R v), ``q_z^2 (1 + X^2 + Y^2) = |v|^2``, and ``|det J| = |q_z|^-3`` depends on
    omega through X, Y only:
    ``d|det J| = 3 |det J| (X dX + Y dY) / (1 + X^2 + Y^2)``. For the divergence ``tr(A
    J)``, ``D_omega`` comes from ``A`` (linear in omega) and from ``R`` with ``dR/domega_j
    = t (J_l e_j)^ R``: ``sum_mn (dD/dR)_mn (dR/domega_j)_mn = t (J_l e_j) . n``, ``n``
    the axial vector of ``R M^T - M R^T``, ``M = dD/dR``; :func:`_rot_vjp_u` contracts
    ``-t J_l^T u``, so ``n`` enters as ``u -= gd n``."""
    a, b, c = abc
    wx, wy, wz, _ = w
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot_matrix(a, b, t, w)
    iz = r02 * X + r12 * Y + r22
    f = gd * T
    p00 = r00 - X * r20
    p01 = r01 - X * r21
    p10 = r10 - Y * r20
    p11 = r11 - Y * r21
    a00 = 2.0 * wy * X - wx * Y
    a01 = -wz - wx * X
    a10 = wz + wy * Y
    a11 = wy * X - 2.0 * wx * Y
    S = a00 * p00 + a01 * p10 + a10 * p01 + a11 * p11  # D = S iz
    # D_X, D_Y into the pixel gradient
    sx = 2.0 * wy * p00 - a00 * r20 - wx * p10 - a10 * r21 + wy * p11
    sy = -wx * p00 - a01 * r20 + wy * p01 - a11 * r21 - 2.0 * wx * p11
    gXd = f * (iz * sx + S * r02)
    gYd = f * (iz * sy + S * r12)
    # M = dD/dR: rows (m0, m1, m2)
    m00 = a00 * iz
    m01 = a10 * iz
    m10 = a01 * iz
    m11 = a11 * iz
    m20 = -(X * a00 + Y * a01) * iz
    m21 = -(X * a10 + Y * a11) * iz
    m02 = S * X
    m12 = S * Y
    # N = R M^T: N_mn = R_m . M_n; n = (N12 - N21, N20 - N02, N01 - N10)
    n0 = (r10 * m20 + r11 * m21 + r12 * S) - (r20 * m10 + r21 * m11 + r22 * m12)
    n1 = (r20 * m00 + r21 * m01 + r22 * m02) - (r00 * m20 + r01 * m21 + r02 * S)
    n2 = (r00 * m10 + r01 * m11 + r02 * m12) - (r10 * m00 + r11 * m01 + r12 * m02)
    # D_omega through A (a00..a11 linear in omega), J = p iz
    ea0 = -Y * p00 - X * p10 - 2.0 * Y * p11
    ea1 = 2.0 * X * p00 + Y * p01 + X * p11
    ea2 = p01 - p10
    d0, d1, d2 = _rot_vjp_u(X, Y, t, b, c, w, gXd, gYd, (-f * n0, -f * n1, -f * n2))
    fi = f * iz
    return d0 + fi * ea0, d1 + fi * ea1, d2 + fi * ea2


def _rot_adj_plain(mode, fuse, use_w):
    """The rotation adjoint (:func:`_rot_loop`) in one case, ``out`` (3,) = ``jx^T gx + jy^T
    gy`` with the Jacobian recomputed per event from the warped pixels of ``ev``
    (:mod:`~.adjoint`; ``prm``: omega, K's 2x2 block, the first two rows of K^-1); with a
    padded image (``fuse``) the pixel gradients come from it (weights times ``scale`` where
    ``use_w``), not from ``gx, gy``."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def rot_adj(ev, prm, src, out):
        store_sums(_rot_loop(mode, fuse, use_w, False, ev, prm, src), out)

    return rot_adj


def _rot_adj_blocks(mode, pair, vk):
    """The rotation adjoint over listed blocks of events (:func:`_rot_block_loop`, ``blk``
    int64, empty: all), with one padded image and unit weights, or two (``pair``, ``wts``
    the per-event values) with ``vk`` saying whether the values are held fixed (0) or are
    the warp's divergence times ``T`` (1) or ``|det J| - 1`` (2), whose derivatives are
    then chained as well (:data:`VALUE_KINDS`)."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def rot_adj_blocks(ev, prm, src, blk, out):
        store_sums(_rot_block_loop(mode, pair, vk, ev, prm, src, blk), out)

    return rot_adj_blocks


def rot_series_mode(dt, w) -> int:
    """The Rodrigues series mode of :func:`_rot_rates` for the window's largest |dt|."""
    tm = max_abs(dt)
    zmax = tm * tm * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    return 0 if zmax < 0.05 else (1 if zmax < 1.0 else 2)


def _rotation_adj(ev, prm, src: AdjointInput, out):
    """The rotation adjoint: picks the case kernel (see :func:`_rot_adj_plain`,
    :func:`_rot_adj_blocks`; blocks are visited in pair mode or with one image and unit
    weights)."""
    mode = rot_series_mode(ev[2], prm)
    fuse, use_w, pair, vk = src.case()
    args = src.kernel_args()
    if pair or (fuse and src.blk.shape[0] > 0):
        kernel_case(_rot_adj_blocks, mode, pair, vk)(ev, prm, args, src.blk, out)
    else:
        kernel_case(_rot_adj_plain, mode, fuse, use_w)(ev, prm, args, out)


@njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
def _k_rot_divdet(x, y, dt, w, Kinv, want_div, val, grad, gw, out):
    """Divergence (3.23 at any dt) or det J (3.24) of the rotation warp into ``val`` and,
    if ``grad`` (N, 3) has rows, their analytic omega-derivatives; if ``gw`` (N,) has rows,
    instead ``out[j] += sum_k gw[k] d val_k / d omega_j`` (events with ``gw[k] == 0`` skip
    the derivative: a trimmed mean's adjoint is zero off its selected pixels). Both are
    invariant under the affine map K, so they are computed in normalized coordinates,
    where the warp is ``X = pi(R v)`` with ``R = exp(dt omega^)``: det J = 1 / q_z^3
    (det R = 1), and since the flow is the rotational field
    ``F(X) = pi'(q) (omega x q)`` evaluated at the warped point,
    div f = tr(dF/dX dX/dx). Derivatives use dR/d omega_j = dt (J_l e_j)^ R."""
    wx, wy, wz, ww, mode = _rot_rates(dt, w)
    i00, i01, i02, i10, i11, i12 = rows01(Kinv)
    mode_g = 1 if grad.shape[0] > 0 else (2 if gw.shape[0] > 0 else 0)
    abuf = np.empty(BLOCK)
    bbuf = np.empty(BLOCK)
    cbuf = np.empty(BLOCK)
    n = x.shape[0]
    for k0 in range(0, n, BLOCK):
        k1 = min(k0 + BLOCK, n)
        rod_block(dt, k0, k1, ww, mode, abuf, bbuf, cbuf)
        _rot_divdet_block(x, y, dt, (wx, wy, wz, ww), (i00, i01, i02, i10, i11, i12),
                          want_div, mode_g, (k0, k1, abuf, bbuf, cbuf), val, grad, gw, out)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_divdet_block(x, y, dt, w, ki, want_div, mode_g, blk, val, grad, gw, out):
    """:func:`_k_rot_divdet` over the events ``k0 <= k < k1`` of ``blk = (k0, k1, abuf,
    bbuf, cbuf)`` (their Rodrigues coefficients in the buffers; ``w``: omega and
    |omega|^2; ``ki``: the first two rows of K^-1)."""
    wx, wy, wz, ww = w
    i00, i01, i02, i10, i11, i12 = ki
    k0, k1, abuf, bbuf, cbuf = blk
    for k in range(k0, k1):
        t = dt[k]
        a = abuf[k - k0]
        b = bbuf[k - k0]
        c = cbuf[k - k0]
        xn = i00 * x[k] + i01 * y[k] + i02
        yn = i10 * x[k] + i11 * y[k] + i12
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot_matrix(a, b, t, w)
        q0 = r00 * xn + r01 * yn + r02
        q1 = r10 * xn + r11 * yn + r12
        q2 = r20 * xn + r21 * yn + r22
        iz = 1.0 / q2
        X = q0 * iz
        Y = q1 * iz
        if not want_div:
            val[k] = iz * iz * iz
        r = (r00, r01, r10, r11, r20, r21)
        j, A = _rot_div_parts(X, Y, iz, r, wx, wy, wz)
        if want_div:
            val[k] = _trace22(A, j)
        if mode_g == 0 or (mode_g == 2 and gw[k] == 0.0):
            continue
        # columns of t J_l(t omega); every d(.)/d omega_j = (t J_l e_j) x (.)
        bt1 = b * t * t
        ct2 = c * t * t * t
        dg = t - ct2 * ww
        cx_ = ct2 * wx
        cy_ = ct2 * wy
        cz_ = ct2 * wz
        if not want_div:
            s3 = -3.0 * iz * iz * iz * iz
            g0 = s3 * ((cx_ * wx + dg) * q1 - (cy_ * wx + bt1 * wz) * q0)
            g1 = s3 * ((cx_ * wy - bt1 * wz) * q1 - (cy_ * wy + dg) * q0)
            g2 = s3 * ((cx_ * wz + bt1 * wy) * q1 - (cy_ * wz - bt1 * wx) * q0)
        else:
            q = (q0, q1, q2)
            g0 = _rot_div_dir((cx_ * wx + dg, cy_ * wx + bt1 * wz, cz_ * wx - bt1 * wy),
                              (1.0, 0.0, 0.0), wx, wy, q, X, Y, iz, r, j, A)
            g1 = _rot_div_dir((cx_ * wy - bt1 * wz, cy_ * wy + dg, cz_ * wy + bt1 * wx),
                              (0.0, 1.0, 0.0), wx, wy, q, X, Y, iz, r, j, A)
            g2 = _rot_div_dir((cx_ * wz + bt1 * wy, cy_ * wz - bt1 * wx, cz_ * wz + dg),
                              (0.0, 0.0, 1.0), wx, wy, q, X, Y, iz, r, j, A)
        if mode_g == 1:
            grad[k, 0] = g0
            grad[k, 1] = g1
            grad[k, 2] = g2
        else:
            f = gw[k]
            out[0] += f * g0
            out[1] += f * g1
            out[2] += f * g2


@njit(cache=True, error_model="numpy", inline="always")
def _rot_div_parts(X, Y, iz, r, wx, wy, wz):
    """``J = dX/dx_n`` and ``A = dF/dX`` (2x2 each, row by row) at the warped normalized
    point (X, Y) with ``iz = 1 / q_z`` and ``r`` = (R00, R01, R10, R11, R20, R21): the
    divergence is ``tr(A J)`` (:func:`_trace22`)."""
    r00, r01, r10, r11, r20, r21 = r
    j = ((r00 - X * r20) * iz, (r01 - X * r21) * iz, (r10 - Y * r20) * iz,
         (r11 - Y * r21) * iz)
    A = (2.0 * wy * X - wx * Y, -wz - wx * X, wz + wy * Y, wy * X - 2.0 * wx * Y)
    return j, A


@njit(cache=True, error_model="numpy", inline="always")
def _trace22(A, j):
    """``tr(A J)`` of two 2x2 matrices given row by row."""
    return A[0] * j[0] + A[1] * j[2] + A[2] * j[1] + A[3] * j[3]


@njit(cache=True, error_model="numpy", inline="always")
def _rot_div_dir(l, e, wx, wy, q, X, Y, iz, r, j, A):
    """Derivative of tr(A J) along omega_j, given ``l = t J_l(t omega) e_j`` and ``e = e_j``
    (3-tuples), the rotated point ``q``, its projection ``(X, Y)`` and ``iz = 1 / q_z``,
    ``r`` = (R00, R01, R10, R11, R20, R21), and ``j``, ``A`` of :func:`_rot_div_parts`."""
    e0, e1, e2 = e
    r00, r01, r10, r11, r20, r21 = r
    j00, j01, j10, j11 = j
    a00, a01, a10, a11 = A
    dq0, dq1, dq2 = cross(l, q)
    dX = (dq0 - X * dq2) * iz
    dY = (dq1 - Y * dq2) * iz
    # the columns of dR = l^ R
    dr00, dr10, dr20 = cross(l, (r00, r10, r20))
    dr01, dr11, dr21 = cross(l, (r01, r11, r21))
    dz = dq2 * iz
    dj00 = (dr00 - dX * r20 - X * dr20) * iz - j00 * dz
    dj01 = (dr01 - dX * r21 - X * dr21) * iz - j01 * dz
    dj10 = (dr10 - dY * r20 - Y * dr20) * iz - j10 * dz
    dj11 = (dr11 - dY * r21 - Y * dr21) * iz - j11 * dz
    da00 = 2.0 * (e1 * X + wy * dX) - e0 * Y - wx * dY
    da01 = -e2 - e0 * X - wx * dX
    da10 = e2 + e1 * Y + wy * dY
    da11 = e1 * X + wy * dX - 2.0 * (e0 * Y + wx * dY)
    return (da00 * j00 + da01 * j10 + da10 * j01 + da11 * j11
            + a00 * dj00 + a01 * dj10 + a10 * dj01 + a11 * dj11)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_value_event(X, Y, t, a, b, w, want_div):
    """Divergence (1/s) or det J of the rotation warp for the event whose warped normalized
    point is (X, Y), ``dt = t``, Rodrigues coefficients ``a, b`` of ``|t omega|``.

    With ``R = exp(t omega^)`` and ``q = R v``, ``v = K^-1 (x, y, 1)``: ``v = R^T q`` and
    ``v_z = 1`` give ``1 / q_z = R_02 X + R_12 Y + R_22``, so neither the event nor a
    division is needed: det J = (1 / q_z)^3, and div f = tr(A J) with ``J = dX/dv``
    (rows ``(R_i. - X_i R_2.) / q_z``) and ``A`` the derivative of the rotational flow at
    (X, Y) (the formulas of :func:`_k_rot_divdet`; ``w``: omega and |omega|^2)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot_matrix(a, b, t, w)
    iz = r02 * X + r12 * Y + r22
    if not want_div:
        return iz * iz * iz
    j, A = _rot_div_parts(X, Y, iz, (r00, r01, r10, r11, r20, r21), w[0], w[1], w[2])
    return _trace22(A, j)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_finish(v, want_div, T, d, fac, k):
    """d_k = divergence times T, or |det J| - 1, and fac_k = d(d_k)/d(v)."""
    if want_div:
        d[k] = v * T
        fac[k] = T
    else:
        d[k] = abs(v) - 1.0
        fac[k] = 1.0 if v >= 0.0 else -1.0


def _rot_values_case(mode, want_div):
    """:func:`rot_values` in series mode ``mode`` for the divergence or det J: one case,
    compiled on first use (:func:`evmotion.jitcache.kernel_case`)."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def rot_values(xw, yw, dt, w, Kinv, T, d, fac):
        wx, wy, wz = w[0], w[1], w[2]
        ww = wx * wx + wy * wy + wz * wz
        w4 = (wx, wy, wz, ww)
        i00, i01, i02, i10, i11, i12 = rows01(Kinv)
        for k in range(xw.shape[0]):
            t = dt[k]
            a, b, _ = rod_mode(t * t * ww, mode)
            v = _rot_value_event(i00 * xw[k] + i01 * yw[k] + i02, i10 * xw[k] + i11 * yw[k]
                                 + i12, t, a, b, w4, want_div)
            _rot_finish(v, want_div, T, d, fac, k)

    return rot_values


def rot_values(xw, yw, dt, w, Kinv, want_div, T, d, fac):
    """Per-event d_k (divergence times T, or |det J| - 1) and fac_k of the rotation warp
    from the warped pixels ``xw, yw`` (one pass; the loop of each series mode has no
    branch, so it vectorizes like the warp's)."""
    kernel_case(_rot_values_case, rot_series_mode(dt, w), bool(want_div))(
        xw, yw, dt, w, Kinv, T, d, fac)


def _rot_warp_values_case(mode, want_div, raw=False):
    """:func:`rot_warp_values` in series mode ``mode`` for the divergence or det J: one
    case, compiled on first use; ``raw`` stores the value itself in ``d`` (``T`` and
    ``fac`` unused): the value-only :meth:`RotationWarp.jacobian_det` and
    :meth:`~RotationWarp.divergence`, which compile this small case instead of
    :func:`_k_rot_divdet`'s derivatives (6 s from an empty cache, each ``egomotion``
    run's collapse check)."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def rot_warp_values(x, y, dt, w, Kmat, Kinv, T, xw, yw, d, fac):
        wx, wy, wz = w[0], w[1], w[2]
        ww = wx * wx + wy * wy + wz * wz
        w4 = (wx, wy, wz, ww)
        k00, k01, k02, k10, k11, k12 = rows01(Kmat)
        ki = rows01(Kinv)
        for k in range(x.shape[0]):
            t = dt[k]
            a, b, _ = rod_mode(t * t * ww, mode)
            X, Y = _rot_warp_norm(x[k], y[k], t, a, b, (wx, wy, wz), ki)
            xw[k] = k00 * X + k01 * Y + k02
            yw[k] = k10 * X + k11 * Y + k12
            v = _rot_value_event(X, Y, t, a, b, w4, want_div)
            if raw:
                d[k] = v
            else:
                _rot_finish(v, want_div, T, d, fac, k)

    return rot_warp_values


def rot_warp_values(x, y, dt, w, Kmat, Kinv, want_div, T, xw, yw, d, fac):
    """The rotation warp (``xw, yw``, as :meth:`~evmotion.core.warps.Warp.warp_into`) and
    the per-event ``d``, ``fac`` of :func:`rot_values` in one pass: each event's
    Rodrigues coefficients and warped normalized point serve both (no reload of the warped
    pixels, no second series)."""
    kernel_case(_rot_warp_values_case, rot_series_mode(dt, w), bool(want_div))(
        x, y, dt, w, Kmat, Kinv, T, xw, yw, d, fac)


class RotationWarp(FusedAdjoint, Warp):
    """3-DOF camera rotation (3.22): ``x'_n ~ exp(dt omega^) x_n`` in normalized
    coordinates ``x_n = K^-1 (x, y, 1)``; theta = omega (wx, wy, wz) in rad/s, camera frame
    x right, y down, z forward. div f = 3 (x_n wy - y_n wx) at dt = 0 (3.23)."""

    _blocked = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        kernel_case(_rot_warp_case, rot_series_mode(dt, th), bool(jac))(
            x, y, dt, th, self.K, self.K_inv, xw, yw, jx, jy)

    def _adj(self, x, y, dt, xw, yw, th, src, out):
        K, Ki = self.K, self.K_inv
        prm = np.array([th[0], th[1], th[2], K[0, 0], K[0, 1], K[1, 0], K[1, 1], Ki[0, 0],
                        Ki[0, 1], Ki[0, 2], Ki[1, 0], Ki[1, 1], Ki[1, 2]])
        _rotation_adj((x, y, dt, xw, yw), prm, src, out)

    def _divdet(self, x, y, dt, theta, want_div, grad):
        x, y, dt = self.check_events(x, y, dt)
        th = self.check_theta(theta)
        n = x.shape[0]
        val = np.empty(n)
        if not grad:
            kernel_case(_rot_warp_values_case, rot_series_mode(dt, th), bool(want_div), True)(
                x, y, dt, th, self.K, self.K_inv, 1.0, np.empty(n), np.empty(n), val, EMPTY1)
            return val
        g = np.empty((n, 3))
        _k_rot_divdet(x, y, dt, th, self.K_inv, want_div, val, g, EMPTY1, EMPTY1)
        return val, g

    def divergence(self, x, y, dt, theta, grad: bool = False):
        """:meth:`Warp.divergence` with analytic (not complex-step) omega-derivatives."""
        return self._divdet(x, y, dt, theta, True, grad)

    def jacobian_det(self, x, y, dt, theta, grad: bool = False):
        """:meth:`Warp.jacobian_det` with analytic omega-derivatives."""
        return self._divdet(x, y, dt, theta, False, grad)

    def values_from_warped(self, xw, yw, dt, th, want_div, T, d, fac) -> None:
        """Per-event collapse values from the warped pixels ``xw, yw`` (:func:`rot_values`):
        ``d`` = divergence times ``T`` or ``|det J| - 1``, ``fac`` = ``dd/d(raw value)``."""
        rot_values(xw, yw, dt, th, self.K_inv, want_div, T, d, fac)

    def warp_values_into(self, x, y, dt, th, want_div, T, xw, yw, d, fac) -> None:
        """:meth:`warp_into` and :meth:`values_from_warped` in one pass
        (:func:`rot_warp_values`)."""
        rot_warp_values(x, y, dt, th, self.K, self.K_inv, want_div, T, xw, yw, d, fac)

    def values_vjp(self, x, y, dt, th, want_div, gw, out, work) -> None:
        """``out += sum_k gw[k] d v_k / d omega`` (3,) with ``v_k`` the raw divergence (or
        det J) of event ``k`` (events with ``gw[k] == 0`` skipped); ``work`` (N,) is
        overwritten."""
        _k_rot_divdet(x, y, dt, th, self.K_inv, want_div, work, EMPTY2, gw, out)
