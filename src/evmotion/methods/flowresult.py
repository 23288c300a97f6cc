"""The result of the dense-flow methods (multicm, dnn) and where events support its flow.

Kept apart from :mod:`evmotion.methods.multicm` (which re-exports every name here) and
free of numba: the network's path (``method="dnn"``) returns the same result type, and
importing numba and loading its first kernel costs ~0.6 s of a one-window command's start.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import EmptyWindowError, EvmotionWarning, ParameterError
from evmotion.events import EventArray, Window
from evmotion.methods.measured import box_offsets, framed_landing
from evmotion.utils import check_finite

__all__ = ["ALIGNED_MIN_EVENTS", "SUPPORT_MIN_EVENTS", "SUPPORT_RADIUS", "FlowResult",
           "aligned_support", "estimate_or_skip", "event_box_counts", "event_support",
           "skipped_window"]

#: Validity mask of the flow: pixels with at least SUPPORT_MIN_EVENTS events within a
#: (2 SUPPORT_RADIUS + 1)-px square over the window (an isolated noise event supports none).
SUPPORT_RADIUS = 2
SUPPORT_MIN_EVENTS = 2


@dataclass(frozen=True)
class FlowResult:
    """Result of :func:`estimate_flow` for one window.

    Attributes
    ----------
    flow : ndarray (H, W, 2) float32
        Dense flow at ``t_ref_us`` in px/s (u right, v down).
    t0_us, t1_us, t_ref_us : int
        Window start/end (first and last event: ``t1_us`` is inclusive, where flow files,
        ``--json`` rows and :meth:`EventArray.slice_time` take the end exclusive, one µs
        later) and reference time (midpoint), µs.
    params : tuple of ndarray
        Tile flow (ny, nx, 2) in px/s for every scale, coarse to fine.
    iwes : dict
        IWEs (H, W) with the estimated flow at ``"t1"``, ``"tmid"``, ``"tN"`` and the
        identity-warp IWE ``"identity"``.
    focus : float
        Multi-reference focus ``f`` (4.6) of the final flow (> 1: sharper than zero flow).
    history : list of tuple
        ``(scale, objective value)`` after each scale.
    timings : dict
        Seconds per scale and in total (``total_s``, wall), of it ``compile_s`` in numba's
        first-use compilation of kernels (:func:`evmotion.jitcache.compile_seconds`) and
        ``estimate_s`` the rest.
    time_aware : str or None
    n_bins : int
    n_events : int
    meta : dict
    valid : ndarray (H, W) bool or None
        Pixels where events support the flow (see the module docstring); elsewhere the
        flow is not a measurement.
    """

    flow: np.ndarray
    t0_us: int
    t1_us: int
    t_ref_us: int
    params: tuple
    iwes: dict
    focus: float
    history: list
    timings: dict
    time_aware: str | None
    n_bins: int
    n_events: int
    meta: dict = field(default_factory=dict)
    valid: np.ndarray | None = field(default=None, repr=False)

    @property
    def duration_s(self) -> float:
        return (self.t1_us - self.t0_us) * 1e-6

    def displacement(self, t0_us: int | None = None, t1_us: int | None = None, *,
                     along_streamlines: bool = False, scheme: str = "burgers") -> np.ndarray:
        """Displacement in px over ``[t0_us, t1_us]`` (default: the window), (H, W, 2).

        Parameters
        ----------
        t0_us, t1_us : int, optional
            Interval in µs, e.g. a ground-truth interval (MVSEC ``dt = 4``).
        along_streamlines : bool
            False (default): the flow at ``t_ref`` times the duration, the displacement
            model of the warp (4.4). True: the displacement of the scene point seen at
            each pixel at ``t0_us``: the flow transported to ``t0_us`` along its own
            streamlines (4.7, :mod:`evmotion.methods.transport`) times the duration, i.e.
            the straight path of (4.7) through that point -- comparable with ground truth
            integrated along the trajectories. On a simulated camera rotation over a dt = 4
            window (25 px) this cuts the error of the exact ``t_mid`` flow from 1.37 to
            0.12 px.
        scheme : {"burgers", "upwind"}
            Transport scheme for ``along_streamlines``.

        Examples
        --------
        >>> import numpy as np
        >>> r = FlowResult(np.full((4, 5, 2), 100.0, np.float32), 0, 10_000, 5_000, (), {},
        ...                1.0, [], {}, None, 0, 0)
        >>> r.displacement(along_streamlines=True)[0, 0].tolist()  # constant flow: 1 px
        [1.0, 1.0]
        """
        # fractional µs (times converted from seconds) are taken to the µs below
        t0 = self.t0_us if t0_us is None else int(check_finite("t0_us", t0_us))
        t1 = self.t1_us if t1_us is None else int(check_finite("t1_us", t1_us))
        if t1 <= t0:
            raise ParameterError(f"displacement: need t1_us > t0_us, got [{t0}, {t1}]")
        d = self.flow.astype(np.float64) * ((t1 - t0) * 1e-6)
        if along_streamlines:
            from evmotion.methods import transport as tr

            # flow in px per (t1 - t0), time in the same unit
            plan = tr.transport_to_times(np.ascontiguousarray(d.transpose(2, 0, 1)),
                                         np.array([(t0 - self.t_ref_us) / (t1 - t0)]),
                                         scheme)
            d = plan.flows[0].transpose(1, 2, 0)
        return d.astype(np.float32)


def skipped_window(sensor_size: tuple[int, int], t0_us: int, t1_us: int, n_events: int,
                   reason: str) -> FlowResult:
    """The result standing for a window of a sequence that could not be estimated (all its
    events at one time, say): zero flow, no pixel valid, ``focus`` NaN and
    ``meta["skipped"]`` the reason, so the outputs keep one entry per window and none of
    it reads as a measurement.

    Examples
    --------
    >>> r = skipped_window((3, 4), 100, 200, 5, "all 5 events at one time")
    >>> bool(r.valid.any()), r.meta["skipped"]
    (False, 'all 5 events at one time')
    """
    h, w = sensor_size
    return FlowResult(flow=np.zeros((h, w, 2), np.float32), t0_us=int(t0_us),
                      t1_us=int(t1_us), t_ref_us=(int(t0_us) + int(t1_us)) // 2, params=(),
                      iwes={}, focus=float("nan"), history=[], timings={"total_s": 0.0},
                      time_aware=None, n_bins=0, n_events=int(n_events),
                      meta={"skipped": str(reason)}, valid=np.zeros((h, w), bool))


def estimate_or_skip(estimate: Callable[[EventArray], FlowResult], events: EventArray,
                     window: Window, on_empty: str = "skip") -> FlowResult:
    """``estimate(events.window(window))``, or with ``on_empty="skip"`` a
    :func:`~evmotion.methods.flowresult.skipped_window` and a warning naming the window
    where it raises :class:`EmptyWindowError`."""
    ev = events.window(window)
    try:
        return estimate(ev)
    except EmptyWindowError as exc:
        if on_empty != "skip":
            raise
        warnings.warn(EvmotionWarning(f"window {window.index} [{window.t0}, {window.t1}) us "
                                      f"skipped: {exc}"), stacklevel=2)
        return skipped_window(events.sensor_size, window.t0, window.t1, len(ev), str(exc))


def event_support(x, y, shape, radius: int = 2, min_count: float = 1.0) -> np.ndarray:
    """Pixels supported by events: the event-count image dilated by a square of
    ``2 * radius + 1`` px, at least ``min_count``.

    Parameters
    ----------
    x, y : array (N,)
        Event pixels (rounded; outside the sensor ignored).
    shape : (int, int)
        ``(H, W)``.
    radius : int
        Dilation radius in px (a tile flow is smooth over a few px around its events).
    min_count : float
        Events needed within the square.

    Returns
    -------
    ndarray (H, W) bool

    Examples
    --------
    >>> m = event_support(np.array([5]), np.array([5]), (10, 10), radius=1)
    >>> int(m.sum()), bool(m[4, 6]), bool(m[5, 7])
    (9, True, False)
    """
    return event_box_counts(x, y, shape, radius) >= min_count


#: Events a warped event's 5x5 pixels must hold, itself included, for it to support a
#: flow (:func:`aligned_support`).
ALIGNED_MIN_EVENTS = 3


def aligned_support(events: EventArray, flow: np.ndarray, t_ref_us: int,
                    radius: int = SUPPORT_RADIUS,
                    min_count: float = SUPPORT_MIN_EVENTS) -> np.ndarray:
    """:func:`event_support` of the events that ``flow`` (px/s, (H, W, 2)) lines up: each
    event moved to ``t_ref_us`` by the flow at its pixel (nearest) must land among
    :data:`ALIGNED_MIN_EVENTS` or more (the :data:`SUPPORT_RADIUS` square, 5x5 pixels,
    itself included).

    Background noise supported whatever flow its pixels got: a static scene's sensor
    noise (0.5 Hz a pixel) held ~4,000 pixels of a 320x240 window valid with the moving
    object's flow (probe DG). A moving edge's events land on one another; noise's land
    alone.

    Examples
    --------
    A dot moving right at 2500 px/s fires every 2.5 px: moved by that flow its events
    land on one another; left still, each lies alone.

    >>> t = np.arange(0, 10_000, 1_000)
    >>> dot = EventArray(x=np.round(2 + 2500e-6 * t), y=np.full(t.size, 5), t=t,
    ...                  p=np.ones(t.size), sensor_size=(12, 30))
    >>> still = np.zeros((12, 30, 2), np.float32)
    >>> moving = still + np.float32([2500.0, 0.0])
    >>> int(aligned_support(dot, moving, 5_000).sum()) > 0
    True
    >>> int(aligned_support(dot, still, 5_000).sum())
    0
    """
    h, w = events.sensor_size
    if not len(events):
        return np.zeros((h, w), bool)
    x = np.clip(np.rint(np.asarray(events.x, np.float64)).astype(np.int64), 0, w - 1)
    y = np.clip(np.rint(np.asarray(events.y, np.float64)).astype(np.int64), 0, h - 1)
    r = SUPPORT_RADIUS
    framed, inside = framed_landing(x, y, events.t, np.asarray(flow)[y, x], t_ref_us, (h, w),
                                    frame=r)
    image = np.bincount(framed[inside], minlength=(h + 2 * r) * (w + 2 * r))
    near = image[framed[:, None] + box_offsets(w + 2 * r, r)].sum(axis=1)
    lined_up = inside & (near >= ALIGNED_MIN_EVENTS)
    return event_support(x[lined_up], y[lined_up], (h, w), radius, min_count)


def event_box_counts(x, y, shape, radius: int = 2) -> np.ndarray:
    """(H, W) float64: the events within the square of ``2 * radius + 1`` px around each
    pixel (the image's border cuts the square), as :func:`event_support` thresholds them.

    Examples
    --------
    >>> event_box_counts(np.array([0, 1]), np.array([0, 0]), (2, 3), radius=1).tolist()
    [[2.0, 2.0, 1.0], [2.0, 2.0, 1.0]]
    """
    h, w = int(shape[0]), int(shape[1])
    if radius < 0:
        raise ParameterError(f"event_support: radius must be >= 0, got {radius}")
    xi = np.rint(np.asarray(x, dtype=np.float64)).astype(np.int64)
    yi = np.rint(np.asarray(y, dtype=np.float64)).astype(np.int64)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.zeros((h, w))
    if not ok.any():
        return out
    xi, yi = xi[ok], yi[ok]
    r = int(radius)
    # the box sums of the events' bounding box grown by the radius: outside it they are 0,
    # and inside it no box reaches an event beyond it. The whole sensor's integral image
    # took 3.2 s of a 21k-event multicm window on 4096x4096 (probe DB)
    ya, yb = max(int(yi.min()) - r, 0), min(int(yi.max()) + r + 1, h)
    xa, xb = max(int(xi.min()) - r, 0), min(int(xi.max()) + r + 1, w)
    bh, bw = yb - ya, xb - xa
    cnt = np.bincount((yi - ya) * bw + (xi - xa), minlength=bh * bw).reshape(bh, bw)
    # box sum by integral image (float64: exact counts)
    ii = np.zeros((bh + 1, bw + 1))
    ii[1:, 1:] = cnt.cumsum(0).cumsum(1)
    y0 = np.clip(np.arange(bh) - r, 0, bh)
    y1 = np.clip(np.arange(bh) + r + 1, 0, bh)
    x0 = np.clip(np.arange(bw) - r, 0, bw)
    x1 = np.clip(np.arange(bw) + r + 1, 0, bw)
    out[ya:yb, xa:xb] = ii[y1][:, x1] - ii[y0][:, x1] - ii[y1][:, x0] + ii[y0][:, x0]
    return out
