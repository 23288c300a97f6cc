"""Event-by-event optical flow by triplet matching (thesis ch. 5).

Every incoming event ``e_k`` looks, within its polarity, for a past event ``e_i`` in the
neighbourhood (5.1) -- ``0 < ||x_i - x_k|| <= d_x`` and ``t_k - tau - d_t <= t_i <= t_k - tau``
-- and, for each, for an older ``e_j`` continuing the same step (5.2):
``x_i - x_j = x_k - x_i`` and ``t_i - tau - d_t <= t_j <= t_i - tau``. Each triplet votes
``v_T = (x_j - x_k) / (t_j - t_k)`` with the weight ``N(t_j; t_i - delta, delta^2)``,
``delta = t_k - t_i`` (5.3). As in the thesis (§5.3.4: "the 8 neighboring pixels"), the
event's own pixel is not a neighbour: it would only vote for zero flow.

Memory is bounded by a ring of the latest ``depth`` timestamps per pixel and polarity
(``2 * H * W * depth`` int32) instead of the thesis' latest 20,000 index maps: because (5.2)
fixes the pixels of e_i and e_j once the offset ``d = x_i - x_k`` is chosen, the answers are
those of Algorithm 1 as long as no pixel emits more than ``depth`` events of one polarity
within ``2 (d_t + tau)``. :attr:`TripletMatcher.overflow` counts the events forgotten
earlier than that (zero means the answers equal the unbounded Algorithm 1 exactly; the
tests check this against a literal implementation).

Accuracy (measured on simulated scenes, ``benchmarks/results/triplet_event_errors.md``):
the per-event direction is unbiased once many events are averaged (the 8-direction votes
mix), but the speed is under-estimated, increasingly with speed: the refractory window
``t_i <= t_k - tau`` drops the fast votes, so with tau = 3 ms the speed along the true flow
comes out ~0.95x at 50-100 px/s and ~0.6-0.8x at 300-600 px/s (one-pixel steps then take
about tau). A smaller tau admits the bursts of several events per edge crossing and
scatters the votes more. On a translating scene rendered without the simulator (a blob
texture of log contrast 2.1, at C = 0.2, OpenCV-warped at 5 kHz, as
``benchmarks/bench_flow_foreign.py`` renders it) the median per-event speed came out
0.87x at 60 px/s and 0.70x at 150 px/s, where ``dense="robust"`` measured 149.7-152.2
px/s (2026-12-03). This is the thesis' estimator, kept as is.

Each triplet also fixes the time-surface gradient ``g`` along its step,
``g . (x_k - x_j) = t_k - t_j``; the matcher returns, besides (5.3), the normal flow
``g / |g|^2`` of the least-squares ``g`` of each event's triplets (:attr:`TripletFlow.nx`),
each triplet weighted by the (5.3) Gaussian narrowed to ``sigma = delta / 16``
(``normal_kappa``): an edge crossing fires a burst of events, one per threshold level, and
only matches whose two steps take equal times pair events of one level.
The batch output ``dense="lsq"`` (an extension) fits each pixel's flow to the normal flows
of its 15 x 15 neighbourhood, which resolves the aperture where edges of several
orientations meet; it defaults to d_x = 2.3 (steps of one and two pixels) and tau = 1 ms
(fast steps kept). Its per-event normal speeds are off by a few percent, in a direction that
depends on the event rate: matches pair different threshold levels of the bursts that an
edge fires at neighbouring pixels (``benchmarks/results/triplet_lsq_budget.md``).
``dense="robust"`` (an extension) avoids that: it matches *burst means* (one event per
burst, at the mean time of its events, :mod:`evmotion.methods.bursts`), whose timing error is
symmetric, and fits the flow over 41 x 41 px re-weighted with Tukey's biweight
(:func:`dense_robust_fit`). Simulated translation / rotation / zoom, AEE over MultiCM's on
the same windows (``benchmarks/results/triplet_accuracy_summary.md``), dt = 1 and dt = 4 at
250-300 px/s: thesis mean 24 / 11 / 9.1 and 157 / 6.2 / 3.7; ``dense="lsq"`` 6.2 / 2.4 /
2.7 and 36 / 1.8 / 1.3; ``dense="robust"`` 0.79 / 1.28 / 1.54 and 2.93 / 1.18 / 0.93; at a
quarter of that speed ``dense="robust"`` 0.14 / 0.54 / 0.49 and 2.47 / 2.12 / 2.06 (the
first 2 (d_t + tau) of each stream read backwards, :func:`two_sided`).

Streaming dense output, window by window in bounded memory:
:func:`evmotion.methods.triplet_stream.iter_flow_triplet`.

Units: pixels, microseconds for times, px/s for flow.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from evmotion.errors import EmptyWindowError, ParameterError, PoorFitWarning
from evmotion.events import (
    EventArray,
    Window,
    as_window,
    check_stream_order,
    pixel_indices,
    require_events,
    sensor_pixels,
)
from evmotion.io.guard import MAX_SENSOR_SIDE
from evmotion.methods import triplet_kernels as K
from evmotion.methods.bursts import BURST_GAP_US, burst_means
from evmotion.methods.measured import (
    MIN_CONTRAST_GAIN,
    MIN_HALVES_CORRELATION,
    alignment_gain,
    box_offsets,
    halves_correlation,
)
from evmotion.utils import check_switches, is_finite_number, whole_number

__all__ = [
    "LSQ_DX",
    "MAX_DX",
    "LSQ_FILTER_SIZE",
    "LSQ_TAU_US",
    "NORMAL_KAPPA",
    "ROBUST_C",
    "ROBUST_FILTER_SIZE",
    "ROBUST_ITERS",
    "ROBUST_RIDGE",
    "TripletBatchResult",
    "TripletFlow",
    "TripletMatcher",
    "add_normal_voxels",
    "add_voxels",
    "collapse_voxels",
    "dense_defaults",
    "dense_from_sums",
    "default_ridge",
    "dense_lsq_from_sums",
    "dense_robust_fit",
    "early_window",
    "estimate_flow_triplet",
    "event_flow_consistency",
    "event_fwl",
    "history_us",
    "max_normal_speed",
    "neighbour_offsets",
    "nonzero_average_filter",
    "triplet_time_us",
    "two_sided",
    "voxelize_flow",
]


# Narrowing of the (5.3) Gaussian in the normal-flow fit of each event (sigma = delta / 16).
NORMAL_KAPPA = 256
# Defaults of the dense="lsq" batch output (measured on the simulated scenes, see
# benchmarks/results/triplet_accuracy_summary.md): steps up to 2.3 px (16 directions, of one
# and two pixels) and tau = 1 ms, a 15 x 15 fit.
LSQ_DX = 2.3
LSQ_TAU_US = 1_000
LSQ_FILTER_SIZE = 15
# Defaults of the dense="robust" output (same steps and tau): burst means, a 41 x 41 fit,
# ridge 1e-3, Tukey's biweight at 30 % of the normal speed, 20 re-weightings (chosen on
# seed 0 of benchmarks/bench_triplet_accuracy.py; seed 1 and the 'object' scene held out).
ROBUST_FILTER_SIZE = 41
ROBUST_RIDGE = 1e-3
ROBUST_C = 0.3
ROBUST_ITERS = 20
DENSE_KINDS = ("mean", "lsq", "robust")


def dense_defaults(dense: str, dx: float | None = None, tau_us: int | None = None,
                   filter_size: int | None = None) -> tuple[float, int, int]:
    """``(dx, tau_us, filter_size)`` with the defaults of the ``dense`` output filled in:
    the thesis' sqrt(2) px, 3 ms and 3x3 average for ``"mean"``; :data:`LSQ_DX`,
    :data:`LSQ_TAU_US` and :data:`LSQ_FILTER_SIZE` for ``"lsq"``; the same steps and tau
    with :data:`ROBUST_FILTER_SIZE` for ``"robust"``.

    Examples
    --------
    >>> dense_defaults("lsq", tau_us=2_000)
    (2.3, 2000, 15)
    """
    if dense not in DENSE_KINDS:
        raise ParameterError(f"dense must be one of {DENSE_KINDS}, got {dense!r}")
    thesis = dense == "mean"
    if dx is None:
        dx = float(np.sqrt(2.0)) if thesis else LSQ_DX
    if tau_us is None:
        tau_us = 3_000 if thesis else LSQ_TAU_US
    if filter_size is None:
        filter_size = {"mean": 3, "lsq": LSQ_FILTER_SIZE, "robust": ROBUST_FILTER_SIZE}[dense]
    return dx, tau_us, filter_size


def default_ridge(dense: str, ridge: float | None = None) -> float:
    """``ridge`` or the default of the ``dense`` output (1e-2 for ``"lsq"``,
    :data:`ROBUST_RIDGE` for ``"robust"``), checked finite and >= 0."""
    if ridge is None:
        ridge = ROBUST_RIDGE if dense == "robust" else 1e-2
    _check_ridge(ridge)
    return float(ridge)


def _check_ridge(ridge: float) -> None:
    if not (is_finite_number(ridge) and ridge >= 0.0):
        raise ParameterError(f"ridge must be a finite number >= 0, got {ridge}")


@dataclass(frozen=True)
class TripletFlow:
    """Per-event flow returned by :meth:`TripletMatcher.process`.

    Attributes
    ----------
    vx, vy : ndarray of float32, shape (N,)
        Flow of each event in px/s (+x right, +y down); 0 where ``valid`` is False.
    valid : ndarray of bool, shape (N,)
        True where at least one triplet was found.
    n_triplets : ndarray of int32, shape (N,)
        Number of triplets (or quadruples) that voted.
    nx, ny : ndarray of float32, shape (N,), optional
        Normal flow in px/s of the event's matches: ``g / |g|^2`` with ``g`` the
        least-squares time-surface gradient (s/px) of ``g . (x_k - x_j) = t_k - t_j`` over
        its triplets (an extension, used by the ``dense="lsq"`` batch output); 0 where no
        match carries weight. None when not computed.
    """

    vx: np.ndarray
    vy: np.ndarray
    valid: np.ndarray
    n_triplets: np.ndarray
    nx: np.ndarray | None = None
    ny: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.vx.shape[0])

    def __getitem__(self, index: slice) -> TripletFlow:
        """The flows of a slice of the events (views, no copy)."""
        if not isinstance(index, slice):
            raise TypeError("TripletFlow supports slices only, e.g. flow[a:b]")
        return TripletFlow(*(None if a is None else a[index] for a in self._arrays()))

    def _arrays(self) -> tuple:
        return (self.vx, self.vy, self.valid, self.n_triplets, self.nx, self.ny)

    @property
    def flow(self) -> np.ndarray:
        """(N, 2) float32 array of (vx, vy) in px/s."""
        return np.stack([self.vx, self.vy], axis=1)

    @property
    def valid_fraction(self) -> float:
        return float(self.valid.mean()) if len(self) else 0.0

    @staticmethod
    def concatenate(parts: Sequence[TripletFlow]) -> TripletFlow:
        """Join per-chunk results in order (normal flow kept only if every part has it)."""
        cols = list(zip(*(f._arrays() for f in parts), strict=True))
        return TripletFlow(*(None if any(a is None for a in c) else np.concatenate(c)
                             for c in cols))


#: Largest neighbourhood radius d_x: 800 neighbours a pixel, 100x the thesis' sqrt(2) in
#: time; a radius of 300 px ran for minutes without progress and did not answer Ctrl-C
#: (probe), 1e308 raised a numpy error
MAX_DX = 16.0
_MAX_DX_WHY = "larger neighbourhoods match unrelated edges at hundreds of times the cost"


def neighbour_offsets(dx: float) -> np.ndarray:
    """Integer pixel offsets ``d`` with ``0 < ||d|| <= dx``, as an (M, 2) int32 array (x, y).

    Examples
    --------
    >>> len(neighbour_offsets(np.sqrt(2)))
    8
    """
    if not is_finite_number(dx) or dx < 1.0 or dx > MAX_DX:
        raise ParameterError(f"dx must be from 1 px (a neighbour must exist) to {MAX_DX:g} px "
                             f"({_MAX_DX_WHY}), got {dx}")
    r = int(np.floor(dx + 1e-9))
    g = np.arange(-r, r + 1)
    ox, oy = np.meshgrid(g, g, indexing="xy")
    d2 = ox**2 + oy**2
    keep = (d2 > 0) & (d2 <= dx * dx + 1e-9)
    return np.ascontiguousarray(np.stack([ox[keep], oy[keep]], axis=1).astype(np.int32))


class TripletMatcher:
    """Streaming triplet-matching flow estimator (thesis Algorithm 1).

    Parameters
    ----------
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    dx : float
        Neighbourhood radius d_x in pixels (default sqrt(2): the 8 neighbours).
    dt_us : int
        Delay window d_t in microseconds (default 100 ms).
    tau_us : int
        Refractory period tau in microseconds (default 3 ms; at least 1).
    quadruple : bool
        Require a 4th event continuing the step (§5.3.5 extension); the weight is the
        product of the Gaussians of the 3rd and 4th events' timestamps.
    depth : int
        Timestamps remembered per pixel and polarity (bounds memory; see module notes).
    normal_kappa : int
        Power of two ``kappa``: in the normal flow (:attr:`TripletFlow.nx`, an extension) each
        match weighs ``exp(-z^2/2)^kappa``, the (5.3) Gaussian narrowed to
        ``sigma = delta / sqrt(kappa)``; 1 is the (5.3) shape. Narrow weights keep the
        matches whose two steps take equal times: an edge crossing fires a burst of events
        (one per threshold level), and matches across levels of the bursts mis-time the
        step. Does not affect the (5.3) flow.

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> m = TripletMatcher(ev.sensor_size)
    >>> f = m.process(ev)
    >>> f.valid.tolist(), float(f.vx[2])
    ([False, False, True], 100.0)
    """

    def __init__(self, sensor_size: tuple[int, int], dx: float = float(np.sqrt(2.0)),
                 dt_us: int = 100_000, tau_us: int = 3_000, *, quadruple: bool = False,
                 depth: int = 8, normal_kappa: int = NORMAL_KAPPA) -> None:
        try:
            h, w = sensor_size
        except (TypeError, ValueError):
            raise ParameterError(f"sensor_size must be (height, width), got {sensor_size!r}"
                                 ) from None
        h, w = (whole_number(f"sensor_size {name}", v, lo=1, hi=MAX_SENSOR_SIDE)
                for name, v in (("height", h), ("width", w)))
        depth = whole_number("depth", depth, lo=1, hi=255)
        dt_us = whole_number("dt_us (microseconds)", dt_us, lo=1)
        # tau = 0 would admit t_i = t_k: delta = 0, a Gaussian of zero width in (5.3).
        tau_us = whole_number("tau_us (microseconds)", tau_us, lo=1)
        if not (is_finite_number(dx) and dx > 0):
            raise ParameterError(f"dx must be a finite number of px > 0, got {dx!r}")
        if 3 * (int(dt_us) + int(tau_us)) >= K.REBASE_SPAN_US // 2:
            raise ParameterError(f"dt_us + tau_us = {int(dt_us) + int(tau_us)} us is too long "
                                 f"(limit {K.REBASE_SPAN_US // 6} us)")
        # (NaN raised "cannot convert float NaN to integer", probe API)
        kappa = int(normal_kappa) if is_finite_number(normal_kappa) else 0
        if kappa != normal_kappa or kappa < 1 or kappa > 2**16 or kappa & (kappa - 1):
            raise ParameterError(f"normal_kappa must be a power of two in 1..65536, "
                                 f"got {normal_kappa}")
        self.normal_kappa = kappa
        self._n_sq = kappa.bit_length() - 1
        self.sensor_size = (h, w)
        self.dx = float(dx)
        self.dt_us = int(dt_us)
        self.tau_us = int(tau_us)
        check_switches(quadruple=quadruple)
        self.quadruple = bool(quadruple)
        self.depth = int(depth)
        self.offsets = neighbour_offsets(self.dx)
        self._ts = np.empty((2, h, w, self.depth), dtype=np.int32)
        self._stats = np.zeros(1, dtype=np.int64)
        self._rebase_span = K.REBASE_SPAN_US
        self.reset()

    def reset(self) -> None:
        """Forget every past event (as if the stream started anew)."""
        self._ts.fill(K.EMPTY)
        self._stats[:] = 0
        self._base: int | None = None
        self._t_last: int | None = None
        self.events_seen = 0

    def fresh(self) -> TripletMatcher:
        """A matcher of the same parameters that has seen no event."""
        return TripletMatcher(self.sensor_size, self.dx, self.dt_us, self.tau_us,
                              quadruple=self.quadruple, depth=self.depth,
                              normal_kappa=self.normal_kappa)

    @property
    def state_nbytes(self) -> int:
        """Bytes of state; constant for a given sensor size and depth."""
        return int(self._ts.nbytes + self._stats.nbytes)

    @property
    def overflow(self) -> int:
        """Events evicted from a full ring while they could still form a triplet."""
        return int(self._stats[0])

    def process(self, chunk: EventArray) -> TripletFlow:
        """Flow of each event of ``chunk``, continuing from the events seen before.

        Any split of a stream into chunks gives bit-identical results. Float (undistorted)
        coordinates are rounded to the nearest pixel, since (5.2) asks for equal pixel steps.
        """
        if not isinstance(chunk, EventArray):  # (off-sensor events: named below)
            require_events(chunk, "TripletMatcher.process")
        if tuple(chunk.sensor_size) != self.sensor_size:
            raise ParameterError(f"chunk sensor_size {chunk.sensor_size} differs from the "
                                 f"matcher's {self.sensor_size}")
        n = len(chunk)
        out = TripletFlow(np.empty(n, np.float32), np.empty(n, np.float32),
                          np.empty(n, np.bool_), np.empty(n, np.int32),
                          np.empty(n, np.float32), np.empty(n, np.float32))
        if n == 0:
            return out
        t = chunk.t
        # The kernel trusts these (rings are newest-first, indices unchecked): an unvalidated
        # EventArray must not reach it unsorted or off-sensor.
        check_stream_order(t, self._t_last)
        x, y = sensor_pixels(chunk)
        p = np.ascontiguousarray(chunk.p, dtype=np.uint8)
        if self._base is None:
            self._base = int(t[0])
        # Relative int32 times: rebase whenever a piece would run past the safe span.
        start = 0
        while start < n:
            if int(t[start]) - self._base >= self._rebase_span // 2:
                self._rebase(int(t[start]))
            limit = self._base + self._rebase_span
            stop = int(np.searchsorted(t, limit, side="left"))
            stop = max(stop, start + 1)
            K.triplet_kernel(x[start:stop], y[start:stop], t[start:stop], p[start:stop],
                             np.int64(self._base), self._ts, self.offsets,
                             np.int64(self.dt_us), np.int64(self.tau_us), self.quadruple,
                             np.int64(self._n_sq), out.vx[start:stop], out.vy[start:stop],
                             out.n_triplets[start:stop], out.valid[start:stop],
                             out.nx[start:stop], out.ny[start:stop], self._stats)
            start = stop
        self._t_last = int(t[-1])
        self.events_seen += n
        return out

    def _rebase(self, t_now: int) -> None:
        horizon = 3 * (self.dt_us + self.tau_us)
        new_base = t_now - horizon
        K.rebase_kernel(self._ts, np.int64(new_base - self._base), np.int64(-horizon))
        self._base = new_base


def history_us(dt_us: int, tau_us: int) -> int:
    """How long after a stream's first event a matcher of delay window ``dt_us`` and
    refractory period ``tau_us`` finds the triplets of every step it looks for: ``2 (d_t +
    tau)`` µs (before, the older partners of slow steps precede the stream).

    Examples
    --------
    >>> history_us(100_000, 1_000)
    202000
    """
    return 2 * (int(dt_us) + int(tau_us))


def two_sided(events: EventArray, flow: TripletFlow, matcher: TripletMatcher,
              t_start: int, *, backwards: bool = True
              ) -> tuple[TripletFlow, tuple[int, int] | None]:
    """``flow`` (of ``events``, a stream begun at ``t_start`` µs) with the events of the
    stream's first :func:`history_us` whose future holds more of it than their past
    taking the flow of the time-reversed stream (negated).

    Within ``2 (d_t + tau)`` of the stream's start, an event's slow steps have their older
    partners before the stream, so only faster steps are matched and the flow comes out
    too fast (2.4x in the first 50 ms of a simulated translation at 30 px/s): run
    backwards, the stream gives each of those events triplets of its successors, a whole
    history where the recording goes on for ``2 (d_t + tau)``.

    Parameters
    ----------
    events : EventArray
        The stream's events from its start, in order (only those before
        ``t_start + 2 history`` are read backwards).
    flow : TripletFlow
        Their forward flow (:meth:`TripletMatcher.process`); not modified.
    matcher : TripletMatcher
        The matcher ``flow`` came from: a :meth:`~TripletMatcher.fresh` one of its
        parameters runs the reversed stream.
    t_start : int
        The stream's first event time, µs.
    backwards : bool
        False: ``flow`` as it is, and ``incomplete`` the events under
        :func:`history_us` from the start (the thesis' ``dense="mean"``, whose per-event
        speeds swing by window both ways: 19-37 px/s for 30 in a stream's first 200 ms
        either way, so it is not reversed).

    Returns
    -------
    flow : TripletFlow
        A copy with those events' flow, normal flow, triplet count and validity replaced.
    incomplete : (int, int) or None
        The span of times, µs, of events with under half :func:`history_us` on either
        side (a stream shorter than it): their steps of over ``(d_t + tau) / 2`` are
        matched neither way, and their flow is too fast where the motion is that slow;
        None when there is none.

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> m = TripletMatcher((10, 10), dt_us=15_000, tau_us=1_000)
    >>> fwd = m.process(ev)
    >>> both, _ = two_sided(ev, fwd, m, 0)
    >>> fwd.valid.tolist(), both.valid.tolist(), float(both.vx[0])
    ([False, False, True], [True, False, True], 100.0)
    """
    h = history_us(matcher.dt_us, matcher.tau_us)
    t = events.t
    n = int(np.searchsorted(t, t_start + 2 * h, side="left"))
    past = t[:n] - t_start
    if not n or past[0] >= h:
        return flow, None
    end = int(t[n - 1]) if n == len(events) else t_start + 2 * h
    if not backwards:
        return flow, (int(t_start), min(int(t_start) + h, end + 1))
    future = end - t[:n]
    take = (past < h) & (future > past)
    seg = events[:n]
    rev = EventArray(seg.x[::-1], seg.y[::-1], (int(t[0]) + int(t[n - 1])) - seg.t[::-1],
                     seg.p[::-1], seg.sensor_size, validate=False)
    back = matcher.fresh().process(rev)
    arrays = [None if a is None else a.copy() for a in flow._arrays()]
    # (vx, vy, valid, n_triplets, nx, ny): the velocities change sign backwards
    for a, b, sign in zip(arrays, back._arrays(), (-1, -1, 0, 0, -1, -1), strict=True):
        if a is not None and b is not None:
            a[:n][take] = sign * b[::-1][take] if sign else b[::-1][take]
    # events with under half the history on both sides (a stream shorter than it): steps
    # of over a quarter of it (d_t + tau) / 2 went unmatched either way
    half = h // 2
    lo, hi = max(end - half, int(t_start)), min(int(t_start) + half, end + 1)
    return TripletFlow(*arrays), ((lo, hi) if lo < hi else None)


# ------------------------------------------------------------------ batch (Algorithm 2)
def nonzero_average_filter(field: np.ndarray, mask: np.ndarray, size: int = 3,
                           ) -> tuple[np.ndarray, np.ndarray]:
    """3x3 average of only the valid (non-zero) neighbours, as in the thesis' batch mode.

    Parameters
    ----------
    field : ndarray, shape (..., H, W, 2)
        Flow in px/s.
    mask : ndarray of bool, shape (..., H, W)
        Where ``field`` holds a value.
    size : int
        Odd filter width in pixels: 3 is the thesis' filter; larger sizes (an extension,
        see :func:`estimate_flow_triplet`) average more per-event scatter away.

    Returns
    -------
    smoothed : ndarray of float32, shape (..., H, W, 2)
        Mean of the valid values in each size x size neighbourhood; 0 where there is none.
    support : ndarray of bool, shape (..., H, W)
        True where at least one valid value was in the neighbourhood.

    Examples
    --------
    >>> f = np.zeros((3, 3, 2)); m = np.zeros((3, 3), bool)
    >>> f[1, 1] = (2.0, 0.0); m[1, 1] = True
    >>> s, sup = nonzero_average_filter(f, m)
    >>> float(s[0, 0, 0]), bool(sup.all())
    (2.0, True)
    """
    r = _filter_radius(size)
    m = mask.astype(np.float64)
    v = np.where(mask[..., None], field, 0.0).astype(np.float64)
    s = _box(v, (-3, -2), r)
    c = _box(m, (-2, -1), r)
    support = c > 0
    out = np.zeros_like(s, dtype=np.float32)
    np.divide(s, c[..., None], out=out, where=support[..., None], casting="unsafe")
    return out, support


def _filter_radius(size: int) -> int:
    if not is_finite_number(size) or int(size) != size or size < 1 or size % 2 == 0:
        raise ParameterError(f"filter size must be an odd number of pixels >= 1, got {size}")
    return int(size) // 2


def _box(a: np.ndarray, axes: tuple[int, int], r: int) -> np.ndarray:
    for ax in axes:
        pad = [(0, 0)] * a.ndim
        pad[ax] = (r, r)
        b = np.pad(a, pad)
        n = a.shape[ax]
        a = sum(np.take(b, range(i, n + i), axis=ax) for i in range(2 * r + 1))
    return a


def voxelize_flow(events: EventArray, flow: TripletFlow, t0_us: int, t1_us: int,
                  n_bins: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Average the valid per-event flow of events in ``[t0_us, t1_us)`` per (bin, pixel).

    Returns
    -------
    voxels : ndarray of float32, shape (n_bins, H, W, 2)
        Mean flow in px/s of each space-time voxel (0 where empty).
    mask : ndarray of bool, shape (n_bins, H, W)
        Voxels holding at least one valid event.
    """
    acc, cnt = _voxel_sums(events, flow, t0_us, t1_us, n_bins)
    return _voxel_mean(acc, cnt)


