"""Streaming triplet-matching flow (thesis ch. 5): per-event flow chunk by chunk and dense
per-window fields, in memory bounded by one window, whatever the length of the recording.

:func:`iter_flow_triplet` is the streaming counterpart of
:func:`~evmotion.methods.triplet.estimate_flow_triplet`: fed the chunks of a reader (e.g.
:func:`evmotion.io.iter_events`), it yields one :class:`TripletWindow` per window with the
same dense flow and mask as the batch function on the whole recording. :class:`TripletStream`
is the object behind it, for callers that also want every chunk's per-event flow (the
``evmotion flow --method triplet`` command writes both).

Units: pixels, microseconds for times, px/s for flow.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray, concatenate
from evmotion.methods import triplet
from evmotion.methods.bursts import BURST_GAP_US, BurstMeans
from evmotion.methods.measured import MIN_HALVES_CORRELATION, lit_not_moved
from evmotion.utils import resolve_options, whole_number

__all__ = ["DEFAULT_WINDOW_US", "LIT_BLOCK_EVENTS", "TripletOptions", "TripletStream",
           "TripletWindow", "iter_flow_triplet", "stream_chunk_events", "stream_chunks"]

# Time windows when neither a duration, a count nor explicit windows are given.
DEFAULT_WINDOW_US = 50_000
#: Events per stretch of a chunk tested for flicker (a dense window's worth): under 50-120 Hz
#: flicker the per-event flow was no better than zero flow (AEE 0.76 against 0.80), valid
#: (probe AK). Stretches of fewer than MIN_LIT_BLOCK events are not tested (too few to tell).
LIT_BLOCK_EVENTS = 30_000
MIN_LIT_BLOCK = 2_000
#: Events :func:`iter_flow_triplet` feeds its stream at a time (:func:`stream_chunks`).
STREAM_CHUNK_EVENTS = 1_000_000


@dataclass(frozen=True)
class TripletWindow:
    """One dense window of :func:`iter_flow_triplet`.

    Attributes
    ----------
    index : int
        Position in the sequence of windows (0, 1, ...).
    t0, t1 : int
        The window ``[t0, t1)`` in µs.
    flow : ndarray of float32, shape (H, W, 2), or None
        Dense flow in px/s (u right, v down); 0 outside ``valid``. None for the windows
        before ``skip`` (delimited, not computed).
    valid : ndarray of bool, shape (H, W), or None
        Pixels whose flow events support.
    n_events : int
        Events of the window (with ``dense="robust"``: burst means).
    iwe : ndarray of float64, shape (H, W), or None
        With ``with_iwe``: the image of the window's events, each warped by its own flow to
        ``t0`` (a picture of how well the per-event flow aligns the events).
    gain : float
        How much better the dense flow aligns the window's events than chance
        (:func:`~evmotion.methods.measured.flow_alignment_gain`); NaN where undefined.
    no_focus : bool
        ``gain`` below :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN` for a flow
        that moves the events by a few pixels, or a flow that does not carry the window's
        first half onto its second (:func:`~evmotion.methods.triplet.focus_checked`): it
        aligns nothing (noise, no texture), is no measurement, and ``valid`` is all False.
    early : bool
        The window's motion is slow enough that its events' triplets cannot be found
        (:func:`~evmotion.methods.triplet.early_window`): with ``dense="lsq"`` /
        ``"robust"`` events under ``d_t + tau`` of the stream on both sides (a stream
        shorter than :attr:`TripletStream.history_us`; the others read the stream
        backwards, :func:`~evmotion.methods.triplet.two_sided`), with ``"mean"`` those
        under ``2 (d_t + tau)`` from its start, whose two steps at the window's speed
        take longer than that history. Such a flow is biased (forwards only, a simulated
        translation at 30 px/s gave 2.45x, 1.24x and 1.12x in its first three 50 ms
        windows with ``"robust"``, 0.65x in the first with ``"mean"``).
    """

    index: int
    t0: int
    t1: int
    flow: np.ndarray | None
    valid: np.ndarray | None
    n_events: int
    iwe: np.ndarray | None = None
    gain: float = float("nan")
    no_focus: bool = False
    early: bool = False

    @property
    def duration_s(self) -> float:
        return (self.t1 - self.t0) * 1e-6


class _Windows:
    """Accumulates per-event flow into the sums of the current window (time, count or
    explicit windows) and closes windows as the stream passes their end."""

    def __init__(self, sensor, *, bins, window_us, window_events, edges, filter_size, dense,
                 ridge, vmax, with_iwe, skip):
        self.sensor, self.bins, self.filter_size = sensor, bins, filter_size
        self.dense, self.ridge, self.vmax = dense, ridge, vmax
        self.with_iwe, self.skip = with_iwe, skip
        # robust windows of N events count the recording's events, not the burst means
        # they are fitted to: their bounds come from the raw stream (:meth:`count_raw`)
        self.live: list[int] | None = [] if window_events and dense == "robust" else None
        self.live_end: list[int] = []
        self.by_count = None if self.live is not None else window_events
        self.count = window_events
        self.raw_n = 0
        self.raw_last: int | None = None
        self.window_us = window_us or (None if window_events or edges else DEFAULT_WINDOW_US)
        self.edges = edges
        self.index = 0
        self.t0: int | None = None if edges is None else (
            int(edges[0][0]) if len(edges[0]) else 0)
        self._new()

    def count_raw(self, t: np.ndarray) -> None:
        """The recording's events (their times, in order), for robust windows of N events:
        a window ends where its N-th event's successor starts, as a count window does.
        Time windows start at the recording's first event, as the other dense flows' do
        (robust ones had started at the first burst mean's time, probe AU)."""
        if self.t0 is None and t.size:
            self.t0 = int(t[0])
        if self.live is None or not t.size:
            return
        # the stream's events 0, N, 2N... start the windows (a bound on the time of the
        # last one is no new window: windows hold a time span), and the event before each
        # ends the window before it: windows span their own events, as count windows do
        for i in range((-self.raw_n) % self.count, t.size, self.count):
            v = int(t[i])
            if not self.live or v > self.live[-1]:
                if self.live:
                    last = int(t[i - 1]) if i else self.raw_last
                    self.live_end.append(min(last + 1, v))
                self.live.append(v)
        self.raw_n += t.size
        self.raw_last = int(t[-1])

    def _bounds(self):
        """(t0, t1) of the current time window, or None past the last explicit window."""
        if self.live is not None:
            if self.index >= len(self.live):
                return None
            return self.live[self.index], (self.live_end[self.index]
                                           if self.index < len(self.live_end)
                                           else np.iinfo(np.int64).max)
        if self.edges is None:
            return self.t0, self.t0 + self.window_us
        if self.index >= self.edges[0].size:
            return None
        return int(self.edges[0][self.index]), int(self.edges[1][self.index])

    def _new(self):
        h, w = self.sensor
        computed = self.index >= self.skip
        if self.dense == "robust" or not computed:
            self.kept = []  # the window's (events, flow): the robust fit re-weights events
        else:
            self.acc = np.zeros((self.bins, h, w, 5 if self.dense == "lsq" else 2), np.float64)
            self.cnt = np.zeros((self.bins, h, w), np.int64)
        self.iwe = np.zeros((h, w), np.float64) if self.with_iwe and computed else None
        self.seen = []  # the window's events, for the gain of its dense flow
        self.n = 0
        self.pending = []  # count windows: (events, flow) until the end time is known

    def add(self, chunk, flow):
        if not len(chunk):
            return
        if self.t0 is None:
            self.t0 = int(chunk.t[0])
        if self.by_count:
            yield from self._add_count(chunk, flow)
            return
        t = chunk.t
        start = 0
        while start < len(chunk) and (b := self._bounds()) is not None:
            t0, t1 = b
            start = max(start, int(np.searchsorted(t, t0, side="left")))
            stop = int(np.searchsorted(t, t1, side="left"))
            self._accumulate(chunk[start:stop], flow[start:stop], t0, t1)
            start = stop
            if stop < len(chunk):
                yield self._close(t0, t1)
                self.t0 = t1
                if self.live is None and self.edges is None and t[stop] >= t1 + self.window_us:
                    # a pause: the windows before the next event hold none; go to its
                    # window (a stray timestamp hours on made millions of empty ones)
                    self.t0 = t1 + (int(t[stop]) - t1) // self.window_us * self.window_us

    def _add_count(self, chunk, flow):
        # a count window spans its own events, [first, last + 1) µs (or up to the next
        # window's first event where that shares the last one's microsecond), as
        # EventArray.windows_by_count's: ended at the next window's first event, one across
        # a gap in the recording took the gap's length (probe CF)
        start = 0
        while start < len(chunk):
            if self.n == 0:
                self.t0 = int(chunk.t[start])
            take = min(self.by_count - self.n, len(chunk) - start)
            self.pending.append((chunk[start:start + take], flow[start:start + take]))
            self.n += take
            start += take
            if self.n == self.by_count:
                t1 = int(self.pending[-1][0].t[-1]) + 1
                if start < len(chunk):
                    t1 = min(t1, int(chunk.t[start]))
                yield self._close_count(t1)

    def _close_count(self, t1):
        n = self.n
        for ev, fl in self.pending:
            self._accumulate(ev, fl, self.t0, t1, count=False)
        self.n = n
        return self._close(self.t0, t1)

    def _accumulate(self, ev, fl, t0, t1, count=True):
        if not len(ev):
            return
        if count:
            self.n += len(ev)
        if self.index < self.skip:
            return
        self.seen.append(ev)
        if self.dense == "robust":
            self.kept.append((ev, fl))
        elif self.dense == "lsq":
            triplet.add_normal_voxels(ev, fl, t0, t1, self.acc, self.cnt, self.vmax)
        else:
            triplet.add_voxels(ev, fl, t0, t1, self.acc, self.cnt)
        if self.iwe is not None:
            from evmotion.core.iwe import accumulate

            dt = (ev.t - t0).astype(np.float64) * 1e-6
            self.iwe += accumulate(ev.x.astype(np.float64) - fl.vx * dt,
                                   ev.y.astype(np.float64) - fl.vy * dt, self.sensor)

    def _close(self, t0, t1):
        if self.index < self.skip:
            flow = mask = None  # delimited only: the caller has this window already
        elif self.dense == "robust" and not self.kept:
            flow = np.zeros((*self.sensor, 2), np.float32)  # no event: no flow anywhere
            mask = np.zeros(self.sensor, bool)
        elif self.dense == "robust":
            ev = concatenate([e for e, _ in self.kept], validate=False)
            fl = triplet.TripletFlow.concatenate([f for _, f in self.kept])
            flow, mask = triplet.dense_robust_fit(ev, fl, t0, t1, n_bins=self.bins,
                                                  filter_size=self.filter_size,
                                                  ridge=self.ridge, vmax=self.vmax)
        elif self.dense == "lsq":
            flow, mask = triplet.dense_lsq_from_sums(self.acc, self.cnt,
                                                     filter_size=self.filter_size,
                                                     ridge=self.ridge)
        else:
            flow, mask = triplet.dense_from_sums(self.acc, self.cnt,
                                                 filter_size=self.filter_size)
        gain, no_focus = float("nan"), False
        if flow is not None and self.seen:
            seen = concatenate(self.seen, validate=False)
            mask = triplet.supported(seen, mask, self.dense)
            gain, mask, no_focus = triplet.focus_checked(seen, flow, mask, t0)
        win = TripletWindow(self.index, int(t0), int(t1), flow, mask, self.n, self.iwe,
                            gain, no_focus)
        self.index += 1
        self._new()
        return win

    def finish(self):
        if self.live is not None:
            if self.raw_last is not None and len(self.live_end) < len(self.live):
                self.live_end.append(self.raw_last + 1)  # the end of the last window
            while self.index < len(self.live_end):
                yield self._close(self.live[self.index], self.live_end[self.index])
            return
        if self.by_count:
            if self.n:
                last = self.pending[-1][0]
                yield self._close_count(int(last.t[-1]) + 1)
            return
        if self.t0 is None:
            return
        while (b := self._bounds()) is not None:
            if self.edges is None and not self.n:
                return
            yield self._close(*b)


@dataclass(frozen=True)
class TripletOptions:
    """Tuning of :class:`TripletStream` and :func:`iter_flow_triplet` as one object
    (every field is also a keyword of them, with the same default).

    Attributes
    ----------
    n_bins : int
        Time bins per window (>= 1), as in
        :func:`~evmotion.methods.triplet.estimate_flow_triplet`.
    filter_size : int, optional
        Side of the non-zero average filter, px (odd, >= 1); default by ``dense``.
    ridge : float, optional
        Ridge of the ``lsq``/``robust`` dense fit; default by ``dense``.
    gap_us : int
        Burst gap of the ``robust`` dense output, µs (>= 1).
    dx : float, optional
        Matching distance, px; default by ``dense``.
    dt_us : int
        Largest time between the events of a triplet, µs.
    tau_us : int, optional
        Time window of the pixel history, µs; default by ``dense``.
    quadruple, depth, normal_kappa
        As in :class:`~evmotion.methods.triplet.TripletMatcher`.

    Raises
    ------
    ParameterError
        One line naming the field and the value (the matcher checks its own fields).

    Examples
    --------
    >>> TripletOptions(n_bins=2).gap_us == BURST_GAP_US
    True
    """

    n_bins: int = 1
    filter_size: int | None = None
    ridge: float | None = None
    gap_us: int = BURST_GAP_US
    dx: float | None = None
    dt_us: int = 100_000
    tau_us: int | None = None
    quadruple: bool = False
    depth: int = 8
    normal_kappa: int = triplet.NORMAL_KAPPA

    def __post_init__(self):
        if int(self.n_bins) != self.n_bins or self.n_bins < 1:
            raise ParameterError(f"n_bins must be an integer >= 1, got {self.n_bins}")
        if self.filter_size is not None:
            _check_filter_size(self.filter_size)
        if int(self.gap_us) != self.gap_us or self.gap_us < 1:
            raise ParameterError(f"gap_us must be an integer >= 1 µs, got {self.gap_us}")


def _stretches(n: int, block: int = LIT_BLOCK_EVENTS) -> list[tuple[int, int]]:
    """``[a, b)`` bounds of ``block`` events each from a chunk of ``n``'s start, the
    remainder a stretch of its own; none under :data:`MIN_LIT_BLOCK` (too few to tell).
    Chunks of a multiple of ``block`` (:func:`stream_chunks`) so cut a stream into the
    same stretches whatever their size (the stretches had been spread evenly over each
    chunk, and chunks under MIN_LIT_BLOCK not tested at all, probe DK)."""
    cuts = [*range(0, n, block), n]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b - a >= MIN_LIT_BLOCK]


def _parts(a: int, b: int, most: int) -> list[tuple[int, int]]:
    """``[a, b)`` in equal parts of at most ``most`` events."""
    cuts = np.linspace(a, b, -(-(b - a) // most) + 1).astype(np.int64)
    return [(int(c), int(d)) for c, d in zip(cuts[:-1], cuts[1:], strict=True)]


def stream_chunk_events(chunk_events: int) -> int:
    """The chunk size a stream of ``chunk_events`` is fed to :class:`TripletStream` in: the
    next multiple of :data:`LIT_BLOCK_EVENTS`, so that its flicker and noise tests judge the
    same stretches of the stream whatever ``chunk_events`` is.

    Examples
    --------
    >>> stream_chunk_events(1000), stream_chunk_events(1_000_000)
    (30000, 1020000)
    """
    return max(1, -(-int(chunk_events) // LIT_BLOCK_EVENTS)) * LIT_BLOCK_EVENTS


def stream_chunks(chunks: Iterable[EventArray], chunk_events: int) -> Iterator[EventArray]:
    """``chunks`` (in time order) as chunks of :func:`stream_chunk_events` events, the
    last one shorter; each carries the ``meta`` of the last chunk it takes events from (a
    reader's share of the file read). Empty chunks are dropped.

    Examples
    --------
    >>> ev = EventArray(x=np.zeros(70_000, int), y=np.zeros(70_000, int),
    ...                 t=np.arange(70_000), p=np.ones(70_000, int), sensor_size=(1, 1))
    >>> [len(c) for c in stream_chunks((ev[k:k + 7000] for k in range(0, 70_000, 7000)), 1)]
    [30000, 30000, 10000]
    """
    size = stream_chunk_events(chunk_events)
    held: list[EventArray] = []
    n = 0
    for chunk in chunks:
        while len(chunk):
            take = chunk[:size - n]
            held.append(take)
            n += len(take)
            chunk = chunk[len(take):]
            if n == size:
                yield _joined(held)
                held, n = [], 0
    if n:
        yield _joined(held)


def _joined(parts: list[EventArray]) -> EventArray:
    joined = parts[0] if len(parts) == 1 else concatenate(parts, validate=False)
    joined.meta = dict(parts[-1].meta)
    return joined


def _clear(flow: triplet.TripletFlow, a: int, b: int) -> None:
    """Events ``a .. b - 1`` get no flow: not valid, and zero (the normal flow too: the
    dense "lsq" windows take theirs from it)."""
    flow.valid[a:b] = False
    for part in (flow.vx, flow.vy, flow.nx, flow.ny):
        if part is not None:
            part[a:b] = 0.0


def _check_filter_size(filter_size) -> None:
    if int(filter_size) != filter_size or filter_size < 1 or filter_size % 2 == 0:
        raise ParameterError(f"filter_size must be an odd number of pixels >= 1, "
                             f"got {filter_size}")


def _check_windows(window_us, window_events, windows, skip) -> tuple | None:
    """The window arguments of :class:`TripletStream` checked; explicit ``windows`` as
    ``(starts, ends)`` arrays (None without)."""
    given = [k for k, v in (("window_us", window_us), ("window_events", window_events),
                            ("windows", windows)) if v is not None]
    if len(given) > 1:
        raise ParameterError(f"give at most one of window_us, window_events and windows, "
                             f"got {', '.join(given)}")
    if window_us is not None:
        whole_number("window_us (microseconds)", window_us, lo=1)
    if window_events is not None:
        whole_number("window_events", window_events, lo=1)
    whole_number("skip", skip, lo=0)
    if windows is None:
        return None
    # whole µs: [t0, 20000.5) had been floored (probe AU)
    raw = np.asarray(list(windows))
    if raw.size % 2 or raw.dtype.kind not in "iuf" or (raw.dtype.kind == "f" and (
            not np.isfinite(raw).all() or np.any(raw != np.round(raw)))):
        raise ParameterError(f"windows must be (t0, t1) pairs of whole microseconds, got "
                             f"{list(windows)[:3]!r}{'...' if len(raw) > 3 else ''}")
    spans = raw.astype(np.int64).reshape(-1, 2)
    if np.any(spans[:, 1] <= spans[:, 0]) or np.any(np.diff(spans[:, 0]) < 0):
        raise ParameterError("windows must be non-empty [t0, t1) µs in time order")
    return spans[:, 0], spans[:, 1]


class TripletStream:
    """Triplet-matching flow of a stream of event chunks: the per-event flow of every chunk
    (:meth:`process`) and, with ``dense``, the dense flow of each window as soon as the
    stream passes its end (:meth:`windows`; :meth:`finish` closes the last ones).

    Parameters
    ----------
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    dense : {None, "mean", "lsq", "robust"}
        The dense output (see :func:`~evmotion.methods.triplet.estimate_flow_triplet`);
        None: per-event flow only (no window is delimited or computed).
    window_us, window_events : int, optional
        Consecutive time windows of ``window_us`` µs from the first event (past a pause,
        the run of windows without events is skipped: the next window is the one on that
        grid holding the next event), or windows of ``window_events`` events; default
        time windows of :data:`DEFAULT_WINDOW_US`.
    windows : sequence of (int, int), optional
        Explicit windows ``[t0, t1)`` µs in time order (e.g. between ground-truth frames).
    with_iwe : bool
        Give each window the image of its events warped by their own flow
        (:attr:`TripletWindow.iwe`).
    skip : int
        Windows ``0 .. skip - 1`` are delimited but not computed (their ``flow`` is None):
        a caller resuming an interrupted output checks their times and carries on.
    options : TripletOptions, optional
        The matcher and dense tuning as one object; then no keyword below may be given.
    **keywords
        The fields of :class:`TripletOptions`: ``n_bins``, ``filter_size``, ``ridge``,
        ``gap_us`` (as in :func:`~evmotion.methods.triplet.estimate_flow_triplet`),
        ``dx``, ``dt_us``, ``tau_us``, ``quadruple``, ``depth``, ``normal_kappa`` (as in
        :class:`~evmotion.methods.triplet.TripletMatcher`); ``dx``, ``tau_us`` and
        ``filter_size`` default by ``dense``
        (:func:`~evmotion.methods.triplet.dense_defaults`).

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> s = TripletStream(ev.sensor_size, dense="mean", window_us=30_000)
    >>> flow = s.process(ev)
    >>> s.finish()
    >>> wins = list(s.windows())
    >>> float(flow.vx[2]), len(wins), float(wins[0].flow[5, 4, 0])
    (100.0, 1, 100.0)
    """

    def __init__(self, sensor_size: tuple[int, int], *, dense: str | None = "mean",
                 window_us: int | None = None, window_events: int | None = None,
                 windows: Sequence[tuple[int, int]] | None = None, with_iwe: bool = False,
                 skip: int = 0, options: TripletOptions | None = None, **keywords) -> None:
        o = resolve_options(TripletOptions, options, keywords, "TripletStream")
        edges = _check_windows(window_us, window_events, windows, skip)
        self.dense = dense
        dx, tau_us, filter_size = triplet.dense_defaults(dense or "mean", o.dx, o.tau_us,
                                                         o.filter_size)
        ridge = triplet.default_ridge(dense or "mean", o.ridge)
        self.matcher = self._matcher(sensor_size, dx, tau_us, o)
        self.sensor_size = self.matcher.sensor_size
        self.params = {"dx": self.matcher.dx, "dt_us": self.matcher.dt_us,
                       "tau_us": self.matcher.tau_us, "quadruple": self.matcher.quadruple,
                       "depth": self.matcher.depth, "dense": dense}
        self._bursts = self._burst_matcher = self._windows = None
        #: events whose flow was left out as lit, not moved (flicker; see :meth:`process`)
        self.lit_events = 0
        #: events whose flow was left out as unaligned: in stretches of the per-event
        #: output (``dense=None``) whose flows do not carry their first half onto their
        #: second (noise; see :meth:`process`)
        self.unaligned_events = 0
        self._start: int | None = None
        self._queue: deque = deque()
        self._held: list | None = []  # (events, flow) until the stream's start is known
        self._incomplete: tuple[int, int] | None = None
        self._finished = self._closed = False
        if dense is None:
            return
        self.params.update(n_bins=int(o.n_bins), filter_size=int(filter_size), ridge=ridge)
        _check_filter_size(filter_size)
        if dense == "robust":
            self.params["gap_us"] = int(o.gap_us)
            self._bursts = BurstMeans(self.sensor_size, int(o.gap_us))
            self._burst_matcher = self._matcher(self.sensor_size, dx, tau_us, o)
        self._windows = _Windows(
            self.sensor_size, bins=int(o.n_bins), window_us=window_us,
            window_events=window_events, edges=edges, filter_size=int(filter_size),
            dense=dense, ridge=ridge, vmax=triplet.max_normal_speed(dx, tau_us),
            with_iwe=with_iwe, skip=int(skip))

    @staticmethod
    def _matcher(sensor_size, dx, tau_us, o: TripletOptions) -> triplet.TripletMatcher:
        return triplet.TripletMatcher(sensor_size, dx, o.dt_us, tau_us, quadruple=o.quadruple,
                                      depth=o.depth, normal_kappa=o.normal_kappa)

    @property
    def overflow(self) -> int:
        """See :attr:`~evmotion.methods.triplet.TripletMatcher.overflow`."""
        return self.matcher.overflow

    def process(self, chunk: EventArray) -> triplet.TripletFlow:
        """Per-event flow of ``chunk`` (continuing the stream); the windows that the chunk
        closes come out of :meth:`windows`. Events of a stretch of the chunk lit rather
        than moved (flicker: :func:`~evmotion.methods.measured.lit_not_moved` on
        :data:`LIT_BLOCK_EVENTS` events from the chunk's start, the rest a stretch of its
        own, none tested under :data:`MIN_LIT_BLOCK`) get no flow (``valid`` False),
        counted in :attr:`lit_events`; without ``dense``, so do the events with a flow of
        a part of a stretch (at most two events a pixel) whose flows do not carry its
        first half onto its second (:func:`~evmotion.methods.triplet.event_flow_consistency`
        below :data:`~evmotion.methods.measured.MIN_HALVES_CORRELATION`: noise), counted in
        :attr:`unaligned_events`. Chunks of a multiple of ``LIT_BLOCK_EVENTS``
        (:func:`stream_chunks`) give the same result whatever their size."""
        if self._start is None and len(chunk):
            self._start = int(chunk.t[0])
            if self.dense == "mean":
                # the thesis' mean is not read backwards: its windows wait for nothing
                self._held = None
                self._incomplete = (self._start, self._start + self.history_us)
        flow = self.matcher.process(chunk)
        self._mask_lit(chunk, flow)
        if self._windows is None:
            self._mask_unaligned(chunk, flow)
        else:
            self._windows.count_raw(chunk.t)
            if self._bursts is not None:
                b = self._bursts.process(chunk)
                self._hold(b, self._burst_matcher.process(b))
            else:
                self._hold(chunk, flow)
        return flow

    def _hold(self, ev: EventArray, flow: triplet.TripletFlow) -> None:
        # the dense windows wait until the stream has run 2 history_us past its start: the
        # events of its first history_us then take the flow of the reversed stream
        # (triplet.two_sided), as the batch function's do
        if self._held is None:
            self._queue.append((ev, flow))
            return
        self._held.append((ev, flow))
        if len(ev) and int(ev.t[-1]) >= self._start + 2 * self.history_us:
            self._release()

    def _release(self) -> None:
        held, self._held = self._held, None
        parts = [(e, f) for e, f in held if len(e)]
        if not parts:
            return
        ev = concatenate([e for e, _ in parts], validate=False)
        fl = triplet.TripletFlow.concatenate([f for _, f in parts])
        m = self._burst_matcher if self._bursts is not None else self.matcher
        fl, self._incomplete = triplet.two_sided(ev, fl, m, self._start)
        start = 0
        for e, _ in parts:
            self._queue.append((e, fl[start:start + len(e)]))
            start += len(e)

    def _mask_lit(self, chunk: EventArray, flow: triplet.TripletFlow) -> None:
        for a, b in _stretches(len(chunk)):
            if lit_not_moved(chunk[a:b]) is not None:
                _clear(flow, a, b)
                self.lit_events += b - a

    def _mask_unaligned(self, chunk: EventArray, flow: triplet.TripletFlow) -> None:
        # The per-event output's own noise test (the dense windows have theirs,
        # triplet.focus_checked): on noise the matcher finds slow triplets, random ones,
        # that left 76 % of a noise recording's events with a flow (probe DG). Stretches
        # of at most two events a pixel (denser noise lines up more: 0.13-0.26 on 80x60
        # at seven a pixel, 0.12 at most at two)
        h, w = self.sensor_size
        for a, b in (part for stretch in _stretches(len(chunk))
                     for part in _parts(*stretch, 2 * h * w)):
            part = flow[a:b]
            valid = int(np.count_nonzero(part.valid))
            if valid >= MIN_LIT_BLOCK // 2 and triplet.event_flow_consistency(
                    chunk[a:b], part) < MIN_HALVES_CORRELATION:
                _clear(flow, a, b)
                self.unaligned_events += valid

    def finish(self) -> None:
        """End of the stream: :meth:`windows` then gives the windows still open."""
        if self._windows is not None and not self._finished:
            if self._bursts is not None:
                b = self._bursts.flush()
                self._hold(b, self._burst_matcher.process(b))
            if self._held is not None:
                self._release()
            self._finished = True

    def windows(self) -> Iterator[TripletWindow]:
        """The dense windows closed by the chunks processed so far (all of them after
        :meth:`finish`), each computed when it is asked for: consume the iterator before
        the next :meth:`process`. Empty without ``dense``."""
        if self._windows is None:
            return
        while self._queue:
            ev, fl = self._queue.popleft()
            yield from map(self._marked, self._windows.add(ev, fl))
        if self._finished and not self._closed:
            self._closed = True
            yield from map(self._marked, self._windows.finish())

    @property
    def history_us(self) -> int:
        """:func:`~evmotion.methods.triplet.history_us` of the matcher: ``2 (d_t + tau)``."""
        return triplet.history_us(self.matcher.dt_us, self.matcher.tau_us)

    def _marked(self, win: TripletWindow) -> TripletWindow:
        early = triplet.early_window(win.t0, win.t1, self._incomplete, win.flow, win.valid,
                                     self.matcher, self._start, forwards=self.dense == "mean")
        return dataclasses.replace(win, early=True) if early else win


def iter_flow_triplet(chunks: Iterable[EventArray], *, dense: str = "mean",
                      **kwargs) -> Iterator[TripletWindow]:
    """Dense triplet-matching flow of a stream of event chunks, window by window.

    The streaming counterpart of :func:`~evmotion.methods.triplet.estimate_flow_triplet`:
    each window's flow and mask equal the batch function's on the whole recording with the
    same windows, while memory stays bounded by one window (a chunk reader such as
    :func:`evmotion.io.iter_events` never holds the file).

    Parameters
    ----------
    chunks : iterable of EventArray, or EventArray
        The recording in time order, in chunks of any size (all of one sensor size), or
        whole.
    dense : {"mean", "lsq", "robust"}
        The dense output (see :func:`~evmotion.methods.triplet.estimate_flow_triplet`).
    **kwargs
        The windows, ``options`` and option keywords of :class:`TripletStream`.

    Yields
    ------
    TripletWindow
        ``(index, t0, t1, flow, valid, n_events)`` of each window, in order.

    Examples
    --------
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> wins = list(iter_flow_triplet([ev[:2], ev[2:]], window_us=30_000))
    >>> [(w.t0, w.t1) for w in wins], float(wins[0].flow[5, 4, 0])
    ([(0, 30000)], 100.0)
    """
    if dense not in triplet.DENSE_KINDS:
        raise ParameterError(f"dense must be one of {triplet.DENSE_KINDS}, got {dense!r}")
    if isinstance(chunks, EventArray):  # the whole recording, one chunk
        chunks = [chunks]
    stream = None
    for chunk in stream_chunks(chunks, STREAM_CHUNK_EVENTS):
        if stream is None:
            stream = TripletStream(chunk.sensor_size, dense=dense, **kwargs)
        stream.process(chunk)
        yield from stream.windows()
    if stream is None:
        raise EmptyWindowError("no events to estimate the triplet flow of")
    stream.finish()
    yield from stream.windows()
