"""The sharpest translation of a set of events, found by a coarse-to-fine grid search: a
check on a flow that needs no training and no start.

A network trained on windows that move a few px fails on windows that move far more, and
its failure can look like a measurement: a 346x260 window translating 47 px came out at
19 px from every input scale, sharpened 2.4x (the truth 7.3x), valid (probe BT). Where one
region's motion dominates, multicm's coarse scales lock every tile onto it (probe BZ).
The events' sharpest translation needs neither: the count image of the events moved back
to the window's midpoint is scored (its sum of squares) on a grid of translations, first
on the image binned coarsely enough that the whole reach is 8 cells either way, then
around the best at each finer binning down to whole px. numpy only (the dnn path avoids
numba's import, 0.5-1 s of a one-window command); :mod:`evmotion.core.tilesearch` scores
with numba, tile by tile.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from evmotion.core.tilegrid import TileGrid, event_tiles

__all__ = ["MAX_TILE_MOVE", "MIN_TILE_EVENTS", "REACH", "SEARCH_EVENTS", "TILE_REACH",
           "box_scores", "sharpest_translation", "tile_gains", "translation_scores"]

#: How far the search looks, px over the window, as a fraction of the sensor's longer side.
REACH = 0.5
#: How far a tile's own translation is searched (multicm's restarts, the other-motion
#: check), the same fraction.
TILE_REACH = 0.25
# cells either way at the coarsest binning, and the events scored there (evenly spaced;
# a coarse image needs few to rank translations whole cells apart)
_CELLS = 8
_COARSE_EVENTS = 8000
#: Tiles with fewer events are not searched (their count image ranks nothing).
MIN_TILE_EVENTS = 100
#: The search ranks translations on at most this many of a tile's events, evenly spaced
#: in time (the comparison with the tile's flow takes them all): 16 tiles of a 30k-event
#: window took 31 ms with all of them.
SEARCH_EVENTS = 1000
#: A tile whose events move (under the flow, or under their own best translation) more
#: than this share of its smaller side gets no verdict: the events that cross the tile's
#: pixels then pile up unmoved as they do on no moved image (probe CA: one translation of
#: 12-20 px on 40x32, tiles 10x8, scored 1.5-2.3x better left unmoved than moved right).
MAX_TILE_MOVE = 0.5
# candidates x events scored at once by box_scores (bounded memory)
_CHUNK = 1 << 21


def translation_scores(x: np.ndarray, y: np.ndarray, s: np.ndarray, k: int,
                       dxs: np.ndarray, dys: np.ndarray, shape: tuple[int, int]
                       ) -> np.ndarray:
    """Sum of squares of the count image, binned ``k`` x ``k`` over the sensor ``shape``,
    of the events moved by each ``(dxs[c], dys[c])`` px over the window to its midpoint
    (``s``: time in windows from it); events moved off the sensor are not counted.

    Examples
    --------
    >>> translation_scores(np.array([0.0, 2.0]), np.zeros(2), np.array([-0.5, 0.5]), 1,
    ...                    np.array([0.0, 2.0]), np.zeros(2), (1, 4)).tolist()
    [2.0, 4.0]
    """
    h, w = shape
    hk, wk = -(-h // k), -(-w // k)
    out = np.empty(len(dxs))
    for c, (dx, dy) in enumerate(zip(dxs, dys, strict=True)):
        xw = np.floor((x - dx * s) / k).astype(np.int64)
        yw = np.floor((y - dy * s) / k).astype(np.int64)
        inside = (xw >= 0) & (xw < wk) & (yw >= 0) & (yw < hk)
        counts = np.bincount(yw[inside] * wk + xw[inside], minlength=hk * wk)
        out[c] = float(np.dot(counts, counts))
    return out


def sharpest_translation(x: np.ndarray, y: np.ndarray, s: np.ndarray,
                         shape: tuple[int, int], reach: float | None = None, *,
                         scores: Callable | None = None) -> tuple[float, float]:
    """The translation ``(dx, dy)`` (px over the window, whole px) within ``reach`` px that
    moves the events to the sharpest image at the window's midpoint.

    Parameters
    ----------
    x, y : ndarray
        Event pixels.
    s : ndarray
        Event times in windows from the window's midpoint (-0.5 to 0.5).
    shape : (H, W)
        Sensor size in px.
    reach : float, optional
        Largest |dx|, |dy| searched, px; default :data:`REACH` times the longer side.
    scores : callable, optional
        ``scores(x, y, s, k, dxs, dys) -> ndarray``, each candidate's score (higher is
        sharper); default :func:`translation_scores` on the sensor.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x0, y0 = rng.uniform(0, 100, 300), rng.uniform(0, 80, 300)   # 300 dots
    >>> s = np.repeat(np.linspace(-0.5, 0.5, 20), 300)                # seen 20 times
    >>> x, y = np.tile(x0, 20) + 30 * s, np.tile(y0, 20) - 12 * s     # moving (30, -12) px
    >>> sharpest_translation(x, y, s, (80, 100))
    (30.0, -12.0)
    """
    h, w = shape
    x, y, s = (np.asarray(a, dtype=np.float64) for a in (x, y, s))
    if scores is None:
        def scores(x, y, s, k, dxs, dys):
            return translation_scores(x, y, s, k, dxs, dys, (h, w))
    reach = REACH * max(h, w) if reach is None else float(reach)
    k = 1
    while reach / k > _CELLS:
        k *= 2
    coarse = np.linspace(0, x.size - 1, min(x.size, _COARSE_EVENTS)).astype(np.intp)
    best, cells = (0.0, 0.0), int(np.ceil(reach / k))
    while True:
        pick = coarse if k > 2 else slice(None)
        steps = np.arange(-cells, cells + 1) * float(k)
        dxs = np.tile(steps, steps.size) + best[0]
        dys = np.repeat(steps, steps.size) + best[1]
        sc = np.asarray(scores(x[pick], y[pick], s[pick], k, dxs, dys), dtype=np.float64)
        # (a tie keeps the smaller move: a window no translation sharpens stays still)
        c = min(range(sc.size), key=lambda i: (-sc[i], abs(dxs[i]) + abs(dys[i])))
        best = (float(dxs[c]), float(dys[c]))
        if k == 1:
            return best
        k //= 2
        cells = 2


def box_scores(x: np.ndarray, y: np.ndarray, s: np.ndarray, k: int, dxs: np.ndarray,
               dys: np.ndarray) -> np.ndarray:
    """Sum of squares of the count image, binned ``k`` x ``k``, of the events moved by each
    ``(dxs[c], dys[c])`` px over the window to its midpoint (``s``: time in windows from
    it); unbounded (each image is its moved events' bounding box).

    Examples
    --------
    >>> box_scores(np.array([0.0, 2.0]), np.zeros(2), np.array([-0.5, 0.5]), 1,
    ...            np.array([0.0, 2.0, -40.0]), np.zeros(3)).tolist()
    [2.0, 4.0, 2.0]
    """
    x, y, s = (np.asarray(a, dtype=np.float64) for a in (x, y, s))
    dxs, dys = np.asarray(dxs, np.float64), np.asarray(dys, np.float64)
    out = np.zeros(dxs.size)
    if not x.size:
        return out
    step = max(1, _CHUNK // x.size)
    for c0 in range(0, dxs.size, step):
        c = slice(c0, c0 + step)
        cx = np.floor((x - dxs[c, None] * s) / k).astype(np.int64)
        cy = np.floor((y - dys[c, None] * s) / k).astype(np.int64)
        cx -= cx.min(axis=1, keepdims=True)
        cy -= cy.min(axis=1, keepdims=True)
        w = cx.max(axis=1) + 1
        size = w * (cy.max(axis=1) + 1)
        start = np.concatenate([[0], np.cumsum(size)[:-1]])
        counts = np.bincount((start[:, None] + cy * w[:, None] + cx).ravel(),
                             minlength=int(size.sum())).astype(np.float64)
        out[c] = np.add.reduceat(counts * counts, start)
    return out


def tile_gains(x: np.ndarray, y: np.ndarray, s: np.ndarray, disp: np.ndarray,
               grid: TileGrid, reach: float, *, scores: Callable | None = None,
               max_move: float = MAX_TILE_MOVE) -> tuple[np.ndarray, np.ndarray]:
    """Each tile's own sharpest translation, and how much more it sharpens the tile's
    events than their displacements ``disp`` do.

    Parameters
    ----------
    x, y : ndarray
        Event positions, px.
    s : ndarray
        Event times in windows from the window's midpoint (-0.5 to 0.5).
    disp : ndarray, (N, 2)
        Each event's displacement over the window (the flow's), px.
    grid : TileGrid
    reach : float
        Largest |dx|, |dy| searched, px over the window.
    scores : callable, optional
        As for :func:`sharpest_translation`; default :func:`box_scores` (numpy;
        :mod:`evmotion.core.tilesearch` passes its numba twin).
    max_move : float
        Tiles moving more than this share of their smaller side get no verdict
        (default :data:`MAX_TILE_MOVE`; ``inf``: every tile).

    Returns
    -------
    best : ndarray, (ny, nx, 2)
        The translation, px over the window.
    gain : ndarray, (ny, nx)
        Its score (sum of squares of the moved events' count image) over that of the
        events moved by ``disp``; NaN for tiles under :data:`MIN_TILE_EVENTS` events, or
        moving more than ``max_move`` of their smaller side.
    """
    x, y, s = (np.asarray(a, dtype=np.float64) for a in (x, y, s))
    disp = np.asarray(disp, dtype=np.float64)
    scores = box_scores if scores is None else scores
    tile = event_tiles(x, y, grid)
    order = np.argsort(tile, kind="stable")
    bounds = np.searchsorted(tile[order], np.arange(grid.ny * grid.nx + 1))
    best = np.zeros((grid.ny, grid.nx, 2))
    gain = np.full((grid.ny, grid.nx), np.nan)
    far = max_move * min(grid.spacing)
    zero = np.zeros(1)
    for t in range(grid.ny * grid.nx):
        idx = order[bounds[t]:bounds[t + 1]]
        if idx.size < MIN_TILE_EVENTS:
            continue
        xt, yt, st = x[idx], y[idx], s[idx]
        few = np.linspace(0, idx.size - 1, min(idx.size, SEARCH_EVENTS)).astype(np.intp)
        b = sharpest_translation(xt[few], yt[few], st[few], grid.shape, reach,
                                 scores=scores)
        then = scores(xt, yt, st, 1, np.array([b[0]]), np.array([b[1]]))[0]
        now = scores(xt - disp[idx, 0] * st, yt - disp[idx, 1] * st, st, 1, zero, zero)[0]
        # whole-px translations near the tile's own displacement, too: a whole-px shift
        # of events on whole pixels piles them up as no fractional one does (60 dots
        # moving 3 px over a window: multicm's 2.9 px scored 1.5-1.9x below the 3-px
        # shift, and 8 of 16 tiles had been flagged)
        mx, my = np.rint(np.median(disp[idx], axis=0))
        best[t // grid.nx, t % grid.nx] = b
        if max(np.hypot(*b), np.hypot(mx, my)) > far:
            continue
        near = np.arange(-1.0, 2.0)
        now = max(now, float(scores(xt, yt, st, 1, np.tile(near, 3) + mx,
                                     np.repeat(near, 3) + my).max()))
        gain[t // grid.nx, t % grid.nx] = then / now
    return best, gain
