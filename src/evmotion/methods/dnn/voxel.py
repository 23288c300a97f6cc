"""Voxel-grid input of the network (Zhu et al., RSS 2018 / CVPR 2019).

The window's time span is mapped to ``[0, n_bins - 1]``; each event adds its signed polarity
(+1 ON, -1 OFF) to the two time bins around its normalized time with linear ("bilinear in
time") weights, at its pixel. The grid is then padded with zeros at the bottom and right to
a multiple of 16 (the four stride-2 levels of EV-FlowNet), for any sensor size: the network
sees the whole sensor, never a fixed crop.
"""

from __future__ import annotations

import numpy as np

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray
from evmotion.utils import whole_number

__all__ = ["N_BINS", "PAD_MULTIPLE", "network_input", "network_inputs", "normalize_voxel",
           "pad_to_multiple", "voxel_grid"]

N_BINS = 5
#: The most time bins a voxel grid takes (the network reads N_BINS).
MAX_VOXEL_BINS = 1024
PAD_MULTIPLE = 16


def voxel_grid(events: EventArray, n_bins: int = N_BINS) -> np.ndarray:
    """The ``(n_bins, H, W)`` float32 voxel grid of one window.

    Parameters
    ----------
    events : EventArray
        One window (sorted by time). Sub-pixel positions are rounded to the nearest pixel.
    n_bins : int
        Time bins (default 5, the thesis).

    Returns
    -------
    ndarray (n_bins, H, W) float32
        Sum of signed polarities, each split linearly between its two nearest bins.

    Examples
    --------
    >>> ev = EventArray(x=np.array([1, 1]), y=np.array([0, 0]), t=np.array([0, 100]),
    ...                 p=np.array([1, 0]), sensor_size=(2, 3))
    >>> voxel_grid(ev, 3)[:, 0, 1].tolist()
    [1.0, 0.0, -1.0]
    """
    h, w = events.sensor_size
    n_bins = _checked_bins(n_bins)
    y, x, b0, w0, w1 = _votes(events, n_bins)
    pix = y * w + x
    size = n_bins * h * w
    grid = np.bincount(b0 * (h * w) + pix, weights=w0, minlength=size)
    grid += np.bincount((b0 + 1) * (h * w) + pix, weights=w1, minlength=size)
    return grid.reshape(n_bins, h, w).astype(np.float32)


def _checked_bins(n_bins) -> int:
    """``n_bins`` as an int in ``[2, MAX_VOXEL_BINS]``, or ParameterError (1e30 and NaN had
    failed in numpy's casts, 2**63 overflowed; probe API)."""
    return whole_number("n_bins", n_bins, lo=2, hi=MAX_VOXEL_BINS)


def _votes(events: EventArray, n_bins: int):
    """Each event's pixel ``(y, x)`` (int64, rounded, clipped to the sensor), lower time
    bin ``b0`` and signed weights ``w0``, ``w1`` (float64) of bins ``b0`` and ``b0 + 1``."""
    if len(events) == 0:
        raise EmptyWindowError("voxel_grid: the window has no events")
    h, w = events.sensor_size
    t = np.asarray(events.t, dtype=np.float64)
    span = t[-1] - t[0]
    tn = (t - t[0]) * ((n_bins - 1) / span) if span > 0 else np.zeros_like(t)
    # b0 <= n_bins - 2, so b0 + 1 is always a bin (frac reaches 1 for the last event)
    b0 = np.minimum(np.floor(tn).astype(np.int64), n_bins - 2)
    frac = tn - b0
    pol = np.where(np.asarray(events.p) > 0, 1.0, -1.0)
    x = np.clip(np.rint(np.asarray(events.x, dtype=np.float64)), 0, w - 1).astype(np.int64)
    y = np.clip(np.rint(np.asarray(events.y, dtype=np.float64)), 0, h - 1).astype(np.int64)
    return y, x, b0, pol * (1.0 - frac), pol * frac


