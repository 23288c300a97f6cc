"""Accuracy and sharpness metrics for optical flow and ego-motion.

Flow accuracy (:func:`flow_metrics`) compares two displacement fields over the same time
interval, in pixels: average endpoint error (AEE), the percentage of pixels whose endpoint
error exceeds N px (NPE, thesis §3.6.1), the outlier percentage %Out (thesis §4.3.1 and
§5.3.1: endpoint error > 3 px; §6.6.1 uses > 1 px, hence the ``out_px`` parameter) and the
angular error (AE) of the space-time vectors (u, v, 1).

Sharpness (:func:`fwl`): the Flow Warp Loss of Stoffregen et al., the variance of the
image of warped events (IWE) with the flow over the variance with zero flow; > 1 means the
flow aligns events better than the identity warp.

Rotation accuracy (:func:`rms_error`): RMS error of angular velocity per axis and overall
(thesis §3.6.1, ECD).

The evaluation masks of the thesis are :func:`valid_gt_mask` (finite ground truth; MVSEC
also treats zero GT as missing) and :func:`event_mask` (at least one event at the pixel).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import EmptyWindowError, EvmotionWarning, ParameterError
from evmotion.events import EventArray, check_image_shape, check_reference_time, require_events
from evmotion.utils import check_number, is_finite_number, whole_number

__all__ = [
    "NPE_THRESHOLDS",
    "FlowMetrics",
    "RmsError",
    "aggregate_flow_metrics",
    "angular_error_deg",
    "endpoint_error",
    "event_mask",
    "events_where_defined",
    "flow_metrics",
    "fwl",
    "rms_error",
    "sample_flow_bilinear",
    "valid_gt_mask",
    "warn_no_better_than_zero",
    "warp_by_flow",
]

NPE_THRESHOLDS: tuple[int, ...] = (1, 2, 3, 5, 10, 20)

#: The smallest Gaussian vote (px) :func:`fwl` takes, and the share of a window's events a
#: flow may warp off the image before :func:`fwl` says its score is not a measurement.
FWL_MIN_SIGMA_PX = 0.1
FWL_MAX_OFF_SHARE = 0.5


@dataclass(frozen=True)
class FlowMetrics:
    """Flow accuracy over the evaluated pixels.

    Attributes
    ----------
    aee : float
        Average endpoint error in px (NaN when no pixel is evaluated).
    npe : dict of int to float
        ``npe[N]``: percentage of pixels with endpoint error > N px.
    pct_out : float
        Percentage of outliers (see :func:`flow_metrics` for the definition used).
    ae_deg : float
        Mean angular error of (u, v, 1) vectors in degrees.
    n_pixels : int
        Number of pixels evaluated.
    """

    aee: float
    npe: dict[int, float] = field(default_factory=dict)
    pct_out: float = float("nan")
    ae_deg: float = float("nan")
    n_pixels: int = 0

    def as_dict(self) -> dict[str, float | int]:
        """Flat dict (``"3PE"`` style keys) for tables, JSON and CSV."""
        d: dict[str, float | int] = {"AEE": self.aee}
        d.update({f"{n}PE": v for n, v in self.npe.items()})
        d.update({"%Out": self.pct_out, "AE_deg": self.ae_deg, "n_pixels": self.n_pixels})
        return d


@dataclass(frozen=True)
class RmsError:
    """RMS error of a vector quantity (e.g. angular velocity in deg/s) over samples.

    Attributes
    ----------
    per_axis : numpy.ndarray
        ``sqrt(mean_i e_ij^2)`` for each axis j, in the input's unit.
    overall : float
        ``sqrt(mean_ij e_ij^2)``: RMS over all samples and axes (the per-axis values
        combined quadratically and averaged).
    norm : float
        ``sqrt(mean_i ||e_i||^2)``: RMS of the error vector's length
        (= ``overall * sqrt(n_axes)``).
    n_samples : int
    """

    per_axis: np.ndarray
    overall: float
    norm: float
    n_samples: int

    def as_dict(self, axes: Sequence[str] = ("x", "y", "z")) -> dict[str, float | int]:
        d: dict[str, float | int] = {
            f"rms_{axes[j] if j < len(axes) else j}": float(v)
            for j, v in enumerate(self.per_axis)
        }
        d.update(rms=self.overall, rms_norm=self.norm, n_samples=self.n_samples)
        return d


# --------------------------------------------------------------------------- masks
def _as_mask(mask) -> np.ndarray:
    """``mask`` as booleans; other values than 0 and 1 (a weight map, NaN) are refused
    rather than read as True."""
    arr = np.asarray(mask)
    if arr.dtype != bool:
        bad = ~np.isin(arr, (0, 1))
        if bad.any():
            raise ParameterError(f"mask must be boolean (or 0 / 1); it holds "
                                 f"{arr[bad].flat[0].item()!r} at {int(bad.sum())} pixels")
    return arr.astype(bool)


def valid_gt_mask(gt: np.ndarray, *, zero_is_invalid: bool = False) -> np.ndarray:
    """Pixels whose ground-truth flow is usable.

    Parameters
    ----------
    gt : ndarray, shape (H, W, 2)
        Ground-truth flow (any unit).
    zero_is_invalid : bool
        Also reject pixels where both components are exactly 0, as the MVSEC evaluation
        does (its GT stores "no depth" as zero flow). Keep False for simulator GT, where a
        static background legitimately has zero flow.

    Returns
    -------
    ndarray of bool, shape (H, W)

    Examples
    --------
    >>> gt = np.zeros((2, 2, 2)); gt[0, 0] = np.nan; gt[1, 1] = 1.0
    >>> valid_gt_mask(gt, zero_is_invalid=True).tolist()
    [[False, False], [False, True]]
    """
    gt = _as_flow(gt, "gt")
    mask = np.isfinite(gt).all(axis=-1)
    if zero_is_invalid:
        mask &= (gt != 0).any(axis=-1)
    return mask


def event_mask(events: EventArray, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Pixels with at least one event (thesis ch. 4 evaluation mask).

    Parameters
    ----------
    events : EventArray
        Events of the evaluation interval. Sub-pixel (undistorted) coordinates are
        rounded to the nearest pixel; events off the image are ignored.
    shape : (int, int), optional
        ``(height, width)``; default ``events.sensor_size``.

    Returns
    -------
    ndarray of bool, shape (H, W)

    Examples
    --------
    >>> ev = EventArray(x=[1, 1], y=[0, 0], t=[0, 5], p=[1, 0], sensor_size=(2, 3))
    >>> event_mask(ev).astype(int).tolist()
    [[0, 1, 0], [0, 0, 0]]
    """
    h, w = events.sensor_size if shape is None else check_image_shape("event_mask: shape",
                                                                       shape)
    mask = np.zeros(h * w, dtype=bool)
    if len(events):
        xi = np.rint(events.x).astype(np.int64)
        yi = np.rint(events.y).astype(np.int64)
        inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        mask[yi[inside] * w + xi[inside]] = True
    return mask.reshape(h, w)


