"""The tile grid of a dense flow field (ch. 4), in numpy: the grid and its geometry, the
bilinear stencils between tile centres and pixels or events, tile means, and the finest
level a window's events support. The numba kernels that warp events with it are
:mod:`evmotion.core.tileflow`'s (which re-exports these names).

Geometry: the centre of tile ``i`` along an axis of ``L`` pixels split into ``n`` tiles
is at pixel coordinate ``(i + 0.5) * L / n - 0.5`` (pixel centres are integers, origin
top-left, x = column, y = row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "AUTO_EVENTS_PER_TILE",
    "AUTO_FINEST_LEVEL",
    "TileGrid",
    "auto_finest_level",
    "axis_matrix",
    "charbonnier_tv",
    "dense_flow",
    "event_tile_means",
    "event_tiles",
    "event_weights",
    "pixel_tiles",
    "resample",
    "scale_grid",
    "tile_means",
]

#: ``finest_level=None`` (the default) ends the coarse-to-fine at the finest level, at most
#: ``AUTO_FINEST_LEVEL`` (16 x 16 tiles, the thesis'), whose tiles hold at least this many
#: events on average. Each tile's flow has two unknowns; fitted to a few dozen events it
#: follows their noise. ECD rotation windows thinned to 8k / 4k events, against their IMU
#: flow: AEE 0.81-0.94 / 1.47-1.92 px with 16 x 16 tiles, 0.63-0.71 / 0.88-1.17 px so;
#: the simulator's rigid scenes at 2k-15k events 4-53 % lower, its moving object 8-21 %
#: higher; the 30k-40k windows of the thesis keep 16 x 16
#: (``benchmarks/results/multicm_finest.md``).
AUTO_EVENTS_PER_TILE = 100
AUTO_FINEST_LEVEL = 5


@dataclass(frozen=True)
class TileGrid:
    """A ``ny x nx`` tile grid over an image of ``shape = (height, width)`` pixels.

    Examples
    --------
    >>> g = TileGrid(2, 2, (4, 4))
    >>> g.centers_x().tolist()
    [0.5, 2.5]
    """

    ny: int
    nx: int
    shape: tuple[int, int]

    def centers_x(self) -> np.ndarray:
        """Tile-centre column coordinates (px), shape ``(nx,)``."""
        return (np.arange(self.nx) + 0.5) * self.shape[1] / self.nx - 0.5

    def centers_y(self) -> np.ndarray:
        """Tile-centre row coordinates (px), shape ``(ny,)``."""
        return (np.arange(self.ny) + 0.5) * self.shape[0] / self.ny - 0.5

    @property
    def spacing(self) -> tuple[float, float]:
        """Distance between neighbouring centres ``(dy, dx)`` in pixels."""
        return self.shape[0] / self.ny, self.shape[1] / self.nx


def scale_grid(level: int, shape: tuple[int, int]) -> TileGrid:
    """The grid of scale ``level`` (1 = coarsest): ``2**(level-1)`` tiles per axis."""
    n = 2 ** (level - 1)
    return TileGrid(n, n, (int(shape[0]), int(shape[1])))


def _axis_weights(pos: np.ndarray, n: int, length: int):
    """Left index and right weight of the 1-D interpolation at ``pos`` (px)."""
    s = (np.asarray(pos, dtype=np.float64) + 0.5) * n / length - 0.5
    if n == 1:
        return np.zeros(s.shape, np.int64), np.zeros(s.shape, np.float64)
    # linear extrapolation in the outer half tiles, so that affine flows (rotation,
    # zoom) are represented exactly up to the image border
    s = np.clip(s, -0.5, n - 0.5)
    i0 = np.clip(np.floor(s).astype(np.int64), 0, n - 2)
    return i0, s - i0


def axis_matrix(pos: np.ndarray, n: int, length: int) -> np.ndarray:
    """Matrix ``(len(pos), n)`` interpolating ``n`` tile-centre values at positions ``pos``.

    Examples
    --------
    >>> axis_matrix(np.array([0.5, 1.5, 2.5]), 2, 4).round(2).tolist()
    [[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]]
    """
    pos = np.asarray(pos, dtype=np.float64)
    m = np.zeros((pos.size, n))
    i0, f = _axis_weights(pos, n, length)
    rows = np.arange(pos.size)
    np.add.at(m, (rows, i0), 1.0 - f)
    if n > 1:
        np.add.at(m, (rows, i0 + 1), f)
    return m


def event_weights(x: np.ndarray, y: np.ndarray, grid: TileGrid) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation stencil of each event on the tile grid.

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        Event column and row (px, sub-pixel allowed).
    grid : TileGrid

    Returns
    -------
    idx : ndarray, shape (N, 4), int64
        Flat tile indices (``iy * nx + ix``).
    w : ndarray, shape (N, 4), float64
        Their weights (sum to 1; slightly negative in the outer half tiles, where the
        interpolation extrapolates linearly).
    """
    iy, fy = _axis_weights(y, grid.ny, grid.shape[0])
    ix, fx = _axis_weights(x, grid.nx, grid.shape[1])
    dy = 1 if grid.ny > 1 else 0
    dx = 1 if grid.nx > 1 else 0
    idx = np.stack([iy * grid.nx + ix, iy * grid.nx + ix + dx,
                    (iy + dy) * grid.nx + ix, (iy + dy) * grid.nx + ix + dx], axis=1)
    w = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx], axis=1)
    return np.ascontiguousarray(idx), np.ascontiguousarray(w)