def _check_interval(t0_us, t1_us, n_bins):
    whole_number("n_bins", n_bins, lo=1)
    if t1_us <= t0_us:
        raise ParameterError(f"empty interval [{t0_us}, {t1_us}) us")


# the space-time voxels' sums and counts (24 bytes a voxel) may take at most this much
VOXEL_MEMORY_BYTES = 4 << 30


def _voxel_sums(events, flow, t0_us, t1_us, n_bins):
    _check_interval(t0_us, t1_us, n_bins)
    h, w = events.sensor_size
    if int(n_bins) * h * w * 24 > VOXEL_MEMORY_BYTES:
        # (n_bins=10**6 at 346x260 met numpy's MemoryError for 71.5 GiB: probe)
        raise ParameterError(f"n_bins={n_bins} needs {int(n_bins) * h * w * 24 / 2**30:.1f} "
                             f"GiB of voxels at {w}x{h} px; at most "
                             f"{VOXEL_MEMORY_BYTES // (h * w * 24)} bins here")
    acc = np.zeros((n_bins, h, w, 2), np.float64)
    cnt = np.zeros((n_bins, h, w), np.int64)
    add_voxels(events, flow, t0_us, t1_us, acc, cnt)
    return acc, cnt


def add_voxels(events: EventArray, flow: TripletFlow, t0_us: int, t1_us: int,
               acc: np.ndarray, cnt: np.ndarray) -> None:
    """Accumulate per-event flow into voxel sums ``acc`` and counts ``cnt`` (in place).

    Used to build windows from a stream chunk by chunk; ``acc`` is (n_bins, H, W, 2) float64.
    """
    K.voxel_accumulate(pixel_indices(events.x, events.width), pixel_indices(events.y, events.height),
                       events.t, flow.vx, flow.vy, flow.valid, np.int64(t0_us),
                       np.int64(t1_us), acc.shape[0], acc, cnt)


