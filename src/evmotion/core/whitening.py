"""Whitening of warped events: the baseline of Nunes & Demiris the thesis compares its
collapse penalties with (Sec. 3.6). Not a penalty: the warped events are normalized to zero
mean and identity covariance (an SVD of the event covariance) before the objective."""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core.warps.common import EMPTY2
from evmotion.errors import EmptyWindowError, ParameterError

__all__ = ["whiten"]

def whiten(xw: np.ndarray, yw: np.ndarray, jx: np.ndarray | None = None,
           jy: np.ndarray | None = None, *, center: tuple[float, float] = (0.0, 0.0),
           scale: float = 1.0):
    """Whiten warped events (the baseline of Nunes & Demiris compared in Sec. 3.6).

    ``z_k = center + scale * C^(-1/2) (p_k - mu)`` with ``mu`` the mean and ``C`` the
    covariance of the warped positions ``p_k = (xw_k, yw_k)`` (eigen-decomposition of the
    2x2 covariance, i.e. an SVD of the centred events). ``center`` and ``scale`` (pixels)
    put the whitened cloud back on an image grid for an IWE objective (e.g. the image
    centre and the spread of the unwarped events, which do not depend on theta).

    Parameters
    ----------
    xw, yw : array (N,)
        Warped events (pixels).
    jx, jy : array (N, P), optional
        Their parameter Jacobians; if given, those of the whitened events are returned.

    Returns
    -------
    zx, zy : array (N,), and ``zjx, zjy`` (N, P) if Jacobians were given.

    Examples
    --------
    >>> zx, zy = whiten(np.array([0.0, 2.0, 0.0, 2.0]), np.array([0.0, 0.0, 4.0, 4.0]))
    >>> zx.tolist(), zy.tolist()
    ([-1.0, 1.0, -1.0, 1.0], [-1.0, -1.0, 1.0, 1.0])
    """
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    n = xw.shape[0]
    if n < 3:
        raise EmptyWindowError(f"whitening needs at least 3 events, got {n}")
    jac = jx is not None and jy is not None
    if jac:
        jx = np.ascontiguousarray(jx, dtype=np.float64)
        jy = np.ascontiguousarray(jy, dtype=np.float64)
        if jx.shape != jy.shape or jx.ndim != 2 or jx.shape[0] != n:
            raise ParameterError(f"jx, jy must be ({n}, P) like the events, got {jx.shape} "
                                 f"and {jy.shape}")
    else:
        jx = jy = EMPTY2
    P = jx.shape[1]
    mu = np.empty(2)
    C = np.empty((2, 2))
    mj = np.empty((2, P))
    _k_whiten_stats(xw, yw, jx, jy, mu, C, mj)
    lam, V = np.linalg.eigh(C)
    if lam[0] <= 1e-12 * max(lam[1], 1e-300):
        raise EmptyWindowError("whitening: the warped events are collinear (singular "
                               "covariance); cannot whiten")
    f = lam ** -0.5
    # C^(-1/2) = V diag(f) V^T, written out (2 x 2: no BLAS call)
    Cm = np.array([[V[0, 0] * f[0] * V[0, 0] + V[0, 1] * f[1] * V[0, 1],
                    V[0, 0] * f[0] * V[1, 0] + V[0, 1] * f[1] * V[1, 1]],
                   [V[1, 0] * f[0] * V[0, 0] + V[1, 1] * f[1] * V[0, 1],
                    V[1, 0] * f[0] * V[1, 0] + V[1, 1] * f[1] * V[1, 1]]])
    # Daleckii-Krein: d f(C) = V (F o (V^T dC V)) V^T, F_ij divided differences of f(l)=l^-1/2
    if abs(lam[1] - lam[0]) > 1e-12 * lam[1]:
        off = (f[1] - f[0]) / (lam[1] - lam[0])
    else:
        off = -0.5 * lam[0] ** -1.5
    F = np.array([[-0.5 * lam[0] ** -1.5, off], [off, -0.5 * lam[1] ** -1.5]])
    zx = np.empty(n)
    zy = np.empty(n)
    zjx = np.empty((n, P))
    zjy = np.empty((n, P))
    _k_whiten_apply(xw, yw, jx, jy, mu, mj, np.ascontiguousarray(V), F, Cm, float(center[0]),
                    float(center[1]), float(scale), zx, zy, zjx, zjy)
    if not jac:
        return zx, zy
    return zx, zy, zjx, zjy


