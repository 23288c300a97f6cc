"""Numba kernels of the simulator: rendering log intensity and emitting events.

The simulator advances in global steps ``(t_a, t_b]`` (integer microseconds) short enough
that no texture point moves by more than about a pixel; :func:`sim_step` then renders the
log intensity at ``t_b`` and, at every pixel whose log intensity changed by more than
``target`` (a fraction of the threshold), re-samples that pixel at ``n`` (a power of two
up to 64) evenly spaced intermediate times of a fixed sub-step grid, so that between consecutive samples of a pixel the change is
about ``target`` or less. Between samples log intensity is linear; a pixel fires an ON
(OFF) event each time it rises (falls) by its threshold from its reference level, at the
interpolated crossing time rounded up to the next microsecond, unless it is within the
refractory period of its previous event (the reference still moves: the pixel is reset).

Plain-numpy references: :func:`render_log_numpy`, :func:`sim_step_numpy`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["MAX_SUBSAMPLES", "EventBuffers", "PixelState", "StepLayers", "emit_crossings",
           "full_boxes", "pad_periodic", "render_log", "render_log_numpy", "sample_wrap_numpy",
           "sim_step", "sim_step_numpy", "step_grid", "textured_cells_sat"]

MAX_SUBSAMPLES = 64
TILE = 16  # pixels per side of the tiles skipped where the texture is locally constant


class StepLayers(NamedTuple):
    """The scene over one step of :func:`sim_step`.

    Attributes
    ----------
    Mseq : ndarray (MAX_SUBSAMPLES + 1, L, 9) float64
        Layer matrices (pixel -> reference pixel) at the sub-sample grid
        ``step_grid(t_a, t_b)``.
    texs, alphas : ndarray (L, Ht + 1, Wt + 1) float32
        Log-intensity and opacity rasters, as :func:`render_log`.
    origins : ndarray (L, 2) float64
        Reference pixel ``(x, y)`` of raster pixel (0, 0) per layer.
    boxes : ndarray (L, 4) float64, optional
        As :func:`render_log`, valid for the whole step (default: the whole sensor).
    sat : ndarray, optional
        :func:`textured_cells_sat` of the bottom layer's raster: 16x16 tiles whose texture
        footprint is constant over the step are copied instead of rendered (same result).
    """

    Mseq: np.ndarray
    texs: np.ndarray
    alphas: np.ndarray
    origins: np.ndarray
    boxes: np.ndarray | None = None
    sat: np.ndarray | None = None


class PixelState(NamedTuple):
    """The sensor's pixels (H, W) as :func:`sim_step` reads and updates them.

    Attributes
    ----------
    la : ndarray float32
        Log intensity at the step's start.
    lb : ndarray float32
        Receives the log intensity at the step's end.
    ref : ndarray float64
        Reference level per pixel (updated).
    cp, cn : ndarray float64
        ON and OFF thresholds per pixel.
    last : ndarray int64
        Time of each pixel's previous event, µs (updated).
    """

    la: np.ndarray
    lb: np.ndarray
    ref: np.ndarray
    cp: np.ndarray
    cn: np.ndarray
    last: np.ndarray


class EventBuffers(NamedTuple):
    """Output buffers of the event kernels: ``x, y`` (uint16), ``t`` (int64 µs), ``p``
    (uint8), of equal length."""

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray

    @classmethod
    def empty(cls, capacity: int) -> EventBuffers:
        """Buffers for ``capacity`` events."""
        return cls(np.empty(capacity, np.uint16), np.empty(capacity, np.uint16),
                   np.empty(capacity, np.int64), np.empty(capacity, np.uint8))


@njit(cache=True)
def _bilinear_wrap(img, k, xr, yr):
    # img (L, Ht + 1, Wt + 1) carries one extra periodic row and column (pad_periodic), so
    # x0 + 1 is valid; indexing the 3-D array directly avoids building a view per sample
    h = img.shape[1] - 1
    w = img.shape[2] - 1
    # inside the raster (with a cell of slack, where floor(xr / w) is surely 0) the wrap is
    # the identity: skip its arithmetic in the common case
    if not 0.0 <= xr < w - 1:
        xr -= w * math.floor(xr * (1.0 / w))
    if not 0.0 <= yr < h - 1:
        yr -= h * math.floor(yr * (1.0 / h))
    x0 = int(xr)
    y0 = int(yr)
    if x0 >= w:
        x0 = w - 1
    if y0 >= h:
        y0 = h - 1
    ax = xr - x0
    ay = yr - y0
    return ((1 - ay) * ((1 - ax) * img[k, y0, x0] + ax * img[k, y0, x0 + 1])
            + ay * ((1 - ax) * img[k, y0 + 1, x0] + ax * img[k, y0 + 1, x0 + 1]))


def pad_periodic(img: np.ndarray) -> np.ndarray:
    """Raster with its first row and column repeated at the end (float32, contiguous), the
    layout the numba kernels expect."""
    img = np.asarray(img, dtype=np.float32)
    return np.ascontiguousarray(np.pad(img, ((0, 1), (0, 1)), mode="wrap"))


@njit(cache=True)
def _render(Ms, texs, alphas, origins, boxes, out):
    h, w = out.shape
    for y in range(h):
        for x in range(w):
            # the layer sampling is written out here and in _resampled_events rather than
            # called: a call with this many array arguments costs ~5x the work (inlined
            # by numba, still ~15% of a step: its arrays' reference counts)
            val = 0.0
            for k in range(Ms.shape[1]):
                if k > 0 and (x < boxes[k, 0] or y < boxes[k, 1] or x > boxes[k, 2]
                              or y > boxes[k, 3]):
                    continue
                den = Ms[0, k, 6] * x + Ms[0, k, 7] * y + Ms[0, k, 8]
                xr = (Ms[0, k, 0] * x + Ms[0, k, 1] * y + Ms[0, k, 2]) / den - origins[k, 0]
                yr = (Ms[0, k, 3] * x + Ms[0, k, 4] * y + Ms[0, k, 5]) / den - origins[k, 1]
                if k == 0:
                    val = _bilinear_wrap(texs, k, xr, yr)
                else:
                    al = _bilinear_wrap(alphas, k, xr, yr)
                    if al > 0.0:  # upper layers are mostly transparent: skip them there
                        val = al * _bilinear_wrap(texs, k, xr, yr) + (1.0 - al) * val
            out[y, x] = val


def full_boxes(n_layers: int, shape: tuple[int, int]) -> np.ndarray:
    """Layer bounding boxes ``(x0, y0, x1, y1)`` covering the whole sensor."""
    h, w = shape
    return np.tile(np.array([0.0, 0.0, w - 1.0, h - 1.0]), (n_layers, 1))


def render_log(Ms: np.ndarray, texs: np.ndarray, alphas: np.ndarray, origins: np.ndarray,
               out: np.ndarray, boxes: np.ndarray | None = None) -> None:
    """Render log intensity into ``out`` (H, W) float32.

    Parameters
    ----------
    Ms : ndarray (L, 9) float64
        Row-major 3x3 matrices, current pixel -> reference pixel, one per layer
        (bottom first).
    texs, alphas : ndarray (L, Ht + 1, Wt + 1) float32
        Log-intensity and opacity rasters, periodic, padded by :func:`pad_periodic`
        (alpha of layer 0 is ignored).
    origins : ndarray (L, 2) float64
        Reference pixel ``(x, y)`` of raster pixel (0, 0) per layer.
    out : ndarray (H, W) float32
        Output, written in place.
    boxes : ndarray (L, 4) float64, optional
        Pixel box ``(x0, y0, x1, y1)`` outside which an upper layer is fully transparent
        (default: the whole sensor); an optimization that must not change the result.
    """
    if boxes is None:
        boxes = full_boxes(Ms.shape[0], out.shape)
    _render(np.ascontiguousarray(Ms, dtype=np.float64)[None], texs, alphas, origins, boxes,
            out)


def sample_wrap_numpy(img: np.ndarray, xr: np.ndarray, yr: np.ndarray) -> np.ndarray:
    """Bilinear sample of the (unpadded) raster ``img`` at raster coordinates ``(xr, yr)``
    with periodic wrap-around (float64)."""
    th, tw = img.shape
    fx, fy = np.floor(xr), np.floor(yr)
    ax, ay = xr - fx, yr - fy
    x0, y0 = fx.astype(np.int64) % tw, fy.astype(np.int64) % th
    x1, y1 = (x0 + 1) % tw, (y0 + 1) % th
    img = img.astype(np.float64)
    return ((1 - ay) * ((1 - ax) * img[y0, x0] + ax * img[y0, x1])
            + ay * ((1 - ax) * img[y1, x0] + ax * img[y1, x1]))


def render_log_numpy(Ms, texs, alphas, origins, xs, ys) -> np.ndarray:
    """Plain-numpy reference of the renderer at pixels ``(xs, ys)`` (any shape), with
    unpadded rasters. ``Ms`` is (L, 9) or, per pixel, (L, ...shape, 9)."""
    xs = np.asarray(xs, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    val = None
    for k in range(len(Ms)):
        m = np.moveaxis(np.asarray(Ms[k], dtype=np.float64), -1, 0)
        den = m[6] * xs + m[7] * ys + m[8]
        xr = (m[0] * xs + m[1] * ys + m[2]) / den - origins[k, 0]
        yr = (m[3] * xs + m[4] * ys + m[5]) / den - origins[k, 1]
        s = sample_wrap_numpy(texs[k], xr, yr)
        if k == 0:
            val = s
        else:
            a = sample_wrap_numpy(alphas[k], xr, yr)
            val = a * s + (1 - a) * val
    return val


@njit(cache=True)
def _cross(a, b, t0, t1, r, c, sign, last, refr, x, y, events, n):
    """Crossings of one polarity between samples (t0, a) and (t1, b) into the buffers
    ``events = (ex, ey, et, ep)`` (counted past their end); returns r, last, n."""
    ex, ey, et, ep = events
    cap = ex.shape[0]
    span = t1 - t0
    d = b - a
    while sign * (b - r) >= c:
        r += sign * c
        ti = np.int64(math.ceil(t0 + (r - a) / d * span - 1e-9))
        if ti <= t0:
            ti = t0 + 1
        if ti > t1:
            ti = t1
        if ti - last >= refr:
            if n < cap:
                ex[n] = x
                ey[n] = y
                et[n] = ti
                ep[n] = 1 if sign > 0 else 0
            n += 1
            last = ti
    return r, last, n


@njit(cache=True)
def _cross_columns(vals, times, pix, width, ref, cp, cn, last, refr, events, n):
    s_count, p_count = vals.shape
    for j in range(p_count):
        k = pix[j]
        y = k // width
        x = k - y * width
        r = ref[k]
        lt = last[k]
        for s in range(1, s_count):
            a = vals[s - 1, j]
            b = vals[s, j]
            if b - r >= cp[k]:
                r, lt, n = _cross(a, b, times[s - 1], times[s], r, cp[k], 1.0, lt, refr, x, y,
                                  events, n)
            elif r - b >= cn[k]:
                r, lt, n = _cross(a, b, times[s - 1], times[s], r, cn[k], -1.0, lt, refr, x,
                                  y, events, n)
        ref[k] = r
        last[k] = lt
    return n


def emit_crossings(vals: np.ndarray, times_us: np.ndarray, pix: np.ndarray, width: int,
                   ref: np.ndarray, cp: np.ndarray, cn: np.ndarray, last: np.ndarray,
                   refractory_us: int, events: EventBuffers, n: int = 0) -> int:
    """Events of pixels whose log intensity is sampled at common times, linear in between.

    The same crossing rule as :func:`sim_step` (interpolated crossing time rounded up to
    the next microsecond, refractory period, reference moved by the threshold at each
    crossing) for callers that render log intensity themselves (e.g. the schlieren
    simulator).

    Parameters
    ----------
    vals : ndarray (S, P) float64
        Log intensity of ``P`` pixels at the ``S`` times ``times_us`` (int64, increasing).
    pix : ndarray (P,) int64
        Row-major pixel index ``y * width + x`` of each column.
    ref, cp, cn, last : ndarray (H * W,)
        Flat reference levels (float64, updated), ON/OFF thresholds (float64), times of the
        previous events (int64 µs, updated).
    refractory_us : int
    events : EventBuffers
        Output buffers; events go from index ``n`` on.

    Returns
    -------
    int
        The new event count; it may exceed the buffer length, in which case the events
        past it were dropped and the caller must redo the call with larger buffers
        (restoring ``ref`` and ``last``).
    """
    return int(_cross_columns(np.ascontiguousarray(vals, dtype=np.float64),
                              np.ascontiguousarray(times_us, dtype=np.int64),
                              np.ascontiguousarray(pix, dtype=np.int64), int(width), ref, cp, cn,
                              last, np.int64(refractory_us), tuple(events), np.int64(n)))


@njit(cache=True)
def _sat_sum(sat, y0, y1, x0, x1):
    """Sum of the cells ``[y0, y1) x [x0, x1)`` from a summed-area table."""
    return sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]


@njit(cache=True)
def _wrapped_sum(sat, y0, y1, x0, x1):
    """Sum over the inclusive cell range ``[y0, y1] x [x0, x1]`` of a periodic raster."""
    th = sat.shape[0] - 1
    tw = sat.shape[1] - 1
    ny = y1 - y0 + 1
    nx = x1 - x0 + 1
    if ny >= th or nx >= tw:
        return 1  # the footprint wraps onto itself: treat as textured
    ya = y0 % th
    xa = x0 % tw
    total = 0
    for yy0, yy1 in ((ya, min(ya + ny, th)), (0, max(0, ya + ny - th))):
        if yy1 <= yy0:
            continue
        for xx0, xx1 in ((xa, min(xa + nx, tw)), (0, max(0, xa + nx - tw))):
            if xx1 > xx0:
                total += _sat_sum(sat, yy0, yy1, xx0, xx1)
    return total


@njit(cache=True)
def _tile_static(m0, m1, sat, origins, boxes, tx0, ty0, tx1, ty1):
    """``m0, m1``: bottom layer's matrices (9,) at the step's ends. True if the bottom layer's texture is constant under the tile during the step and
    no upper layer reaches it: its pixels keep their log intensity exactly."""
    for k in range(1, boxes.shape[0]):
        if not (tx1 < boxes[k, 0] or ty1 < boxes[k, 1] or tx0 > boxes[k, 2]
                or ty0 > boxes[k, 3]):
            return False
    xmin = 1e300
    xmax = -1e300
    ymin = 1e300
    ymax = -1e300
    for m in (m0, m1):
        for cx, cy in ((tx0, ty0), (tx1, ty0), (tx0, ty1), (tx1, ty1)):
            den = m[6] * cx + m[7] * cy + m[8]
            if den <= 0.0:
                return False
            xr = (m[0] * cx + m[1] * cy + m[2]) / den - origins[0, 0]
            yr = (m[3] * cx + m[4] * cy + m[5]) / den - origins[0, 1]
            xmin = min(xmin, xr)
            xmax = max(xmax, xr)
            ymin = min(ymin, yr)
            ymax = max(ymax, yr)
    # two cells of margin: bilinear support and the trajectory's bend within the step
    return _wrapped_sum(sat, int(math.floor(ymin)) - 2, int(math.floor(ymax)) + 2,
                        int(math.floor(xmin)) - 2, int(math.floor(xmax)) + 2) == 0


def textured_cells_sat(log_i: np.ndarray) -> np.ndarray:
    """Summed-area table (int64, ``(Ht + 1, Wt + 1)``) of the raster cells whose four
    corners (periodic) are not all equal: where bilinear samples are not constant."""
    t = np.asarray(log_i)
    right = np.roll(t, -1, axis=1)
    down = np.roll(t, -1, axis=0)
    diag = np.roll(down, -1, axis=1)
    textured = (t != right) | (t != down) | (t != diag)
    sat = np.zeros((t.shape[0] + 1, t.shape[1] + 1), dtype=np.int64)
    sat[1:, 1:] = textured.cumsum(axis=0).cumsum(axis=1)
    return sat


@njit(cache=True, error_model="numpy")
def _step(layers, state, events, t_a, t_b, refr, target):
    """:func:`sim_step` on ``layers = (Mseq, texs, alphas, origins, boxes, sat)``,
    ``state = (la, lb, ref, cp, cn, last)`` and ``events = (ex, ey, et, ep)``: tile by
    tile, copying the tiles where the texture is locally constant. Returns the event and
    extra sub-sample counts."""
    Mseq, _, _, origins, boxes, sat = layers
    la, lb = state[0], state[1]
    h, w = la.shape
    scratch = _tile_scratch()
    # a typed start: a literal 0 would make numba compile the tile kernels a second time
    n = np.int64(0)
    nsub_total = 0
    for ty0 in range(0, h, TILE):
        ty1 = min(ty0 + TILE, h) - 1
        for tx0 in range(0, w, TILE):
            tx1 = min(tx0 + TILE, w) - 1
            tile = (tx0, ty0, tx1, ty1)
            if sat.shape[0] > 1 and _tile_static(Mseq[0, 0], Mseq[MAX_SUBSAMPLES, 0], sat,
                                                 origins, boxes, tx0, ty0, tx1, ty1):
                _copy_tile(la, lb, tile)
                continue
            n, nsub = _tile_events(layers, state, events, scratch, tile, t_a, t_b, refr,
                                   target, n)
            nsub_total += nsub
    return n, nsub_total


# The passes of a tile below (inlined into _tile_events) each loop over the tile's pixels
# with the per-pixel work written out: a call per pixel (or per row) pays for the
# reference counts of its array arguments even when numba inlines it, which costs more
# than the pixel's work (measured: the kernel took 1.3-3x as long with per-pixel helpers).


@njit(cache=True)
def _tile_scratch():
    """Per-tile scratch of :func:`_tile_events`: the bottom layer's raster cells and
    bilinear weights ``(x0, y0, ax, ay)`` of each pixel, the unrounded log intensity at
    the step's end, and the pixels to re-sample ``(x, y, n)``; TILE x TILE each."""
    cells = (np.empty((TILE, TILE), np.int64), np.empty((TILE, TILE), np.int64),
             np.empty((TILE, TILE), np.float64), np.empty((TILE, TILE), np.float64))
    rare = (np.empty(TILE * TILE, np.int64), np.empty(TILE * TILE, np.int64),
            np.empty(TILE * TILE, np.int64))
    return cells, np.empty((TILE, TILE), np.float64), rare


