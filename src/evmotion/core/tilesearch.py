"""Tiles whose events a translation of their own sharpens far more than the coarse-to-fine
flow does: where multicm restarts.

A coarse scale fits one translation to regions that move differently. Where one region
dominates the events (a large textured object over a sparser background) every finer tile
inherits its motion, and a tile of the other region, its events displaced farther than the
focus basin (a few px) from where that motion puts them, never leaves it: a probe's own
renderer (346x260, a 90-px patch at (180, 90) px/s over a background at (-60, 30) px/s,
60-74 % of the events on the patch) came out with the patch's flow everywhere, AEE above
the zero flow's, valid (probe BZ). Each tile's events are scored here under the tile's
flow and under their own sharpest translation (:func:`~evmotion.core.translation.
sharpest_translation`, scored with numba within the events' bounding box,
:func:`box_scores_jit`; :mod:`evmotion.core.translation` holds its numpy twin); the tiles
that translation sharpens :data:`RESTART_GAIN` times more are where a restart starts from
it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.core import translation
from evmotion.core.tilegrid import TileGrid, event_tiles

__all__ = ["RESTART_GAIN", "box_scores_jit", "jit_scores", "tile_gains", "tile_restarts"]

#: A tile's own translation must sharpen its events this much more than the flow does
#: (sum of squares of their count image) to restart it. The probe's background tiles
#: scored 1.7-2.0 against the patch's flow; tiles whose flow is right 0.86-1.12.
RESTART_GAIN = 1.25


@njit(cache=True)
def box_scores_jit(x, y, s, k, dxs, dys):
    """Sum of squares of the count image, binned ``k`` x ``k``, of the events moved by each
    ``(dxs[c], dys[c])`` px over the window to its midpoint (``s``: time in windows from
    it); unbounded (the image is the moved events' bounding box)."""
    n = x.size
    out = np.empty(dxs.size)
    cx = np.empty(n, np.int64)
    cy = np.empty(n, np.int64)
    for c in range(dxs.size):
        x0 = y0 = np.iinfo(np.int64).max
        x1 = y1 = np.iinfo(np.int64).min
        for i in range(n):
            cx[i] = np.int64(np.floor((x[i] - dxs[c] * s[i]) / k))
            cy[i] = np.int64(np.floor((y[i] - dys[c] * s[i]) / k))
            x0, x1 = min(x0, cx[i]), max(x1, cx[i])
            y0, y1 = min(y0, cy[i]), max(y1, cy[i])
        total = 0.0
        if n:
            w = x1 - x0 + 1
            counts = np.zeros((y1 - y0 + 1) * w, np.int64)
            for i in range(n):
                counts[(cy[i] - y0) * w + cx[i] - x0] += 1
            for j in range(counts.size):
                total += float(counts[j]) * float(counts[j])
        out[c] = total
    return out


def jit_scores(x, y, s, k, dxs, dys) -> np.ndarray:
    """:func:`box_scores_jit` on any arrays: the ``scores`` of
    :func:`evmotion.core.translation.tile_gains` and
    :func:`~evmotion.core.translation.sharpest_translation`."""
    return box_scores_jit(np.ascontiguousarray(x, np.float64),
                          np.ascontiguousarray(y, np.float64),
                          np.ascontiguousarray(s, np.float64), int(k),
                          np.ascontiguousarray(dxs, np.float64),
                          np.ascontiguousarray(dys, np.float64))


def tile_gains(x: np.ndarray, y: np.ndarray, s: np.ndarray, disp: np.ndarray,
               grid: TileGrid, reach: float, **kw) -> tuple[np.ndarray, np.ndarray]:
    """:func:`evmotion.core.translation.tile_gains`, scored with numba."""
    return translation.tile_gains(x, y, s, disp, grid, reach, scores=jit_scores, **kw)


def tile_restarts(x: np.ndarray, y: np.ndarray, s: np.ndarray, params: np.ndarray,
                  grid: TileGrid, reach: float) -> np.ndarray | None:
    """``params`` with each tile whose events' own sharpest translation (within ``reach``
    px) scores :data:`RESTART_GAIN` times its flow's replaced by that translation, or None
    where no tile does (:func:`tile_gains`, each tile's events moved by its own flow).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x0, y0 = rng.uniform(0, 64, 400), rng.uniform(0, 32, 400)
    >>> s = np.repeat(np.linspace(-0.5, 0.5, 15), 400)
    >>> left = np.tile(x0, 15) < 32                   # the left half moves 12 px right
    >>> x = np.floor(np.tile(x0, 15) + np.where(left, 12.0, 0.0) * s)
    >>> y = np.floor(np.tile(y0, 15))
    >>> start = np.zeros((1, 2, 2)); start[..., 0] = 12.0     # both tiles at 12 px
    >>> tile_restarts(x, y, s, start, TileGrid(1, 2, (32, 64)), 20.0)[0].tolist()
    [[12.0, 0.0], [0.0, 0.0]]
    """
    disp = np.asarray(params, dtype=np.float64).reshape(-1, 2)[event_tiles(x, y, grid)]
    # every tile, those moving far too: a restart is only a start, and the finest scale's
    # objective decides (the translations that tile search found for 25-40 px windows
    # took them from 25-38 px to 0.2-12 px, probe CA)
    best, gain = tile_gains(x, y, s, disp, grid, reach, max_move=np.inf)
    restart = gain >= RESTART_GAIN
    if not restart.any():
        return None
    out = np.array(params, dtype=np.float64, copy=True)
    out[restart] = best[restart]
    return out
