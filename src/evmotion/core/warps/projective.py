"""The affine (A.47) and homography (A.1) warps: forward kernels with their Jacobians, and
the divergence and det J of ``x' ~ (Id + dt G)^-1 x`` (complex, for complex-step
derivatives). No fused adjoint: CMax chains their gradient through stored Jacobians."""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core.warps.base import Warp
from evmotion.core.warps.common import FAST_FINITE

__all__ = ["AffineWarp", "HomographyWarp"]

@njit(cache=True, error_model="numpy", inline="always")
def _inv33(h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """The inverse of the 3x3 matrix ``h`` (entries row by row) by cofactors, its nine
    entries row by row, and ``1 / det h`` (real or complex: complex-step derivatives)."""
    c00 = h11 * h22 - h12 * h21
    c01 = h02 * h21 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    idet = 1.0 / (h00 * c00 + h10 * c01 + h20 * c02)
    return ((c00 * idet, c01 * idet, c02 * idet,
             (h12 * h20 - h10 * h22) * idet, (h00 * h22 - h02 * h20) * idet,
             (h02 * h10 - h00 * h12) * idet,
             (h10 * h21 - h11 * h20) * idet, (h01 * h20 - h00 * h21) * idet,
             (h00 * h11 - h01 * h10) * idet), idet)


@njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
def _k_affine(x, y, dt, th, cx, cy, xw, yw, jx, jy, jac):
    vx, vy, g11, g12, g21, g22 = th[0], th[1], th[2], th[3], th[4], th[5]
    if not jac:
        for k in range(x.shape[0]):
            w0, w1, _, _, _, _ = _affine_event(x[k], y[k], dt[k], vx, vy, g11, g12, g21, g22,
                                               cx, cy)
            xw[k] = cx + w0
            yw[k] = cy + w1
        return
    # flat views: strided stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        w0, w1, a00, a01, a10, a11 = _affine_event(x[k], y[k], t, vx, vy, g11, g12, g21, g22,
                                                   cx, cy)
        xw[k] = cx + w0
        yw[k] = cy + w1
        r = 6 * k
        jxf[r] = -t * a00
        jyf[r] = -t * a10
        jxf[r + 1] = -t * a01
        jyf[r + 1] = -t * a11
        jxf[r + 2] = -t * a00 * w0
        jyf[r + 2] = -t * a10 * w0
        jxf[r + 3] = -t * a00 * w1
        jyf[r + 3] = -t * a10 * w1
        jxf[r + 4] = -t * a01 * w0
        jyf[r + 4] = -t * a11 * w0
        jxf[r + 5] = -t * a01 * w1
        jyf[r + 5] = -t * a11 * w1


@njit(cache=True, error_model="numpy")
def _affine_event(x, y, t, vx, vy, g11, g12, g21, g22, cx, cy):
    """Centred warped point ``(w0, w1)`` of one event and ``A(t)^-1`` (4 entries)."""
    a00 = 1.0 + t * g22
    a01 = -t * g12
    a10 = -t * g21
    a11 = 1.0 + t * g11
    idet = 1.0 / (a00 * a11 - a01 * a10)
    a00 *= idet
    a01 *= idet
    a10 *= idet
    a11 *= idet
    u = x - cx - t * vx
    v = y - cy - t * vy
    return a00 * u + a01 * v, a10 * u + a11 * v, a00, a01, a10, a11


@njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
def _k_homography(x, y, dt, th, cx, cy, xw, yw, jx, jy, jac):
    inv = np.empty((3, 3))
    q = np.empty(3)
    for k in range(x.shape[0]):
        t = dt[k]
        h00 = 1.0 + t * th[0]
        h01 = t * th[1]
        h02 = t * th[2]
        h10 = t * th[3]
        h11 = 1.0 + t * th[4]
        h12 = t * th[5]
        h20 = t * th[6]
        h21 = t * th[7]
        h22 = 1.0
        m, _ = _inv33(h00, h01, h02, h10, h11, h12, h20, h21, h22)
        for i in range(3):
            for j in range(3):
                inv[i, j] = m[3 * i + j]
        u = x[k] - cx
        v = y[k] - cy
        for i in range(3):
            q[i] = inv[i, 0] * u + inv[i, 1] * v + inv[i, 2]
        iz = 1.0 / q[2]
        ox = q[0] * iz
        oy = q[1] * iz
        xw[k] = cx + ox
        yw[k] = cy + oy
        if jac:
            # d(H^-1)/dg_ij = -t H^-1 E_ij H^-1, so dq = -t inv[:, i] q_j
            for p in range(8):
                i = p // 3
                j = p % 3
                s = -t * q[j]
                d0 = s * inv[0, i]
                d1 = s * inv[1, i]
                d2 = s * inv[2, i]
                jx[k, p] = (d0 - ox * d2) * iz
                jy[k, p] = (d1 - oy * d2) * iz