@njit(cache=True, inline="always")
def _copy_tile(la, lb, tile):
    """``lb = la`` over the tile (its log intensity did not change)."""
    tx0, ty0, tx1, ty1 = tile
    # element by element: a slice assignment makes numba compile its shape-mismatch
    # message (string formatting, ~1 s on first use)
    for yy in range(ty0, ty1 + 1):
        for xx in range(tx0, tx1 + 1):
            lb[yy, xx] = la[yy, xx]


@njit(cache=True, error_model="numpy")
def _tile_events(layers, state, events, scratch, tile, t_a, t_b, refr, target, n):
    """Render the tile ``(tx0, ty0, tx1, ty1)`` (inclusive pixels) at the step's end into
    ``lb`` and emit its pixels' events from index ``n`` on (those of the re-sampled
    pixels last). Returns the event count and the extra sub-samples."""
    Mseq, texs, _, origins, _, _ = layers
    cells, v_end, rare = scratch
    _bottom_cells(Mseq[MAX_SUBSAMPLES, 0], origins, texs.shape[2] - 1, texs.shape[1] - 1,
                  tile, cells)
    _render_tile(layers, cells, tile, v_end, state[1])
    n, n_rare, nsub = _tile_crossings(state, events, v_end, tile, t_a, t_b, refr, target,
                                      rare, n)
    n = _resampled_events(layers, state, events, rare, n_rare, t_a, t_b, refr, n)
    return n, nsub


