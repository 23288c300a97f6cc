"""Numba kernels of triplet matching (thesis ch. 5, Algorithm 1).

State layout (one slot array per polarity): ``ts[c, y, x, s]`` holds the timestamps of the
latest ``depth`` events of polarity ``c`` at pixel ``(x, y)``, as int32 microseconds
relative to a base time. Empty slots hold
``EMPTY``. Only timestamps are needed: the triplet condition (5.2) fixes the pixels of the
2nd and 3rd events once the neighbour offset is chosen, so the index maps of Algorithm 1
reduce to "which past events sit at pixel x_k + d (and x_k + 2d) within the delay window".
Slots are ordered newest first (an insert shifts the ring by one slot).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EMPTY = np.int32(-(2**31) + 1)
# Relative timestamps must stay far from the int32 limits; rebase before this span.
REBASE_SPAN_US = 2**30
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


_LOG2E = 1.0 / math.log(2.0)
_LN2 = math.log(2.0)
# Taylor coefficients of exp(-u), u in [0, ln 2), highest first: truncation error < 1e-9.
_C = [(-1.0) ** i / math.factorial(i) for i in range(11)][::-1]
C0, C1, C2, C3, C4, C5, C6, C7, C8, C9, C10 = _C


@njit(cache=True, fastmath=True)
def _weights(m, ab, nb, db, sxb, syb, pb, bits, scale):
    """Vote sums of ``m`` collected triplets, in branch-free loops the compiler vectorizes.

    exp(-a) = 2^-n * exp(-u), u = (a log2 e - n) ln 2 in [0, ln 2): a polynomial for the
    second factor and the exponent bits of a float64 for the first.
    """
    for q in range(m):
        y = ab[q] * _LOG2E
        n = np.int64(y)
        u = (y - n) * _LN2
        pb[q] = ((((((((((C0 * u + C1) * u + C2) * u + C3) * u + C4) * u + C5) * u + C6) * u
                    + C7) * u + C8) * u + C9) * u + C10)
        bits[q] = (1023 - n) << 52
    sw = 0.0
    swx = 0.0
    swy = 0.0
    for q in range(m):
        e = pb[q] * scale[q] * nb[q]
        sw += e
        r = e / db[q]
        swx += r * sxb[q]
        swy += r * syb[q]
    return sw, swx, swy


# Not fastmath here: its reciprocal shortcut overflows when every weight is subnormal.
@njit(cache=True)
def triplet_kernel(x, y, t, p, base, ts, offsets, dt_us, tau_us, quadruple,
                   out_vx, out_vy, out_n, out_valid, stats):
    """Process events in order, writing one flow per event and updating the ring state.

    ``x, y`` int32 pixels, ``t`` int64 µs absolute, ``p`` uint8; ``base`` the µs subtracted
    from ``t`` before it is stored. Each ring ``ts[c, y, x, :]`` is kept newest first, so a
    scan skips the too-recent slots and stops at the first too-old (or empty) one. The
    matches of one event are collected first and weighed in one vectorized pass.
    ``stats[0]`` counts evictions of events that could still take part in a future triplet
    (answers then may differ from unbounded Algorithm 1).
    """
    h = ts.shape[1]
    w = ts.shape[2]
    depth = ts.shape[3]
    flat = ts.reshape(-1)
    n_off = offsets.shape[0]
    horizon = (3 if quadruple else 2) * (dt_us + tau_us)
    cap = n_off * depth * depth * (depth if quadruple else 1)
    ab = np.empty(cap)   # exponent a of the Gaussian weight exp(-a)
    nb = np.empty(cap)   # its normalization (1/delta per Gaussian, per second)
    db = np.empty(cap)   # t_k - t_j (or t_k - t_l), µs
    sxb = np.empty(cap)  # -(x_j - x_k) * 1e6, so that v = sx / (t_k - t_j)
    syb = np.empty(cap)
    pb = np.empty(cap)
    bits = np.empty(cap, np.int64)
    scale = bits.view(np.float64)
    for k in range(t.shape[0]):
        xk = x[k]
        yk = y[k]
        plane = p[k] * h
        tk = t[k] - base
        lo_i = tk - tau_us - dt_us
        hi_i = tk - tau_us
        rk = ((plane + yk) * w + xk) * depth
        m = 0
        tail_w = 0.0
        tail_x = 0.0
        tail_y = 0.0
        tail_n = 0
        for o in range(n_off):
            ox = offsets[o, 0]
            oy = offsets[o, 1]
            xj = xk + 2 * ox
            yj = yk + 2 * oy
            if xj < 0 or xj >= w or yj < 0 or yj >= h:
                continue
            if quadruple:
                xl = xj + ox
                yl = yj + oy
                if xl < 0 or xl >= w or yl < 0 or yl >= h:
                    continue
            step_o = (oy * w + ox) * depth
            ri = rk + step_o
            rj = ri + step_o
            rl = rj + step_o
            stp = 3.0 if quadruple else 2.0
            sx = -stp * ox * 1e6
            sy = -stp * oy * 1e6
            for s in range(depth):
                ti = np.int64(flat[ri + s])
                if ti > hi_i:
                    continue
                if ti < lo_i:
                    break
                delta = float(tk - ti)
                inv_delta = 1.0 / delta
                # Gaussian density N(t_j; t_i - delta, delta^2) per second.
                norm = _INV_SQRT_2PI * 1e6 * inv_delta
                t_hat = float(ti) - delta
                lo_j = ti - tau_us - dt_us
                hi_j = ti - tau_us
                for s2 in range(depth):
                    tj = np.int64(flat[rj + s2])
                    if tj > hi_j:
                        continue
                    if tj < lo_j:
                        break
                    z = (float(tj) - t_hat) * inv_delta
                    if not quadruple:
                        a = 0.5 * z * z
                        if a < 700.0:
                            ab[m] = a
                            nb[m] = norm
                            db[m] = float(tk - tj)
                            sxb[m] = sx
                            syb[m] = sy
                            m += 1
                        else:
                            # Far tail (2^-n below the float64 exponent range): exact exp.
                            e = math.exp(-a) * norm
                            tail_w += e
                            tail_x += e * sx / float(tk - tj)
                            tail_y += e * sy / float(tk - tj)
                            tail_n += 1
                        continue
                    lo_l = tj - tau_us - dt_us
                    hi_l = tj - tau_us
                    t_hat_l = float(tj) - delta
                    for s3 in range(depth):
                        tl = np.int64(flat[rl + s3])
                        if tl > hi_l:
                            continue
                        if tl < lo_l:
                            break
                        zl = (float(tl) - t_hat_l) * inv_delta
                        a = 0.5 * (z * z + zl * zl)
                        if a < 700.0:
                            ab[m] = a
                            nb[m] = norm * norm
                            db[m] = float(tk - tl)
                            sxb[m] = sx
                            syb[m] = sy
                            m += 1
                        else:
                            e = math.exp(-a) * norm * norm
                            tail_w += e
                            tail_x += e * sx / float(tk - tl)
                            tail_y += e * sy / float(tk - tl)
                            tail_n += 1
        sw, swx, swy = _weights(m, ab, nb, db, sxb, syb, pb, bits, scale)
        sw += tail_w
        swx += tail_x
        swy += tail_y
        n = m + tail_n
        out_n[k] = n
        if n > 0 and sw > 0.0:
            out_vx[k] = swx / sw
            out_vy[k] = swy / sw
            out_valid[k] = True
        else:
            out_vx[k] = 0.0
            out_vy[k] = 0.0
            out_valid[k] = False
        old = np.int64(flat[rk + depth - 1])
        if old != EMPTY and old >= tk - horizon:
            stats[0] += 1
        for s in range(depth - 1, 0, -1):
            flat[rk + s] = flat[rk + s - 1]
        flat[rk] = np.int32(tk)


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


@njit(cache=True)
def dense_from_sums(acc, cnt, r, out, out_mask):
    """Voxel means, (2r+1)x(2r+1) non-zero average per bin (r = 1: the thesis' 3x3; r = 0:
    none), mean over the bins that hold a value: ``acc`` (B, H, W, 2) sums, ``cnt``
    (B, H, W) counts -> ``out`` (H, W, 2) float32 and ``out_mask`` (H, W) bool. Fused
    version of the numpy functions in :mod:`evmotion.methods.triplet`."""
    nb, h, w = cnt.shape
    for yy in range(h):
        for xx in range(w):
            su = 0.0
            sv = 0.0
            nbins = 0
            for b in range(nb):
                bu = 0.0
                bv = 0.0
                nv = 0
                for qy in range(max(yy - r, 0), min(yy + r + 1, h)):
                    for qx in range(max(xx - r, 0), min(xx + r + 1, w)):
                        c = cnt[b, qy, qx]
                        if c > 0:
                            # float32 voxel means, as the numpy path stores them
                            bu += np.float32(acc[b, qy, qx, 0] / c)
                            bv += np.float32(acc[b, qy, qx, 1] / c)
                            nv += 1
                if nv > 0:
                    su += np.float32(bu / nv)
                    sv += np.float32(bv / nv)
                    nbins += 1
            if nbins > 0:
                out[yy, xx, 0] = su / nbins
                out[yy, xx, 1] = sv / nbins
                out_mask[yy, xx] = True
            else:
                out[yy, xx, 0] = 0.0
                out[yy, xx, 1] = 0.0
                out_mask[yy, xx] = False
