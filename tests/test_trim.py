"""The sparse votes of the trimmed means (core.trim) against plain numpy: the count image,
the tile marks and block boxes, the guarantee that every pixel whose mean is below the
margin lies on a ``near`` tile where the sparse image of values is exact, and that
reduce_pair with the block flags gives the gradient of every event."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import bilinear_adjoint_numpy
from evmotion.core.iwe import accumulate
from evmotion.core.trim import (
    BLOCK,
    MIN_COUNT,
    TILE,
    flag_blocks,
    n_blocks,
    tile_grid,
    trim_pass,
    vote_marked,
    vote_values,
)
from evmotion.core.warps import make_warp
from evmotion.errors import ParameterError

SHAPE = (45, 70)


def _cloud(seed, n=3000):
    """Events clustered by position (as in CMax's tile order), some across and beyond the
    border and one NaN; values below the margin in a disc only."""
    rng = np.random.default_rng(seed)
    h, w = SHAPE
    xw = np.sort(rng.uniform(-3.0, w + 2.0, n))
    yw = rng.uniform(-3.0, h + 2.0, n)
    xw[5] = np.nan
    yw[:4] = [-1.0, -0.5, h - 1.0, h]
    d = rng.uniform(0.0, 1.0, n)
    disc = (xw - 0.3 * w) ** 2 + (yw - 0.6 * h) ** 2 < 8.0**2
    d[disc] = rng.uniform(-2.0, 0.5, disc.sum())
    return xw, yw, d


def _padded_tiles(ix, iy):
    return (iy + 1) // TILE, (ix + 1) // TILE


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sparse_votes_match_numpy(seed):
    xw, yw, d = _cloud(seed)
    h, w = SHAPE
    n = xw.shape[0]
    margin = -0.2
    grid = tile_grid(SHAPE)
    marks, near = np.empty(grid, np.uint8), np.empty(grid, np.uint8)
    boxes = np.empty((n_blocks(n), 4), np.int64)
    flags = np.empty(n_blocks(n), np.uint8)
    cnt, num = np.full(SHAPE, np.nan), np.full(SHAPE, np.nan)
    vote_marked(xw, yw, d, margin, cnt, True, marks, boxes)
    n_flag = flag_blocks(marks, boxes, near, flags)
    vote_values(xw, yw, d, flags, num)
    # the count image is the IWE, bit for bit
    np.testing.assert_array_equal(cnt, accumulate(xw, yw, SHAPE))
    # marks and boxes from the cells of the events with votes
    votes = (xw > -1) & (xw < w) & (yw > -1) & (yw < h)
    ix, iy = np.floor(xw[votes]).astype(int), np.floor(yw[votes]).astype(int)
    tr, tc = _padded_tiles(ix, iy)
    ref = np.zeros(grid, np.uint8)
    below = d[votes] < margin
    ref[tr[below], tc[below]] = 1
    np.testing.assert_array_equal(marks, ref)
    blk = np.flatnonzero(votes) // BLOCK
    for b in range(0, n_blocks(n), 7):
        sel = blk == b
        if sel.any():
            assert list(boxes[b]) == [tr[sel].min(), tr[sel].max(), tc[sel].min(),
                                      tc[sel].max()]
        else:
            assert boxes[b, 0] > boxes[b, 1]
    assert 0 < n_flag == flags.sum() < n_blocks(n)
    # every pixel below the margin is on a near tile, where the values' image is exact
    full = accumulate(xw, yw, SHAPE, weights=np.nan_to_num(d, nan=0.0))
    sup = cnt > MIN_COUNT
    mean = np.divide(full, cnt, out=np.zeros(SHAPE), where=sup)
    rows, cols = np.mgrid[0:h, 0:w]
    on_near = near[(rows + 1) // TILE, (cols + 1) // TILE] > 0
    low = sup & (mean < margin)
    assert low.sum() > 10 and on_near[low].all() and not on_near.all()
    np.testing.assert_allclose(num[on_near], full[on_near], rtol=1e-12, atol=1e-12)
    # the trim over near tiles selects what the full maps select
    size = (h + 2) * (w + 2)
    pads = np.full(2 * size, np.nan)
    total, n_sel = trim_pass(cnt, num, margin, pads[:size], pads[size:], near)
    assert n_sel == low.sum() and total == pytest.approx(mean[low].sum(), rel=1e-12)
    img = pads.reshape(2, h + 2, w + 2)
    gS = np.where(low, 1.0 / np.where(sup, cnt, 1.0), 0.0)
    np.testing.assert_allclose(img[1, 1:-1, 1:-1], gS, rtol=1e-15)
    np.testing.assert_allclose(img[0, 1:-1, 1:-1], -mean * gS, rtol=1e-15)


def test_interleaved_votes_and_trim_match_the_two_images():
    """Where most values are below the margin, counts and values are voted into one
    interleaved image (bit for bit the two images) and trimmed from it, the counts copied
    out for the caller."""
    from evmotion.core.iwe import vote_pair as _vote_pair
    from evmotion.core.iwe import vote_pairs as _vote_pairs
    from evmotion.core.trim import pairs_size, pairs_view, trim_pairs

    xw, yw, d = _cloud(4)
    h, w = SHAPE
    pairs = np.full(SHAPE + (2,), np.nan)
    _vote_pairs(xw, yw, d, pairs)
    cnt, num = np.empty(SHAPE), np.empty(SHAPE)
    _vote_pair(xw, yw, d, cnt, num, True)
    np.testing.assert_array_equal(pairs[..., 0], cnt)
    np.testing.assert_array_equal(pairs[..., 1], num)
    size = (h + 2) * (w + 2)
    ref, got = np.full(2 * size, np.nan), np.full(2 * size, np.nan)
    out = np.full(SHAPE, np.nan)
    r = trim_pass(cnt, num, 0.3, ref[:size], ref[size:], np.zeros((0, 0), np.uint8))
    g = trim_pairs(pairs, 0.3, got[:size], got[size:], out)
    assert r[1] > 100 and g[1] == r[1] and g[0] == pytest.approx(r[0], rel=1e-13)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(out, cnt)
    # the votes inside the second adjoint image's memory (pairs_view), overwritten there
    for shape in (SHAPE, (3, 4), (1, 2)):
        hh, ww = shape
        sz = (hh + 2) * (ww + 2)
        x2, y2 = xw * ww / w, yw * hh / h
        buf = np.full(pairs_size(shape), np.nan)
        view = pairs_view(buf, shape)
        _vote_pairs(x2, y2, d, view)
        sep = np.empty(shape + (2,))
        _vote_pairs(x2, y2, d, sep)
        ref2 = np.full(2 * sz, np.nan)
        r2 = trim_pairs(sep, 0.3, ref2[:sz], ref2[sz:], np.empty(shape))
        out2 = np.full(shape, np.nan)
        g2 = trim_pairs(view, 0.3, buf[:sz], buf[sz:2 * sz], out2)
        assert g2 == r2
        np.testing.assert_array_equal(buf[:2 * sz], ref2)
        np.testing.assert_array_equal(out2, sep[..., 0])


def test_no_value_below_flags_nothing():
    xw, yw, d = _cloud(3)
    d = np.abs(d) + 1.0
    grid = tile_grid(SHAPE)
    marks, near = np.empty(grid, np.uint8), np.empty(grid, np.uint8)
    nb = n_blocks(xw.shape[0])
    boxes, flags = np.empty((nb, 4), np.int64), np.empty(nb, np.uint8)
    vote_marked(xw, yw, d, -0.2, np.empty(SHAPE), False, marks, boxes)
    assert flag_blocks(marks, boxes, near, flags) == 0
    assert not marks.any() and not near.any() and not flags.any()


@pytest.mark.parametrize("fast", [1.0, 12.0])
def test_reduce_pair_with_block_flags_equals_every_block(fast):
    """The flagged blocks with both images and the others with the first only give the
    gradient of every event (B nonzero on a few columns, events in column order); the
    rotation's series modes included (fast: |dt omega| beyond 1 rad)."""
    rng = np.random.default_rng(4)
    h, w = SHAPE
    n = 2500
    x = np.sort(rng.uniform(-2.0, w + 1.0, n))
    y = rng.uniform(-2.0, h + 1.0, n)
    dt = rng.uniform(-0.02, 0.03, n)
    K = np.array([[60.0, 0.0, 35.0], [0.0, 60.0, 22.0], [0.0, 0.0, 1.0]])
    warp = make_warp("rotation", SHAPE, K=K)
    theta = fast * np.array([1.5, -2.0, 1.0])
    xw, yw, jx, jy = warp.warp(x, y, dt, theta, jacobian=True)
    A, B = rng.normal(size=SHAPE), rng.normal(size=SHAPE)
    B[:, np.arange(w) % 30 >= 5] = 0.0
    d = rng.normal(size=n)
    pads = np.zeros((2, h + 2, w + 2))
    pads[0, 1:-1, 1:-1] = A
    pads[1, 1:-1, 1:-1] = B
    # flags: the blocks with an event whose cell touches a column where B != 0
    ax, ay, _ = bilinear_adjoint_numpy(xw, yw, A)
    bx, by, _ = bilinear_adjoint_numpy(xw, yw, B)
    touches = (np.abs(bx) + np.abs(by)) > 0
    flags = np.zeros(n_blocks(n), np.uint8)
    flags[np.flatnonzero(touches) // BLOCK] = 1
    assert 0 < flags.sum() < flags.size
    for derivs in (None, "divergence", "deformation"):
        ref = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3),
                               0.7, derivs, 0.05)
        got = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3),
                               0.7, derivs, 0.05, flags)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    votes = ((ax + d * bx) @ jx + (ay + d * by) @ jy) * 0.7
    got = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3), 0.7,
                           None, 1.0, flags)
    np.testing.assert_allclose(got, votes, rtol=1e-9, atol=1e-11 * np.abs(votes).max())
    # all flagged, none flagged (B = 0): the same
    ones = np.ones_like(flags)
    got = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3), 0.7,
                           None, 1.0, ones)
    np.testing.assert_allclose(got, votes, rtol=1e-9, atol=1e-11 * np.abs(votes).max())
    pads[1] = 0.0
    ref = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3), 0.7)
    got = warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3), 0.7,
                           None, 1.0, np.zeros_like(flags))
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    with pytest.raises(ParameterError, match="blocks"):
        warp.reduce_pair(x, y, dt, xw, yw, theta, pads, d, np.empty(3), 0.7,
                         None, 1.0, flags[1:])