@njit(cache=True, error_model="numpy", inline="always")
def _bottom_cells(m, origins, tw, th, tile, cells):
    """The bottom layer's raster cell and bilinear weights of each pixel of the tile under
    its matrix ``m`` (9,) into ``cells = (x0, y0, ax, ay)``: the arithmetic of
    :func:`_bilinear_wrap`, with the matrix in scalars (every textured pixel, every
    step)."""
    tx0, ty0, tx1, ty1 = tile
    cx0, cy0, cax, cay = cells
    m0, m1, m2 = m[0], m[1], m[2]
    m3, m4, m5 = m[3], m[4], m[5]
    m6, m7, m8 = m[6], m[7], m[8]
    ox, oy = origins[0, 0], origins[0, 1]
    for j in range(ty1 - ty0 + 1):
        y = ty0 + j
        m1y = m1 * y
        m4y = m4 * y
        m7y = m7 * y
        for i in range(tx1 - tx0 + 1):
            x = tx0 + i
            den = m6 * x + m7y + m8
            xr = (m0 * x + m1y + m2) / den - ox
            yr = (m3 * x + m4y + m5) / den - oy
            if not 0.0 <= xr < tw - 1:
                xr -= tw * math.floor(xr * (1.0 / tw))
            if not 0.0 <= yr < th - 1:
                yr -= th * math.floor(yr * (1.0 / th))
            x0 = min(int(xr), tw - 1)
            y0 = min(int(yr), th - 1)
            cx0[j, i] = x0
            cy0[j, i] = y0
            cax[j, i] = xr - x0
            cay[j, i] = yr - y0