def network_input(events: EventArray, n_bins: int = N_BINS,
                  multiple: int = PAD_MULTIPLE) -> np.ndarray:
    """The network's input in one pass: the voxel grid, normalized and zero-padded to a
    multiple of ``multiple``, channels last: ``(H', W', n_bins)`` float32.

    ``pad_to_multiple(normalize_voxel(voxel_grid(events)))`` transposed to ``(H', W',
    n_bins)``, to float32 rounding, at about half its cost: one ``np.bincount`` straight
    into the padded grid, in the channels-last layout of the CPU's convolutions (no pad,
    no transposed copy), and the scale from one sum.

    Examples
    --------
    >>> ev = EventArray(x=np.array([1, 1]), y=np.array([0, 0]), t=np.array([0, 100]),
    ...                 p=np.array([1, 0]), sensor_size=(2, 3))
    >>> g = network_input(ev, 3)
    >>> g.shape, g[0, 1].tolist()
    ((16, 16, 3), [1.0, 0.0, -1.0])
    """
    return network_inputs(events, (1,), n_bins, multiple)[0]


def network_inputs(events: EventArray, scales: tuple[int, ...], n_bins: int = N_BINS,
                   multiple: int = PAD_MULTIPLE) -> list[np.ndarray]:
    """:func:`network_input` of the events binned ``k`` times coarser (pixel ``(x // k,
    y // k)``, grid ``ceil(H / k) x ceil(W / k)``) for each ``k`` in ``scales`` (each a
    divisor of ``multiple``), from one set of votes: a coarse grid is the sum of the
    ``k x k`` blocks of the padded fine one.

    Examples
    --------
    >>> ev = EventArray(x=np.array([1, 2]), y=np.array([0, 3]), t=np.array([0, 100]),
    ...                 p=np.array([1, 1]), sensor_size=(4, 4))
    >>> [g.shape for g in network_inputs(ev, (1, 2), 3)]
    [(16, 16, 3), (16, 16, 3)]
    >>> network_inputs(ev, (1, 2), 3)[1][:2, :2, 0].tolist()
    [[1.0, 0.0], [0.0, 0.0]]
    """
    if any(int(k) != k or k < 1 or multiple % k for k in scales):
        raise ParameterError(f"scales must divide {multiple}, got {tuple(scales)}")
    h, w = events.sensor_size
    hp, wp = h + (-h % multiple), w + (-w % multiple)
    n_bins = _checked_bins(n_bins)
    y, x, b0, w0, w1 = _votes(events, n_bins)
    cell = (y * wp + x) * n_bins + b0
    fine = np.bincount(np.concatenate([cell, cell + 1]), weights=np.concatenate([w0, w1]),
                       minlength=hp * wp * n_bins).astype(np.float32).reshape(hp, wp, n_bins)
    out = []
    for k in scales:
        k = int(k)
        if k == 1:
            grid = fine
        else:
            hk, wk = -(-h // k), -(-w // k)
            grid = np.zeros((hk + (-hk % multiple), wk + (-wk % multiple), n_bins),
                            np.float32)
            # the k x k strided slices added up (a reshape to (H/k, k, W/k, k, bins) summed
            # over its k axes took 8 ms at 346 x 260, this about 1 ms); the fine grid's
            # padding is a multiple of k, and past the events it is zero
            view = grid[:hp // k, :wp // k]
            for i in range(k):
                for j in range(k):
                    view += fine[i::k, j::k][:view.shape[0], :view.shape[1]]
        nonzero = np.count_nonzero(grid)
        if nonzero:
            # normalize_voxel's scale, the mean |cell| over the non-zero cells
            grid = grid / np.float32(np.abs(grid).sum(dtype=np.float64) / nonzero)
        out.append(grid)
    return out


def normalize_voxel(grid: np.ndarray) -> np.ndarray:
    """Divide by the mean absolute value of the non-zero cells, so that the input scale
    does not depend on the event density (a window of 10k or 100k events looks alike).

    Examples
    --------
    >>> normalize_voxel(np.array([[[0.0, 2.0, -4.0]]], np.float32)).tolist()
    [[[0.0, 0.6666666865348816, -1.3333333730697632]]]
    """
    a = np.abs(grid)
    nz = a > 0
    scale = float(a[nz].mean()) if nz.any() else 1.0
    return (grid / scale).astype(np.float32)


def pad_to_multiple(grid: np.ndarray, multiple: int = PAD_MULTIPLE) -> np.ndarray:
    """Zero-pad the last two axes at the bottom/right to a multiple of ``multiple``.

    Examples
    --------
    >>> pad_to_multiple(np.ones((5, 180, 240), np.float32)).shape
    (5, 192, 240)
    """
    h, w = grid.shape[-2:]
    ph = -h % multiple
    pw = -w % multiple
    if ph == 0 and pw == 0:
        return grid
    pad = [(0, 0)] * (grid.ndim - 2) + [(0, ph), (0, pw)]
    return np.pad(grid, pad)
