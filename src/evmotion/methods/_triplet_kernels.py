"""Numba kernels of triplet matching (thesis ch. 5, Algorithm 1).

State layout (one slot array per polarity): ``ts[c, y, x, s]`` holds the timestamps of the
latest ``depth`` events of polarity ``c`` at pixel ``(x, y)``, as int32 microseconds
relative to a base time, in a ring indexed by ``head[c, y, x]``. Empty slots hold
``EMPTY``. Only timestamps are needed: the triplet condition (5.2) fixes the pixels of the
2nd and 3rd events once the neighbour offset is chosen, so the index maps of Algorithm 1
reduce to "which past events sit at pixel x_k + d (and x_k + 2d) within the delay window".
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EMPTY = np.int32(-(2**31) + 1)
# Relative timestamps must stay far from the int32 limits; rebase before this span.
REBASE_SPAN_US = 2**30
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, inline="always")
def _gauss(t: float, mean: float, sigma_us: float) -> float:
    # Density per second: the 1/sigma factor makes short-delta triplets count more.
    z = (t - mean) / sigma_us
    return math.exp(-0.5 * z * z) * _INV_SQRT_2PI / (sigma_us * 1e-6)


@njit(cache=True)
def triplet_kernel(x, y, t, p, base, ts, head, offsets, dt_us, tau_us, quadruple,
                   out_vx, out_vy, out_n, out_valid, stats):
    """Process events in order, writing one flow per event and updating the ring state.

    ``x, y`` int32 pixels, ``t`` int64 µs absolute, ``p`` uint8; ``base`` the µs subtracted
    from ``t`` before it is stored. ``stats[0]`` counts evictions of events that could still
    take part in a future triplet (answers then may differ from unbounded Algorithm 1).
    """
    h = ts.shape[1]
    w = ts.shape[2]
    depth = ts.shape[3]
    n_off = offsets.shape[0]
    horizon = (3 if quadruple else 2) * (dt_us + tau_us)
    for k in range(t.shape[0]):
        xk = x[k]
        yk = y[k]
        c = p[k]
        tk = t[k] - base
        lo_i = tk - tau_us - dt_us
        hi_i = tk - tau_us
        sw = 0.0
        swx = 0.0
        swy = 0.0
        n = 0
        for o in range(n_off):
            ox = offsets[o, 0]
            oy = offsets[o, 1]
            xi = xk + ox
            yi = yk + oy
            xj = xi + ox
            yj = yi + oy
            if xj < 0 or xj >= w or yj < 0 or yj >= h:
                continue
            if quadruple:
                xl = xj + ox
                yl = yj + oy
                if xl < 0 or xl >= w or yl < 0 or yl >= h:
                    continue
            for s in range(depth):
                ti = np.int64(ts[c, yi, xi, s])
                if ti < lo_i or ti > hi_i:
                    continue
                delta = float(tk - ti)
                lo_j = ti - tau_us - dt_us
                hi_j = ti - tau_us
                for s2 in range(depth):
                    tj = np.int64(ts[c, yj, xj, s2])
                    if tj < lo_j or tj > hi_j:
                        continue
                    wj = _gauss(float(tj), float(ti) - delta, delta)
                    if not quadruple:
                        # v_T = (x_j - x_k) / (t_j - t_k), in px/s.
                        inv = 1e6 / float(tk - tj)
                        sw += wj
                        swx += wj * (2 * ox) * -inv
                        swy += wj * (2 * oy) * -inv
                        n += 1
                        continue
                    lo_l = tj - tau_us - dt_us
                    hi_l = tj - tau_us
                    for s3 in range(depth):
                        tl = np.int64(ts[c, yl, xl, s3])
                        if tl < lo_l or tl > hi_l:
                            continue
                        wq = wj * _gauss(float(tl), float(tj) - delta, delta)
                        inv = 1e6 / float(tk - tl)
                        sw += wq
                        swx += wq * (3 * ox) * -inv
                        swy += wq * (3 * oy) * -inv
                        n += 1
        out_n[k] = n
        if n > 0 and sw > 0.0:
            out_vx[k] = swx / sw
            out_vy[k] = swy / sw
            out_valid[k] = True
        else:
            out_vx[k] = 0.0
            out_vy[k] = 0.0
            out_valid[k] = False
        hd = head[c, yk, xk]
        old = np.int64(ts[c, yk, xk, hd])
        if old != EMPTY and old >= tk - horizon:
            stats[0] += 1
        ts[c, yk, xk, hd] = np.int32(tk)
        hd += 1
        if hd == depth:
            hd = 0
        head[c, yk, xk] = hd


@njit(cache=True)
def rebase_kernel(ts, shift, keep_after):
    """Subtract ``shift`` µs from every stored time; drop those older than ``keep_after``."""
    flat = ts.reshape(-1)
    for i in range(flat.shape[0]):
        v = np.int64(flat[i])
        if v == EMPTY:
            continue
        v -= shift
        flat[i] = np.int32(v) if v >= keep_after else EMPTY


@njit(cache=True)
def voxel_accumulate(x, y, t, vx, vy, valid, t0, t1, n_bins, acc, cnt):
    """Add the valid per-event flows of events with ``t0 <= t < t1`` into time-bin voxels.

    ``acc`` (n_bins, H, W, 2) float64 sums, ``cnt`` (n_bins, H, W) int64 counts.
    """
    span = float(t1 - t0)
    for k in range(t.shape[0]):
        if not valid[k]:
            continue
        tk = t[k]
        if tk < t0 or tk >= t1:
            continue
        b = int((tk - t0) * n_bins / span)
        if b >= n_bins:
            b = n_bins - 1
        acc[b, y[k], x[k], 0] += vx[k]
        acc[b, y[k], x[k], 1] += vy[k]
        cnt[b, y[k], x[k]] += 1