@njit(cache=True, error_model="numpy", inline="always")
def _render_tile(layers, cells, tile, v_end, lb):
    """Log intensity of the tile's pixels at the step's end: bilinear samples of the
    bottom raster at ``cells`` (:func:`_bottom_cells`), upper layers composited over
    them; into ``v_end`` (float64, tile coordinates) and ``lb`` (float32)."""
    Mseq, texs, alphas, origins, boxes, _ = layers
    cx0, cy0, cax, cay = cells
    tx0, ty0, tx1, ty1 = tile
    m_end = Mseq[MAX_SUBSAMPLES]
    tex0 = texs[0]
    for y in range(ty0, ty1 + 1):
        j = y - ty0
        for x in range(tx0, tx1 + 1):
            i = x - tx0
            x0 = cx0[j, i]
            y0 = cy0[j, i]
            ax = cax[j, i]
            ay = cay[j, i]
            v = ((1 - ay) * ((1 - ax) * tex0[y0, x0] + ax * tex0[y0, x0 + 1])
                 + ay * ((1 - ax) * tex0[y0 + 1, x0] + ax * tex0[y0 + 1, x0 + 1]))
            for k in range(1, m_end.shape[0]):
                if x < boxes[k, 0] or y < boxes[k, 1] or x > boxes[k, 2] or y > boxes[k, 3]:
                    continue
                den = m_end[k, 6] * x + m_end[k, 7] * y + m_end[k, 8]
                xr = (m_end[k, 0] * x + m_end[k, 1] * y + m_end[k, 2]) / den - origins[k, 0]
                yr = (m_end[k, 3] * x + m_end[k, 4] * y + m_end[k, 5]) / den - origins[k, 1]
                al = _bilinear_wrap(alphas, k, xr, yr)
                if al > 0.0:  # upper layers are mostly transparent: skip them there
                    v = al * _bilinear_wrap(texs, k, xr, yr) + (1.0 - al) * v
            v_end[j, i] = v
            lb[y, x] = v


