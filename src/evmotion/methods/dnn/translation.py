"""The window's sharpest global translation, found by a coarse-to-fine grid search: a check
on the network's flow that needs no training.

A network trained on windows that move a few px fails on windows that move far more, and
its failure can look like a measurement: a 346x260 window translating 47 px came out at
19 px from every input scale, sharpened 2.4x (the truth 7.3x), valid (probe BT). The
events' sharpest translation needs no network: the count image of the events moved back
to the window's midpoint is scored (its sum of squares) on a grid of translations, first
on the image binned coarsely enough that the whole reach is 8 cells either way, then
around the best at each finer binning down to whole px. numpy only, as the rest of the dnn
path (numba's import and compilation cost a one-window command 0.5-1 s).
"""

from __future__ import annotations

import numpy as np

__all__ = ["REACH", "sharpest_translation"]

#: How far the search looks, px over the window, as a fraction of the sensor's longer side.
REACH = 0.5
# cells either way at the coarsest binning, and the events scored there (evenly spaced;
# a coarse image needs few to rank translations whole cells apart)
_CELLS = 8
_COARSE_EVENTS = 8000


def _score(x: np.ndarray, y: np.ndarray, s: np.ndarray, shape: tuple[int, int], k: int,
           dx: float, dy: float) -> float:
    """Sum of squares of the count image, binned ``k`` x ``k``, of the events moved by
    ``(dx, dy)`` px over the window to its midpoint (``s``: time in windows from it)."""
    h, w = shape
    hk, wk = -(-h // k), -(-w // k)
    xw = np.floor((x - dx * s) / k).astype(np.int64)
    yw = np.floor((y - dy * s) / k).astype(np.int64)
    inside = (xw >= 0) & (xw < wk) & (yw >= 0) & (yw < hk)
    counts = np.bincount(yw[inside] * wk + xw[inside], minlength=hk * wk)
    return float(np.dot(counts, counts))


def sharpest_translation(x: np.ndarray, y: np.ndarray, s: np.ndarray,
                         shape: tuple[int, int], reach: float | None = None
                         ) -> tuple[float, float]:
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
    reach = REACH * max(h, w) if reach is None else float(reach)
    k = 1
    while reach / k > _CELLS:
        k *= 2
    coarse = np.linspace(0, x.size - 1, min(x.size, _COARSE_EVENTS)).astype(np.intp)
    best, cells = (0.0, 0.0), int(np.ceil(reach / k))
    while True:
        pick = coarse if k > 2 else slice(None)
        steps = np.arange(-cells, cells + 1) * float(k)
        grid = [(best[0] + i, best[1] + j) for j in steps for i in steps]
        scores = [_score(x[pick], y[pick], s[pick], shape, k, dx, dy) for dx, dy in grid]
        # (a tie keeps the smaller move: a window no translation sharpens stays still)
        best = min(zip(scores, grid, strict=True),
                   key=lambda sg: (-sg[0], abs(sg[1][0]) + abs(sg[1][1])))[1]
        if k == 1:
            return float(best[0]), float(best[1])
        k //= 2
        cells = 2
