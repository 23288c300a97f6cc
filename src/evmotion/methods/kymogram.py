"""Kymograms (space-time plots along a line) and velocimetry by a line fit to their ridge.

Thesis ch. 6, §6.6.4–6.6.5 (Fig. 6.11): a streak-schlieren analysis follows one line of the
schlieren image over time. From events the line is sampled at any rate (1200 Hz and above,
"slow motion"), from frames or a q/flow sequence at the rate of its images. A schlieren
structure travelling along the line at a constant speed draws a straight ridge; the ridge's
slope is its speed in px/s, which the set-up geometry turns into m/s
(:func:`px_per_s_to_m_per_s`).

Geometry: the line runs from ``(x0, y0)`` to ``(x1, y1)`` (x = column, y = row, px); the
position ``s`` along it is measured in px from the start, sampled every pixel; ``width``
px across it are averaged. Velocities are signed along the line (start -> end).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import ndimage

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray, concatenate, require_events
from evmotion.utils import (
    check_finite,
    check_number,
    check_switches,
    is_finite_number,
    is_whole_number,
    whole_number,
    whole_time_us,
)

__all__ = [
    "Kymogram",
    "KymoLine",
    "LineEvents",
    "RidgeFit",
    "fit_correlation",
    "fit_ridge",
    "kymogram_from_events",
    "kymogram_from_frame_differences",
    "kymogram_from_images",
    "events_near_line",
    "px_per_s_to_m_per_s",
    "ridge_points",
]


@dataclass(frozen=True)
class KymoLine:
    """A straight sampling line on the image: start, end (px) and averaging width (px).

    Examples
    --------
    >>> KymoLine.column(10, (48, 64)).length_px
    47.0
    >>> KymoLine.row(5, (48, 64), width=3)
    KymoLine(x0=0.0, y0=5.0, x1=63.0, y1=5.0, width=3)
    """

    x0: float
    y0: float
    x1: float
    y1: float
    width: int = 1

    def __post_init__(self) -> None:
        for name in ("x0", "y0", "x1", "y1"):
            object.__setattr__(self, name, float(check_finite(name, getattr(self, name))))
        if not is_whole_number(self.width) \
                or not 1 <= self.width <= MAX_SMOOTH_PX:  # (NaN failed in int(), probe API)
            raise ParameterError(f"line width must be an integer in [1, {MAX_SMOOTH_PX:g}] px, "
                                 f"got {self.width!r}")
        object.__setattr__(self, "width", int(self.width))
        if self.length_px < 1.0:
            raise ParameterError(f"line from ({self.x0}, {self.y0}) to ({self.x1}, {self.y1}) "
                                 f"is shorter than 1 px")

    @classmethod
    def row(cls, row: int, shape: tuple[int, int], width: int = 1) -> KymoLine:
        """Image row ``row`` from left to right (an x–t kymogram)."""
        h, w = shape
        if not 0 <= row < h:
            raise ParameterError(f"row {row} is outside the image (0 <= row < {h})")
        return cls(0.0, float(row), float(w - 1), float(row), width)

    @classmethod
    def column(cls, col: int, shape: tuple[int, int], width: int = 1) -> KymoLine:
        """Image column ``col`` from top to bottom (a y–t kymogram; upward motion is < 0)."""
        h, w = shape
        if not 0 <= col < w:
            raise ParameterError(f"column {col} is outside the image (0 <= col < {w})")
        return cls(float(col), 0.0, float(col), float(h - 1), width)

    @property
    def length_px(self) -> float:
        return float(np.hypot(self.x1 - self.x0, self.y1 - self.y0))

    @property
    def n_samples(self) -> int:
        """Positions along the line, one per px: ``0, 1, ..., floor(length)``."""
        return int(np.floor(self.length_px + 1e-9)) + 1

    @property
    def direction(self) -> tuple[float, float]:
        """Unit vector (ux, uy) from start to end."""
        n = self.length_px
        return (self.x1 - self.x0) / n, (self.y1 - self.y0) / n

    def check_inside(self, shape: tuple[int, int]) -> None:
        """Raise :class:`ParameterError` if the line (with its width) leaves the image."""
        h, w = shape
        ux, uy = self.direction
        half = (self.width - 1) / 2
        for x, y in ((self.x0, self.y0), (self.x1, self.y1)):
            for side in (-half, half):
                px, py = x - uy * side, y + ux * side
                if not (-0.5 <= px <= w - 0.5 and -0.5 <= py <= h - 0.5):
                    raise ParameterError(
                        f"line ({self.x0:g}, {self.y0:g}) -> ({self.x1:g}, {self.y1:g}) of width "
                        f"{self.width} leaves the image ({w} px wide, {h} high)")

    def near(self, x, y, margin_px: float = 0.5) -> np.ndarray:
        """Boolean mask of the positions ``x, y`` (px) within ``margin_px`` of the band an
        event kymogram along the line counts (its width across, its samples along): every
        event :func:`kymogram_from_events` counts, and a few beside.

        Examples
        --------
        >>> KymoLine.row(2, (5, 6)).near(np.array([0, 3, 3]), np.array([2, 2, 4])).tolist()
        [True, True, False]
        """
        ux, uy = self.direction
        dx = np.asarray(x, dtype=np.float64) - self.x0
        dy = np.asarray(y, dtype=np.float64) - self.y0
        half = self.width / 2.0 + margin_px
        across = uy * dx - ux * dy
        along = ux * dx + uy * dy
        return ((across >= -half) & (across < half) & (along >= -0.5 - margin_px)
                & (along < self.n_samples - 0.5 + margin_px))


@dataclass(frozen=True)
class Kymogram:
    """A space-time plot: ``data[k, i]`` is the signal at time ``t_s[k]``, position ``s_px[i]``.

    Attributes
    ----------
    data : ndarray (T, S) float32
        Events per px per time bin (event kymograms) or the sampled image values.
    t_s : ndarray (T,) float64
        Bin centres (events) or image times, in seconds.
    s_px : ndarray (S,) float64
        Position along the line in px from its start.
    line : KymoLine
    rate_hz : float
        Time samples per second.
    source : str
        What was sampled ("events", "q", "frames", ...).
    meta : dict
    """

    data: np.ndarray
    t_s: np.ndarray
    s_px: np.ndarray
    line: KymoLine
    rate_hz: float
    source: str
    meta: dict = field(default_factory=dict)


@njit(cache=True)
def _bin_on_line(x, y, t, p, x0, y0, ux, uy, half_w, n_s, t0, bins_per_us, n_t, signed, out):
    # one pass over the events: project on the line, keep those within the width, vote
    for k in range(t.size):
        dx = x[k] - x0
        dy = y[k] - y0
        n = uy * dx - ux * dy
        if n < -half_w or n >= half_w:
            continue
        i = int(np.floor(ux * dx + uy * dy + 0.5))
        if i < 0 or i >= n_s:
            continue
        j = int(np.floor((t[k] - t0) * bins_per_us))
        if j < 0 or j >= n_t:
            continue
        if signed:
            out[j, i] += 1.0 if p[k] else -1.0
        else:
            out[j, i] += 1.0


#: Most cells (time bins x samples along the line) of an event kymogram: 80 MB as float64,
#: and the fits hold a few copies (1e6 Hz over 0.2 s had taken 20 s and 3.7 GB, probe BA);
#: 10 s at 1200 Hz along a 720 px line is 8.6e6.
MAX_KYMOGRAM_CELLS = 10_000_000


def kymogram_from_events(events: EventArray, line: KymoLine, rate_hz: float = 1200.0, *,
                         t0_us: int | None = None, t1_us: int | None = None,
                         signed: bool = False) -> Kymogram:
    """Kymogram of event histograms: events near ``line`` binned at ``rate_hz``.

    An event at ``(x, y)`` counts at position ``s = round((x, y) - start) . u`` (``u`` the
    line's direction) when its distance across the line ``n`` satisfies
    ``-width/2 <= n < width/2``; counts are divided by ``width`` (events per px per bin).

    Parameters
    ----------
    events : EventArray
    line : KymoLine
        Must lie inside the sensor.
    rate_hz : float
        Time bins per second (e.g. 1200 for 10x a 120 fps camera).
    t0_us, t1_us : int, optional
        Time span (default: first event to last event + 1 µs); only whole bins are kept.
    signed : bool
        Sum polarities (+1/-1) instead of counting.

    Returns
    -------
    Kymogram

    Examples
    --------
    >>> ev = EventArray(x=[2, 2, 3], y=[0, 0, 1], t=[0, 100, 900], p=[1, 1, 0],
    ...                 sensor_size=(2, 5))
    >>> k = kymogram_from_events(ev, KymoLine.row(0, (2, 5)), 1000.0, t0_us=0, t1_us=2000)
    >>> k.data.tolist()
    [[0.0, 0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]]
    >>> k.t_s.tolist()
    [0.0005, 0.0015]
    """
    events = require_events(events, "kymogram_from_events")
    check_switches(signed=signed)
    rate = check_number("rate_hz", rate_hz, 0.0, lo_open=True, units="Hz")
    line.check_inside(events.sensor_size)
    if t0_us is None or t1_us is None:
        if not len(events):
            raise EmptyWindowError("no events to make a kymogram from")
    # (NaN failed in int(), probe API)
    t0 = int(events.t[0]) if t0_us is None else whole_time_us("t0_us", t0_us)
    t1 = int(events.t[-1]) + 1 if t1_us is None else whole_time_us("t1_us", t1_us)
    n_t = _time_bins(t0, t1, rate, line)
    if n_t < 1:
        raise EmptyWindowError(f"time span [{t0}, {t1}) us is shorter than one bin at "
                               f"rate_hz={rate:g} ({1e6 / rate:.6g} us)")
    ev = events.slice_time(t0, t1)
    ux, uy = line.direction
    out = np.zeros((n_t, line.n_samples), dtype=np.float64)
    _bin_on_line(np.ascontiguousarray(ev.x, dtype=np.float64),
                 np.ascontiguousarray(ev.y, dtype=np.float64), ev.t, ev.p, line.x0, line.y0,
                 ux, uy, line.width / 2.0, line.n_samples, t0, rate * 1e-6, n_t, signed, out)
    out /= line.width
    t_s = (t0 + (np.arange(n_t) + 0.5) * 1e6 / rate) * 1e-6
    return Kymogram(data=out.astype(np.float32), t_s=t_s, s_px=np.arange(line.n_samples, dtype=float),
                    line=line, rate_hz=rate, source="events signed" if signed else "events",
                    meta={"t0_us": t0, "t1_us": t1, "n_events": len(ev)})


def _time_bins(t0: int, t1: int, rate: float, line: KymoLine) -> int:
    """The time bins of an event kymogram over ``[t0, t1)`` µs at ``rate`` Hz, refused past
    :data:`MAX_KYMOGRAM_CELLS` cells along ``line``."""
    n_t = int(np.floor((t1 - t0) * rate * 1e-6 + 1e-9))
    if n_t * line.n_samples > MAX_KYMOGRAM_CELLS:
        most = MAX_KYMOGRAM_CELLS / line.n_samples / ((t1 - t0) * 1e-6)
        raise ParameterError(f"rate_hz={rate:g} over {(t1 - t0) * 1e-6:.6g} s makes {n_t:,} "
                             f"time bins of {line.n_samples} px, over {MAX_KYMOGRAM_CELLS:,} "
                             f"cells: at most {most:.4g} Hz over this span, or a shorter one")
    return n_t


class LineEvents(NamedTuple):
    """What :func:`events_near_line` gathers from a stream."""

    #: the events near the line, in time order
    events: EventArray
    #: the first and last event's time of the whole stream, µs
    t_first_us: int
    t_last_us: int
    #: how many events the stream held
    n_read: int


def events_near_line(chunks: Iterable[EventArray], line: KymoLine, *,
                     rate_hz: float | None = None, t1_us: int | None = None) -> LineEvents:
    """The events of a stream of chunks (:func:`evmotion.io.iter_events`) that an event
    kymogram along ``line`` counts, gathered in memory that grows with those events alone,
    and the span of all: a kymogram of a long recording need not hold it whole (a 97.5 M
    event file had taken 2.9 GB, probe DL).

    ``rate_hz`` refuses the stream, as soon as its span gets there, where a kymogram at that
    rate from its first event to the last (or ``t1_us``) would pass
    :data:`MAX_KYMOGRAM_CELLS` cells (as :func:`kymogram_from_events` does, after reading
    all of it).

    Examples
    --------
    >>> ev = EventArray(x=[2, 2, 3, 0], y=[0, 0, 1, 3], t=[0, 100, 900, 950], p=[1, 1, 0, 1],
    ...                 sensor_size=(4, 5))
    >>> got = events_near_line([ev[:2], ev[2:]], KymoLine.row(0, (4, 5)))
    >>> len(got.events), got.t_first_us, got.t_last_us, got.n_read  # (0, 3) is far off
    (3, 0, 950, 4)
    """
    parts, n_read, t_first, t_last = [], 0, None, None
    first = None
    for chunk in chunks:
        if not len(chunk):
            continue
        if first is None:
            first = chunk
            line.check_inside(chunk.sensor_size)
            t_first = int(chunk.t[0])
        n_read += len(chunk)
        t_last = int(chunk.t[-1])
        if rate_hz is not None:
            end = t_last + 1 if t1_us is None else min(t_last + 1, int(t1_us))
            _time_bins(t_first, end, float(rate_hz), line)
        parts.append(chunk[line.near(chunk.x, chunk.y)])
    if first is None:
        raise EmptyWindowError("no events to make a kymogram from")
    return LineEvents(concatenate(parts), t_first, t_last, n_read)


#: Median step between images beyond which times in seconds (``t_s``) are taken for µs, and
#: below which times in µs (``t_us``) are taken for seconds: a kymogram's images lie at
#: least a millisecond and at most a minute apart in any schlieren or flow recording.
MAX_IMAGE_STEP_S = 60.0
MIN_FRAME_STEP_US = 1.0


def _check_time_unit(t: np.ndarray, name: str) -> None:
    """Refuse image times given in the other unit (seconds for µs, µs for seconds): the
    kymogram was drawn with no word at 0.00012 Hz, or its rows 4 ns apart (probe CB)."""
    if t.size < 2:
        return
    step = float(np.median(np.diff(t)))
    if name == "t_s" and step > MAX_IMAGE_STEP_S:
        raise ParameterError(f"t_s: the images lie {step:g} s apart (median): microseconds? "
                             "t_s is in seconds (FrameSequence.t * 1e-6)")
    if name == "t_us" and step < MIN_FRAME_STEP_US:
        raise ParameterError(f"t_us: the frames lie {step:g} us apart (median): seconds? "
                             "t_us is in microseconds (FrameSequence.t as read)")


def kymogram_from_images(images: np.ndarray, t_s, line: KymoLine, *,
                         source: str = "images") -> Kymogram:
    """Kymogram sampled from an image sequence (frames, q, a flow component ...).

    Each image is sampled along ``line`` every px by bilinear interpolation and averaged over
    ``width`` parallel lines 1 px apart. NaN pixels (no measurement: a flow no event
    supports, a field outside its ROI) carry no weight: a sample is the mean of the finite
    pixels around it, and NaN where there is none.

    Parameters
    ----------
    images : ndarray (T, H, W)
    t_s : array_like (T,)
        Time of each image in seconds (increasing).
    line : KymoLine
    source : str
        Label stored in the result (e.g. "q", "frames").

    Returns
    -------
    Kymogram
        Its ``rate_hz`` is the mean image rate.

    Examples
    --------
    >>> imgs = np.arange(2 * 3 * 4, dtype=float).reshape(2, 3, 4)
    >>> kymogram_from_images(imgs, [0.0, 0.1], KymoLine.column(1, (3, 4))).data.tolist()
    [[1.0, 5.0, 9.0], [13.0, 17.0, 21.0]]
    >>> imgs[0, 1, :] = np.nan                            # a row with no measurement
    >>> line = KymoLine.column(1, (3, 4), width=3)
    >>> kymogram_from_images(imgs, [0.0, 0.1], line).data[0].tolist()
    [1.0, nan, 9.0]
    """
    imgs = np.asarray(images)
    if imgs.ndim != 3 or imgs.shape[0] < 1:
        raise ParameterError(f"images must be an array (T, H, W), got shape {imgs.shape}")
    t = check_finite("t_s", t_s).ravel()
    if t.size != imgs.shape[0]:
        raise ParameterError(f"{t.size} times for {imgs.shape[0]} images")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        raise ParameterError("image times t_s must be increasing")
    _check_time_unit(t, "t_s")
    line.check_inside(imgs.shape[1:])
    ux, uy = line.direction
    s = np.arange(line.n_samples, dtype=float)
    offsets = np.arange(line.width, dtype=float) - (line.width - 1) / 2
    xs = line.x0 + ux * s[None, :] - uy * offsets[:, None]
    ys = line.y0 + uy * s[None, :] + ux * offsets[:, None]
    h, w = imgs.shape[1:]
    xs = np.clip(xs, 0, w - 1)
    ys = np.clip(ys, 0, h - 1)
    data = np.empty((t.size, s.size), dtype=np.float32)
    coords = [ys.ravel(), xs.ravel()]
    for k in range(t.size):
        img = np.asarray(imgs[k], dtype=np.float64)
        finite = np.isfinite(img)
        # normalized interpolation: a NaN pixel taken as 0 had drawn unmeasured flow as
        # still air and pulled a width's mean down (probe BX)
        vals = ndimage.map_coordinates(np.where(finite, img, 0.0), coords, order=1,
                                       mode="nearest").reshape(xs.shape).sum(axis=0)
        if finite.all():
            data[k] = _float32_row(vals / line.width, k)
            continue
        weight = ndimage.map_coordinates(finite.astype(np.float64), coords, order=1,
                                         mode="nearest").reshape(xs.shape).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            data[k] = _float32_row(np.where(weight > 1e-9, vals / weight, np.nan), k)
    rate = float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 else float("nan")
    return Kymogram(data=data, t_s=t, s_px=s, line=line, rate_hz=rate, source=source)


def _float32_row(row: np.ndarray, k: int) -> np.ndarray:
    """A kymogram row as the float32 it is stored in, refused where its values lie past
    float32's range (they were cast to inf with numpy's overflow warning, probe EVAL)."""
    big = float(np.nanmax(np.abs(row), initial=0.0))
    if big > float(np.finfo(np.float32).max):
        raise ParameterError(f"image {k} holds values of {big:.3g} along the line, past "
                             "what a kymogram stores (float32, 3.4e38): rescale the images")
    return row.astype(np.float32)


def kymogram_from_frame_differences(frames: np.ndarray, t_us, line: KymoLine) -> Kymogram:
    """Frame-rate kymogram: ``|F[k+1] - F[k]|`` along ``line`` at the mid-frame times.

    A background seen through still air does not change; where the schlieren moves it
    displaces the background, so the frame difference is the frame camera's counterpart of
    an event histogram (at the frame rate, thesis Fig. 6.11a).

    Parameters
    ----------
    frames : ndarray (N, H, W)
        At least two frames (uint8, uint16 or float in [0, 1]; on the 8-bit scale after
        :func:`evmotion.methods.farneback.frame_to_float`).
    t_us : array_like (N,)
        Frame timestamps in µs (increasing).
    line : KymoLine

    Examples
    --------
    >>> f = np.zeros((3, 4, 5), np.uint8); f[1, 2, 3] = 10
    >>> k = kymogram_from_frame_differences(f, [0, 1000, 2000], KymoLine.row(2, (4, 5)))
    >>> k.data.tolist(), k.t_s.tolist()
    ([[0.0, 0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 10.0, 0.0]], [0.0005, 0.0015])
    """
    from evmotion.methods.farneback import frame_to_float

    fr = np.asarray(frames)
    if fr.ndim != 3 or fr.shape[0] < 2:
        raise ParameterError(f"frames must be an array (N >= 2, H, W), got shape {fr.shape}")
    t = check_finite("t_us", t_us).ravel()
    if t.size != fr.shape[0]:
        raise ParameterError(f"{t.size} timestamps for {fr.shape[0]} frames")
    if np.any(np.diff(t) <= 0):
        raise ParameterError("frame timestamps t_us must be increasing")
    _check_time_unit(t, "t_us")
    prev = frame_to_float(fr[0], "frame 0")
    diffs = np.empty((fr.shape[0] - 1, *prev.shape), np.float32)
    for k in range(1, fr.shape[0]):
        cur = frame_to_float(fr[k], f"frame {k}")
        diffs[k - 1] = np.abs(cur - prev)
        prev = cur
    return kymogram_from_images(diffs, 0.5 * (t[1:] + t[:-1]) * 1e-6, line,
                                source="frame differences")


@dataclass(frozen=True)
class RidgeFit:
    """A line ``s = s0 + velocity * (t - t_ref)`` fitted to a kymogram's ridge.

    Attributes
    ----------
    velocity_px_s : float
        Slope, px/s along the line (start -> end); negative: towards the start.
    velocity_std_px_s : float
        Standard error of the slope (least squares over the inliers).
    s0_px : float
        Ridge position at ``t_ref_s``.
    t_ref_s : float
        Mean time of the inliers.
    t_s, s_px : ndarray
        The ridge points (one per time bin with a ridge).
    inliers : ndarray of bool
        Points within the robust residual bound.
    residual_px : float
        RMS residual of the inliers in px.
    method : str
        "ridge" (:func:`fit_ridge`) or "correlation" (:func:`fit_correlation`, whose points
        are the lags and shifts of the autocorrelation, not kymogram positions).
    origin_offset_px : float
        Correlation fits: the shift at lag 0 of the line fitted to the autocorrelation's
        ridge, px. A ridge of structures moving at one speed passes through the origin;
        0 for ridge fits.
    speed_change_px_s, speed_change_std_px_s : float
        Ridge fits: how much the speed changes over the inliers' time span (last minus
        first, px/s; from a parabola through the inliers) and its standard error; 0 for
        correlation fits.
    """

    velocity_px_s: float
    velocity_std_px_s: float
    s0_px: float
    t_ref_s: float
    t_s: np.ndarray
    s_px: np.ndarray
    inliers: np.ndarray
    residual_px: float
    method: str = "ridge"
    origin_offset_px: float = 0.0
    speed_change_px_s: float = 0.0
    speed_change_std_px_s: float = 0.0

    @property
    def reliable(self) -> bool:
        """Whether the speed is a measurement (:attr:`unreliable_because` is None)."""
        return self.unreliable_because is None

    @property
    def unreliable_because(self) -> str | None:
        """Why the speed is no measurement, or None: its standard error exceeds a quarter
        of it (a fit to a nearly empty kymogram can give 3271 +- 16000 px/s; a correlation
        fit over puffs 34 px apart 699 +- 331 px/s for 500), or, for a ridge
        fit, the ridge points lie off the line: RMS residual over :data:`RELIABLE_RESIDUAL`
        of the line's travel over the fit (and 3 px at least); a ridge jumping between
        parallel streaks gave 75 +- 15 px/s for 120 with residuals of 79 px; or its
        speed changes over the fit by more than :data:`RELIABLE_CHANGE` of it, beyond
        three standard errors (a feature slowing from 600 to 60 px/s was fitted 426 +- 9
        px/s with residuals of 7 px, within the bound; probe BU). For a
        correlation fit, the line misses the origin by more than :data:`RELIABLE_ORIGIN` of
        the travel at the longest fitted lag (and 1 px at least): its points follow the edge
        of the stationary band, not a moving peak (62 +- 7 px/s for 200, 3.8 px off the
        origin, on a sparse row whose structures moved less than the band over the lags)."""
        if not self.velocity_std_px_s <= RELIABLE_SPREAD * abs(self.velocity_px_s):
            return "the spread exceeds a quarter of the speed"
        if not len(self.t_s):
            return None
        inl = np.asarray(self.inliers, bool)
        if self.method == "correlation":
            longest = float(np.max(np.asarray(self.t_s)[inl])) if np.any(inl) else 0.0
            bound = max(MIN_ORIGIN_BOUND_PX, RELIABLE_ORIGIN * abs(self.velocity_px_s) * longest)
            if abs(self.origin_offset_px) <= bound:
                return None
            return (f"the autocorrelation's ridge misses the origin by "
                    f"{self.origin_offset_px:.3g} px (> {bound:.3g}): the structures hardly "
                    "move beyond stationary_px over the lags (try a longer max_lag_s or "
                    "a lower stationary_px)")
        if self.method != "ridge":
            return None
        span = float(np.ptp(np.asarray(self.t_s)[inl])) if np.any(inl) else 0.0
        bound = max(MIN_RESIDUAL_BOUND_PX, RELIABLE_RESIDUAL * abs(self.velocity_px_s) * span)
        if self.residual_px > bound:
            return (f"the ridge points lie {self.residual_px:.3g} px (RMS) off the line "
                    "(several streaks? the correlation fit takes their common slope)")
        dv = self.speed_change_px_s
        if abs(dv) > max(RELIABLE_CHANGE * abs(self.velocity_px_s),
                         3.0 * self.speed_change_std_px_s):
            v0 = self.velocity_px_s - dv / 2
            return (f"the speed changes over the fit, from about {v0:.3g} to {v0 + dv:.3g} "
                    "px/s: no one speed (fit a shorter t_range)")
        return None

    @property
    def speed_px_s(self) -> float:
        return abs(self.velocity_px_s)

    def s_at(self, t_s) -> np.ndarray:
        """Position of the fitted line at times ``t_s`` (px)."""
        return self.s0_px + self.velocity_px_s * (np.asarray(t_s, dtype=float) - self.t_ref_s)


RIDGE_POLARITIES = ("abs", "positive", "negative")
#: Widest smoothing, shift or line a kymogram takes, px or bins (1e30 reached scipy's
#: "Maximum allowed size exceeded", probe API).
MAX_SMOOTH_PX = 10_000.0


def _check_widths(**widths) -> None:
    """ParameterError naming the first of ``widths`` (px or bins) that is not a finite
    number in ``[0, MAX_SMOOTH_PX]``."""
    for name, v in widths.items():
        if not (is_finite_number(v) and 0 <= v <= MAX_SMOOTH_PX):
            raise ParameterError(f"parameter '{name}' must be finite and in "
                                 f"[0, {MAX_SMOOTH_PX:g}], got {v!r}")


def _ridge_signal(kymo: Kymogram, polarity: str, sigma_px: float, sigma_bins: float,
                  ) -> np.ndarray:
    if polarity not in RIDGE_POLARITIES:
        raise ParameterError(f"polarity must be one of {RIDGE_POLARITIES}, got {polarity!r}")
    _check_widths(sigma_px=sigma_px, sigma_bins=sigma_bins)
    # a NaN cell (a field with no measurement there) carries no signal: 0
    d = np.nan_to_num(np.asarray(kymo.data, dtype=np.float64), nan=0.0)
    d = {"abs": np.abs(d), "positive": d, "negative": -d}[polarity]
    if sigma_px > 0 or sigma_bins > 0:
        d = ndimage.gaussian_filter(d, (sigma_bins, sigma_px), mode="nearest")
    return d


def ridge_points(kymo: Kymogram, *, sigma_px: float = 2.0, sigma_bins: float = 1.0,
                 polarity: str = "abs", s_range: tuple[float, float] | None = None,
                 t_range: tuple[float, float] | None = None, min_snr: float = 3.0,
                 noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ridge of a kymogram: per time bin, the sub-pixel peak of the smoothed profile.

    The kymogram is Gaussian-smoothed (``sigma_px`` along the line, ``sigma_bins`` in time),
    each time bin's peak within ``s_range`` is refined by a parabola through the logarithms
    of its neighbours,
    and bins whose peak does not stand ``min_snr`` robust standard deviations (1.4826 MAD of
    the smoothed values in the search region) above their median, or lies within two
    smoothing sigmas (at least 1 px) of the region's or kymogram's border, are dropped.

    Returns
    -------
    t_s, s_px : ndarray
        Times (s) and ridge positions (px along the line) of the bins kept.
    """
    d = _ridge_signal(kymo, polarity, sigma_px, sigma_bins)
    s = kymo.s_px
    t = kymo.t_s
    tmask, smask = _region_masks(kymo, s_range, t_range)
    if smask.sum() < 3 or not tmask.any():
        raise ParameterError(f"the search region ({_region(s_range, t_range)}) holds fewer "
                             "than 3 positions or no time bin of the kymogram")
    cols = np.flatnonzero(smask)
    sub = d[np.ix_(tmask, cols)]
    k = np.argmax(sub, axis=1)
    peak = sub[np.arange(sub.shape[0]), k]
    if noise is None:
        med = np.median(sub)
        noise = 1.4826 * np.median(np.abs(sub - med))
        if noise <= 0:
            noise = sub.std()
    else:
        noise = np.asarray(noise, np.float64)
        if noise.shape != d.shape or not np.all(np.isfinite(noise)) or noise.min() < 0:
            raise ParameterError(f"noise must be finite standard errors >= 0 of the "
                                 f"kymogram's shape {d.shape}, got shape {noise.shape}")
        med = np.median(sub, axis=1)
        noise = noise[np.ix_(tmask, cols)][np.arange(sub.shape[0]), k]
    # a peak within 2 sigma of the region's border (in position or time) is pulled by the
    # smoothing's padding or belongs to a structure outside the region: no ridge there
    ms = max(1, int(np.ceil(2 * sigma_px)))
    mt = int(np.ceil(2 * sigma_bins))
    tidx = np.flatnonzero(tmask)
    keep = ((peak - med > min_snr * noise) & (peak > med) & (k >= ms) & (k < cols.size - ms)
            & (cols[k] >= ms) & (cols[k] < s.size - ms)
            & (tidx >= mt) & (tidx < t.size - mt))
    # sub-pixel refinement where both neighbours are inside the search region: a parabola
    # through the logarithms (exact for the Gaussian peaks the smoothing makes; a parabola
    # through the values is biased towards the nearest pixel) where all three are positive
    km = np.clip(k - 1, 0, cols.size - 1)
    kp = np.clip(k + 1, 0, cols.size - 1)
    rows = np.arange(sub.shape[0])
    a, b, c = sub[rows, km], peak, sub[rows, kp]
    pos3 = (a > 0) & (b > 0) & (c > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b, c = (np.where(pos3, np.log(np.where(pos3, v, 1.0)), v) for v in (a, b, c))
    den = a - 2 * b + c
    inner = den < 0
    delta = np.where(inner, 0.5 * (a - c) / np.where(inner, den, -1.0), 0.0)
    pos = s[cols[k]] + np.clip(delta, -0.5, 0.5) * (s[1] - s[0] if s.size > 1 else 1.0)
    return t[tmask][keep], pos[keep]


def _check_fit_options(min_snr: float, inlier_px: float | None = None) -> None:
    """Refuse a ``min_snr`` or ``inlier_px`` no fit can use (NaN had ended in "a ridge in
    only 0 time bins", probe BU)."""
    if not (is_finite_number(min_snr) and min_snr >= 0):
        raise ParameterError(f"parameter 'min_snr' must be finite and >= 0, got {min_snr!r}")
    if inlier_px is not None and not (is_finite_number(inlier_px) and inlier_px > 0):
        raise ParameterError(f"parameter 'inlier_px' must be finite and > 0, got "
                             f"{inlier_px!r}")


def _theil_sen(t: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    i, j = np.triu_indices(t.size, 1)
    dt = t[j] - t[i]
    ok = dt != 0
    slope = float(np.median((s[j] - s[i])[ok] / dt[ok]))
    return slope, float(np.median(s - slope * t))


def _region(s_range, t_range) -> str:
    """A fit's search region in words (None: the whole line / the whole kymogram)."""
    s = "the whole line" if s_range is None else \
        f"s_range={s_range[0]:g}..{s_range[1]:g} px"
    t = "all times" if t_range is None else f"t_range={t_range[0]:g}..{t_range[1]:g} s"
    return f"{s}, {t}"


def _region_masks(kymo: Kymogram, s_range, t_range) -> tuple[np.ndarray, np.ndarray]:
    """The time bins and positions of a fit's region (None: all of them)."""
    s, t = kymo.s_px, kymo.t_s
    smask = np.ones(s.size, bool) if s_range is None else (s >= s_range[0]) & (s <= s_range[1])
    tmask = np.ones(t.size, bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
    return tmask, smask


def _check_signal(region: np.ndarray, kymo: Kymogram, s_range, t_range) -> None:
    """An empty region (``region``: its cells, NaN where nothing was measured) has
    nothing to fit: said as such (a row with no event had been told of "a ridge at fewer
    than 3 lags ... periodic structures alias", probe BX)."""
    if not np.any(np.nan_to_num(region, nan=0.0)):
        unmeasured = np.isnan(region).all()
        why = ("nothing was measured along the line there" if unmeasured
               else "nothing crosses the line there")
        raise EmptyWindowError(f"the kymogram ({kymo.source}) holds "
                               f"{'no measurement' if unmeasured else 'only zeros'} in the "
                               f"region ({_region(s_range, t_range)}): {why}; choose another "
                               "line, a wider one, or another region")


def fit_ridge(kymo: Kymogram, *, sigma_px: float = 2.0, sigma_bins: float = 1.0,
              polarity: str = "abs", s_range: tuple[float, float] | None = None,
              t_range: tuple[float, float] | None = None, min_snr: float = 3.0,
              inlier_px: float | None = None, max_points: int = 4000,
              noise: np.ndarray | None = None) -> RidgeFit:
    """Velocimetry: a robust line fit to the kymogram's ridge (thesis §6.6.5).

    The ridge points of :func:`ridge_points` are fitted by Theil–Sen (the median of the
    pairwise slopes: insensitive to up to ~29 % outliers); points within ``inlier_px`` of that
    line (default ``max(3 * 1.4826 * MAD of the residuals, 1 px)``) are then fitted by least
    squares, whose slope and standard error are returned (the error accounts for the
    correlation of neighbouring bins that ``sigma_bins`` introduces).

    Parameters
    ----------
    kymo : Kymogram
    sigma_px, sigma_bins, polarity, s_range, t_range, min_snr, noise
        See :func:`ridge_points`.
    inlier_px : float, optional
        Residual bound of the inliers in px.
    max_points : int
        Theil–Sen on at most this many evenly spaced points (its cost is quadratic).

    Returns
    -------
    RidgeFit

    Examples
    --------
    >>> t = np.arange(200) / 1200.0                       # 1200 Hz
    >>> s = np.arange(100.0)
    >>> data = np.exp(-0.5 * ((s[None, :] - 90 + 800.0 * t[:, None]) / 2.0) ** 2)
    >>> k = Kymogram(data, t, s, KymoLine.column(0, (100, 1)), 1200.0, "test")
    >>> round(fit_ridge(k, sigma_bins=0).velocity_px_s, 1)
    -800.0
    """
    _check_fit_options(min_snr, inlier_px)
    _check_widths(sigma_px=sigma_px, sigma_bins=sigma_bins)
    n_t = np.asarray(kymo.t_s).size
    margin = int(np.ceil(2 * sigma_bins))
    if n_t - 2 * margin < 3:
        # the bins within two sigma_bins of either end are dropped: no ridge whatever the
        # SNR (3 bins and sigma_bins=1 had said "lower min_snr=0", probe BU)
        raise EmptyWindowError(f"the kymogram has {n_t} time bins; a ridge fit needs "
                               f"{3 + 2 * margin} or more ({margin} at each end lie within "
                               f"two sigma_bins={sigma_bins:g} of its edge): a longer time "
                               "range, a higher rate, or a smaller sigma_bins")
    tmask, smask = _region_masks(kymo, s_range, t_range)
    _check_signal(np.asarray(kymo.data)[np.ix_(tmask, smask)], kymo, s_range, t_range)
    t, s = ridge_points(kymo, sigma_px=sigma_px, sigma_bins=sigma_bins, polarity=polarity,
                        s_range=s_range, t_range=t_range, min_snr=min_snr, noise=noise)
    if t.size < 3:
        raise EmptyWindowError(f"the kymogram has a ridge in only {t.size} time bins "
                               f"(need >= 3; lower min_snr={min_snr} or choose the region)")
    step = max(1, -(-t.size // whole_number("max_points", max_points, lo=3)))
    slope, icpt = _theil_sen(t[::step], s[::step])
    res = s - (icpt + slope * t)
    if inlier_px is None:
        mad = np.median(np.abs(res - np.median(res)))
        inlier_px = max(3.0 * 1.4826 * mad, 1.0)
    inl = np.abs(res) <= inlier_px
    if inl.sum() < 3:
        raise EmptyWindowError(f"only {int(inl.sum())} ridge points within {inlier_px:g} px "
                               "of the robust line")
    ti, si = t[inl], s[inl]
    t_ref = float(ti.mean())
    tc = ti - t_ref
    sxx = float(np.sum(tc * tc))
    if sxx <= 0:
        raise EmptyWindowError("the ridge inliers all lie in one time bin")
    v = float(np.sum(tc * (si - si.mean())) / sxx)
    s0 = float(si.mean())
    r = si - (s0 + v * tc)
    dof = max(ti.size - 2, 1)
    sigma = float(np.sqrt(np.sum(r * r) / dof))
    # smoothing in time correlates neighbouring ridge points: a Gaussian of sigma_bins
    # leaves about one independent point per 2 sqrt(pi) sigma_bins bins
    corr = max(1.0, 2.0 * np.sqrt(np.pi) * sigma_bins)
    change, change_std = _speed_change(tc, si, corr)
    return RidgeFit(velocity_px_s=v, velocity_std_px_s=sigma * np.sqrt(corr / sxx), s0_px=s0,
                    t_ref_s=t_ref, t_s=t, s_px=s, inliers=inl,
                    residual_px=float(np.sqrt(np.mean(r * r))), speed_change_px_s=change,
                    speed_change_std_px_s=change_std)


def _speed_change(tc: np.ndarray, s: np.ndarray, corr: float) -> tuple[float, float]:
    """The change of speed over the span of ``tc`` (times about their mean) of a parabola
    fitted to positions ``s``, and its standard error (``corr`` points per independent one);
    ``(0, inf)`` with too few points for a parabola."""
    if tc.size < 5:
        return 0.0, float("inf")
    a = np.stack([np.ones_like(tc), tc, tc * tc], axis=1)
    coef, _, rank, _ = np.linalg.lstsq(a, s, rcond=None)
    if rank < 3:
        return 0.0, float("inf")
    r = s - a @ coef
    var = float(np.sum(r * r)) / (tc.size - 3) * corr
    c_std = float(np.sqrt(var * np.linalg.inv(a.T @ a)[2, 2]))
    span = float(np.ptp(tc))
    return float(2.0 * coef[2] * span), 2.0 * c_std * span


def px_per_s_to_m_per_s(v_px_s, focal_mm: float, distance_m: float, pixel_um: float):
    """Image speed to object-plane speed (pinhole): ``v = v_px * pitch * Z / f``.

    Parameters
    ----------
    v_px_s : float or ndarray
        Speed on the sensor in px/s.
    focal_mm : float
        Focal length f in mm.
    distance_m : float
        Distance Z from the camera to the flow being measured, in m.
    pixel_um : float
        Pixel pitch in µm.

    Returns
    -------
    float or ndarray
        Speed in m/s at distance Z.

    Examples
    --------
    The thesis' hot plate (§6.6.5): 166 px in 68.8 ms, f = 25 mm, Z = 1.7 m, 4.86 µm pixels
    (the thesis prints 0.805 m/s; the rounded 166 px and 68.8 ms give 0.797, 1 % less):

    >>> round(px_per_s_to_m_per_s(166 / 68.8e-3, 25.0, 1.7, 4.86), 3)
    0.797
    """
    focal_mm, distance_m, pixel_um = (check_number(name, val, 0.0, lo_open=True, units=unit)
                                      for name, val, unit in (("focal_mm", focal_mm, "mm"),
                                                              ("distance_m", distance_m, "m"),
                                                              ("pixel_um", pixel_um, "µm")))
    v = check_finite("v_px_s", v_px_s)
    out = v * (pixel_um * 1e-6) * distance_m / (focal_mm * 1e-3)
    return float(out) if out.ndim == 0 else out


#: Largest standard error of a reliable fit's speed, as a fraction of it (RidgeFit.reliable):
#: good fits have 1-2 % (bos_kymogram.md); one of 699 +- 331 px/s was 40 % off the truth
RELIABLE_SPREAD = 0.25
#: Largest RMS residual of a reliable ridge fit, as a fraction of the line's travel over
#: the fitted time span, and the bound's least value in px (RidgeFit.reliable).
RELIABLE_RESIDUAL = 0.1
MIN_RESIDUAL_BOUND_PX = 3.0
#: Largest change of a reliable ridge fit's speed over its time span, as a fraction of the
#: speed (RidgeFit.reliable).
RELIABLE_CHANGE = 0.25
#: Largest shift at lag 0 of a reliable correlation fit's line, as a fraction of its travel
#: at the longest fitted lag, and the bound's least value in px (RidgeFit.reliable): good
#: fits on simulated translations pass within 0.03 px of the origin
RELIABLE_ORIGIN = 0.1
MIN_ORIGIN_BOUND_PX = 1.0
#: Longest max_lag_s fit_correlation takes, as a fraction of the kymogram's time span.
MAX_LAG_SHARE = 0.75


def _lag_spectra(d: np.ndarray, n_lags: int, edges: np.ndarray) -> np.ndarray:
    # per time block b and lag: sum over t in b of conj(F[t]) F[t + lag], F the zero-padded
    # spectra of the rows (no wrap-around); the inverse FFT of a sum is the autocorrelation
    # sum_t,s d[t, s] d[t + lag, s + shift] over those t. Along time each block's sum is a
    # cross-correlation, taken by FFT over the block and the n_lags rows after it: a loop
    # over the lags cost n_lags x n_t rows (14.6 s for 2831 bins x 346 px)
    from scipy import fft as sfft

    n_t, n_s = d.shape
    f = np.fft.rfft(d, n=2 * n_s, axis=1)
    out = np.zeros((edges.size - 1, n_lags, f.shape[1]), dtype=complex)
    for b, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        if hi <= lo:
            continue
        n = sfft.next_fast_len(int(hi - lo) + n_lags - 1)
        head = sfft.fft(f[lo:hi], n=n, axis=0)
        tail = sfft.fft(f[lo:min(hi + n_lags - 1, n_t)], n=n, axis=0)
        out[b] = sfft.ifft(np.conj(head) * tail, axis=0)[:n_lags]
    return out


def _correlation_image(spec: np.ndarray, n_s: int) -> np.ndarray:
    a = np.fft.irfft(spec, n=2 * n_s, axis=-1)
    # columns: shift from -(S - 1) to S - 1
    return np.concatenate([a[:, n_s + 1:], a[:, :n_s]], axis=1)


def _without_stationary_peak(a: np.ndarray, band: int) -> np.ndarray:
    # columns of `a` are shifts -(S-1)..S-1: the band |shift| <= `band` takes the running
    # median over 2 band + 3 shifts, wider than the stationary peak it removes
    if band <= 0:
        return a
    c = (a.shape[1] - 1) // 2
    lo, hi = max(c - band, 0), min(c + band + 1, a.shape[1])
    med = ndimage.median_filter(a[:, max(lo - band - 1, 0):hi + band + 1],
                                size=(1, 2 * band + 3), mode="nearest")
    out = a.copy()
    off = lo - max(lo - band - 1, 0)
    out[:, lo:hi] = med[:, off:off + hi - lo]
    return out


def fit_correlation(kymo: Kymogram, *, sigma_px: float = 1.0, max_lag_s: float | None = None,
                    s_range: tuple[float, float] | None = None,
                    t_range: tuple[float, float] | None = None, n_blocks: int = 8,
                    min_shift_px: float = 3.0, min_snr: float = 3.0,
                    stationary_px: float | None = None) -> RidgeFit:
    """Velocimetry of many structures at once: the slope of the kymogram's autocorrelation.

    Where many structures travel along the line at one speed (the puffs of a plume, the
    eddies of a jet) the kymogram holds parallel streaks, and the ridge of a single time bin
    jumps between them. Their common speed ``v`` is the slope of the ridge of the space-time
    autocorrelation ``A(lag, shift) = sum_t,s d(t, s) d(t + lag, s + shift)``: a structure
    at ``s`` at time ``t`` is at ``s + v lag`` at ``t + lag``. ``d`` is the kymogram with
    its mean over time (the static envelope) and over position (the overall rate) removed,
    smoothed by ``sigma_px`` along the line and not in time, so that the noise of different
    bins stays uncorrelated at lags >= 1. The ridge of ``A`` is fitted as in
    :func:`fit_ridge` over the lags up to ``max_lag_s`` whose shift is at least
    ``min_shift_px`` (at shorter lags the ridge is pulled towards shift 0 by pixels that
    fire over consecutive bins); the slope's standard error is the block jackknife over
    ``n_blocks`` contiguous time blocks. Structures entering and leaving the line's ends
    pull the short-lag peaks slightly towards shift 0 (the correlation of the visible part
    is weighted by the overlap): a bias of a few % where the structures travel less than
    the line's length over the lags (measured: 3 % for 12 streaks over 80 px, 60 bins).

    A pixel keeps firing for as long as a structure passes it, and its own contrast (the
    background's texture) sets how much, so the autocorrelation also holds a narrow peak at
    shift 0 that lasts as long as the structures take to pass. Where they move a few px per
    bin it is gone by the lags that are fitted; where they move slowly (a plume rising at
    360 px/s seen at 1200 Hz) it sits beside the moving peak over the fitted lags and pushes
    its maximum away (speeds 19-27 % too high measured on rendered plumes). Within
    ``stationary_px`` of shift 0 the autocorrelation is therefore replaced by its running
    median across shifts (a window wider than that peak), which keeps the broad moving peak,
    and only lags whose shift exceeds that band are fitted.

    Parameters
    ----------
    kymo : Kymogram
    sigma_px : float
        Smoothing along the line, px (default 1).
    max_lag_s : float, optional
        Longest lag (default a quarter of the kymogram's duration, at least 3 bins; at
        most :data:`MAX_LAG_SHARE` of it).
    s_range, t_range : (float, float), optional
        Part of the kymogram used (px along the line, s).
    n_blocks : int
        Time blocks of the jackknife (>= 2; default 8).
    min_shift_px : float
        Leave out the lags whose shift (by a first fit over all lags) is below this, px.
    min_snr : float
        As :func:`ridge_points`, on the autocorrelation. Where no lag's peak stands that
        high against the MAD of the whole autocorrelation (a travelling wave's is a wave
        too, its MAD its amplitude), each peak is held against its own noise, the
        jackknife over the time blocks, and the fit is kept only if it is reliable.
    stationary_px : float, optional
        Half-width of the band around shift 0 replaced by the running median, px (default
        ``3 * sigma_px + 1``; 0 keeps the autocorrelation as it is).

    Returns
    -------
    RidgeFit
        Its points ``t_s``, ``s_px`` (and ``inliers``, ``residual_px``) are the lags and
        shifts of the autocorrelation's ridge; its line (``s0_px`` at ``t_ref_s``, the
        region's mid time) is placed on the kymogram's strongest streak of that slope.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(400) / 2000.0; s = np.arange(120.0)
    >>> starts = rng.uniform(-400, 120, 60)        # 60 streaks moving at -1500 px/s
    >>> c = starts[None, :] - 1500.0 * t[:, None]
    >>> data = np.exp(-0.5 * ((s[None, :, None] - c[:, None, :]) / 1.5) ** 2).sum(-1)
    >>> data = rng.poisson(2 * data).astype(float)                 # shot noise
    >>> k = Kymogram(data, t, s, KymoLine.column(0, (120, 1)), 2000.0, "events")
    >>> bool(abs(fit_correlation(k).velocity_px_s / -1500 - 1) < 0.02)
    True
    """
    _check_widths(sigma_px=sigma_px)
    if stationary_px is None:
        stationary_px = 3.0 * sigma_px + 1.0
    _check_widths(min_shift_px=min_shift_px, stationary_px=stationary_px)
    if not is_whole_number(n_blocks) or n_blocks < 2:
        raise ParameterError(f"parameter 'n_blocks' must be an integer >= 2, got {n_blocks!r}")
    _check_fit_options(min_snr)
    if max_lag_s is not None and not (is_finite_number(max_lag_s) and max_lag_s > 0):
        raise ParameterError(f"parameter 'max_lag_s' must be > 0, got {max_lag_s!r}")
    t = kymo.t_s
    tmask, smask = _region_masks(kymo, s_range, t_range)
    region = np.asarray(kymo.data, dtype=np.float64)[np.ix_(tmask, smask)]
    d = np.nan_to_num(region, nan=0.0)
    n_t, n_s = d.shape
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if max_lag_s is not None and dt > 0 and max_lag_s > MAX_LAG_SHARE * n_t * dt:
        # the autocorrelation at lags near the whole span rests on the few bins that still
        # overlap, and its spread across blocks then says the speed is far surer than it
        # is (95 % of a 0.1 s span: 203 +- 0.27 px/s for 200, 10 sigma off; 60 %: 1.9)
        raise ParameterError(f"max_lag_s={max_lag_s:g} is over {MAX_LAG_SHARE:g} of the "
                             f"kymogram's time span ({n_t * dt:.3g} s): at most "
                             f"{MAX_LAG_SHARE * n_t * dt:.3g} s")
    if n_s < 5 or n_t < 2 * n_blocks or dt <= 0:
        raise ParameterError(f"the region ({_region(s_range, t_range)}) holds "
                             f"{n_s} positions and {n_t} time bins; the correlation needs "
                             f">= 5 positions and >= {2 * n_blocks} bins ({n_blocks} blocks)")
    _check_signal(region, kymo, s_range, t_range)
    n_lags = max(3, int(round((0.25 * n_t * dt if max_lag_s is None else max_lag_s) / dt)))
    n_lags = min(n_lags, n_t - 1) + 1
    d = d - d.mean(axis=0, keepdims=True)
    d = d - d.mean(axis=1, keepdims=True)
    if sigma_px > 0:
        d = ndimage.gaussian_filter1d(d, sigma_px, axis=1, mode="constant")
    edges = np.linspace(0, n_t, int(n_blocks) + 1).round().astype(int)
    spectra = _lag_spectra(d, n_lags, edges)
    total = spectra.sum(axis=0)
    shifts = np.arange(-(n_s - 1), n_s, dtype=float)
    lags = np.arange(n_lags) * dt

    band = int(np.ceil(stationary_px))

    block_noise = None  # each cell's standard error, where the MAD finds no ridge

    def fit(spec: np.ndarray, first: int) -> RidgeFit:
        a = _without_stationary_peak(_correlation_image(spec[first:], n_s), band)
        ka = Kymogram(a.astype(np.float32), lags[first:], shifts, kymo.line, 1.0 / dt,
                      "autocorrelation")
        return fit_ridge(ka, sigma_px=0.0, sigma_bins=0.0, polarity="positive",
                         min_snr=min_snr,
                         noise=None if block_noise is None else block_noise[first:])

    # fit_ridge's words are about a kymogram's time bins; here they are lags
    no_ridge = EmptyWindowError(
        f"the kymogram's autocorrelation has a ridge (peaks min_snr={min_snr} robust "
        f"sigmas high) at fewer than 3 lags: no structure travels along the line at "
        "one speed within max_lag_s (periodic structures alias); try a wider line, "
        "another max_lag_s, or the ridge method")
    try:
        rough = fit(total, 1)
    except EmptyWindowError:
        # the significance of each peak by the jackknife over the time blocks, where the
        # MAD of the whole image cannot give it (a travelling wave's autocorrelation is
        # itself a wave, its MAD its amplitude: a clear 1000 px/s wave had no fit, probe CC)
        loo_images = np.stack([_correlation_image(total - b, n_s) for b in spectra])
        block_noise = np.sqrt((len(spectra) - 1) * loo_images.var(axis=0))
        try:
            rough = fit(total, 1)
        except EmptyWindowError as exc:
            raise no_ridge from exc
    speed = abs(rough.velocity_px_s)
    shortest = max(min_shift_px, band + 1.0 if band else 0.0)
    first = int(np.ceil(shortest / (speed * dt))) if speed > 0 else 1
    if first > n_lags - 3:
        # where even that speed is no measurement, nothing may move at all (noise, an
        # empty line): a longer max_lag_s was the only advice (probe BU)
        still = ("" if rough.reliable else
                 f"; that speed ({rough.velocity_px_s:.3g} +- {rough.velocity_std_px_s:.2g} "
                 "px/s) is itself no measurement: nothing may move along the line (try "
                 "another line), or")
        raise EmptyWindowError(
            f"the structures move {speed * dt:.3g} px a lag ({dt:.3g} s), "
            f"{speed * (n_lags - 1) * dt:.3g} px at the longest ({(n_lags - 1) * dt:.3g} s): "
            f"the fit needs 3 lags at which they have moved >= {shortest:g} px, here "
            f"{max(n_lags - first, 0)}{still or ':'} give a longer max_lag_s or a lower "
            "min_shift_px / stationary_px")
    first = max(first, 1)
    whole = fit(total, first)
    loo = []
    for b in spectra:
        try:
            loo.append(fit(total - b, first).velocity_px_s)
        except EmptyWindowError:
            continue
    n = len(loo)
    std = (float(np.sqrt((n - 1) / n * np.sum((np.array(loo) - np.mean(loo)) ** 2)))
           if n >= 2 else float("nan"))
    v = whole.velocity_px_s
    t_ref = float(t[tmask].mean())
    out = RidgeFit(velocity_px_s=v, velocity_std_px_s=std,
                   s0_px=_strongest_streak(kymo, v, t_ref, tmask, smask, sigma_px),
                   t_ref_s=t_ref, t_s=whole.t_s, s_px=whole.s_px, inliers=whole.inliers,
                   residual_px=whole.residual_px, method="correlation",
                   origin_offset_px=float(whole.s0_px - v * whole.t_ref_s))
    if block_noise is not None and not out.reliable:
        # held against their own noise, peaks of noise can stand high too: such a fit is
        # kept only where it is a measurement
        raise no_ridge
    return out


def _strongest_streak(kymo: Kymogram, v: float, t_ref: float, tmask: np.ndarray,
                      smask: np.ndarray, sigma_px: float) -> float:
    # position at t_ref of the line of slope v along which the (smoothed, |.|) kymogram sums
    # highest within the region: where the fitted speed is drawn
    d = np.abs(np.asarray(kymo.data, dtype=np.float64))
    if sigma_px > 0:
        d = ndimage.gaussian_filter1d(d, sigma_px, axis=1, mode="constant")
    rows = np.flatnonzero(tmask)
    s = kymo.s_px
    c = s[smask]
    pos = c[None, :] + v * (kymo.t_s[rows] - t_ref)[:, None]
    idx = np.interp(pos, s, np.arange(s.size), left=-1.0, right=-1.0)
    inside = idx >= 0
    vals = ndimage.map_coordinates(d, [np.broadcast_to(rows[:, None], idx.shape),
                                       np.where(inside, idx, 0.0)], order=1)
    score = np.where(inside, vals, 0.0).sum(axis=0)
    return float(c[int(np.argmax(score))])