@njit(cache=True, error_model="numpy", inline="always")
def _tile_crossings(state, events, v_end, tile, t_a, t_b, refr, target, rare, n):
    """Events of the tile's pixels whose change over the step is within ``target``
    (linear between ``la`` and ``lb``); the others go to ``rare = (x, y, n_samples)``
    with the fewest samples (a power of two) that keep the change between consecutive
    samples within ``target``. Returns the event count, the rare pixel count and their
    extra sub-samples."""
    la, lb, ref, cp, cn, last = state
    tx0, ty0, tx1, ty1 = tile
    rx, ry, rns = rare
    n_rare = 0
    nsub_total = 0
    for y in range(ty0, ty1 + 1):
        for x in range(tx0, tx1 + 1):
            a = np.float64(la[y, x])
            # the change is that of the unrounded sample, the one rendered
            change = abs(v_end[y - ty0, x - tx0] - a)
            ns = 1
            while ns < MAX_SUBSAMPLES and change > target * ns:
                ns *= 2
            if ns > 1:
                rx[n_rare] = x
                ry[n_rare] = y
                rns[n_rare] = ns
                n_rare += 1
                nsub_total += ns - 1
                continue
            b = np.float64(lb[y, x])
            r = ref[y, x]
            if b - r >= cp[y, x]:
                r, lt, n = _cross(a, b, t_a, t_b, r, cp[y, x], 1.0, last[y, x], refr, x, y,
                                  events, n)
            elif r - b >= cn[y, x]:
                r, lt, n = _cross(a, b, t_a, t_b, r, cn[y, x], -1.0, last[y, x], refr, x, y,
                                  events, n)
            else:
                continue
            ref[y, x] = r
            last[y, x] = lt
    return n, n_rare, nsub_total


