"""Plain-numpy references of the BOS kernels (:mod:`evmotion.methods.bos_kernels`), for tests.

Written for clarity, not speed: dense interpolation matrices, whole-array expressions, the
objective (6.10) with the same smooth L1 (Charbonnier) as the kernels.
"""

from __future__ import annotations

import numpy as np

__all__ = ["interp_matrix", "objective_numpy", "upsample_numpy"]


def interp_matrix(i0: np.ndarray, frac: np.ndarray, n_in: int) -> np.ndarray:
    """Dense (n_out, n_in) matrix of the bilinear interpolation ``(i0, frac)``."""
    a = np.zeros((len(i0), n_in))
    rows = np.arange(len(i0))
    np.add.at(a, (rows, i0), 1.0 - frac)
    np.add.at(a, (rows, np.minimum(i0 + 1, n_in - 1)), frac)
    return a


def upsample_numpy(x: np.ndarray, iy, fy, ix, fx) -> np.ndarray:
    """``A_y x[c] A_x^T`` for each channel of x (c, nh, nw)."""
    ay = interp_matrix(iy, fy, x.shape[1])
    ax = interp_matrix(ix, fx, x.shape[2])
    return np.stack([ay @ xc @ ax.T for xc in x])


def _charb(r, eps):
    return np.sqrt(r * r + eps * eps) - eps


def objective_numpy(fields, gimg, meas, weight, s_meas, k, lam_tv, lam_p, eps_d, eps_r,
                    normalized, use_p):
    """(total, data, tv, p) of :func:`evmotion.methods.bos_kernels.objective_grad`."""
    du, dv, pu, pv = (np.asarray(f, dtype=np.float64) for f in fields)
    gx, gy, hxx, hxy, hyy = gimg
    h, w = gx.shape
    if use_p:
        sx = gx + hxx * pu + hxy * pv
        sy = gy + hxy * pu + hyy * pv
    else:
        sx, sy = gx, gy
    pred = -(sx * du + sy * dv)
    if normalized:
        r = pred / np.sqrt(np.mean(pred ** 2) + 1e-30) - meas / s_meas
    else:
        r = (pred - meas) / s_meas
    data = _charb(r, eps_d).mean()
    tv = 0.0
    for f in (du, dv):
        tv += (weight[:, :-1] * _charb(np.diff(f, axis=1) / k, eps_r)).sum()
        tv += (weight[:-1, :] * _charb(np.diff(f, axis=0) / k, eps_r)).sum()
    tv /= h * w
    preg = (_charb(pu, eps_r) + _charb(pv, eps_r)).mean() if use_p else 0.0
    return data + lam_tv * tv + lam_p * preg, data, tv, preg
