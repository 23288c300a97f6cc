"""Sparse votes of the trimmed pixel means of :mod:`evmotion.core.regularizers` (the DIWE and
IWA maps of ch. 3, (3.11)/(3.16), and their trimmed means (3.12)/(3.17)).

A pixel's mean is a vote-weighted average of the values of the events that vote there, so
it can fall below the margin only where one of those values does. Near collapse such events
are a minority, and clustered, so the image of values is voted, trimmed and chained back
only around them:

* :func:`vote_marked` votes the count image (the data term's IWE, bit for bit
  :func:`evmotion.core.iwe.vote_counts`), marks the ``TILE`` x ``TILE`` pixel tiles of
  the cells of the events below the margin, and keeps the box of the tiles of each block of
  ``BLOCK`` consecutive events;
* :func:`flag_blocks`: the tiles whose pixels can fall below the margin (``near``: the marks
  grown by one tile right and down, as a cell's corners reach one pixel further) and the
  blocks whose events can vote into them (``flags``: their box meets the marks grown by one
  tile each way);
* :func:`vote_values` votes the values of the flagged blocks only: the image of values is
  exact on the ``near`` tiles, which is all that :func:`trim_pass` reads;
* the adjoint images are 0 outside ``near``, so the gradient pass gathers the values' image
  in the flagged blocks only (:meth:`~evmotion.core.warps.Warp.reduce_pair`'s ``blocks``).

Tiles are over the image padded by one pixel (pixel ``(i, j)`` at ``(i + 1, j + 1)``, a
cell's top-left corner from ``(0, 0)``). The events keep their order (CMax's sensor-tile
order makes the blocks compact: at the benchmark's rotation collapse, 500k events, about
a fifth of the blocks are flagged).

Where most values are below the margin (the warps whose values depend on dt only: below it
everywhere at once) nothing is sparse: counts and values are voted together into one
interleaved image (:func:`evmotion.core.iwe.vote_pairs`) placed inside the memory of the
second adjoint image (:func:`pairs_view`), and :func:`trim_pairs` writes that image over
the rows it has read -- one image less in the working set, which at 500k events keeps it
within the last-level cache.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core.iwe import block_bufs, vote_block, vote_counts
from evmotion.core.warps.adjoint import DIV_BLOCK

__all__ = ["BLOCK", "MIN_COUNT", "TILE", "flag_blocks", "n_blocks", "pairs_size", "pairs_view",
           "tile_grid", "trim_pairs", "trim_pass", "vote_marked", "vote_values"]

_SHIFT = 3
#: Pixels per side of a tile.
TILE = 1 << _SHIFT
#: Events per block (the blocks of the rotation's gradient pass).
BLOCK = DIV_BLOCK
_NO_WEIGHTS = np.empty(0)
#: Pixels with less bilinear vote mass hold no warped event.
MIN_COUNT = 1e-9


def tile_grid(shape: tuple[int, int]) -> tuple[int, int]:
    """Rows and columns of tiles of an (H, W) image (padded by one pixel each side)."""
    return ((int(shape[0]) + 1) >> _SHIFT) + 1, ((int(shape[1]) + 1) >> _SHIFT) + 1


def n_blocks(n: int) -> int:
    """Blocks of :data:`BLOCK` events in ``n`` events."""
    return (int(n) + BLOCK - 1) // BLOCK


@njit(cache=True, error_model="numpy")
def vote_marked(xw, yw, d, margin, cnt, with_cnt, marks, boxes):
    """Pass one: the bilinear IWE of ``xw, yw`` into ``cnt`` (H, W) if ``with_cnt``; in
    ``marks`` (uint8, :func:`tile_grid`) 1 at the tiles of the cells of the events with
    ``d < margin`` (a NaN is not below), 0 elsewhere; in ``boxes`` (int64, (n_blocks, 4))
    the first and last tile row, then column, of the cells of each block of events (first
    > last: no event of the block votes)."""
    h, wd = cnt.shape
    if with_cnt:
        vote_counts(xw, yw, cnt)
    marks[:] = 0
    nc = marks.shape[1]
    flat = marks.reshape(marks.size)
    big = marks.shape[0] + nc
    for b in range(boxes.shape[0]):
        k0 = b * BLOCK
        xs, ys, ds = xw[k0:k0 + BLOCK], yw[k0:k0 + BLOCK], d[k0:k0 + BLOCK]
        r0 = c0 = big
        r1 = c1 = -1
        # branch-free, so that it vectorizes: the padded cell of an event with votes is
        # (floor(y) + 1, floor(x) + 1), and y + 1 > 0 truncates to that
        for j in range(xs.shape[0]):
            xv = xs[j]
            yv = ys[j]
            ok = (xv > -1.0) & (xv < wd) & (yv > -1.0) & (yv < h)
            r = np.int64((yv if ok else 0.0) + 1.0) >> _SHIFT
            c = np.int64((xv if ok else 0.0) + 1.0) >> _SHIFT
            r0 = min(r0, r if ok else big)
            r1 = max(r1, r if ok else -1)
            c0 = min(c0, c if ok else big)
            c1 = max(c1, c if ok else -1)
        for j in range(xs.shape[0]):
            if ds[j] < margin:
                xv = xs[j]
                yv = ys[j]
                if (xv > -1.0) & (xv < wd) & (yv > -1.0) & (yv < h):
                    flat[(np.int64(yv + 1.0) >> _SHIFT) * nc
                         + (np.int64(xv + 1.0) >> _SHIFT)] = 1
        boxes[b, 0] = r0
        boxes[b, 1] = r1
        boxes[b, 2] = c0
        boxes[b, 3] = c1


@njit(cache=True, error_model="numpy")
def flag_blocks(marks, boxes, near, flags):
    """From the marked tiles: ``near`` (like ``marks``) 1 where a pixel can fall below
    the margin (the marks and their right, lower and lower-right neighbours), and
    ``flags`` (uint8, (n_blocks,)) 1 for the blocks whose box meets the marks grown by one
    tile each way (those whose events can vote into a ``near`` tile). Returns the number
    of flagged blocks."""
    nr, nc = marks.shape
    near[:] = 0
    # summed-area table of the grown marks
    sat = np.zeros((nr + 1, nc + 1), np.int64)
    for r in range(nr):
        for c in range(nc):
            if marks[r, c] == 0:
                continue
            for rr in range(r, min(r + 2, nr)):
                for cc in range(c, min(c + 2, nc)):
                    near[rr, cc] = 1
            for rr in range(max(r - 1, 0), min(r + 2, nr)):
                for cc in range(max(c - 1, 0), min(c + 2, nc)):
                    sat[rr + 1, cc + 1] = 1
    for r in range(nr):
        for c in range(nc):
            sat[r + 1, c + 1] += sat[r, c + 1] + sat[r + 1, c] - sat[r, c]
    n_flag = 0
    for b in range(boxes.shape[0]):
        r0, r1, c0, c1 = boxes[b, 0], boxes[b, 1], boxes[b, 2], boxes[b, 3]
        hit = r1 >= r0 and (sat[r1 + 1, c1 + 1] - sat[r0, c1 + 1] - sat[r1 + 1, c0]
                            + sat[r0, c0]) > 0
        flags[b] = 1 if hit else 0
        n_flag += 1 if hit else 0
    return n_flag


@njit(cache=True, error_model="numpy")
def vote_values(xw, yw, d, flags, num):
    """Pass two: the bilinear IWE of the per-event values ``d`` of the flagged blocks into
    ``num`` (H, W) (zeroed first): the arithmetic of :func:`evmotion.core.iwe.vote_pair`,
    exact on every ``near`` tile of :func:`flag_blocks`."""
    num[:] = 0.0
    flat = num.reshape(num.size)
    ib, w00, w01, w10, w11 = block_bufs(BLOCK)
    n = xw.shape[0]
    for b in range(flags.shape[0]):
        if flags[b]:
            k0 = b * BLOCK
            vote_block(xw, yw, _NO_WEIGHTS, False, num, flat, d, num, flat, True, False, k0,
                        min(k0 + BLOCK, n), ib, w00, w01, w10, w11)


@njit(cache=True, error_model="numpy", fastmath=True)
def trim_pass(cnt, num, margin, gN, gS, near):
    """Adjoint images of ``sum_{num/cnt < margin} num/cnt`` over the pixels of the ``near``
    tiles (the only ones that can be below, :func:`flag_blocks`; empty: every pixel):
    ``gN = -mean/cnt`` (of ``cnt``) and ``gS = 1/cnt`` (of ``num``) there, 0 elsewhere,
    each written flat into the image padded by a ring of zeros ((H + 2) (W + 2); the layout
    of :meth:`evmotion.core.warps.Warp.reduce_pair`). Returns (sum, n)."""
    h, w = cnt.shape
    wp = w + 2
    if near.shape[0] > 0:
        gN[:] = 0.0
        gS[:] = 0.0
    else:
        _zero_ring(gN, h, w)
        _zero_ring(gS, h, w)
    total = 0.0
    n_sel = 0
    for i in range(h):
        r = (i + 1) * wp
        if near.shape[0] == 0:
            t, k = _trim_span(cnt[i], num[i], margin, gN[r + 1:r + 1 + w], gS[r + 1:r + 1 + w])
            total += t
            n_sel += k
            continue
        row = near[(i + 1) >> _SHIFT]
        for c in range(row.shape[0]):
            if row[c] == 0:
                continue
            # the pixels j of padded column (j + 1) in tile c
            j0 = max((c << _SHIFT) - 1, 0)
            j1 = min(((c + 1) << _SHIFT) - 1, w)
            if j1 <= j0:
                continue
            t, k = _trim_span(cnt[i, j0:j1], num[i, j0:j1], margin, gN[r + 1 + j0:r + 1 + j1],
                              gS[r + 1 + j0:r + 1 + j1])
            total += t
            n_sel += k
    return total, n_sel


@njit(cache=True, error_model="numpy", fastmath=True, inline="always")
def _trim_span(cnt, num, margin, gN, gS):
    """:func:`trim_pass` over a run of pixels: branch-free (selects, no jumps) so that it
    vectorizes; fastmath only reorders the sum."""
    total = 0.0
    n_sel = 0
    for j in range(cnt.shape[0]):
        c = cnt[j]
        ok = c > MIN_COUNT
        ic = 1.0 / (c if ok else 1.0)
        m = num[j] * ic
        sel = ok and m < margin
        gs = ic if sel else 0.0
        total += m if sel else 0.0
        n_sel += 1 if sel else 0
        gN[j] = -m * gs
        gS[j] = gs
    return total, n_sel


def pairs_size(shape: tuple[int, int]) -> int:
    """Length of the buffer that holds the two padded adjoint images of
    :func:`trim_pass` and, overlapping the second, the interleaved votes of
    :func:`trim_pairs` (:func:`pairs_view`)."""
    h, w = int(shape[0]), int(shape[1])
    size = (h + 2) * (w + 2)
    return max(2 * size, size + _PAIRS_AT + 2 * h * w)


def pairs_view(buf: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The (H, W, 2) interleaved votes inside a :func:`pairs_size` buffer: from the
    ``_PAIRS_AT``-th value of the second adjoint image on, so that :func:`trim_pairs` writes
    that image over rows it has read (one image of memory less than apart: at 500k
    events the cost's working set no longer fills the last-level cache)."""
    h, w = int(shape[0]), int(shape[1])
    at = (h + 2) * (w + 2) + _PAIRS_AT
    return buf[at:at + 2 * h * w].reshape(h, w, 2)