@njit(cache=True, error_model="numpy")
def _k_whiten_stats(xw, yw, jx, jy, mu, C, mj):
    """Means of the warped events ``mu`` (2,) and of their Jacobians ``mj`` (2, P), and
    their covariance ``C`` (2, 2) (centred, divided by N)."""
    n = xw.shape[0]
    P = jx.shape[1]
    sx = 0.0
    sy = 0.0
    for k in range(n):
        sx += xw[k]
        sy += yw[k]
    mx = sx / n
    my = sy / n
    cxx = 0.0
    cxy = 0.0
    cyy = 0.0
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        cxx += a * a
        cxy += a * b
        cyy += b * b
    mu[0] = mx
    mu[1] = my
    C[0, 0] = cxx / n
    C[0, 1] = cxy / n
    C[1, 0] = cxy / n
    C[1, 1] = cyy / n
    for j in range(P):
        mj[0, j] = 0.0
        mj[1, j] = 0.0
    for k in range(jx.shape[0]):
        for j in range(P):
            mj[0, j] += jx[k, j]
            mj[1, j] += jy[k, j]
    for j in range(P):
        mj[0, j] /= n
        mj[1, j] /= n


@njit(cache=True, error_model="numpy")
def _k_whiten_apply(xw, yw, jx, jy, mu, mj, V, F, Cm, c0, c1, scale, zx, zy, zjx, zjy):
    """Whitened events and, if ``jx`` has rows, their parameter Jacobians (see
    :func:`whiten`): one pass for the covariance derivatives ``dC_j``, one for the
    outputs."""
    n = xw.shape[0]
    P = jx.shape[1]
    mx = mu[0]
    my = mu[1]
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        zx[k] = c0 + scale * (Cm[0, 0] * a + Cm[0, 1] * b)
        zy[k] = c1 + scale * (Cm[1, 0] * a + Cm[1, 1] * b)
    if jx.shape[0] == 0:
        return
    # S_j = sum_k c_k dc_kj^T; dC_j = (S_j + S_j^T) / n
    S = np.zeros((P, 2, 2))
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        for j in range(P):
            u = jx[k, j] - mj[0, j]
            v = jy[k, j] - mj[1, j]
            S[j, 0, 0] += a * u
            S[j, 0, 1] += a * v
            S[j, 1, 0] += b * u
            S[j, 1, 1] += b * v
    D = np.empty((P, 2, 2))
    for j in range(P):
        d00 = 2.0 * S[j, 0, 0] / n
        d01 = (S[j, 0, 1] + S[j, 1, 0]) / n
        d11 = 2.0 * S[j, 1, 1] / n
        # M = F o (V^T dC V), then dCm = V M V^T
        m = np.empty((2, 2))
        for p in range(2):
            for q in range(2):
                t = (V[0, p] * (d00 * V[0, q] + d01 * V[1, q])
                     + V[1, p] * (d01 * V[0, q] + d11 * V[1, q]))
                m[p, q] = F[p, q] * t
        for p in range(2):
            for q in range(2):
                D[j, p, q] = (V[p, 0] * (m[0, 0] * V[q, 0] + m[0, 1] * V[q, 1])
                              + V[p, 1] * (m[1, 0] * V[q, 0] + m[1, 1] * V[q, 1]))
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        for j in range(P):
            u = jx[k, j] - mj[0, j]
            v = jy[k, j] - mj[1, j]
            zjx[k, j] = scale * (D[j, 0, 0] * a + D[j, 0, 1] * b + Cm[0, 0] * u + Cm[0, 1] * v)
            zjy[k, j] = scale * (D[j, 1, 0] * a + D[j, 1, 1] * b + Cm[1, 0] * u + Cm[1, 1] * v)