@njit(cache=True, error_model="numpy", inline="always")
def _resampled_events(layers, state, events, rare, n_rare, t_a, t_b, refr, n):
    """Events of the pixels ``rare = (x, y, n_samples)``, each re-sampled at
    ``n_samples`` evenly spaced points of the step's grid (rendered from the layer
    matrices there), linear in between. Returns the event count."""
    Mseq, texs, alphas, origins, boxes, _ = layers
    la, lb, ref, cp, cn, last = state
    rx, ry, rns = rare
    span = t_b - t_a
    for q in range(n_rare):
        x = rx[q]
        y = ry[q]
        ns = rns[q]
        stride = MAX_SUBSAMPLES // ns
        r = ref[y, x]
        lt = last[y, x]
        t0 = t_a
        v0 = np.float64(la[y, x])
        for j in range(1, ns + 1):
            if j == ns:
                v1 = np.float64(lb[y, x])
                t1 = t_b
            else:
                g = j * stride
                t1 = t_a + (g * span) // MAX_SUBSAMPLES
                v1 = 0.0
                for k in range(Mseq.shape[1]):
                    if k > 0 and (x < boxes[k, 0] or y < boxes[k, 1] or x > boxes[k, 2]
                                  or y > boxes[k, 3]):
                        continue
                    den = Mseq[g, k, 6] * x + Mseq[g, k, 7] * y + Mseq[g, k, 8]
                    xr = (Mseq[g, k, 0] * x + Mseq[g, k, 1] * y + Mseq[g, k, 2]) / den \
                        - origins[k, 0]
                    yr = (Mseq[g, k, 3] * x + Mseq[g, k, 4] * y + Mseq[g, k, 5]) / den \
                        - origins[k, 1]
                    if k == 0:
                        v1 = _bilinear_wrap(texs, k, xr, yr)
                    else:
                        al = _bilinear_wrap(alphas, k, xr, yr)
                        if al > 0.0:
                            v1 = al * _bilinear_wrap(texs, k, xr, yr) + (1.0 - al) * v1
            if v1 - r >= cp[y, x]:
                r, lt, n = _cross(v0, v1, t0, t1, r, cp[y, x], 1.0, lt, refr, x, y, events, n)
            elif r - v1 >= cn[y, x]:
                r, lt, n = _cross(v0, v1, t0, t1, r, cn[y, x], -1.0, lt, refr, x, y, events,
                                  n)
            t0 = t1
            v0 = v1
        ref[y, x] = r
        last[y, x] = lt
    return n