@njit(cache=True, error_model="numpy")
def _k_hom_divdet(x, y, dt, G, cx, cy, div, det):
    """Divergence and det J of x' ~ (Id + dt G)^-1 x in centred pixels (both invariant under
    the centring), complex so that a complex G gives complex-step derivatives:
    M = H^-1, dM/dt = -M G M."""
    M = np.empty((3, 3), dtype=np.complex128)
    for k in range(x.shape[0]):
        t = dt[k]
        h00 = 1.0 + t * G[0, 0]
        h01 = t * G[0, 1]
        h02 = t * G[0, 2]
        h10 = t * G[1, 0]
        h11 = 1.0 + t * G[1, 1]
        h12 = t * G[1, 2]
        h20 = t * G[2, 0]
        h21 = t * G[2, 1]
        h22 = 1.0 + t * G[2, 2]
        m, idet = _inv33(h00, h01, h02, h10, h11, h12, h20, h21, h22)
        for i in range(3):
            for j in range(3):
                M[i, j] = m[3 * i + j]
        u = x[k] - cx
        v = y[k] - cy
        q0 = M[0, 0] * u + M[0, 1] * v + M[0, 2]
        q1 = M[1, 0] * u + M[1, 1] * v + M[1, 2]
        q2 = M[2, 0] * u + M[2, 1] * v + M[2, 2]
        # p = dM/dt x = -M G q
        g0 = G[0, 0] * q0 + G[0, 1] * q1 + G[0, 2] * q2
        g1 = G[1, 0] * q0 + G[1, 1] * q1 + G[1, 2] * q2
        g2 = G[2, 0] * q0 + G[2, 1] * q1 + G[2, 2] * q2
        p0 = -(M[0, 0] * g0 + M[0, 1] * g1 + M[0, 2] * g2)
        p2 = -(M[2, 0] * g0 + M[2, 1] * g1 + M[2, 2] * g2)
        p1 = -(M[1, 0] * g0 + M[1, 1] * g1 + M[1, 2] * g2)
        iq = 1.0 / q2
        iq2 = iq * iq
        d = 0.0j
        for i in range(2):
            a0 = M[0, i]
            a1 = M[1, i]
            a2 = M[2, i]
            # b = dM/dt e_i = -M G a
            e0 = G[0, 0] * a0 + G[0, 1] * a1 + G[0, 2] * a2
            e1 = G[1, 0] * a0 + G[1, 1] * a1 + G[1, 2] * a2
            e2 = G[2, 0] * a0 + G[2, 1] * a1 + G[2, 2] * a2
            bi = -(M[i, 0] * e0 + M[i, 1] * e1 + M[i, 2] * e2)
            b2 = -(M[2, 0] * e0 + M[2, 1] * e1 + M[2, 2] * e2)
            qi = q0 if i == 0 else q1
            pi = p0 if i == 0 else p1
            ai = a0 if i == 0 else a1
            d += (bi * iq - (pi * a2 + ai * p2 + qi * b2) * iq2
                  + 2.0 * qi * p2 * a2 * iq2 * iq)
        div[k] = d
        det[k] = idet * iq2 * iq


def _hom_divdet(warp, x, y, dt, G):
    n = x.shape[0]
    div = np.empty(n, dtype=np.complex128)
    det = np.empty(n, dtype=np.complex128)
    _k_hom_divdet(x, y, dt, G.astype(np.complex128), warp.center[0], warp.center[1], div, det)
    return div, det


class AffineWarp(Warp):
    """6-DOF affine (A.47): ``x' = c + A^-1(dt)(x - c - dt v)`` with ``A(dt) = Id + dt G``;
    theta = (vx, vy [px/s], g11, g12, g21, g22 [1/s])."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_affine(x, y, dt, th, self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _G(self, th):
        z = 0 * th[0]
        return np.array([[th[2], th[3], th[0]], [th[4], th[5], th[1]], [z, z, z]])

    def _div(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[0]

    def _det(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[1]


class HomographyWarp(Warp):
    """8-DOF homography (A.1): ``x' ~ H(dt)^-1 x`` in centred pixels, trajectory
    ``H(dt) = Id + dt G`` with ``G = [[g11, g12, g13], [g21, g22, g23], [g31, g32, 0]]``
    (g13, g23 in px/s; g31, g32 in 1/(px s); the others in 1/s)."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_homography(x, y, dt, th, self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _G(self, th):
        return np.array([[th[0], th[1], th[2]], [th[3], th[4], th[5]], [th[6], th[7], 0 * th[0]]])

    def _div(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[0]

    def _det(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[1]