def dense_from_sums(acc: np.ndarray, cnt: np.ndarray, *, smooth: bool = True,
                    filter_size: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Dense (H, W, 2) px/s flow and mask from voxel sums ``acc`` (n_bins, H, W, 2) and counts
    ``cnt`` (n_bins, H, W) (see :func:`add_voxels`): the fused, compiled equivalent of
    :func:`voxelize_flow` followed by :func:`collapse_voxels` (same ``smooth`` and
    ``filter_size``)."""
    h, w = cnt.shape[1:]
    out = np.empty((h, w, 2), np.float32)
    mask = np.empty((h, w), np.bool_)
    r = _filter_radius(filter_size) if smooth else 0
    K.dense_from_sums(np.ascontiguousarray(acc, np.float64), np.ascontiguousarray(cnt),
                      np.int64(r), out, mask)
    return out, mask


def max_normal_speed(dx: float, tau_us: int) -> float:
    """Fastest normal flow (px/s) the ``dense="lsq"`` output admits: twice the fastest triplet
    step ``d_x / tau``; faster normal flows come from ill-conditioned fits and are dropped."""
    return 2.0 * float(dx) / (float(tau_us) * 1e-6)


def add_normal_voxels(events: EventArray, flow: TripletFlow, t0_us: int, t1_us: int,
                      acc: np.ndarray, cnt: np.ndarray, vmax: float) -> None:
    """Accumulate the per-event normal-flow constraints (``flow.nx``, ``flow.ny``) into voxel
    normal equations ``acc`` (n_bins, H, W, 5) float64 and counts ``cnt`` (n_bins, H, W)
    int64, in place; normal flows faster than ``vmax`` px/s are left out (see
    :func:`max_normal_speed`). Counterpart of :func:`add_voxels` for ``dense="lsq"``."""
    if flow.nx is None or flow.ny is None:
        raise ParameterError("this TripletFlow carries no normal flow (nx, ny); use the "
                             "output of TripletMatcher.process")
    K.voxel_accumulate_normal(pixel_indices(events.x, events.width), pixel_indices(events.y, events.height),
                              events.t, flow.nx, flow.ny, np.int64(t0_us), np.int64(t1_us),
                              acc.shape[0], float(vmax), acc, cnt)


def dense_lsq_from_sums(acc: np.ndarray, cnt: np.ndarray, *, filter_size: int = LSQ_FILTER_SIZE,
                        ridge: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """Dense (H, W, 2) px/s flow and mask from normal-flow voxel sums (see
    :func:`add_normal_voxels`): per time bin and pixel, the flow ``v`` that best meets the
    constraints ``v . n = |u|`` of the events in the ``filter_size`` x ``filter_size``
    neighbourhood (least squares, ridge ``ridge`` x the mean eigenvalue, which keeps
    single-orientation neighbourhoods at their normal flow), then the mean over the bins
    that hold a value."""
    _check_ridge(ridge)
    h, w = cnt.shape[1:]
    out = np.empty((h, w, 2), np.float32)
    mask = np.empty((h, w), np.bool_)
    K.dense_lsq_from_sums(np.ascontiguousarray(acc, np.float64), np.ascontiguousarray(cnt),
                          np.int64(_filter_radius(filter_size)), float(ridge), out, mask)
    return out, mask


def dense_robust_fit(events: EventArray, flow: TripletFlow, t0_us: int, t1_us: int, *,
                     n_bins: int = 1, filter_size: int = ROBUST_FILTER_SIZE,
                     ridge: float = ROBUST_RIDGE, c: float = ROBUST_C,
                     iters: int = ROBUST_ITERS,
                     vmax: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Dense (H, W, 2) px/s flow and mask from the normal flows of ``events`` in
    ``[t0_us, t1_us)``: the neighbourhood fit of :func:`dense_lsq_from_sums`, re-weighted
    ``iters`` times with Tukey's biweight of each event's relative residual
    ``(v . n - |u|) / |u|`` (weight zero beyond ``c``), ``v`` the fitted flow at its pixel.

    Parameters
    ----------
    events : EventArray
        Events (in ``dense="robust"``: burst means, see :mod:`evmotion.methods.bursts`).
    flow : TripletFlow
        Their matcher output, with normal flows (``nx``, ``ny``).
    t0_us, t1_us : int
        The window, µs; split into ``n_bins`` time bins whose fits are averaged.
    filter_size : int
        Odd width of the neighbourhood, px.
    ridge : float
        Tikhonov weight relative to the mean eigenvalue of the normal equations.
    c : float
        Residual (relative to the event's normal speed) beyond which an event is ignored.
    iters : int
        Re-weightings (0: plain least squares over the events).
    vmax : float
        Normal flows faster than this (px/s) are left out (see :func:`max_normal_speed`).

    Examples
    --------
    >>> ev = EventArray(x=[5, 5], y=[4, 5], t=[0, 10], p=[1, 1], sensor_size=(10, 10))
    >>> fl = TripletFlow(*(np.zeros(2, np.float32) for _ in range(2)), np.ones(2, bool),
    ...                  np.ones(2, np.int32), np.float32([100, 0]), np.float32([0, 50]))
    >>> v, m = dense_robust_fit(ev, fl, 0, 20, filter_size=3, ridge=0.0)
    >>> v[5, 5].tolist(), bool(m[0, 0])
    ([100.0, 50.0], False)
    """
    if flow.nx is None or flow.ny is None:
        raise ParameterError("this TripletFlow carries no normal flow (nx, ny); use the "
                             "output of TripletMatcher.process")
    if len(flow) != len(events):
        raise ParameterError(f"{len(flow)} flows for {len(events)} events")
    _check_ridge(ridge)
    if not (is_finite_number(c) and c > 0.0):
        raise ParameterError(f"c must be a finite number > 0, got {c}")
    if int(iters) != iters or iters < 0:
        raise ParameterError(f"iters must be an integer >= 0, got {iters}")
    _check_interval(t0_us, t1_us, n_bins)
    h, w = events.sensor_size
    out = np.empty((h, w, 2), np.float32)
    mask = np.empty((h, w), np.bool_)
    K.dense_robust(pixel_indices(events.x, w), pixel_indices(events.y, h), events.t,
                   np.ascontiguousarray(flow.nx), np.ascontiguousarray(flow.ny),
                   np.int64(t0_us), np.int64(t1_us), np.int64(n_bins), float(vmax),
                   np.int64(_filter_radius(filter_size)), float(ridge), float(c),
                   np.int64(iters), out, mask)
    return out, mask


def _voxel_mean(acc, cnt):
    mask = cnt > 0
    vox = np.zeros(acc.shape, np.float32)
    np.divide(acc, cnt[..., None], out=vox, where=mask[..., None], casting="unsafe")
    return vox, mask


def collapse_voxels(voxels: np.ndarray, mask: np.ndarray, *, smooth: bool = True,
                    filter_size: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Dense (H, W, 2) flow from time-bin voxels: 3x3 (``filter_size``) non-zero average per
    bin, then the mean of the bins that hold a value (the thesis' "2D collapsed" flow).
    Returns (flow, mask)."""
    if smooth:
        voxels, mask = nonzero_average_filter(voxels, mask, filter_size)
    c = mask.sum(axis=0)
    s = np.where(mask[..., None], voxels, 0.0).sum(axis=0)
    out = np.zeros(s.shape, np.float32)
    np.divide(s, c[..., None], out=out, where=(c > 0)[..., None], casting="unsafe")
    return out, c > 0


@dataclass(frozen=True)
class TripletBatchResult:
    """Dense per-window flow of :func:`estimate_flow_triplet` and the sparse per-event flow.

    Attributes
    ----------
    flow : ndarray of float32, shape (n_windows, H, W, 2)
        Voxelized, non-zero-averaged (3x3 by default) and collapsed flow in px/s (named as
        :class:`~evmotion.io.flowfiles.FlowSequence` names it).
    valid : ndarray of bool, shape (n_windows, H, W)
        Pixels with a flow value.
    windows : list of Window
        The windows, in order.
    events : TripletFlow
        Per-event flow of the input events up to the end of the last window.
    overflow : int
        See :attr:`TripletMatcher.overflow`.
    bursts : EventArray or None
        ``dense="robust"``: the burst means the dense flow was fitted to
        (:func:`~evmotion.methods.bursts.burst_means`); None otherwise.
    burst_flow : TripletFlow or None
        ``dense="robust"``: the matcher's output on ``bursts``.
    gains : ndarray of float, shape (n_windows,)
        How much better each window's dense flow aligns its events than chance
        (:func:`~evmotion.methods.measured.flow_alignment_gain`; of the burst means with
        ``dense="robust"``); where
        :func:`focus_checked` finds it below
        :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN` the window is no measurement,
        its mask all False (a :class:`~evmotion.errors.PoorFitWarning` counts them).
    """

    flow: np.ndarray
    valid: np.ndarray
    windows: list[Window]
    events: TripletFlow
    overflow: int
    bursts: EventArray | None = None
    burst_flow: TripletFlow | None = None
    gains: np.ndarray | None = None

    def displacement(self, i: int) -> np.ndarray:
        """Flow of window ``i`` as pixel displacement over the window's duration."""
        return self.flow[i] * np.float32(self.windows[i].duration_s)


def estimate_flow_triplet(events: EventArray, windows: Sequence[Window] | None = None, *,
                          dx: float | None = None, dt_us: int = 100_000,
                          tau_us: int | None = None, quadruple: bool = False, n_bins: int = 1,
                          smooth: bool = True, filter_size: int | None = None,
                          depth: int = 8, dense: str = "mean", ridge: float | None = None,
                          normal_kappa: int = NORMAL_KAPPA,
                          gap_us: int | None = None) -> TripletBatchResult:
    """Triplet-matching flow of a recording, dense per window (thesis Algorithm 2).

    Every event is processed in order (events before a window serve as its history), then
    each window's events are voxelized into ``n_bins`` time bins, smoothed with the 3x3
    non-zero average filter and collapsed to one (H, W, 2) field in px/s.

    Parameters
    ----------
    events : EventArray
        The recording, sorted by time.
    windows : sequence of Window or of (t0, t1) µs, optional
        E.g. ``events.windows_at(gt_times, dt=1)``; default: one window over all events.
    dx, dt_us, tau_us, quadruple, depth, normal_kappa
        As in :class:`TripletMatcher`. ``dx`` and ``tau_us`` default to the thesis' sqrt(2)
        px and 3 ms with ``dense="mean"``, and to :data:`LSQ_DX` (2.3 px) and
        :data:`LSQ_TAU_US` (1 ms) with ``dense="lsq"``: steps of up to two pixels time the
        normal flow more precisely, and a shorter refractory period keeps the fast steps
        that tau = 3 ms cuts (the per-event flow in :attr:`TripletBatchResult.events` is
        then that of these parameters).
    n_bins : int
        Time bins per window for the voxelization.
    smooth : bool
        Apply the 3x3 non-zero average filter (``dense="mean"``).
    filter_size : int, optional
        Width of that filter; 3 (default) is the thesis' method. Larger odd sizes are an
        extension: the per-event triplet flow scatters by about 30-70 % of the speed from
        event to event, mostly independently between nearby pixels, so a wider average
        lowers the dense error where the motion is smooth (it cannot remove the method's
        speed bias; see ``benchmarks/results/triplet_event_errors.md``). With
        ``dense="lsq"``: the neighbourhood width of the fit (default 15).
    dense : {"mean", "lsq", "robust"}
        ``"mean"``: the thesis' voxel mean of the per-event flow (5.3). ``"lsq"`` (an
        extension): each event's triplets fix its time-surface gradient and so its normal
        flow (:attr:`TripletFlow.nx`); per bin and pixel, the flow meeting the normal-flow
        constraints of the neighbourhood best in least squares. Averaging (5.3) mixes step
        directions that each carry only the normal component of the motion, which biases
        the dense mean towards the edges' normals; the fit resolves the aperture wherever the
        neighbourhood holds edges of several orientations
        (``benchmarks/results/triplet_accuracy_summary.md``). Default width
        :data:`LSQ_FILTER_SIZE` (15).
        ``"robust"`` (an extension, the most accurate): the same fit, over a 41 x 41
        neighbourhood (:data:`ROBUST_FILTER_SIZE`), re-weighted with Tukey's biweight
        (:func:`dense_robust_fit`), of the normal flows of triplets of *burst means* (one
        event per edge crossing of a pixel, at the mean time of its burst;
        :mod:`evmotion.methods.bursts`): matching single events pairs different threshold
        levels of neighbouring pixels' bursts, which biases the normal speeds by a few percent;
        burst means do not.
    ridge : float, optional
        ``dense="lsq"``/``"robust"``: Tikhonov weight relative to the mean eigenvalue of the
        normal equations (default 1e-2 and :data:`ROBUST_RIDGE`).
    gap_us : int, optional
        ``dense="robust"`` only: a silence longer than this (µs) ends a pixel's burst
        (default :data:`~evmotion.methods.bursts.BURST_GAP_US`).

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> res = estimate_flow_triplet(ev)
    >>> res.flow.shape, float(res.flow[0, 5, 4, 0])
    ((1, 10, 10, 2), 100.0)
    """
    # the events off the sensor are left out, as the warning about them says (they were
    # refused a line later: "event 4 has x=90 outside the sensor", probe DB)
    events = require_events(events, "estimate_flow_triplet", on_sensor=True)
    check_switches(smooth=smooth)
    if gap_us is None:
        gap_us = BURST_GAP_US
    elif dense != "robust":
        # (ignored unsaid, as the CLI's --gap-ms is not, probe BQ)
        raise ParameterError(f"gap_us={gap_us!r} applies to dense='robust' only (it ends the "
                             f"bursts whose means it matches), not dense={dense!r}")
    if ridge is not None and dense == "mean":
        # (ignored unsaid, probe CB)
        raise ParameterError(f"ridge={ridge!r} applies to dense='lsq' or 'robust' (their "
                             "least-squares fits), not the thesis' mean")
    if len(events) == 0:
        raise EmptyWindowError("no events to estimate the triplet flow of")
    dx, tau_us, filter_size = dense_defaults(dense, dx, tau_us, filter_size)
    ridge = default_ridge(dense, ridge)
    _filter_radius(filter_size)
    if windows is None:
        windows = [Window(0, events.t_start, events.t_end + 1, 0, len(events))]
    windows = [as_window(events, k, win) for k, win in enumerate(windows)]
    m = TripletMatcher(events.sensor_size, dx, dt_us, tau_us, quadruple=quadruple, depth=depth,
                       normal_kappa=normal_kappa)
    stop = max((w.stop for w in windows), default=len(events))
    # the dense windows take the flow of the stream's first 2 (d_t + tau) from the stream
    # run backwards (two_sided), which reads up to twice that far: the events' for lsq, the
    # burst means' for robust (the thesis' mean is not reversed)
    start_end = events.t_start + 2 * history_us(m.dt_us, m.tau_us)
    reach = max(stop, int(np.searchsorted(events.t, start_end)))
    ahead = m.process(events[:reach])
    flow = dflow = ahead[:stop]
    bursts = bflow = None
    if dense == "robust":
        bursts = burst_means(events, gap_us)  # bursts running past the last window complete
        t_end = max((w.t1 for w in windows), default=events.t_start)
        cut = int(np.searchsorted(bursts.t, t_end))
        breach = max(cut, int(np.searchsorted(bursts.t, start_end)))
        bm = m.fresh()
        bflow, incomplete = two_sided(bursts[:breach], bm.process(bursts[:breach]), bm,
                                      events.t_start)
        bursts, bflow = bursts[:cut], bflow[:cut]
    else:
        dflow, incomplete = two_sided(events[:reach], ahead, m, events.t_start,
                                      backwards=dense == "lsq")
    h, w = events.sensor_size
    vmax = max_normal_speed(dx, tau_us)
    flows = np.zeros((len(windows), h, w, 2), np.float32)
    masks = np.zeros((len(windows), h, w), bool)
    gains = np.full(len(windows), np.nan)
    flagged = np.zeros(len(windows), bool)
    for i, win in enumerate(windows):
        sub = events[win.start:win.stop]
        fsub = dflow[win.start:win.stop]
        if dense == "robust":
            lo, hi = np.searchsorted(bursts.t, [win.t0, win.t1])
            sub = bursts[lo:hi]  # what the window's flow was fitted to, as the stream's
            flows[i], masks[i] = dense_robust_fit(sub, bflow[lo:hi], win.t0, win.t1,
                                                  n_bins=n_bins, filter_size=filter_size,
                                                  ridge=ridge, vmax=vmax)
        elif dense == "lsq":
            acc = np.zeros((n_bins, h, w, 5))
            cnt = np.zeros((n_bins, h, w), np.int64)
            _check_interval(win.t0, win.t1, n_bins)
            add_normal_voxels(sub, fsub, win.t0, win.t1, acc, cnt, vmax)
            flows[i], masks[i] = dense_lsq_from_sums(acc, cnt, filter_size=filter_size,
                                                     ridge=ridge)
        else:
            acc, cnt = _voxel_sums(sub, fsub, win.t0, win.t1, n_bins)
            flows[i], masks[i] = dense_from_sums(acc, cnt, smooth=smooth,
                                                 filter_size=filter_size)
        masks[i] = supported(sub, masks[i], dense)
        gains[i], masks[i], flagged[i] = focus_checked(sub, flows[i], masks[i], win.t0)
    _warn_no_focus(gains, flagged)
    _warn_incomplete(incomplete, windows, flows, masks, m, events.t_start,
                     forwards=dense == "mean")
    _warn_empty(windows)
    return TripletBatchResult(flows, masks, windows, flow, m.overflow, bursts, bflow, gains)


def _warn_empty(windows) -> None:
    """Say which windows hold no event (no flow; they were returned empty unsaid, probe
    BQ)."""
    empty = [w for w in windows if w.stop <= w.start]
    if empty:
        w = empty[0]
        warnings.warn(PoorFitWarning(
            f"{len(empty)} of {len(windows)} window(s) hold no event (first: window "
            f"{w.index}, [{w.t0}, {w.t1}) us): no flow, their masks all False"), stacklevel=3)


def triplet_time_us(flow: np.ndarray | None, valid: np.ndarray | None, dx: float) -> float:
    """The time (µs) a triplet of two ``dx`` px steps takes at a dense flow's slower speeds
    (the lower quartile over its ``valid`` pixels: edges at an angle to the motion step
    slower); inf where nothing is valid (nothing says the motion is fast)."""
    if flow is None or valid is None or not valid.any():
        return float("inf")
    speed = float(np.percentile(np.hypot(*flow[valid].T), 25))
    return 2e6 * dx / speed if speed > 0 else float("inf")


def early_window(t0: int, t1: int, incomplete: tuple[int, int] | None, flow, valid,
                 matcher: TripletMatcher, t_start: int, forwards: bool) -> bool:
    """Whether window ``[t0, t1)``'s flow is biased by the stream's short history: it
    overlaps ``incomplete`` (:func:`two_sided`) and a triplet at its speed
    (:func:`triplet_time_us`) outlasts the history its events have: forwards (the thesis'
    mean), the time since the stream's start ``t_start``; read both ways, the quarter
    history ``(d_t + tau) / 2`` whose slower steps neither way matches. (Marked on overlap
    alone, every window of short recordings was, at 398 px/s too, AEE 0.13-0.24 px:
    probe CD.)"""
    if incomplete is None or not (t0 < incomplete[1] and t1 > incomplete[0]):
        return False
    held = t0 - t_start if forwards else (matcher.dt_us + matcher.tau_us) // 2
    return triplet_time_us(flow, valid, matcher.dx) > held


def _warn_incomplete(incomplete: tuple[int, int] | None, windows, flows, masks,
                     matcher: TripletMatcher, t_start: int, forwards: bool) -> None:
    """Say which windows' flow the stream's short history biases (:func:`early_window`)."""
    if incomplete is None:
        return
    lo, hi = incomplete
    hit = [w.index for w, f, v in zip(windows, flows, masks, strict=True)
           if early_window(w.t0, w.t1, incomplete, f, v, matcher, t_start, forwards)]
    if hit:
        warnings.warn(PoorFitWarning(
            f"{len(hit)} window(s) (first: {hit[0]}) hold events in [{lo}, {hi}) us whose "
            "slow steps' triplets cannot be found (their partners lie before the recording, "
            "or past its end too where the dense flow also reads it backwards) and move "
            "that slowly: their flow is biased (a longer recording, or a shorter d_t for "
            "fast motion)"),
            stacklevel=3)


def _warn_no_focus(gains: np.ndarray, flagged: np.ndarray) -> None:
    """One :class:`~evmotion.errors.PoorFitWarning` for the windows whose dense flow
    sharpens their events by less than the threshold."""
    low = np.flatnonzero(flagged)
    if low.size:
        warnings.warn(
            f"no focus in {low.size} of {gains.size} windows (e.g. window {low[0]}: the "
            f"dense flow aligns its events {100 * (gains[low[0]] - 1):+.1f} % better than "
            f"chance; threshold {100 * (MIN_CONTRAST_GAIN - 1):.0f} %, or a flow that "
            "does not carry the window's first half onto its second): noise or no "
            "texture; their masks are all False", PoorFitWarning, stacklevel=3)


def event_flow_consistency(events: EventArray, flow: TripletFlow) -> float:
    """How well a per-event flow carries its events' first half onto their second:
    :func:`~evmotion.methods.measured.halves_consistency` (warped to their middle) of
    the dense field the valid events' flows make (each pixel's mean, then
    :func:`nonzero_average_filter`), over all the events; NaN with fewer than two valid.

    The flows themselves would not do: a triplet carries its event onto its partners by
    construction, so even noise's line up (0.16-0.18 on dense noise), nor would the
    valid events alone, which gather where noise fired often (0.20). Averaged over
    neighbours and tried on every event, noise's random flows carry nothing (-0.05..0.04
    on noise of 120x160 sensors and larger), a motion's do (0.52-0.78 on moving scenes
    and recordings).

    Examples
    --------
    >>> t = np.arange(0, 50_000, 10)
    >>> bar = EventArray(x=np.round(10 + 400e-6 * t), y=t % 40, t=t, p=np.ones(t.size),
    ...                  sensor_size=(40, 60))
    >>> n = len(bar)
    >>> right = TripletFlow(np.full(n, 400.0, np.float32), np.zeros(n, np.float32),
    ...                     np.ones(n, bool), np.ones(n, np.int32))
    >>> round(event_flow_consistency(bar, right), 1)
    1.0
    """
    if len(flow) != len(events):
        raise ParameterError(f"flow has {len(flow)} entries for {len(events)} events")
    on = np.flatnonzero(flow.valid)
    if on.size < 2:
        return float("nan")
    h, w = events.sensor_size
    x = np.clip(np.rint(events.x).astype(np.int64), 0, w - 1)
    y = np.clip(np.rint(events.y).astype(np.int64), 0, h - 1)
    # each flow pixel's mean, then its 3x3 non-zero average at every event's pixel, on
    # the sensor's grid with a one-pixel frame (no sensor-sized float images, nor their
    # filter: 72 ms a stretch at 1280x720)
    framed = (y + 1) * (w + 2) + x + 1
    index = np.full((h + 2) * (w + 2), -1, np.int64)
    pix, inv = np.unique(framed[on], return_inverse=True)
    index[pix] = np.arange(pix.size)
    cnt = np.bincount(inv, minlength=pix.size)
    near = index[framed[:, None] + box_offsets(w + 2)]  # (N, 9), -1: no flow pixel
    found = np.count_nonzero(near >= 0, axis=1)
    f = np.zeros((len(events), 2))
    for c, v in enumerate((flow.vx, flow.vy)):
        mean = np.zeros(pix.size + 1)  # a last zero, which index -1 reads: no flow there
        mean[:-1] = np.bincount(inv, v[on].astype(np.float64), pix.size) / cnt
        np.divide(mean[near].sum(axis=1), found, out=f[:, c], where=found > 0)
    return halves_correlation(x, y, events.t, f, (int(events.t[0]) + int(events.t[-1])) // 2,
                              (h, w))


def supported(events: EventArray, mask: np.ndarray, dense: str) -> np.ndarray:
    """The valid mask of a ``dense`` window's flow: for ``lsq`` and ``robust``, ``mask``
    where ``events`` support a flow (:func:`~evmotion.methods.flowresult.event_support`,
    as multicm's ``valid``), since their 9-px filter carries it up to 4 px past the
    events, into still background (54 % of a window valid where 11 % of its pixels had
    events); ``mask`` itself for ``mean`` (the thesis' 3x3 non-zero average)."""
    if dense not in ("lsq", "robust"):
        return mask
    from evmotion.methods.flowresult import SUPPORT_MIN_EVENTS, SUPPORT_RADIUS, event_support

    return mask & event_support(events.x, events.y, mask.shape, SUPPORT_RADIUS,
                                SUPPORT_MIN_EVENTS)


def focus_checked(events: EventArray, flow: np.ndarray, mask: np.ndarray,
                  t0_us: int) -> tuple[float, np.ndarray, bool]:
    """``(gain, mask, no_focus)`` of a dense window:
    :func:`~evmotion.methods.measured.flow_alignment_gain` of the flow inside
    ``mask``, and ``mask`` all False (``no_focus`` True) when the flow does not carry the
    window's first half onto its second
    (:func:`~evmotion.methods.measured.halves_correlation` below
    :data:`~evmotion.methods.measured.MIN_HALVES_CORRELATION`, multicm's test), or moves
    the events by :data:`MIN_TESTED_SHIFT_PX` or more (median) and aligns them less than
    :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN` times better than chance (noise
    or no texture gave a flow "everywhere")."""
    if not len(events):
        return float("nan"), mask, False
    h, w = mask.shape
    x = np.clip(np.rint(events.x).astype(np.intp), 0, w - 1)
    y = np.clip(np.rint(events.y).astype(np.intp), 0, h - 1)
    on = mask[y, x]  # the events where the window has a flow
    if not on.any():
        return float("nan"), mask, False
    at = np.where(on[:, None], flow[y, x], 0)  # the flow inside the mask, at the events
    gain = alignment_gain(x, y, events.t, at, t0_us, (h, w))
    # On noise the matcher still finds triplets, slow ones, which the gain below leaves
    # untested: 76-100 % of a 320x240 noise recording's pixels were valid at ~24 px/s
    # (probe DG). Warped by such a flow the window's halves stay unrelated (correlation
    # 0.00-0.03 there; 0.65-0.97 on moving scenes' 10 and 30 ms windows).
    # (warped to the middle, as multicm does: both halves move alike)
    t_mid = (t0_us + int(events.t[-1])) // 2
    if halves_correlation(x, y, events.t, at, t_mid, (h, w)) < MIN_HALVES_CORRELATION:
        return gain, np.zeros_like(mask), True
    speed = float(np.median(np.hypot(*at[on].T)))
    shift = speed * (int(events.t[-1]) - t0_us) * 1e-6
    # a flow that moves the events by less than a few pixels over the window sharpens
    # little even when right (1.2-1.6 px: gains 0.94-1.4 for accurate flows): untested
    if shift < MIN_TESTED_SHIFT_PX or not gain < MIN_CONTRAST_GAIN:
        return gain, mask, False
    return gain, np.zeros_like(mask), True


#: The median shift (px) a window's dense flow must give its events over the window for
#: :func:`focus_checked` to test it: below, right flows sharpen too little to tell.
MIN_TESTED_SHIFT_PX = 3.0


def event_fwl(events: EventArray, flow: TripletFlow, t_ref_us: int | None = None) -> float:
    """Flow Warp Loss of per-event flow: each event moves with its own flow.

    ``x_k + v_k (t_ref - t_k)`` (events without a triplet keep zero flow); the ratio of
    the variances of the bilinear IWE and of the unwarped event image. > 1: sharper than
    the zero flow. Same definition as :func:`evmotion.eval.metrics.fwl`, which samples a
    dense field instead.

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> f = TripletFlow(np.full(3, 100.0, np.float32), np.zeros(3, np.float32),
    ...                 np.ones(3, bool), np.ones(3, np.int32))
    >>> round(event_fwl(ev, f), 2)
    3.06
    """
    from evmotion.core.iwe import accumulate

    if len(events) == 0:
        raise EmptyWindowError("FWL needs events; the window is empty")
    if len(flow) != len(events):
        raise ParameterError(f"flow has {len(flow)} entries for {len(events)} events")
    t_ref = events.t_start if t_ref_us is None else int(t_ref_us)
    dt = (np.int64(t_ref) - events.t).astype(np.float64) * 1e-6
    x = events.x.astype(np.float64)
    y = events.y.astype(np.float64)
    iwe = accumulate(x + flow.vx * dt, y + flow.vy * dt, events.sensor_size)
    base = accumulate(x, y, events.sensor_size)
    var0 = float(np.var(base))
    if var0 <= 0.0:
        raise EmptyWindowError("the zero-flow event image is constant: FWL is undefined")
    return float(np.var(iwe)) / var0
