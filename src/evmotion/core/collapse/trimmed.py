"""The DIWE (3.11) and IWA (3.16) trimmed-mean penalties (3.12), (3.17) with their gradients.

The per-event values (:mod:`evmotion.core.collapse.values`) are voted into two bilinear
images, of ones and of values; the pixel means below the margin are averaged; the gradient
chains the votes' adjoint and the values' own derivatives through the warp, in one pass
over the events where the warp has fused adjoints
(:meth:`~evmotion.core.warps.adjoint.FusedAdjoint.reduce_pair`), else through stored
Jacobians.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core.collapse.values import (
    PenaltyEvents,
    all_above,
    checked_theta,
    event_values,
    rotation_grad,
    scratch,
)
from evmotion.core.iwe import vote_bilinear, vote_pair, vote_pairs
from evmotion.core.trim import (
    MIN_COUNT,
    flag_blocks,
    n_blocks,
    pairs_size,
    pairs_view,
    tile_grid,
    trim_pairs,
    trim_pass,
    vote_marked,
    vote_values,
)
from evmotion.core.warps import Warp
from evmotion.core.warps.adjoint import pad_diff, pad_index
from evmotion.core.warps.common import EMPTY1, EMPTY2
from evmotion.errors import EmptyWindowError, ParameterError

__all__ = ["MIN_COUNT", "chains_pair", "pixel_average", "trimmed_parts",
           "trimmed_value_grad"]

def _count_image_for(shape, count=None, count_out=None):
    """Where the vote counts are: the caller's ``count`` (already voted), else
    ``count_out`` (to be voted), else a scratch buffer."""
    if count is not None:
        return count
    return count_out if count_out is not None else scratch((shape,), "cnt")[0]


def _votes(xw, yw, d, shape, count=None, count_out=None):
    """``(cnt, num)``: the bilinear IWE of ones and of the per-event values ``d``, in one
    pass (:func:`evmotion.core.iwe.vote_pair`); ``cnt`` is ``count`` when the caller has
    it (not voted again), else written into ``count_out`` if given; scratch buffers
    otherwise."""
    cnt = _count_image_for(shape, count, count_out)
    (num,) = scratch((shape,), "num")
    vote_pair(xw, yw, d, cnt, num, count is None)
    return cnt, num


def _sparse_votes(xw, yw, d, margin, shape, count=None, count_out=None):
    """``(cnt, num, near, blocks)`` of :mod:`evmotion.core.trim`: the count image as
    :func:`_votes`'s, the image of values exact on the ``near`` tiles (those that can hold
    a pixel mean below ``margin``), the flags of the blocks of events that vote there
    (for at most :data:`_SPARSE_MAX` of the values below ``margin``)."""
    grid = tile_grid(shape)
    marks, near = scratch((grid, grid), "tiles", np.uint8)
    (num,) = scratch((shape,), "num")
    nb = n_blocks(xw.shape[0])
    (boxes,) = scratch(((nb, 4),), "boxes", np.int64)
    (blocks,) = scratch(((nb,),), "blocks", np.uint8)
    cnt = _count_image_for(shape, count, count_out)
    vote_marked(xw, yw, d, margin, cnt, count is None, marks, boxes)
    flag_blocks(marks, boxes, near, blocks)
    vote_values(xw, yw, d, blocks, num)
    return cnt, num, near, blocks


#: Largest fraction of values below the margin for which the values are voted sparsely.
_SPARSE_MAX = 0.25


_ALL_NEAR = np.zeros((0, 0), np.uint8)  # trim_pass's near: every pixel


@njit(cache=True, error_model="numpy")
def _backward_events(xw, yw, d, pads, h, wd, scale, gx, gy, gd):
    """Per-event derivatives ``gx, gy, gd`` (N,) of ``scale * sum(gS * num + gN * cnt)``
    with respect to ``xw_k, yw_k, d_k`` (0 off the image), ``num``/``cnt`` the bilinear
    IWEs of ``d`` and of ones, for the chain rule through stored Jacobians; ``pads`` holds
    ``gN`` then ``gS``, padded (:func:`evmotion.core.trim.trim_pass`), so no corner needs a
    bounds test."""
    wp = wd + 2
    b = (h + 2) * wp
    for k in range(xw.shape[0]):
        _, _, _, a, fx, fy, i = pad_index(xw[k], yw[k], 0.0, scale, 1.0, h, wd)
        gx[k], gy[k], gd[k] = pad_diff(True, a, fx, fy, d[k], pads, i, wp, b)


@njit(cache=True, error_model="numpy")
def _contract(gx, gy, gd, jx, jy, dd, out):
    """``out = jx^T gx + jy^T gy`` (+ ``dd^T gd`` if ``dd`` has rows): the chain rule
    through stored Jacobians (a compiled loop: BLAS threads pinned to one core spin for
    milliseconds on these small products)."""
    P = out.shape[0]
    use_dd = dd.shape[0] > 0
    acc = np.zeros(P)
    for k in range(gx.shape[0]):
        for j in range(P):
            acc[j] += gx[k] * jx[k, j] + gy[k] * jy[k, j] + (gd[k] * dd[k, j] if use_dd
                                                               else 0.0)
    for j in range(P):
        out[j] = acc[j]


@njit(cache=True, error_model="numpy")
def _any_vote(xw, yw, h, wd):
    """Whether any event votes into the image (the bilinear support test of the votes)."""
    for k in range(xw.shape[0]):
        x = xw[k]
        y = yw[k]
        if x > -1.0 and x < wd and y > -1.0 and y < h:
            return True
    return False


def _count_image(count, shape) -> np.ndarray:
    """A caller's vote-count image, checked: (H, W) float64 C-contiguous, read only."""
    if not (isinstance(count, np.ndarray) and count.dtype == np.float64
            and count.shape == tuple(shape) and count.flags.c_contiguous):
        raise ParameterError(f"count must be the (H, W) = {tuple(shape)} C-contiguous "
                             f"float64 bilinear IWE of the warped events, got "
                             f"{getattr(count, 'shape', type(count))}")
    return count