def step_grid(t_a: int, t_b: int) -> np.ndarray:
    """The ``MAX_SUBSAMPLES + 1`` integer-µs times at which a step may sample a pixel:
    ``t_a + floor(g (t_b - t_a) / MAX_SUBSAMPLES)``. A pixel is re-sampled at ``ns`` (a
    power of two) evenly spaced points of this grid."""
    g = np.arange(MAX_SUBSAMPLES + 1, dtype=np.int64)
    return t_a + (g * (t_b - t_a)) // MAX_SUBSAMPLES


def sim_step(layers: StepLayers, state: PixelState, events: EventBuffers, t_a: int, t_b: int,
             refractory_us: int, target: float) -> tuple[int, int]:
    """Advance the sensor from ``t_a`` to ``t_b`` (integer µs, ``t_b > t_a``).

    Parameters
    ----------
    layers : StepLayers
        The layers' matrices over the step, rasters, origins and (optional) boxes and
        summed-area table.
    state : PixelState
        Log intensity at ``t_a`` (``lb`` receives it at ``t_b``), reference levels,
        thresholds and previous event times (updated).
    events : EventBuffers
        Output buffers; the events of the step in no particular order.
    refractory_us : int
        Refractory period, µs.
    target : float
        Largest log-intensity change between samples of a pixel before it is re-sampled.

    Returns
    -------
    n_events, n_subsamples : int
        ``n_events`` may exceed the buffer length, in which case the buffers hold only the
        first events and the caller must redo the step with larger buffers (restoring
        ``ref`` and ``last``).
    """
    boxes = full_boxes(layers.Mseq.shape[1], state.la.shape) if layers.boxes is None \
        else layers.boxes
    sat = np.zeros((1, 1), dtype=np.int64) if layers.sat is None else layers.sat
    n, ns = _step((*layers[:4], boxes, sat), tuple(state), tuple(events), np.int64(t_a),
                  np.int64(t_b), np.int64(refractory_us), float(target))
    return int(n), int(ns)


