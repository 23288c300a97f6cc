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
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

EMPTY = np.int32(-(2**31) + 1)
# Relative timestamps must stay far from the int32 limits; rebase before this span.
REBASE_SPAN_US = 2**30
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
NORMAL_RIDGE = 1e-3


_LOG2E = 1.0 / math.log(2.0)
_LN2 = math.log(2.0)
# Taylor coefficients of exp(-u), u in [0, ln 2), highest first: truncation error < 1e-9.
_C = [(-1.0) ** i / math.factorial(i) for i in range(11)][::-1]
C0, C1, C2, C3, C4, C5, C6, C7, C8, C9, C10 = _C
# Events ahead whose rings the kernel asks the memory to fetch while it matches the current
# one: the 2 x H x W x depth state outgrows the caches, and the rings an event reads sit on
# five rows of the sensor (measured: 8-10 % off the kernel on a 1280x720 recording).
PREFETCH_AHEAD = 3


@intrinsic
def _prefetch(typingctx, arr, idx):
    """Hint the CPU to bring ``arr[idx]`` into the caches (``llvm.prefetch``: read, high
    locality); no effect on results."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        i8p = ir.IntType(8).as_pointer()
        ptr = builder.bitcast(builder.gep(ary.data, [args[1]]), i8p)
        i32 = ir.IntType(32)
        mangle = "p0" if str(i8p) == "ptr" else "p0i8"  # opaque or typed LLVM pointers
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
            f"llvm.prefetch.{mangle}")
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, fastmath=True)
def _weights(m, ab, nb, db, sxb, syb, pb, bits, scale, lsq, n_sq, pw):
    """Vote sums of ``m`` collected triplets, in branch-free loops the compiler vectorizes.

    exp(-a) = 2^-n * exp(-u), u = (a log2 e - n) ln 2 in [0, ln 2): a polynomial for the
    second factor and the exponent bits of a float64 for the first. ``lsq[:5]`` receives the
    normal equations of the time-surface gradient ``g`` (s/px) that every match constrains,
    ``g . (x_k - x_j) = t_k - t_j``, weighted by the Gaussian's shape ``exp(-a)``:
    ``[sum s_x^2, sum s_x s_y, sum s_y^2, sum s_x D, sum s_y D]`` (``s = x_k - x_j``,
    ``D = t_k - t_j``; any common unit scale of the two cancels). There each match weighs
    ``exp(-a)^(2^n_sq)`` (``n_sq`` squarings): the Gaussian of (5.3) narrowed to
    ``sigma = delta / 2^(n_sq/2)``, which keeps the matches whose two steps take equal times.
    """
    for q in range(m):
        y = ab[q] * _LOG2E
        n = np.int64(y)
        u = (y - n) * _LN2
        pb[q] = ((((((((((C0 * u + C1) * u + C2) * u + C3) * u + C4) * u + C5) * u + C6) * u
                    + C7) * u + C8) * u + C9) * u + C10)
        bits[q] = (1023 - n) << 52
    # exp(-a)^kappa, 0 below 1e-304: no subnormal (slow) products in the squarings
    kappa_a = float(1 << n_sq)
    for q in range(m):
        pw[q] = pb[q] * scale[q] if ab[q] * kappa_a < 700.0 else 0.0
    # one pass per squaring: loops the compiler vectorizes (a loop inside would stop it)
    for _ in range(n_sq):
        for q in range(m):
            pw[q] = pw[q] * pw[q]
    sw = 0.0
    swx = 0.0
    swy = 0.0
    a11 = 0.0
    a12 = 0.0
    a22 = 0.0
    b1 = 0.0
    b2 = 0.0
    for q in range(m):
        g = pb[q] * scale[q]
        e = g * nb[q]
        sw += e
        r = e / db[q]
        sx = sxb[q]
        sy = syb[q]
        swx += r * sx
        swy += r * sy
        g = pw[q]
        # s and D in units of 1e-6 px and µs: both sides scale by 1e12, g keeps s/px
        gx = g * sx
        gy = g * sy
        a11 += gx * sx
        a12 += gx * sy
        a22 += gy * sy
        b1 += gx * db[q]
        b2 += gy * db[q]
    lsq[0] = a11
    lsq[1] = a12
    lsq[2] = a22
    lsq[3] = b1
    lsq[4] = b2
    return sw, swx, swy


@njit(cache=True, inline="always")
def normal_flow(lsq):
    """Normal flow ``g / |g|^2`` (px/s) of the least-squares time-surface gradient ``g``.

    A ridge of ``NORMAL_RIDGE`` x their trace regularizes the normal equations: with matches
    along one direction only (singular equations) it returns the minimum-norm solution,
    speeds overestimated by that fraction, and a second direction carrying less than about
    that share of the weight cannot swing the solution. (0, 0) when no match carries weight.
    """
    tr = lsq[0] + lsq[2]
    if not tr > 0.0:
        return 0.0, 0.0
    # scaled by the trace: the weights may be as small as 1e-304
    inv = 1.0 / tr
    a11 = lsq[0] * inv + NORMAL_RIDGE
    a12 = lsq[1] * inv
    a22 = lsq[2] * inv + NORMAL_RIDGE
    b1 = lsq[3] * inv
    b2 = lsq[4] * inv
    # g = h / det, so g / |g|^2 = h det / |h|^2
    h1 = a22 * b1 - a12 * b2
    h2 = a11 * b2 - a12 * b1
    hh = h1 * h1 + h2 * h2
    if not hh > 0.0:
        return 0.0, 0.0
    f = (a11 * a22 - a12 * a12) / hh
    return h1 * f, h2 * f


# Not fastmath here: its reciprocal shortcut overflows when every weight is subnormal.
# numpy's error model: no zero-divisor test before each division (every divisor here is a
# time difference of at least tau >= 1 µs or a sum tested > 0); 7-8 % faster, same bits.
@njit(cache=True, error_model="numpy")
def triplet_kernel(x, y, t, p, base, ts, offsets, dt_us, tau_us, quadruple, n_sq,
                   out_vx, out_vy, out_n, out_valid, out_nx, out_ny, stats):
    """Process events in order, writing one flow per event and updating the ring state.

    ``x, y`` int32 pixels, ``t`` int64 µs absolute, ``p`` uint8; ``base`` the µs subtracted
    from ``t`` before it is stored. Each ring ``ts[c, y, x, :]`` is kept newest first, so a
    scan skips the too-recent slots and stops at the first too-old (or empty) one. The
    matches of one event are collected first and weighed in one vectorized pass.
    ``out_nx, out_ny`` receive the normal flow of the matches' least-squares time-surface
    gradient (see :func:`_weights`; ``n_sq`` narrows its weights). ``stats[0]`` counts
    evictions of events that could still take part in a future triplet (answers then may
    differ from unbounded Algorithm 1).
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
    pw = np.empty(cap)   # weights of the normal-flow fit
    lsq = np.empty(5)
    n_ev = t.shape[0]
    size = flat.shape[0]
    for k in range(n_ev):
        f = k + PREFETCH_AHEAD
        if f < n_ev:
            rf = ((p[f] * h + y[f]) * w + x[f]) * depth
            _prefetch(flat, rf)
            for o in range(n_off):
                step_f = (offsets[o, 1] * w + offsets[o, 0]) * depth
                for q in range(1, 4 if quadruple else 3):
                    if 0 <= rf + q * step_f < size:
                        _prefetch(flat, rf + q * step_f)
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
        sw, swx, swy = _weights(m, ab, nb, db, sxb, syb, pb, bits, scale, lsq, n_sq, pw)
        # Far-tail matches (exp(-a) < 1e-304) add nothing to the normal equations.
        nx, ny = normal_flow(lsq)
        out_nx[k] = nx
        out_ny[k] = ny
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
    version of the numpy functions in :mod:`evmotion.methods.triplet`; only the pixels
    within ``r`` of a voxel with events are computed (elsewhere there is no value)."""
    nb, h, w = cnt.shape
    out[:] = 0.0
    out_mask[:] = False
    need = np.zeros((h, w), np.bool_)
    todo = np.empty(h * w, np.int64)
    n = 0
    for b in range(nb):
        for yy in range(h):
            for xx in range(w):
                if cnt[b, yy, xx] == 0:
                    continue
                for qy in range(max(yy - r, 0), min(yy + r + 1, h)):
                    for qx in range(max(xx - r, 0), min(xx + r + 1, w)):
                        if not need[qy, qx]:
                            need[qy, qx] = True
                            todo[n] = qy * w + qx
                            n += 1
    for i in range(n):
        yy = todo[i] // w
        xx = todo[i] % w
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


@njit(cache=True)
def voxel_accumulate_normal(x, y, t, nx, ny, t0, t1, n_bins, vmax, acc, cnt):
    """Add the normal-flow constraints of events with ``t0 <= t < t1`` to time-bin voxels.

    Each event with a normal flow ``u`` (``0 < |u| <= vmax`` px/s) constrains the flow ``v``
    of its neighbourhood by ``v . u/|u| = |u|``: ``acc`` (n_bins, H, W, 5) float64 sums its
    normal equations ``[n_x^2, n_x n_y, n_y^2, u_x, u_y]`` (``n = u/|u|``), ``cnt``
    (n_bins, H, W) counts the events.
    """
    span = float(t1 - t0)
    for k in range(t.shape[0]):
        tk = t[k]
        if tk < t0 or tk >= t1:
            continue
        ux = float(nx[k])
        uy = float(ny[k])
        s2 = ux * ux + uy * uy
        if not (s2 > 0.0 and s2 <= vmax * vmax):
            continue
        b = int((tk - t0) * n_bins / span)
        if b >= n_bins:
            b = n_bins - 1
        yk = y[k]
        xk = x[k]
        acc[b, yk, xk, 0] += ux * ux / s2
        acc[b, yk, xk, 1] += ux * uy / s2
        acc[b, yk, xk, 2] += uy * uy / s2
        acc[b, yk, xk, 3] += ux
        acc[b, yk, xk, 4] += uy
        cnt[b, yk, xk] += 1


@njit(cache=True, inline="always")
def _mean_over_bins(su, nbins, out, out_mask):
    """``out`` = per-pixel sum ``su`` (H, W, 2) over ``nbins`` bins, 0 and masked out where 0."""
    h, w = nbins.shape
    for yy in range(h):
        for xx in range(w):
            nb = nbins[yy, xx]
            out_mask[yy, xx] = nb > 0
            out[yy, xx, 0] = su[yy, xx, 0] / nb if nb > 0 else 0.0
            out[yy, xx, 1] = su[yy, xx, 1] / nb if nb > 0 else 0.0


@njit(cache=True)
def dense_lsq_from_sums(acc, cnt, r, ridge, out, out_mask):
    """Per bin, the flow that best meets the normal-flow constraints of a (2r+1)^2
    neighbourhood, ``(M + ridge tr(M)/2 I) v = sum u`` with ``M = sum n n^T``; then the mean
    over the bins that hold a value. ``acc``/``cnt`` from :func:`voxel_accumulate_normal`;
    ``out`` (H, W, 2) float32 px/s, ``out_mask`` (H, W) bool. Only the pixels within ``r``
    of a voxel with events are fitted (:func:`_final_fit`); elsewhere there is no flow."""
    nb, h, w = cnt.shape
    direct = nb == 1
    out[:] = 0.0
    out_mask[:] = False
    su = np.zeros((1, 1, 2)) if direct else np.zeros((h, w, 2))
    nbins = np.zeros((1, 1), np.int64) if direct else np.zeros((h, w), np.int64)
    for b in range(nb):
        m = 0
        for yy in range(h):
            for xx in range(w):
                if cnt[b, yy, xx] > 0:
                    m += 1
        if m == 0:
            continue
        px = np.empty(m, np.int64)
        py = np.empty(m, np.int64)
        rows = np.empty((m, 6))
        i = 0
        for yy in range(h):
            for xx in range(w):
                if cnt[b, yy, xx] > 0:
                    px[i] = xx
                    py[i] = yy
                    for ch in range(5):
                        rows[i, ch] = acc[b, yy, xx, ch]
                    rows[i, 5] = cnt[b, yy, xx]
                    i += 1
        x0 = max(np.min(px) - r, 0)
        y0 = max(np.min(py) - r, 0)
        bw = min(np.max(px) + r + 1, w) - x0
        bh = min(np.max(py) + r + 1, h) - y0
        _final_fit(rows, px, py, x0, y0, bh, bw, r, ridge, su, nbins, direct, out, out_mask)
    if not direct:
        _mean_over_bins(su, nbins, out, out_mask)


@njit(cache=True, inline="always")
def _solve_row(b, ridge):
    """Flow from one box-summed row of normal equations ``b`` = ``[M11, M12, M22, r1, r2,
    n]``, ``(M + ridge tr(M)/2 I) v = r``: ``(ok, vx, vy)``; not ok where the neighbourhood
    holds no event (``n``), where its events' weights (the trace: unit normals) all but
    vanish, or where the system is singular."""
    if b[5] < 0.5:
        return False, 0.0, 0.0
    m11 = b[0]
    m12 = b[1]
    m22 = b[2]
    # Summed-area differences leave rounding residue where every weight is zero.
    if not m11 + m22 > 1e-9 * b[5]:
        return False, 0.0, 0.0
    eps = ridge * 0.5 * (m11 + m22)
    m11 += eps
    m22 += eps
    det = m11 * m22 - m12 * m12
    if not det > 0.0:
        return False, 0.0, 0.0
    return True, (m22 * b[3] - m12 * b[4]) / det, (m11 * b[4] - m12 * b[3]) / det


@njit(cache=True)
def _row_segments(px, py, r):
    """For the active pixels ``(px, py)`` sorted by row then column: the neighbours of each
    within the (2r+1)^2 box around it, as one run of the sorted order per row of the box,
    CSR ``(start, seg)`` with ``seg[s] = (first, stop)``."""
    m = px.shape[0]
    h = np.max(py) + 1
    row_start = np.zeros(h + 1, np.int64)
    for i in range(m):
        row_start[py[i] + 1] += 1
    for yy in range(h):
        row_start[yy + 1] += row_start[yy]
    start = np.zeros(m + 1, np.int64)
    seg = np.empty((m * (2 * r + 1), 2), np.int64)
    n = 0
    for i in range(m):
        start[i] = n
        for yy in range(max(py[i] - r, 0), min(py[i] + r + 1, h)):
            rs = row_start[yy]
            re = row_start[yy + 1]
            if rs == re:
                continue
            a = rs + np.searchsorted(px[rs:re], px[i] - r)
            b = rs + np.searchsorted(px[rs:re], px[i] + r, side="right")
            if a < b:
                seg[n, 0] = a
                seg[n, 1] = b
                n += 1
    start[m] = n
    return start, seg[:n]


@njit(cache=True)
def _box_at(acc, px, py, x0, y0, bh, bw, r, sat, box):
    """(2r+1)^2 box sums of the per-pixel rows ``acc`` (P, 6) at the active pixels, through
    a summed-area table ``sat`` over the ``bh`` x ``bw`` region at ``(x0, y0)``."""
    sat[: bh + 1, : bw + 1, :] = 0.0
    for i in range(px.shape[0]):
        for ch in range(6):
            sat[py[i] - y0 + 1, px[i] - x0 + 1, ch] += acc[i, ch]
    for yy in range(1, bh + 1):
        for xx in range(1, bw + 1):
            for ch in range(6):
                sat[yy, xx, ch] += sat[yy - 1, xx, ch] + sat[yy, xx - 1, ch] \
                    - sat[yy - 1, xx - 1, ch]
    for i in range(px.shape[0]):
        _sat_query(sat, py[i] - y0, px[i] - x0, bh, bw, r, box[i])


@njit(cache=True)
def _sat_query(sat, yy, xx, bh, bw, r, dst):
    ya = max(yy - r, 0)
    yb = min(yy + r + 1, bh)
    xa = max(xx - r, 0)
    xb = min(xx + r + 1, bw)
    for ch in range(6):
        dst[ch] = sat[yb, xb, ch] - sat[ya, xb, ch] - sat[yb, xa, ch] + sat[ya, xa, ch]


@njit(cache=True)
def dense_robust(x, y, t, nx, ny, t0, t1, n_bins, vmax, r, ridge, c, iters, out, out_mask):
    """Robust counterpart of :func:`dense_lsq_from_sums` over the events themselves: per time
    bin, ``iters`` re-weightings of the neighbourhood fit, each event's normal-flow
    constraint weighted by Tukey's biweight of its relative residual
    ``(v . n - |u|) / |u|`` (zero beyond ``c``) under the flow ``v`` of its own pixel.
    Events outside ``[t0, t1)`` or with ``|u|`` = 0 or over ``vmax`` are left out.

    Only the bin's active pixels enter the re-weightings (their box sums from runs of
    neighbours in row order, or a summed-area table over the active region when the runs
    would be longer),
    and the final fit covers the active region grown by ``r``: outside it no event is near,
    so there is no flow. The work follows the events, not the sensor."""
    h, w = out_mask.shape
    n = t.shape[0]
    span = float(t1 - t0)
    bin_of = np.empty(n, np.int64)
    per_bin = np.zeros(n_bins + 1, np.int64)
    for k in range(n):
        s2 = np.float64(nx[k]) * nx[k] + np.float64(ny[k]) * ny[k]
        if t[k] < t0 or t[k] >= t1 or not (s2 > 0.0 and s2 <= vmax * vmax):
            bin_of[k] = -1
        else:
            bin_of[k] = min(int((t[k] - t0) * n_bins / span), n_bins - 1)
            per_bin[bin_of[k] + 1] += 1
    for b in range(n_bins):
        per_bin[b + 1] += per_bin[b]
    order = np.empty(per_bin[n_bins], np.int64)
    fill = per_bin[:-1].copy()
    for k in range(n):
        if bin_of[k] >= 0:
            order[fill[bin_of[k]]] = k
            fill[bin_of[k]] += 1
    # constraint rows of the events: [n_x^2, n_x n_y, n_y^2, u_x, u_y] (n = u / |u|)
    rows = np.empty((order.shape[0], 5))
    for j in range(order.shape[0]):
        k = order[j]
        ux = np.float64(nx[k])
        uy = np.float64(ny[k])
        s2 = ux * ux + uy * uy
        rows[j, 0] = ux * ux / s2
        rows[j, 1] = ux * uy / s2
        rows[j, 2] = uy * uy / s2
        rows[j, 3] = ux
        rows[j, 4] = uy
    # one bin: the fits go straight to the output (no per-pixel sums over bins to average)
    direct = n_bins == 1
    out[:] = 0.0
    out_mask[:] = False
    su = np.zeros((1, 1, 2)) if direct else np.zeros((h, w, 2))
    nbins = np.zeros((1, 1), np.int64) if direct else np.zeros((h, w), np.int64)
    pid = np.full(h * w, -1, np.int32)
    sat = np.empty((0, 0, 6))
    for b in range(n_bins):
        lo = per_bin[b]
        hi = per_bin[b + 1]
        m = hi - lo
        if m == 0:
            continue
        # the bin's active pixels, and each event's
        ev_pix = np.empty(m, np.int64)
        px = np.empty(m, np.int64)
        py = np.empty(m, np.int64)
        npx = 0
        for j in range(m):
            k = order[lo + j]
            q = y[k] * w + x[k]
            if pid[q] < 0:
                pid[q] = npx
                px[npx] = x[k]
                py[npx] = y[k]
                npx += 1
            ev_pix[j] = pid[q]
        # sorted by row, then column: a box's neighbours are one run per row
        key = np.empty(npx, np.int64)
        for i in range(npx):
            key[i] = py[i] * w + px[i]
            pid[key[i]] = -1
        perm = np.argsort(key)
        rank = np.empty(npx, np.int64)
        for i in range(npx):
            rank[perm[i]] = i
        for j in range(m):
            ev_pix[j] = rank[ev_pix[j]]
        px = px[:npx][perm]
        py = py[:npx][perm]
        x0 = max(np.min(px) - r, 0)
        y0 = max(np.min(py) - r, 0)
        bw = min(np.max(px) + r + 1, w) - x0
        bh = min(np.max(py) + r + 1, h) - y0
        if sat.shape[0] < bh + 1 or sat.shape[1] < bw + 1:
            sat = np.empty((max(bh + 1, sat.shape[0]), max(bw + 1, sat.shape[1]), 6))
        # row runs of neighbours while they cost less than a summed-area table of the region
        runs = npx * (2 * r + 1) <= 2 * (bh + 1) * (bw + 1)
        if runs:
            start, seg = _row_segments(px, py, r)
        wgt = np.ones(m)
        acc = np.empty((npx, 6))
        box = np.empty((npx, 6))
        pre = np.empty((npx + 1, 6))
        for it in range(iters + 1):
            acc[:] = 0.0
            for j in range(m):
                i = ev_pix[j]
                wk = wgt[j]
                for ch in range(5):
                    acc[i, ch] += wk * rows[lo + j, ch]
                acc[i, 5] += 1.0
            if it == iters:
                break
            if runs:
                pre[0, :] = 0.0
                for i in range(npx):
                    for ch in range(6):
                        pre[i + 1, ch] = pre[i, ch] + acc[i, ch]
                for i in range(npx):
                    for ch in range(6):
                        box[i, ch] = 0.0
                    for sg in range(start[i], start[i + 1]):
                        a = seg[sg, 0]
                        b = seg[sg, 1]
                        for ch in range(6):
                            box[i, ch] += pre[b, ch] - pre[a, ch]
            else:
                _box_at(acc, px, py, x0, y0, bh, bw, r, sat, box)
            for j in range(m):
                i = ev_pix[j]
                ok, vx, vy = _solve_row(box[i], ridge)
                if not ok:
                    continue
                k = order[lo + j]
                ux = np.float64(nx[k])
                uy = np.float64(ny[k])
                z = ((vx * ux + vy * uy) / (ux * ux + uy * uy) - 1.0) / c
                wgt[j] = (1.0 - z * z) ** 2 if z * z < 1.0 else 0.0
        _final_fit(acc, px, py, x0, y0, bh, bw, r, ridge, su, nbins, direct, out, out_mask)
    if not direct:
        _mean_over_bins(su, nbins, out, out_mask)


@njit(cache=True)
def _final_fit(acc, px, py, x0, y0, bh, bw, r, ridge, su, nbins, direct, out, out_mask):
    """The fit at every pixel within ``r`` of an active pixel, added to ``su`` / ``nbins``
    (``direct``: written to ``out`` / ``out_mask``):
    block by block (64 x 64 px) of the ``bh`` x ``bw`` region at ``(x0, y0)``, only the
    blocks an active pixel's box reaches, each through a summed-area table of the block
    grown by ``r``."""
    bs = 64
    nby = (bh + bs - 1) // bs
    nbx = (bw + bs - 1) // bs
    need = np.zeros((nby, nbx), np.bool_)
    for i in range(px.shape[0]):
        lx = px[i] - x0
        ly = py[i] - y0
        for by in range(max(ly - r, 0) // bs, min(ly + r, bh - 1) // bs + 1):
            for bx in range(max(lx - r, 0) // bs, min(lx + r, bw - 1) // bs + 1):
                need[by, bx] = True
    side = bs + 2 * r + 1
    sat = np.empty((side, side, 6))
    row = np.empty(6)
    for by in range(nby):
        for bx in range(nbx):
            if not need[by, bx]:
                continue
            ra = max(by * bs - r, 0)
            rb = min(by * bs + bs + r, bh)
            ca = max(bx * bs - r, 0)
            cb = min(bx * bs + bs + r, bw)
            sh = rb - ra
            sw = cb - ca
            sat[: sh + 1, : sw + 1, :] = 0.0
            for i in range(px.shape[0]):
                ly = py[i] - y0 - ra
                lx = px[i] - x0 - ca
                if 0 <= ly < sh and 0 <= lx < sw:
                    for ch in range(6):
                        sat[ly + 1, lx + 1, ch] += acc[i, ch]
            for yy in range(1, sh + 1):
                for xx in range(1, sw + 1):
                    for ch in range(6):
                        sat[yy, xx, ch] += sat[yy - 1, xx, ch] + sat[yy, xx - 1, ch] \
                            - sat[yy - 1, xx - 1, ch]
            for yy in range(by * bs, min(by * bs + bs, bh)):
                for xx in range(bx * bs, min(bx * bs + bs, bw)):
                    ya = max(yy - r, 0) - ra
                    yb = min(yy + r + 1, bh) - ra
                    xa = max(xx - r, 0) - ca
                    xb = min(xx + r + 1, bw) - ca
                    for ch in range(6):
                        row[ch] = (sat[yb, xb, ch] - sat[ya, xb, ch] - sat[yb, xa, ch]
                                   + sat[ya, xa, ch])
                    ok, vx, vy = _solve_row(row, ridge)
                    if ok and direct:
                        out[y0 + yy, x0 + xx, 0] = vx
                        out[y0 + yy, x0 + xx, 1] = vy
                        out_mask[y0 + yy, x0 + xx] = True
                    elif ok:
                        su[y0 + yy, x0 + xx, 0] += vx
                        su[y0 + yy, x0 + xx, 1] += vy
                        nbins[y0 + yy, x0 + xx] += 1