def _prepare(warp, ev: PenaltyEvents, theta, shape):
    """``ev`` with checked events, warped events (computed unless given) and count image
    (if given; of ``shape``), and the checked theta."""
    x, y, dt = Warp.check_events(ev.x, ev.y, ev.dt)
    if x.shape[0] == 0:
        raise EmptyWindowError("the regularizer needs at least one event, got none")
    th = checked_theta(warp, theta)
    xw, yw = ev.xw, ev.yw
    if xw is None or yw is None:
        xw, yw = warp.warp(x, y, dt, th)
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    count = None if ev.count is None else _count_image(ev.count, shape)
    # built, not _replace()d: this runs per evaluation, and _replace costs microseconds
    return PenaltyEvents(x, y, dt, xw, yw, ev.jx, ev.jy, ev.span, count), th


def pixel_average(kind, warp, x, y, dt, th, shape, xw, yw):
    """(d, fac, cnt, num) of the DIWE/IWA: per-event values and their vote images."""
    d, _, fac = event_values(kind, warp, x, y, dt, th, want_grad=False, xw=xw, yw=yw)
    cnt, num = _votes(xw, yw, d, shape)
    return d, fac, cnt, num


def trimmed_value_grad(kind, warp, ev: PenaltyEvents, theta, shape, margin, grad=True):
    """The divergence or deformation penalty (``kind``) of the events ``ev`` with
    ``theta`` and its gradient (None without ``grad``), DIWE/IWA maps ``shape`` (H, W),
    trimming margin ``margin``."""
    ev, th = _prepare(warp, ev, theta, shape)
    h, wd = shape
    (buf,) = scratch(((pairs_size(shape),),), "adj")
    value, g, d, fac, scale, blocks = trimmed_parts(kind, warp, ev, th, shape, margin, buf,
                                                     grad)
    if d is None or not grad:
        return value, g
    x, y, dt, xw, yw, jx, jy = ev.x, ev.y, ev.dt, ev.xw, ev.yw, ev.jx, ev.jy
    pads = buf[:2 * (h + 2) * (wd + 2)]
    T = ev.duration()
    if (jx is None or jy is None) and chains_pair(warp):
        warp.reduce_pair(x, y, dt, xw, yw, th, pads.reshape(2, h + 2, wd + 2), d, g, scale,
                         kind, T, blocks)
        return value, g
    n = x.shape[0]
    dd = None
    if fac is None:
        # the value derivatives (the values themselves are unchanged)
        d, dd, _ = event_values(kind, warp, x, y, dt, th, T=T)
    if jx is None or jy is None:
        # only now: the Jacobians matter only when some pixel is trimmed
        _, _, jx, jy = warp.warp(x, y, dt, th, jacobian=True)
    gx, gy, gd = scratch(((n,),) * 3, "gjac")
    _backward_events(xw, yw, d, pads, h, wd, scale, gx, gy, gd)
    _contract(gx, gy, gd, np.ascontiguousarray(jx), np.ascontiguousarray(jy),
              EMPTY2 if dd is None else np.ascontiguousarray(dd), g)
    if fac is not None:
        rotation_grad(warp, kind, x, y, dt, th, gd, fac, g)
    return value, g


def chains_pair(warp: Warp) -> bool:
    """Whether the trimmed penalties of ``warp`` chain their gradient, the values' own
    derivatives included, through :meth:`~evmotion.core.warps.Warp.reduce_pair` (no stored
    Jacobians): the warps with fused adjoints whose per-event values have compiled
    derivatives (closed forms, rotation)."""
    return hasattr(warp, "reduce_pair") and (hasattr(warp, "event_values")
                                             or hasattr(warp, "values_from_warped"))