_PAIRS_AT = 4  # offset of the votes in the second image (an even one keeps them aligned)


@njit(cache=True, error_model="numpy", fastmath=True)
def trim_pairs(pairs, margin, gN, gS, cnt_out):
    """:func:`trim_pass` over every pixel of the interleaved (H, W, 2) image of counts and
    sums of values of :func:`evmotion.core.iwe.vote_pairs`, the counts copied into
    ``cnt_out`` (H, W). ``pairs`` may lie in ``gS`` as :func:`pairs_view` puts it: each of
    its rows is read before the values of ``gS`` that overlap it are written (row i of
    ``gS`` and its ring ends before row i + 1 of ``pairs`` starts, the top ring reaches row
    0 only, the bottom ring is written last)."""
    h, w = pairs.shape[0], pairs.shape[1]
    wp = w + 2
    _zero_ring(gN, h, w)
    total = 0.0
    n_sel = 0
    num = np.empty(w)
    for i in range(h):
        r = (i + 1) * wp
        row = pairs[i].reshape(2 * w)
        cnt = cnt_out[i]
        for j in range(w):
            cnt[j] = row[2 * j]
            num[j] = row[2 * j + 1]
        if i == 0:
            gS[:wp] = 0.0
        gS[r] = 0.0
        gS[r + wp - 1] = 0.0
        t, k = _trim_span(cnt, num, margin, gN[r + 1:r + 1 + w], gS[r + 1:r + 1 + w])
        total += t
        n_sel += k
    gS[(h + 1) * wp:(h + 2) * wp] = 0.0
    return total, n_sel


@njit(cache=True, error_model="numpy", inline="always")
def _zero_ring(g, h, w):
    """Zeros on the ring of the (h + 2, w + 2) padded image ``g`` (flat)."""
    wp = w + 2
    for j in range(wp):
        g[j] = 0.0
        g[(h + 1) * wp + j] = 0.0
    for i in range(1, h + 1):
        g[i * wp] = 0.0
        g[i * wp + wp - 1] = 0.0
