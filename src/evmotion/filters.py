"""Event filters: refractory period, hot pixels and stuck rows or columns."""

from __future__ import annotations

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray, require_events, sensor_pixels
from evmotion.jitcache import lazy_njit
from evmotion.utils import check_number, whole_number

__all__ = ["hot_line_mask", "hot_pixel_mask", "hot_pixel_mask_of_counts", "pixel_counts",
           "refractory_filter", "remove_hot_pixels"]


def _pixels(events: EventArray, func: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~evmotion.events.sensor_pixels` of ``events``, named by ``func`` when not an
    EventArray: per-pixel state and counts need every event on the sensor (an unchecked
    array's were written out of bounds, or counted on the next row), where
    :func:`~evmotion.events.require_events` only warns of a few."""
    if not isinstance(events, EventArray):
        require_events(events, func)  # raises, naming what was given
    return sensor_pixels(events)


# compiled on first use: the hot-pixel mask, used at a network's start-up, needs no numba
@lazy_njit(cache=True)
def _refractory_keep(x, y, t, p, width, height, refractory_us, per_polarity, keep):
    n_pol = 2 if per_polarity else 1
    last = np.full(n_pol * width * height, np.iinfo(np.int64).min // 2, dtype=np.int64)
    for k in range(t.shape[0]):
        idx = (int(y[k]) * width + int(x[k])) * n_pol + (int(p[k]) if per_polarity else 0)
        if t[k] - last[idx] >= refractory_us:
            keep[k] = True
            last[idx] = t[k]
        else:
            keep[k] = False


def refractory_filter(events: EventArray, refractory_us: int, *, per_polarity: bool = False,
                      ) -> EventArray:
    """Drop events that follow a kept event at the same pixel within ``refractory_us`` µs.

    Parameters
    ----------
    events : EventArray
        Events on the sensor grid (integer coordinates).
    refractory_us : int
        Refractory period in microseconds; 0 keeps everything.
    per_polarity : bool
        Count the period separately for each polarity.

    Examples
    --------
    >>> ev = EventArray([0, 0, 0], [0, 0, 0], [0, 50, 200], [1, 1, 1], (1, 1))
    >>> refractory_filter(ev, 100).t.tolist()
    [0, 200]
    """
    x, y = _pixels(events, "refractory_filter")
    if not events.validate:
        # the kernel keeps the latest time per pixel: unsorted, it kept a meaningless subset
        events.check_order()
    # (10.5 had run as 10 µs, probe BE)
    refractory_us = whole_number("refractory_us", refractory_us, lo=0)
    if events.x.dtype.kind == "f":
        raise ParameterError("refractory_filter needs integer sensor coordinates (filter before "
                             "undistortion)")
    keep = np.empty(len(events), dtype=np.bool_)
    _refractory_keep(x, y, events.t, events.p, events.width, events.height,
                     np.int64(refractory_us), per_polarity, keep)
    return events[keep]


def pixel_counts(events: EventArray) -> np.ndarray:
    """(H, W) int64 count of the events at each pixel (:func:`~evmotion.events.sensor_pixels`:
    undistorted coordinates rounded), what :func:`hot_pixel_mask` tests; counts of a
    recording's chunks add up to the recording's.

    Examples
    --------
    >>> ev = EventArray(x=[0, 1, 1], y=[0, 0, 0], t=[0, 1, 2], p=[1, 1, 1], sensor_size=(1, 2))
    >>> pixel_counts(ev).tolist()
    [[1, 2]]
    """
    return _counts(events, "pixel_counts")


def _counts(events: EventArray, func: str) -> np.ndarray:
    x, y = _pixels(events, func)  # (counts do not depend on time order)
    return np.bincount(y.astype(np.intp) * events.width + x,
                       minlength=events.width * events.height).reshape(events.sensor_size)


def hot_pixel_mask(events: EventArray, *, n_sigma: float = 5.0, min_count: int = 10,
                   neighbour_ratio: float | None = None) -> np.ndarray:
    """(H, W) bool mask of hot pixels: event count above ``median + n_sigma * 1.4826 * MAD``
    of the active pixels and at least ``min_count`` events; with ``neighbour_ratio``, also
    more than that many times the count of each of its 8 neighbours (a hot pixel fires
    alone, while a busy pixel of a moving edge or texture has busy neighbours), or, on a
    stuck row or column (:func:`hot_line_mask`), of the pixels on either side of its line.
    :func:`hot_pixel_mask_of_counts` does the same from :func:`pixel_counts` (a recording
    read in chunks).

    Examples
    --------
    >>> x = np.r_[np.repeat(3, 40), np.arange(8), np.arange(8)]
    >>> y = np.r_[np.repeat(2, 40), np.zeros(8, int), np.ones(8, int)]
    >>> ev = EventArray(x=x, y=y, t=np.arange(56), p=np.ones(56), sensor_size=(6, 8))
    >>> np.argwhere(hot_pixel_mask(ev, neighbour_ratio=4)).tolist()
    [[2, 3]]
    """
    return hot_pixel_mask_of_counts(_counts(events, "hot_pixel_mask"), n_sigma=n_sigma,
                                    min_count=min_count, neighbour_ratio=neighbour_ratio)


def hot_pixel_mask_of_counts(counts: np.ndarray, *, n_sigma: float = 5.0,
                             min_count: int = 10,
                             neighbour_ratio: float | None = None) -> np.ndarray:
    """:func:`hot_pixel_mask` of the per-pixel event counts ``counts`` ((H, W),
    :func:`pixel_counts`).

    Examples
    --------
    >>> counts = np.ones((3, 4), np.int64); counts[1, 2] = 50
    >>> np.argwhere(hot_pixel_mask_of_counts(counts, neighbour_ratio=4)).tolist()
    [[1, 2]]
    """
    # (n_sigma=-1 or nan had run, marking the busy half of the pixels hot; probe BE)
    n_sigma = check_number("n_sigma", n_sigma, 0.0)
    min_count = whole_number("min_count", min_count, lo=0)
    if neighbour_ratio is not None:
        neighbour_ratio = check_number("neighbour_ratio", neighbour_ratio, 1.0)
    img = np.asarray(counts)
    if img.ndim != 2:
        raise ParameterError(f"counts must be an (H, W) image of event counts, got shape "
                             f"{img.shape}")
    flat = img.ravel()
    active = flat[flat > 0]
    if active.size == 0:
        return np.zeros(img.shape, dtype=bool)
    med = np.median(active)
    mad = 1.4826 * np.median(np.abs(active - med))
    thr = max(med + n_sigma * max(mad, 1.0), float(min_count))
    hot = img > thr
    if neighbour_ratio is not None and hot.any():
        pad = np.pad(img, 1)
        h, w = img.shape
        around = np.max([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                         for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx], axis=0)
        hot &= img > neighbour_ratio * around
    if neighbour_ratio is not None:
        hot |= hot_line_mask(img, thr, neighbour_ratio)
    return hot


# pixels over the threshold a row or column needs to count as a stuck line (hot_line_mask):
# fewer is a cluster of hot pixels, which the 8-neighbour test handles
MIN_LINE_PIXELS = 8


def hot_line_mask(counts: np.ndarray, threshold: float, ratio: float) -> np.ndarray:
    """(H, W) bool mask of the busy pixels of stuck rows and columns of a count image.

    A stuck row fires all along itself, so its pixels have busy neighbours on the row and
    escape the 8-neighbour test of :func:`hot_pixel_mask`; a moving edge spreads over many
    rows. A row counts as stuck when its total is more than ``ratio`` times each adjacent
    row's and at least :data:`MIN_LINE_PIXELS` of its pixels count more than ``threshold``
    events and ``ratio`` times each of the three pixels above and below; those pixels are
    masked (columns alike).

    Examples
    --------
    >>> counts = np.ones((6, 20)); counts[3] = 50
    >>> np.flatnonzero(hot_line_mask(counts, 10, 4).any(axis=1)).tolist()
    [3]
    """
    out = np.zeros(counts.shape, dtype=bool)
    for img, view in ((counts, out), (counts.T, out.T)):
        if img.shape[0] < 2:
            continue
        pad = np.pad(img, 1)
        w = img.shape[1]
        # the three pixels above and the three below each pixel
        across = np.max([pad[r:r + img.shape[0], 1 + dx:1 + dx + w]
                         for r in (0, 2) for dx in (-1, 0, 1)], axis=0)
        busy = (img > threshold) & (img > ratio * across)
        rows = img.sum(axis=1)
        side = np.maximum(np.r_[0.0, rows[:-1]], np.r_[rows[1:], 0.0])
        stuck = (rows > ratio * side) & (busy.sum(axis=1) >= MIN_LINE_PIXELS)
        view[stuck] = busy[stuck]
    return out


def remove_hot_pixels(events: EventArray, mask: np.ndarray | None = None, **kw) -> EventArray:
    """Drop events at hot pixels (``mask`` from :func:`hot_pixel_mask` when not given)."""
    if mask is None:
        mask = hot_pixel_mask(events, **kw)
    if mask.shape != events.sensor_size:
        raise ParameterError(f"hot-pixel mask has shape {mask.shape}, sensor is {events.sensor_size}")
    x, y = sensor_pixels(events)  # the pixels hot_pixel_mask counted
    return events[~mask[y, x]]