# ------------------------------------------------------------------ flow accuracy
def endpoint_error(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-pixel endpoint error ``||flow - gt||`` (same unit as the inputs), shape (H, W)."""
    flow, gt = _pair(flow, gt)
    return np.hypot(flow[..., 0] - gt[..., 0], flow[..., 1] - gt[..., 1])


def angular_error_deg(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-pixel angle between (u, v, 1) and (u_gt, v_gt, 1) in degrees, shape (H, W).

    The standard Middlebury form (Barron et al.; Baker et al.): flows are displacements in
    px over the evaluation interval, so the result depends on that interval.
    """
    flow, gt = _pair(flow, gt)
    u, v = flow[..., 0], flow[..., 1]
    ug, vg = gt[..., 0], gt[..., 1]
    num = u * ug + v * vg + 1.0
    den = np.sqrt((u * u + v * v + 1.0) * (ug * ug + vg * vg + 1.0))
    return np.degrees(np.arccos(np.clip(num / den, -1.0, 1.0)))


def flow_metrics(
    flow: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    events: EventArray | None = None,
    *,
    out_px: float = 3.0,
    out_rel: float | None = None,
    npe_thresholds: Iterable[int] = NPE_THRESHOLDS,
) -> FlowMetrics:
    """Accuracy of an estimated flow against ground truth.

    Parameters
    ----------
    flow, gt : ndarray, shape (H, W, 2)
        Estimated and ground-truth **displacements in px over the same time interval**
        (multiply px/s flows by the interval in seconds first); u right, v down.
    mask : ndarray of bool, shape (H, W), optional
        Pixels to evaluate. Always intersected with the finite-GT mask
        (:func:`valid_gt_mask`); pass ``valid_gt_mask(gt, zero_is_invalid=True)`` for the
        MVSEC protocol.
    events : EventArray, optional
        If given, only pixels with at least one event are evaluated (:func:`event_mask`),
        as in thesis ch. 4 ("valid ground truth and at least one event") and ch. 6;
        ch. 5 evaluates all pixels with valid ground truth.
    out_px : float
        %Out threshold: a pixel is an outlier when its endpoint error is > ``out_px``
        (thesis §4.3.1 and §5.3.1: 3 px; §6.6.1 uses 1 px).
    out_rel : float, optional
        KITTI-style outliers: additionally require endpoint error > ``out_rel`` times the
        GT magnitude (KITTI uses 0.05). Default None: the thesis definition (absolute only).
    npe_thresholds : iterable of int
        N values for the NPE percentages (default 1, 2, 3, 5, 10, 20 px).

    Returns
    -------
    FlowMetrics
        With ``n_pixels == 0`` and NaN values when no pixel is evaluated.

    Raises
    ------
    ParameterError
        Shapes differ, or the estimate has NaN/inf at an evaluated pixel.

    Examples
    --------
    >>> gt = np.zeros((4, 4, 2), np.float32); est = gt.copy(); est[..., 0] = 4.0
    >>> m = flow_metrics(est, gt)
    >>> m.aee, m.npe[3], m.pct_out, m.n_pixels
    (4.0, 100.0, 100.0, 16)
    """
    flow, gt = _pair(flow, gt)
    sel = valid_gt_mask(gt)
    if mask is not None:
        mask = _as_mask(mask)
        if mask.shape != sel.shape:
            raise ParameterError(f"mask has shape {mask.shape}, expected {sel.shape} (H, W)")
        sel &= mask
    if events is not None:
        require_events(events, "flow_metrics")  # (a structured array failed deep inside)
        if tuple(events.sensor_size) != sel.shape:
            raise ParameterError(f"events are on a {events.sensor_size} sensor but the flow "
                                 f"is {sel.shape} px (height, width)")
        sel &= event_mask(events, sel.shape)
    if not (is_finite_number(out_px) and out_px > 0):
        raise ParameterError(f"out_px must be a finite number of px > 0, got {out_px!r}")
    thresholds = check_npe_thresholds(npe_thresholds)
    if out_rel is not None:  # (-1 had made every pixel past out_px an outlier, probe BE)
        out_rel = check_number("out_rel", out_rel, 0.0)
    n = int(sel.sum())
    if n == 0:
        nan = float("nan")
        return FlowMetrics(nan, {t: nan for t in thresholds}, nan, nan, 0)
    f, g = flow[sel], gt[sel]
    if not np.isfinite(f).all():
        bad = int((~np.isfinite(f).all(axis=-1)).sum())
        raise ParameterError(
            f"the estimated flow has NaN/inf at {bad} of the {n} evaluated pixels "
            "(exclude them with `mask` if the method leaves them undefined)"
        )
    f = f.astype(np.float64)
    g = g.astype(np.float64)
    ee = np.hypot(f[:, 0] - g[:, 0], f[:, 1] - g[:, 1])
    outlier = ee > out_px
    if out_rel is not None:
        outlier &= ee > out_rel * np.hypot(g[:, 0], g[:, 1])
    num = f[:, 0] * g[:, 0] + f[:, 1] * g[:, 1] + 1.0
    den = np.sqrt((f * f).sum(axis=1) + 1.0) * np.sqrt((g * g).sum(axis=1) + 1.0)
    ae = np.degrees(np.arccos(np.clip(num / den, -1.0, 1.0)))
    return FlowMetrics(
        aee=float(ee.mean()),
        npe={t: float(100.0 * np.mean(ee > t)) for t in thresholds},
        pct_out=float(100.0 * outlier.mean()),
        ae_deg=float(ae.mean()),
        n_pixels=n,
    )


def check_npe_thresholds(npe_thresholds: Iterable[int]) -> tuple[int, ...]:
    """The NPE thresholds as whole px >= 1, or :class:`ParameterError` (1.5 had been
    floored to 1, and the string "13" read as 1 and 3).

    Examples
    --------
    >>> check_npe_thresholds([1, 3.0])
    (1, 3)
    >>> check_npe_thresholds("13")
    Traceback (most recent call last):
    evmotion.errors.ParameterError: npe_thresholds must be whole numbers of px, got '13'
    """
    if isinstance(npe_thresholds, (str, bytes)) or not isinstance(npe_thresholds, Iterable):
        raise ParameterError(f"npe_thresholds must be whole numbers of px, got "
                             f"{npe_thresholds!r}")
    return tuple(whole_number("npe_thresholds", n, lo=1) for n in npe_thresholds)


def aggregate_flow_metrics(items: Iterable[FlowMetrics], *, weight: str = "window",
                           ) -> FlowMetrics:
    """Combine per-window metrics into one.

    Parameters
    ----------
    items : iterable of FlowMetrics
        Windows with ``n_pixels == 0`` are skipped.
    weight : {"window", "pixel"}
        ``"window"``: plain mean over windows (the MVSEC/DSEC convention of averaging
        per-frame values); ``"pixel"``: weighted by each window's pixel count.

    Examples
    --------
    >>> a = FlowMetrics(1.0, {3: 0.0}, 0.0, 1.0, 10); b = FlowMetrics(3.0, {3: 50.0}, 50.0, 3.0, 30)
    >>> aggregate_flow_metrics([a, b]).aee, aggregate_flow_metrics([a, b], weight="pixel").aee
    (2.0, 2.5)
    """
    if weight not in ("window", "pixel"):
        raise ParameterError(f"weight must be 'window' or 'pixel', got {weight!r}")
    items = [m for m in items if m.n_pixels > 0]
    if not items:
        raise EmptyWindowError("no window has evaluated pixels: nothing to aggregate")
    w = np.array([m.n_pixels if weight == "pixel" else 1.0 for m in items], dtype=np.float64)
    w /= w.sum()

    def avg(values) -> float:
        return float(np.dot(w, np.asarray(values, dtype=np.float64)))

    keys = items[0].npe.keys()
    return FlowMetrics(
        aee=avg([m.aee for m in items]),
        npe={k: avg([m.npe.get(k, np.nan) for m in items]) for k in keys},
        pct_out=avg([m.pct_out for m in items]),
        ae_deg=avg([m.ae_deg for m in items]),
        n_pixels=int(sum(m.n_pixels for m in items)),
    )


def warn_no_better_than_zero(aee: float, aee_zero: float, scored: str) -> bool:
    """Warn when an estimate is no closer to the ground truth than the zero flow.

    Such an AEE is not a measurement of the estimate's accuracy: either the estimate failed
    or the ground truth is another scene's or another time's (the scores of a flow against
    the wrong scene otherwise read like those of a poor estimate).

    Parameters
    ----------
    aee, aee_zero : float
        The estimate's AEE and the zero flow's on the same pixels or events, px.
    scored : str
        What was scored, for the message (e.g. the file names).

    Returns
    -------
    bool
        Whether it warned (a ground truth that does not move gives no verdict).

    Examples
    --------
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     warn_no_better_than_zero(0.24, 0.064, "est.h5 against gt.h5")
    True
    >>> warn_no_better_than_zero(0.17, 0.30, "est.h5 against gt.h5")
    False
    """
    if not (is_finite_number(aee) and is_finite_number(aee_zero)) or aee_zero <= 0 \
            or aee < aee_zero:
        return False
    warnings.warn(EvmotionWarning(
        f"{scored}: AEE {aee:.4g} px is no lower than the zero flow's {aee_zero:.4g} px: the "
        "estimate carries no information on this ground truth's motion (a failed estimate, "
        "or the ground truth of another scene or time?)"), stacklevel=3)
    return True


# ---------------------------------------------------------------------- sharpness
def sample_flow_bilinear(flow: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Flow at sub-pixel positions by bilinear interpolation, clamped at the border.

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2)
    x, y : ndarray, shape (N,)
        Column and row positions in px.

    Returns
    -------
    ndarray, shape (N, 2), float64

    Examples
    --------
    >>> f = np.zeros((2, 2, 2)); f[:, 1, 0] = 2.0
    >>> sample_flow_bilinear(f, np.array([0.5]), np.array([0.0])).tolist()
    [[1.0, 0.0]]
    """
    flow = np.asarray(flow)
    # (an empty or (H, W) flow had failed as an IndexError or come back as [[0.]], probe EVAL)
    if flow.ndim != 3 or flow.shape[2] != 2 or 0 in flow.shape or flow.dtype.kind not in "fiu":
        raise ParameterError(f"sample_flow_bilinear: flow must be a numeric array (H, W, 2) "
                             f"of at least one pixel, got shape {flow.shape}, dtype "
                             f"{flow.dtype}")
    h, w = flow.shape[:2]
    try:
        xf, yf = (np.asarray(a, dtype=np.float64).ravel() for a in (x, y))
    except (TypeError, ValueError):
        raise ParameterError("sample_flow_bilinear: x and y must be arrays of positions "
                             "(px)") from None
    if xf.shape != yf.shape:
        raise ParameterError(f"sample_flow_bilinear: x and y must have one length, got "
                             f"{xf.size} and {yf.size}")
    if not (np.isfinite(xf).all() and np.isfinite(yf).all()):
        raise ParameterError("sample_flow_bilinear: x and y must be finite positions (px), "
                             "got NaN or inf")
    xf = np.clip(xf, 0.0, w - 1.0)
    yf = np.clip(yf, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(xf).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(yf).astype(np.int64), max(h - 2, 0))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    ax = (xf - x0)[:, None]
    ay = (yf - y0)[:, None]
    f = flow.astype(np.float64, copy=False)
    top = f[y0, x0] * (1 - ax) + f[y0, x1] * ax
    bottom = f[y1, x0] * (1 - ax) + f[y1, x1] * ax
    return top * (1 - ay) + bottom * ay


def warp_by_flow(events: EventArray, flow_px_per_s: np.ndarray, t_ref_us: int | None = None,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Move each event along the flow at its position to the reference time.

    Event k goes to ``x_k + flow(x_k) * (t_ref - t_k)``: the flow (px/s) is looked up
    bilinearly at the event's sub-pixel position, the time difference is in seconds.

    Parameters
    ----------
    events : EventArray
    flow_px_per_s : ndarray, shape (H, W, 2)
        Flow on the sensor grid in px/s (u right, v down).
    t_ref_us : int, optional
        Reference time in µs (absolute); default the first event's timestamp. It must lie
        within ``max(span, 1 s)`` of the events' times ``[first, last]`` (a time farther
        away is another window's: :func:`evmotion.events.check_reference_time`).

    Returns
    -------
    xw, yw : ndarray of float64, shape (N,)
        Warped columns and rows in px (contiguous, ready for ``core.iwe.accumulate``).

    Examples
    --------
    >>> ev = EventArray(x=[2], y=[1], t=[1000], p=[1], sensor_size=(3, 4))
    >>> flow = np.zeros((3, 4, 2)); flow[..., 0] = 1000.0
    >>> [a.tolist() for a in warp_by_flow(ev, flow, t_ref_us=0)]
    [[1.0], [1.0]]
    """
    if not len(events):
        raise EmptyWindowError("no events to warp; the window is empty")
    flow = _as_flow(flow_px_per_s, "flow_px_per_s", per_second=True)
    if flow.shape[:2] != events.sensor_size:
        raise ParameterError(
            f"flow has shape {flow.shape[:2]}, expected the sensor size {events.sensor_size}"
        )
    t_ref = (events.t_start if t_ref_us is None
             else check_reference_time("t_ref_us", t_ref_us, events.t))
    x = events.x.astype(np.float64)
    y = events.y.astype(np.float64)
    dt = (np.int64(t_ref) - events.t).astype(np.float64) * 1e-6
    uv = sample_flow_bilinear(flow, x, y)
    return np.ascontiguousarray(x + uv[:, 0] * dt), np.ascontiguousarray(y + uv[:, 1] * dt)


def events_where_defined(events: EventArray, flow: np.ndarray) -> EventArray:
    """The events whose bilinear flow lookup reads only finite pixels of ``flow`` (H, W, 2):
    what :func:`fwl` can warp when the flow is undefined somewhere (NaN outside a BOS ROI,
    "unknown" in a ``.flo``).

    Examples
    --------
    >>> ev = EventArray(x=[0, 1, 3], y=[0, 0, 0], t=[0, 5, 9], p=[1, 1, 1],
    ...                 sensor_size=(1, 4))
    >>> flow = np.zeros((1, 4, 2)); flow[0, 1] = np.nan   # read by the events at x 0 and 1
    >>> events_where_defined(ev, flow).x.tolist()
    [3]
    """
    known = np.isfinite(flow).all(axis=-1)
    if known.all() or not len(events):
        return events
    h, w = known.shape
    # the four pixels the bilinear lookup of warp_by_flow reads (a zero weight on a NaN
    # neighbour is still NaN)
    xf = np.clip(events.x.astype(np.float64), 0.0, w - 1.0)
    yf = np.clip(events.y.astype(np.float64), 0.0, h - 1.0)
    x0 = np.minimum(np.floor(xf).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(yf).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ok = known[y0, x0] & known[y0, x1] & known[y1, x0] & known[y1, x1]
    return events[ok]


def fwl(
    events: EventArray,
    flow_px_per_s: np.ndarray,
    t_ref_us: int | None = None,
    *,
    kernel: str = "bilinear",
    sigma: float = 1.0,
    mask: np.ndarray | None = None,
) -> float:
    """Flow Warp Loss (Stoffregen et al. 2020): IWE variance with the flow over that of
    the zero flow.

    Each event k moves to ``x_k + flow(x_k) * (t_ref - t_k)``, the flow (px/s) looked up
    bilinearly at the event's sub-pixel position and the time in seconds; the images
    count events (no polarity) with :func:`evmotion.core.iwe.accumulate`.

    Parameters
    ----------
    events : EventArray
        Events of the evaluation interval.
    flow_px_per_s : ndarray, shape (H, W, 2)
        Flow in px/s on the sensor grid (u right, v down).
    t_ref_us : int, optional
        Reference time in µs (absolute); default the first event's timestamp. It must lie
        within ``max(span, 1 s)`` of the events' times, as in :func:`warp_by_flow`.
    kernel : {"bilinear", "gaussian"}
        Voting kernel passed to ``accumulate`` (default bilinear).
    sigma : float
        Gaussian kernel standard deviation in px.
    mask : ndarray of bool, shape (H, W), optional
        Compute the variances over these pixels only.

    Returns
    -------
    float
        > 1: the flow produces a sharper IWE than the identity warp.

    Raises
    ------
    EmptyWindowError
        No events, or the zero-flow IWE has zero variance.
    ParameterError
        The flow is NaN/inf where events are, or ``t_ref_us`` is far outside the events.

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[1, 1], t=[0, 1000], p=[1, 1], sensor_size=(3, 4))
    >>> flow = np.zeros((3, 4, 2), np.float32); flow[..., 0] = 1000.0  # 1 px per ms
    >>> round(fwl(ev, flow), 2)
    2.2
    """
    from evmotion.core.iwe import accumulate

    require_events(events, "fwl")
    # (NaN or -1 were ignored under the default bilinear kernel, probe API; below 0.1 px
    # a Gaussian vote misses the pixel centres, and 1e-30 scored an exact flow 1.5e-05,
    # probe EVAL)
    sigma = check_number("sigma", sigma, FWL_MIN_SIGMA_PX, units="px")

    xw, yw = warp_by_flow(events, flow_px_per_s, t_ref_us)
    lost = ~(np.isfinite(xw) & np.isfinite(yw))
    if lost.any():
        raise ParameterError(f"the flow is NaN/inf where {int(lost.sum())} of the "
                             f"{len(events)} events are: they would drop out of the warped "
                             "image (pass only the events where the flow is defined)")
    x = events.x.astype(np.float64)
    y = events.y.astype(np.float64)
    shape = events.sensor_size
    h, w = shape
    off = np.count_nonzero((xw < -0.5) | (xw > w - 0.5) | (yw < -0.5) | (yw > h - 0.5))
    if off > FWL_MAX_OFF_SHARE * len(events):
        # the score of the events left, near 0 (a flow of 1e6 px/s printed FWL 0.0009 as a
        # plain score, probe EVAL)
        warnings.warn(EvmotionWarning(
            f"FWL: the flow warps {100 * off / len(events):.0f} % of the {len(events)} events "
            "off the image: the score is not the flow's sharpness"), stacklevel=2)
    warped = np.asarray(accumulate(xw, yw, shape, weights=None, kernel=kernel, sigma=sigma))
    identity = np.asarray(accumulate(x, y, shape, weights=None, kernel=kernel, sigma=sigma))
    if mask is not None:
        mask = _as_mask(mask)
        if mask.shape != tuple(shape):
            raise ParameterError(f"mask has shape {mask.shape}, expected the sensor's "
                                 f"{tuple(shape)}")
        if not mask.any():
            raise EmptyWindowError("the mask selects no pixel: FWL is undefined")
        warped, identity = warped[mask], identity[mask]
    var0 = float(np.var(identity))
    if var0 <= 0.0:
        raise EmptyWindowError("the zero-flow IWE is constant: FWL is undefined")
    return float(np.var(warped)) / var0


# ------------------------------------------------------------------------ rotation
def rms_error(est: np.ndarray, gt: np.ndarray) -> RmsError:
    """RMS error between estimated and ground-truth vectors (e.g. angular velocity).

    Parameters
    ----------
    est, gt : ndarray, shape (N, D) or (N,)
        One row per window (e.g. ω in deg/s at each window's midpoint). Rows where
        either is NaN are dropped.

    Returns
    -------
    RmsError
        Per-axis, overall and norm RMS, in the input's unit.

    Examples
    --------
    >>> r = rms_error(np.array([[1.0, 0, 0], [1.0, 0, 0]]), np.zeros((2, 3)))
    >>> r.per_axis.tolist(), r.norm
    ([1.0, 0.0, 0.0], 1.0)
    """
    try:
        e = np.asarray(est, dtype=np.float64)
        g = np.asarray(gt, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"rms_error takes arrays of numbers, got {type(est).__name__} "
                             f"and {type(gt).__name__}") from None
    if e.ndim == 1:
        e = e[:, None]
    if g.ndim == 1:
        g = g[:, None]
    if e.shape != g.shape or e.ndim != 2:
        raise ParameterError(f"est has shape {np.shape(est)} and gt {np.shape(gt)}; "
                             "expected equal shapes (N, D)")
    keep = np.isfinite(e).all(axis=1) & np.isfinite(g).all(axis=1)
    if not keep.any():
        raise EmptyWindowError("no sample with finite estimate and ground truth")
    d = e[keep] - g[keep]
    # squared on the largest error's scale: d * d overflowed past 1.3e154 (probe EVAL)
    scale = float(np.max(np.abs(d)))
    scale = scale if 0 < scale < np.inf else 1.0
    u = d / scale
    return RmsError(
        per_axis=scale * np.sqrt(np.mean(u * u, axis=0)),
        overall=scale * float(np.sqrt(np.mean(u * u))),
        norm=scale * float(np.sqrt(np.mean(np.sum(u * u, axis=1)))),
        n_samples=int(keep.sum()),
    )


# ------------------------------------------------------------------------ helpers
def _as_flow(a, name: str, per_second: bool = False) -> np.ndarray:
    """``a`` as a float flow (H, W, 2); ``per_second``: px/s is asked (else px over one
    interval), which the advice for a FlowResult follows."""
    if callable(getattr(a, "displacement", None)) and not isinstance(a, np.ndarray):
        # a FlowResult (or a FlowSequence) holds px/s: its shape () said nothing of that
        # (probe CB); fwl takes px/s, which its advice had not said (res.displacement()
        # gave FWL 0.985 where res.flow gives 2.22, probe DB)
        raise ParameterError(
            f"'{name}' is a {type(a).__name__}: give "
            + ("the flow in px/s, e.g. res.flow" if per_second else
               "displacements in px over one interval, e.g. res.displacement() (a "
               "FlowResult's flow is px/s)"))
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[-1] != 2:
        raise ParameterError(f"'{name}' must have shape (H, W, 2), got {a.shape}")
    if a.dtype.kind not in "fiu":
        raise ParameterError(f"'{name}' must be numeric, got dtype {a.dtype}")
    # integer flows (DSEC PNG-decoded, quantized) in float: uint8 differences wrapped
    # (an error of 4 px read 252) and int16 squares overflowed (probe AU)
    return a.astype(np.float64) if a.dtype.kind in "iu" else a


def _pair(flow, gt) -> tuple[np.ndarray, np.ndarray]:
    flow = _as_flow(flow, "flow")
    gt = _as_flow(gt, "gt")
    if flow.shape != gt.shape:
        raise ParameterError(f"flow has shape {flow.shape} but gt has {gt.shape}")
    return flow, gt