def dense_flow(params: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Interpolate tile parameters ``(ny, nx, 2)`` to every pixel: ``(H, W, 2)`` float64."""
    ny, nx = params.shape[:2]
    return _separable(params, axis_matrix(np.arange(shape[0]), ny, shape[0]),
                      axis_matrix(np.arange(shape[1]), nx, shape[1]))


def pixel_tiles(shape: tuple[int, int], grid: TileGrid) -> tuple[np.ndarray, np.ndarray]:
    """Row and column index ``(ty (H, 1), tx (1, W))`` of the tile each pixel falls in.

    Examples
    --------
    >>> ty, tx = pixel_tiles((2, 4), TileGrid(1, 2, (2, 4)))
    >>> tx.ravel().tolist()
    [0, 0, 1, 1]
    """
    h, w = shape
    ty = np.minimum(np.arange(h) * grid.ny // h, grid.ny - 1)
    tx = np.minimum(np.arange(w) * grid.nx // w, grid.nx - 1)
    return ty[:, None], tx[None, :]


def event_tiles(x: np.ndarray, y: np.ndarray, grid: TileGrid) -> np.ndarray:
    """The flat index (``row * nx + col``) of the tile each event at ``x``, ``y`` (px, taken
    to the pixel below, clipped to the image) falls in.

    Examples
    --------
    >>> event_tiles(np.array([0.0, 3.7, 9.0]), np.array([1.0, 0.2, 0.0]),
    ...             TileGrid(1, 2, (2, 4))).tolist()
    [0, 1, 1]
    """
    ty, tx = pixel_tiles(grid.shape, grid)
    h, w = grid.shape
    xi = np.clip(np.asarray(x).astype(np.int64), 0, w - 1)
    yi = np.clip(np.asarray(y).astype(np.int64), 0, h - 1)
    return ty.ravel()[yi] * grid.nx + tx.ravel()[xi]


def tile_means(img: np.ndarray, grid: TileGrid) -> np.ndarray:
    """Mean of ``img`` (H, W) or (H, W, C) over the pixels of each tile
    (:func:`pixel_tiles`): (ny, nx) or (ny, nx, C).

    Examples
    --------
    >>> img = np.arange(8.0).reshape(2, 4)
    >>> tile_means(img, TileGrid(1, 2, (2, 4))).tolist()
    [[2.5, 4.5]]
    """
    h, w = img.shape[:2]
    ty, tx = pixel_tiles((h, w), grid)
    key = (ty * grid.nx + tx).ravel()
    n = grid.ny * grid.nx
    counts = np.maximum(np.bincount(key, minlength=n), 1)
    flat = img.reshape(h * w, -1)
    out = np.stack([np.bincount(key, weights=flat[:, c], minlength=n) / counts
                    for c in range(flat.shape[1])], axis=-1)
    return out.reshape((grid.ny, grid.nx) + img.shape[2:])


def event_tile_means(flow: np.ndarray, x: np.ndarray, y: np.ndarray,
                     grid: TileGrid) -> np.ndarray:
    """Tile flow ``(ny, nx, 2)``: the mean of a dense ``flow`` (H, W, 2) over the events at
    ``x``, ``y`` (px, rounded to their pixel) in each tile (a pixel counts once per event
    on it); zero flow in a tile without events (nothing there to fit it to).

    Examples
    --------
    >>> flow = np.zeros((2, 4, 2)); flow[:, 0] = 8.0; flow[:, 3] = 2.0
    >>> event_tile_means(flow, np.array([1, 3, 3]), np.array([0, 1, 1]),
    ...                  TileGrid(1, 2, (2, 4)))[0, :, 0].tolist()
    [0.0, 2.0]
    """
    h, w = flow.shape[:2]
    ty, tx = pixel_tiles((h, w), grid)
    key = (ty * grid.nx + tx).ravel()
    n = grid.ny * grid.nx
    xi = np.clip(np.rint(np.asarray(x, dtype=np.float64)), 0, w - 1).astype(np.int64)
    yi = np.clip(np.rint(np.asarray(y, dtype=np.float64)), 0, h - 1).astype(np.int64)
    hits = np.bincount(yi * w + xi, minlength=h * w).astype(np.float64)
    n_events = np.bincount(key, weights=hits, minlength=n)
    out = np.stack([np.bincount(key, weights=hits * flow[..., c].ravel(), minlength=n)
                    for c in range(2)], axis=-1) / np.maximum(n_events, 1.0)[:, None]
    return out.reshape(grid.ny, grid.nx, 2)


def _separable(params, ay, ax):
    return np.stack([ay @ params[..., c] @ ax.T for c in range(params.shape[2])], axis=-1)


def resample(params: np.ndarray, grid: TileGrid) -> np.ndarray:
    """Evaluate a tile flow at the centres of another grid (coarse-to-fine upsampling,
    or downsampling a warm start).

    Examples
    --------
    >>> p = np.ones((1, 1, 2))
    >>> resample(p, TileGrid(2, 2, (8, 8))).shape
    (2, 2, 2)
    """
    ny, nx = params.shape[:2]
    return _separable(params, axis_matrix(grid.centers_y(), ny, grid.shape[0]),
                      axis_matrix(grid.centers_x(), nx, grid.shape[1]))


def auto_finest_level(n_events: int, shape: tuple[int, int]) -> int:
    """The finest level multicm uses by default for a window of ``n_events`` on a sensor
    of ``shape`` (H, W): the finest, at most ``AUTO_FINEST_LEVEL``, whose
    ``2^(l-1) x 2^(l-1)`` tiles hold ``AUTO_EVENTS_PER_TILE`` events on average, and whose
    tiles are at least a pixel.

    Examples
    --------
    >>> [auto_finest_level(n, (260, 346)) for n in (300, 2000, 8000, 30000)]
    [1, 3, 4, 5]
    """
    level = AUTO_FINEST_LEVEL
    while level > 1 and (n_events < AUTO_EVENTS_PER_TILE * 4 ** (level - 1)
                         or 2 ** (level - 1) > max(shape)):
        level -= 1
    return level


def charbonnier_tv(params: np.ndarray, spacing: tuple[float, float], duration_s: float,
                   eps: float, grad: bool = True) -> tuple[float, np.ndarray | None]:
    """Charbonnier TV of a tile flow ``params`` (ny, nx, 2, px over the window) and its
    gradient (ny, nx, 2; None without ``grad``): the mean over tiles of
    ``sqrt(gx^2 + gy^2 + eps^2)`` summed over the two components, ``gx``, ``gy`` the
    forward differences to the right / lower tile in px/s per px of ``spacing`` (rows,
    columns; zero past the last tile), so in 1/s: multicm's smoothness term (4.9).

    Examples
    --------
    >>> p = np.zeros((2, 2, 2)); p[:, 1, 0] = 1.0            # a 1 px step, 1 s window
    >>> value, grad = charbonnier_tv(p, (1.0, 1.0), 1.0, 1e-2)
    >>> round(value, 3), grad[0, :, 0].round(2).tolist()
    (0.515, [-0.25, 0.25])
    """
    total = 0.0
    g = np.zeros(params.shape) if grad else None
    n = float(params.shape[0] * params.shape[1])
    kx = 1.0 / (duration_s * spacing[1])
    ky = 1.0 / (duration_s * spacing[0])
    for c in range(2):
        p = params[..., c]
        dx = np.zeros(p.shape)
        dy = np.zeros(p.shape)
        dx[:, :-1] = (p[:, 1:] - p[:, :-1]) * kx
        dy[:-1, :] = (p[1:, :] - p[:-1, :]) * ky
        mag = np.sqrt(dx * dx + dy * dy + eps ** 2)
        total += float(mag.sum()) / n
        if not grad:
            continue
        ax = dx / mag / n * kx
        ay = dy / mag / n * ky
        gc = g[..., c]
        gc[:, :-1] -= ax[:, :-1]
        gc[:, 1:] += ax[:, :-1]
        gc[:-1, :] -= ay[:-1, :]
        gc[1:, :] += ay[:-1, :]
    return total, g