def _cross_numpy(a, b, t0, t1, ref, c, sign, last, refr, xs, ys, out):
    """Vectorized crossings of one polarity over pixels (1-D arrays); updates ref, last."""
    d = b - a
    k = np.floor(np.maximum(sign * (b - ref), 0.0) / c + 1e-12).astype(np.int64)
    k[~(sign * (b - ref) >= c)] = 0
    for j in range(1, int(k.max(initial=0)) + 1):
        sel = np.nonzero(k >= j)[0]
        r = ref[sel] + sign * j * c[sel]
        tc = t0[sel] + (r - a[sel]) / d[sel] * (t1[sel] - t0[sel])
        ti = np.clip(np.ceil(tc - 1e-9).astype(np.int64), t0[sel] + 1, t1[sel])
        ok = ti - last[sel] >= refr
        last[sel[ok]] = ti[ok]
        out.append((xs[sel[ok]], ys[sel[ok]], ti[ok],
                    np.full(int(ok.sum()), 1 if sign > 0 else 0)))
    ref += sign * k * c


def sim_step_numpy(Mseq, texs, alphas, origins, la, ref, cp, cn, last, t_a: int, t_b: int,
                   refractory_us: int, target: float):
    """Plain-numpy reference of :func:`sim_step` (unpadded rasters).

    Vectorized over pixels, looping over sub-sample and crossing indices. Updates ``ref``
    and ``last`` (flattened views are written back); returns ``lb`` (H, W) float64 and the
    events ``x, y, t, p`` sorted by pixel (row-major) then time."""
    h, w = la.shape
    span = t_b - t_a
    ys, xs = np.mgrid[0:h, 0:w]
    xs, ys = xs.ravel(), ys.ravel()
    a0 = la.astype(np.float64).ravel()
    lb = render_log_numpy(Mseq[MAX_SUBSAMPLES], texs, alphas, origins, xs, ys)
    lb = lb.astype(np.float32).astype(np.float64)  # the kernel stores samples as float32
    ns = np.ones(h * w, dtype=np.int64)
    for _ in range(int(np.log2(MAX_SUBSAMPLES))):
        ns[np.abs(lb - a0) > target * ns] *= 2
    stride = MAX_SUBSAMPLES // ns
    refv, lastv = ref.reshape(-1), last.reshape(-1)
    cpv, cnv = cp.reshape(-1), cn.reshape(-1)
    t0 = np.full(h * w, t_a, dtype=np.int64)
    v0 = a0.copy()
    out: list = []
    for j in range(1, int(ns.max()) + 1):
        sel = np.nonzero(ns >= j)[0]
        g = j * stride[sel]
        t1 = np.where(j == ns[sel], t_b, t_a + (g * span) // MAX_SUBSAMPLES)
        v1 = np.where(j == ns[sel], lb[sel],
                      render_log_numpy(Mseq[g].transpose(1, 0, 2),
                                       texs, alphas, origins, xs[sel], ys[sel]))
        r, lt = refv[sel].copy(), lastv[sel].copy()
        on = v1 - r >= cpv[sel]
        off = ~on & (r - v1 >= cnv[sel])
        for mask, c, sign in ((on, cpv[sel], 1.0), (off, cnv[sel], -1.0)):
            idx = np.nonzero(mask)[0]
            rr, ll = r[idx], lt[idx]
            _cross_numpy(v0[sel][idx], v1[idx], t0[sel][idx], t1[idx], rr, c[idx], sign, ll,
                         refractory_us, xs[sel][idx], ys[sel][idx], out)
            r[idx], lt[idx] = rr, ll
        refv[sel], lastv[sel] = r, lt
        t0[sel] = t1
        v0[sel] = v1
    if out:
        x, y, t, p = (np.concatenate(v) for v in zip(*out, strict=True))
    else:
        x = y = t = p = np.zeros(0, np.int64)
    order = np.lexsort((t, x, y))
    return lb.reshape(h, w), x[order], y[order], t[order], p[order]