def trimmed_parts(kind, warp, ev: PenaltyEvents, th, shape, margin, pads, grad=True,
                  count_out=None, values=None):
    """The divergence or deformation penalty up to the chain rule through the warp, for
    callers that fuse that step with their own (CMax's data term): ``(value, g, d, fac,
    scale, blocks)`` for checked events and theta (:func:`_prepare`; ``ev.xw, ev.yw``
    given, ``ev.jx, ev.jy`` unused).

    ``d`` None: ``value`` and ``g`` (P,) are complete (no pixel trimmed, or the constant
    divergence; ``g`` None without ``grad``). Otherwise ``g`` (P,) is uninitialized and
    ``pads`` (:func:`evmotion.core.trim.pairs_size`: the votes are made in it too) holds in
    its first 2 (H + 2) (W + 2) values the adjoint images ``gN``, ``gS`` of the penalty
    divided by ``scale`` (with respect to the vote counts and the votes of the per-event
    values ``d``; padded by a ring of zeros): the gradient is that of ``scale * sum(gN *
    cnt + gS * num)`` through the votes and the values
    (:meth:`~evmotion.core.warps.Warp.reduce_pair` with ``derivs=kind``; ``fac``: the
    rotation's factor from its raw divergence / det J to ``d``, for the chain rule through
    stored Jacobians; ``blocks``: the flags of the blocks of events that reach a nonzero
    ``gS``, for ``reduce_pair``'s ``blocks``: :mod:`evmotion.core.trim`).
    ``count_out`` (H, W), if given (and ``ev.count`` not), receives the bilinear IWE of
    ``xw, yw`` in every case, voted with the values' IWE where the maps are built (the data
    term's IWE of a caller that votes once). ``values``: ``(d, fac)`` of
    :func:`event_values` for ``xw, yw``, if at hand (:func:`warp_values`)."""
    zero = (0.0, np.zeros(warp.n_params) if grad else None, None, None, 0.0, None)
    x, y, dt, xw, yw, count = ev.x, ev.y, ev.dt, ev.xw, ev.yw, ev.count

    def unvoted(result):
        # returned before the maps: the caller's count image is still to be voted
        if count_out is not None and count is None:
            vote_bilinear(xw, yw, EMPTY1, count_out)
        return result

    T = ev.duration() if kind == "divergence" else None
    # deformation's map is 1 + mean: its margin on `mean` is margin - 1
    m = margin - 1.0 if kind == "deformation" else margin
    if kind == "divergence" and getattr(warp, "constant_divergence", False):
        # the divergence is the same for every event: so is the DIWE on its support, and
        # the trimmed mean is that constant (no vote moves it); one event gives it
        d, dd, _ = event_values(kind, warp, x[:1], y[:1], dt[:1], th, T=T)
        if not (d[0] < m and _any_vote(xw, yw, shape[0], shape[1])):
            return unvoted(zero)
        return unvoted((-float(d[0]), (-dd[0].copy() if grad else None), None, None, 0.0,
                        None))
    if values is None:
        d, _, fac = event_values(kind, warp, x, y, dt, th, want_grad=False, T=T, xw=xw,
                                  yw=yw)
    else:
        d, fac = values
    above, m_round, n_below = all_above(d, m)
    if above:
        # no collapse anywhere (the usual case away from collapse): no maps to build
        return unvoted(zero)
    # R = -(1/n) sum_sel S/N with S = sum d_k b_k, N = sum b_k (b_k: bilinear votes)
    size = (shape[0] + 2) * (shape[1] + 2)
    gN, gS = pads[:size], pads[size:2 * size]
    blocks = None
    if n_below > _SPARSE_MAX * d.shape[0]:
        # most values below (the zoom's, similarity's and in-plane warp's depend on dt
        # only: below everywhere at once): both images in full, interleaved in one pass
        # unless the counts are given
        if count is None:
            # in the second adjoint image's memory: trim_pairs writes it over read rows
            pairs = pairs_view(pads, shape)
            vote_pairs(xw, yw, d, pairs)
            total, n_sel = trim_pairs(pairs, m, gN, gS, _count_image_for(shape, None, count_out))
        else:
            cnt, num = _votes(xw, yw, d, shape, count)
            total, n_sel = trim_pass(cnt, num, m, gN, gS, _ALL_NEAR)
    else:
        # the values voted only around the events below the margin (core.trim)
        cnt, num, near, blocks = _sparse_votes(xw, yw, d, m_round, shape, count, count_out)
        total, n_sel = trim_pass(cnt, num, m, gN, gS, near)
    if n_sel == 0:
        return zero
    scale = -1.0 / n_sel
    if not grad:
        return total * scale, None, None, None, 0.0, None
    return total * scale, np.empty(warp.n_params), d, fac, scale, blocks
